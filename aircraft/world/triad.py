"""The world of the live triad aircraft (truth; :class:`aircraft.triad_core.TriadAircraftCore` is its
navigator): the scenario's physical coordinates taken as the ENU frame :class:`nav.constellation.EnuFrame`
at a geodetic origin, the 6-DOF motion of ``[aircraft.trajectory]`` in it, the GPS-like almanac's sky
(:mod:`aircraft.world.sky`, almanac time = fleet time), the receiver clock of the scenario, the IMU
(fixed, separately seeded blocks), the baro (Gauss-Markov bias, :mod:`aircraft.world.baro`), the
geodetic survey of the tie stations, and the station radio channel in that frame.

Every draw has its own generator keyed by the world seed and the block, epoch or (station, broadcast
seq), so that the same world replays whatever the navigator does: ``key + [1]`` the IMU blocks, ``[2]``
the tie survey, ``[3]`` the baro bias at the start, ``[4, k]`` epoch ``k``'s satellite noise, ``[5, k]``
its baro, ``[6, station, seq]`` a broadcast's timing noise.
"""

from __future__ import annotations

import numpy as np

from nav.constellation import EnuFrame, gps_like, satellite_elevation_deg
from net.radio import reception_sigma_m

from . import baro as wbaro
from . import radio, sky
from .field import Field
from .imu import ImuBlocks, ImuEmulator


class TriadWorld:
    """The truth side of one live triad aircraft (module doc). ``epoch_s``: the satellite and baro
    epoch; ``visible``: the satellites above ``mask_deg`` at the start, highest first;
    ``tie_surveyed_m`` (3, 3): the first three stations' geodetic survey (what a receiver's database
    holds, with ``sigma_tie_m`` errors)."""

    def __init__(self, sc, world, key: list[int], frame: EnuFrame, motion, pre, block: int, t0_s: float,
                 epoch_s: float, net_clock, sigma_sat_m: float, mask_deg: float, baro: wbaro.BaroModel,
                 sigma_tie_m) -> None:
        self.cfg, self.net_clock, self.key = world, net_clock, list(key)  # aircraft.config.AircraftWorldConfig
        self.field = Field.from_scenario(sc)
        self.frame, self.alm, self.motion = frame, gps_like(), motion
        self.t0_s, self.epoch_s = float(t0_s), float(epoch_s)
        self.sigma_sat_m, self.mask_deg = float(sigma_sat_m), float(mask_deg)
        self.imu = ImuEmulator(pre, 1, np.random.default_rng(self.key + [1]))
        self.imu_blocks = ImuBlocks(self.imu, self.motion, self.key + [1], block)
        p0 = self.position(self.t0_s)
        s0 = self.frame.from_ecef(self.alm.ecef(float(t0_s))[0])
        el0 = satellite_elevation_deg(s0, p0[None, :])
        vis = np.flatnonzero(el0 >= self.mask_deg)
        self.visible = vis[np.argsort(-el0[vis])]
        true_l = self.to_local(self.field.stations_n[:3])
        rng_s = np.random.default_rng(self.key + [2])
        self.tie_surveyed_m = true_l + np.asarray(sigma_tie_m, float) * rng_s.standard_normal((3, 3))
        self.baro_model = baro
        self._baro_b = float(np.random.default_rng(self.key + [3]).normal(0.0, baro.sigma_bias_m))
        self._baro_t = float(t0_s)

    def to_local(self, p_n: np.ndarray) -> np.ndarray:
        """Network-frame points (..., 3) -> the physical (Earth-tied) frame."""
        return np.asarray(p_n, float) @ self.field.R + self.field.t

    def truth_n(self, t_s: float):
        """True position, velocity, attitude in the Earth-tied frame at fleet time ``t_s``."""
        p, v, _ = self.motion.pva(np.array([t_s - self.t0_s]))
        return p[0], v[0], self.motion.attitude(np.array([t_s - self.t0_s]))[0]

    def position(self, t_s: float) -> np.ndarray:
        """True position (3,) in the Earth-tied frame at fleet time ``t_s`` (no attitude)."""
        return self.motion.pva(np.array([t_s - self.t0_s]))[0][0]

    def imu_sample(self, k: int, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """IMU step ``k``: (gyro, accel) increments (1, 3) each."""
        return self.imu_blocks.sample(k, dt_s)

    def sky(self, k: int, ids: np.ndarray) -> np.ndarray:
        """Pseudoranges (len(ids),) of epoch ``k`` (NaN below the mask), on the receiver clock."""
        t = self.t0_s + k * self.epoch_s
        _, r, el, t_tx = sky.satellites_seen(self.alm, self.frame, self.position(t)[None], np.array([t]), ids)
        rng = np.random.default_rng(self.key + [4, k])
        rho = (sky.clean_pseudorange_m(self.alm, ids, r[0], el[0], t_tx[0]) + float(self.cfg.clock.bias_m(t))
               + self.sigma_sat_m * rng.standard_normal(ids.size))
        return np.where(el[0] >= self.mask_deg, rho, np.nan)

    def baro(self, k: int) -> float:
        """The baro altitude of epoch ``k`` (its bias walks from the previous call's epoch)."""
        t = self.t0_s + k * self.epoch_s
        m = self.baro_model
        a = np.exp(-(t - self._baro_t) / m.tc_s)
        rng = np.random.default_rng(self.key + [5, k])
        self._baro_b = a * self._baro_b + m.sigma_bias_m * np.sqrt(1.0 - a * a) * rng.standard_normal()
        self._baro_t = t
        return float(self.position(t)[2] + self.frame.h_m + self._baro_b + m.sigma_m * rng.standard_normal())

    def measure(self, phy: dict, msg: dict) -> tuple[float, float, float] | None:
        """A station broadcast's pseudorange on the receiver clock: (true reception time, pseudorange,
        one-way timing sigma in m), ``None`` where ``[radio]`` has no link; the light time from the
        sender's true position and transmit time, the broadcast clock correction's residual
        (:func:`net.nettime.pseudorange_time_error_s`), the noise from the generator of (station, seq)."""
        p_tx = self.to_local(np.asarray(phy["pos_m"], float))
        t_tx = float(phy["t_true_s"])
        t_rx, p_rx = radio.heard(self.position, p_tx, t_tx)
        # the radio's parameters are in the network frame: the receiver back there (p_n = R (p - t))
        sigma = reception_sigma_m(np.asarray(phy["pos_m"], float), (p_rx - self.field.t) @ self.field.R.T,
                                  self.cfg.radio, self.cfg.sigma_m)
        if sigma is None:
            return None
        rng = np.random.default_rng(self.key + [6, sum(map(ord, str(msg.get("src")))), int(msg.get("seq", 0))])
        rho = radio.pseudorange_m(p_rx, p_tx, t_tx, t_rx, msg, self.cfg.clock, self.net_clock) \
            + sigma * float(rng.standard_normal())
        return t_rx, rho, sigma
