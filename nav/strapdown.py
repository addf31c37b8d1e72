"""Strapdown inertial mechanization in a local Cartesian navigation frame (pure math, vectorized).

The navigation frame ``n`` is the LARNS network frame: a Cartesian frame fixed to the ground
(seed 000 constraints (1)). Over a field of tens of kilometres the mechanization treats it as
inertial with uniform gravity ``g_n`` (a flat, non-rotating Earth; the world side emulates the same
physics, see docs/ins.md for what this neglects). The network frame is *not* level: ``g_n`` is not
along ``-Z``; who supplies it is the navigator's business (:mod:`nav.errorstate` estimates its tilt).

Inputs are IMU increments over ``[t_{k-1}, t_k]``: ``dtheta = int w_b dt`` (rad) and
``dv = int f_b dt`` (m/s), body frame, as integrating IMUs deliver them (ADIS16480 delta-angle and
delta-velocity outputs). One step (Savage's two-sample algorithms, ``dt`` fixed):

* attitude: ``phi = dtheta_k + dtheta_{k-1} x dtheta_k / 12`` (coning), ``C_k = C_{k-1} exp([phi x])``;
* velocity: ``dv_rot = dv_k + dtheta_k x dv_k / 2`` (rotation) ``+ (dtheta_{k-1} x dv_k + dv_{k-1} x dtheta_k) / 12``
  (sculling), ``v_k = v_{k-1} + C_{k-1} dv_rot + g_n dt``;
* position: ``p_k = p_{k-1} + (v_{k-1} + v_k) dt / 2`` (exact for piecewise-constant acceleration).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .rotations import exp_so3

G0_M_S2 = 9.80665  # standard gravity


_I1 = np.array([1, 2, 0])
_I2 = np.array([2, 0, 1])


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product over the last axis (cheaper than np.cross for small batches)."""
    return a[..., _I1] * b[..., _I2] - a[..., _I2] * b[..., _I1]


@dataclass
class NavState:
    """Nominal strapdown state, leading axes (...,) for runs: ``p_m`` (..., 3), ``v_m_s`` (..., 3),
    ``C_nb`` (..., 3, 3) body-to-navigation DCM, ``t_s`` time of the state."""

    p_m: np.ndarray
    v_m_s: np.ndarray
    C_nb: np.ndarray
    t_s: float = 0.0

    def copy(self) -> "NavState":
        return NavState(self.p_m.copy(), self.v_m_s.copy(), self.C_nb.copy(), self.t_s)


def coning_sculling(dth_prev, dv_prev, dth, dv):
    """Two-sample coning-corrected rotation vector and sculling/rotation-corrected velocity increment.

    All arguments (..., 3) in the body frame. Returns ``phi`` (..., 3), ``dv_body`` (..., 3) expressed
    in the body frame at the *start* of the interval.
    """
    x = _cross(np.stack([dth_prev, dth, dth_prev, dv_prev]), np.stack([dth, dv, dv, dth]))
    phi = dth + x[0] / 12.0
    dvr = dv + 0.5 * x[1] + (x[2] + x[3]) / 12.0
    return phi, dvr


def step(s: NavState, dth, dv, dth_prev, dv_prev, g_n_m_s2, dt_s: float) -> NavState:
    """One mechanization step from ``s`` over ``dt_s`` with increments (..., 3); ``g_n_m_s2`` (..., 3).

    Returns the new state (new arrays); also available as :func:`step_arrays` for the hot loop.
    """
    p, v, C = step_arrays(s.p_m, s.v_m_s, s.C_nb, dth, dv, dth_prev, dv_prev, g_n_m_s2, dt_s)
    return NavState(p, v, C, s.t_s + dt_s)


def step_arrays(p, v, C, dth, dv, dth_prev, dv_prev, g_n, dt_s):
    """Array form of :func:`step`: returns ``p, v, C`` (new arrays)."""
    phi, dvr = coning_sculling(dth_prev, dv_prev, dth, dv)
    dv_n = np.einsum("...ij,...j->...i", C, dvr)
    v_new = v + dv_n + g_n * dt_s
    p_new = p + 0.5 * (v + v_new) * dt_s
    C_new = C @ exp_so3(phi)
    return p_new, v_new, C_new


def run(s: NavState, dth: np.ndarray, dv: np.ndarray, g_n_m_s2, dt_s: float,
        dth_prev=None, dv_prev=None) -> NavState:
    """Integrate a sequence of increments ``dth``/``dv`` (K, ..., 3) from ``s``; returns the final state."""
    dth_prev = np.zeros_like(dth[0]) if dth_prev is None else dth_prev
    dv_prev = np.zeros_like(dv[0]) if dv_prev is None else dv_prev
    p, v, C = s.p_m, s.v_m_s, s.C_nb
    for k in range(dth.shape[0]):
        p, v, C = step_arrays(p, v, C, dth[k], dv[k], dth_prev, dv_prev, g_n_m_s2, dt_s)
        dth_prev, dv_prev = dth[k], dv[k]
    return NavState(p, v, C, s.t_s + dth.shape[0] * dt_s)
