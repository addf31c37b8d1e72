"""The station radio channel of the world (truth): a nav broadcast heard by the aircraft.

One implementation for the radio, INS and triad live cores. A broadcast sent from ``p_tx`` at the
true time ``t_tx`` reaches the aircraft at the true time ``t_rx = t_tx + |p(t_rx) - p_tx| / c``
(fixed point from ``t_rx = t_tx``; two steps leave nanometres at aircraft speeds), and the receiver
reads it as the pseudorange

    rho = |p(t_rx) - p_tx| + c (t_rx_ac - T_tx) = |p(t_rx) - p_tx| + c dt + b(t_rx),

``dt`` the residual of the station's broadcast clock correction and the network time
(:func:`net.nettime.pseudorange_time_error_s`), ``b`` the receiver clock of the scenario; the timing
noise (the link's, :func:`net.radio.reception_sigma_m`) is the caller's draw.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from nav.geometry import SPEED_OF_LIGHT_M_S
from net.nettime import pseudorange_time_error_s

LIGHT_TIME_STEPS = 2


def _norm(d: np.ndarray) -> float:
    """``|d|`` of one vector (3,) (float64): ``numpy.linalg.norm``'s own ``sqrt(d . d)``."""
    return math.sqrt(d.dot(d))


def heard(position_at: Callable[[float], np.ndarray], p_tx_m: np.ndarray, t_tx_s: float) -> tuple[float, np.ndarray]:
    """The true reception time of a broadcast sent from ``p_tx_m`` (3,) at ``t_tx_s`` by a receiver whose
    true position at a time is ``position_at(t)`` (3,), and that position (module doc)."""
    t_rx = t_tx_s
    for _ in range(LIGHT_TIME_STEPS):
        t_rx = t_tx_s + _norm(position_at(t_rx) - p_tx_m) / SPEED_OF_LIGHT_M_S
    return t_rx, position_at(t_rx)


def pseudorange_m(p_rx_m: np.ndarray, p_tx_m: np.ndarray, t_tx_s: float, t_rx_s: float, msg: dict | None,
                  clock, net_clock) -> float:
    """The noise-free pseudorange (m) of a broadcast ``msg`` heard at ``(t_rx_s, p_rx_m)`` (module doc);
    ``clock`` the receiver clock (``bias_m(t)``), ``net_clock`` the receiver's network-time error."""
    return _norm(p_rx_m - p_tx_m) \
        + SPEED_OF_LIGHT_M_S * pseudorange_time_error_s(msg, t_tx_s, t_rx_s, net_clock) \
        + float(clock.bias_m(t_rx_s))
