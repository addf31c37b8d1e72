"""The field's physical geometry (world side): the level frame ``L`` of the scenario's physical
coordinates, the network frame ``n`` the stations build (``p_n = R (p_L - t)``), and the truth of an
aircraft flying a :class:`aircraft.world.motion.Motion` expressed in the network frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nav.geometry import SPEED_OF_LIGHT_M_S, to_network_frame

from .motion import G_L, Motion


@dataclass
class Field:
    """``R`` (3, 3), ``t`` (3,) level-to-network transform; ``stations_n`` (m, 3) true positions."""

    R: np.ndarray
    t: np.ndarray
    stations_n: np.ndarray

    @classmethod
    def from_scenario(cls, sc) -> "Field":
        """From a loaded :class:`net.scenario.Scenario` with explicit ``[[stations]]``."""
        st = sorted(sc.raw["stations"], key=lambda s: int(s["id"]))
        phys = np.array([[float(v) for v in s["pos_m"]] for s in st])
        ids = [int(s["id"]) for s in st]
        zi = ids.index(sc.z_ref) if sc.z_ref in ids else 3
        pos, R, t = to_network_frame(phys, z_ref=zi)
        return cls(R, t, pos)

    @property
    def g_n(self) -> np.ndarray:
        return self.R @ G_L

    @property
    def up_n(self) -> np.ndarray:
        """Physical up in the network frame."""
        return self.R[:, 2]

    def truth(self, motion: Motion, t_s: np.ndarray):
        """Position, velocity (T, 3) and attitude ``C_nb`` (T, 3, 3) in the network frame."""
        p, v, _ = motion.pva(t_s)
        return (p - self.t) @ self.R.T, v @ self.R.T, self.R @ motion.attitude(t_s)

    def reception(self, motion: Motion, t_tx_s: np.ndarray, station_idx: np.ndarray):
        """Reception times (K,) and true ranges (K,) of transmissions at ``t_tx`` from stations
        ``station_idx`` (two fixed-point passes of ``t_rx = t_tx + |p(t_rx) - s| / c``)."""
        s = self.stations_n[station_idx]
        t_rx = np.asarray(t_tx_s, dtype=float)
        for _ in range(2):
            p = (motion.pva(t_rx)[0] - self.t) @ self.R.T
            r = np.linalg.norm(p - s, axis=-1)
            t_rx = t_tx_s + r / SPEED_OF_LIGHT_M_S
        p = (motion.pva(t_rx)[0] - self.t) @ self.R.T
        return t_rx, np.linalg.norm(p - s, axis=-1)
