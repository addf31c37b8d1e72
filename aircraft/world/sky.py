"""The satellite sky of the world (truth): where the satellites are when the receiver hears them, and
the pseudorange they give before the receiver clock and the noise.

One model for the triad's Monte Carlo (:mod:`aircraft.montecarlo.triad`) and its live core
(:mod:`aircraft.world.triad`): a satellite ``i`` heard at ``t`` by a receiver at ``p`` transmitted at
``t_tx = t - |p - s_i(t_tx)| / c`` (three fixed-point steps: satellites move ~3 km/s, the light time is
~70 ms, the third step changes the range by micrometres); its pseudorange is

    rho_i = |p - s_i(t_tx)| + tropo(el_i) - c (af0_i + af1_i t_tx) + b(t) + n_i,

the troposphere of :func:`nav.constellation.tropo_delay_m` and the satellite clock of the almanac; the
receiver clock ``b`` and the noise ``n`` are the caller's (each draws them its own way).
"""

from __future__ import annotations

import numpy as np

from nav.constellation import Almanac, EnuFrame, satellite_elevation_deg, tropo_delay_m
from nav.geometry import SPEED_OF_LIGHT_M_S

LIGHT_TIME_STEPS = 3


def satellites_seen(alm: Almanac, frame: EnuFrame, p_m: np.ndarray, t_s: np.ndarray, ids: np.ndarray):
    """Satellites ``ids`` (N,) heard at times ``t_s`` (K,) by a receiver at ``p_m`` (K, 3) (local frame).

    Returns their local positions at transmission (K, N, 3), the geometric ranges (K, N), the elevations
    (K, N) in degrees and the transmission times (K, N)."""
    p = np.asarray(p_m, float)
    t = np.asarray(t_s, float)
    ids = np.asarray(ids)
    t_tx = np.repeat(t[:, None], ids.size, axis=1)
    for _ in range(LIGHT_TIME_STEPS):
        e, _ = alm.ecef(t_tx)  # (K, N, N_all, 3)
        s = frame.from_ecef(np.take_along_axis(e, ids[None, :, None, None], axis=2)[:, :, 0])
        r = np.linalg.norm(p[:, None, :] - s, axis=-1)
        t_tx = t[:, None] - r / SPEED_OF_LIGHT_M_S
    return s, r, satellite_elevation_deg(s, p[:, None, :]), t_tx


def clean_pseudorange_m(alm: Almanac, ids: np.ndarray, r_m: np.ndarray, el_deg: np.ndarray,
                        t_tx_s: np.ndarray) -> np.ndarray:
    """The pseudoranges (K, N) of :func:`satellites_seen`'s satellites before the receiver clock and
    noise: range plus troposphere minus the satellite clock at transmission (module doc)."""
    ids = np.asarray(ids)
    return r_m + tropo_delay_m(el_deg) - SPEED_OF_LIGHT_M_S * (alm.af0_s[ids] + alm.af1[ids] * t_tx_s)
