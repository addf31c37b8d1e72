"""Seed 003's INS aiding through fictitious station positions (eqs. 8-12), as the paper has it.

* Eq. (8): ``r(t_i) = r0 + v0 (t_i - t0) + S(t_i)`` with ``S(t) = int_{t0}^{t} int_{t0}^{s} a`` the
  double integral of the INS acceleration. Eq. (10): fictitious stations ``p~_i = p_i - S(t_i)``, so
  eq. (11) ``|r0 + v0 (t_i - t0) - p~_i|`` has the uniform-motion form of eq. (5) for any motion:
  :func:`double_integral`, :func:`fictitious_stations`.
* Eq. (12): a constant-velocity Kalman filter on the reduced state ``[rho, rho']`` (``rho = r - S``),
  step = one working cycle ``T``, discrete white-noise acceleration (DWNA, Bar-Shalom) with the
  accelerometer's ``sigma_a = 0.015 m/s^2`` per axis, the primary fix's position as the measurement
  and the one-cycle CRLB (eqs. 1-7, :func:`nav.pcrb.fisher_cycle`) as its covariance ``R``. Only the
  covariance recursion matters for the paper's Figs 6-7: :func:`covariance_curves`.
"""

from __future__ import annotations

import numpy as np

from nav.kalman import kf_predict, kf_update
from nav.pcrb import crlb_cycle, fisher_cycle

SIGMA_A_M_S2 = 0.015  # seed 003: ADIS16480 rms acceleration noise, 1.5 mg


def double_integral(acc_m_s2: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Velocity increment ``int a`` and double integral ``S`` (K+1, 3) from samples ``a`` (K+1, 3) at
    ``t0 + k dt`` (trapezoid on the acceleration, then on the velocity increment: exact for
    piecewise-linear ``a`` up to O(dt^3) per step)."""
    a = np.asarray(acc_m_s2, dtype=float)
    dv = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (a[1:] + a[:-1]) * dt_s, axis=0)])
    # position increment per step with linear a: v dt + (2 a0 + a1) dt^2 / 6
    dS = dv[:-1] * dt_s + (2.0 * a[:-1] + a[1:]) * dt_s**2 / 6.0
    S = np.concatenate([np.zeros((1, 3)), np.cumsum(dS, axis=0)])
    return dv, S


def fictitious_stations(stations_m: np.ndarray, S_m: np.ndarray) -> np.ndarray:
    """Eq. (10): ``p~_i = p_i - S(t_i)``; stations (..., 3), S (..., 3)."""
    return np.asarray(stations_m, dtype=float) - np.asarray(S_m, dtype=float)


def dwna(T_s: float, sigma_a: float) -> tuple[np.ndarray, np.ndarray]:
    """CV transition and DWNA process noise (6, 6) for the state ``[x y z vx vy vz]``."""
    F = np.eye(6)
    F[0:3, 3:6] = T_s * np.eye(3)
    g = np.array([T_s**2 / 2.0, T_s])
    q = sigma_a**2 * np.outer(g, g)
    Q = np.zeros((6, 6))
    for i in range(3):
        Q[np.ix_([i, i + 3], [i, i + 3])] = q
    return F, Q


def cycle_crlb(pos_m: np.ndarray, vel_m_s: np.ndarray, stations_m: np.ndarray, slot_s: float,
               sigma_m: float) -> np.ndarray:
    """One-cycle CRLB position block ``[J^-1]_rr`` (K, 3, 3) at cycle-start positions (K, 3) with
    velocities (K, 3) (seed 003 eqs. 1, 7: position and velocity estimated, synchronized clock)."""
    t_rel = np.arange(len(stations_m)) * slot_s
    J = fisher_cycle(pos_m, vel_m_s, stations_m, t_rel, sigma_m, clock=False, velocity=True)
    return crlb_cycle(J)["cov"]


def covariance_curves(R_seq: np.ndarray, T_s: float, sigma_a: float = SIGMA_A_M_S2,
                      sigma_v0_m_s: float = 5.0) -> np.ndarray:
    """Eq. (12) covariance recursion with position measurements of covariance ``R_seq`` (K, 3, 3);
    ``P0`` = the first fix (``R_0``, velocity ``sigma_v0``). Returns the posterior ``P`` (K, 6, 6)."""
    F, Q = dwna(T_s, sigma_a)
    H = np.hstack([np.eye(3), np.zeros((3, 3))])
    P = np.zeros((6, 6))
    P[:3, :3] = R_seq[0]
    P[3:, 3:] = sigma_v0_m_s**2 * np.eye(3)
    x = np.zeros(6)
    out = np.empty((len(R_seq), 6, 6))
    out[0] = P
    for k in range(1, len(R_seq)):
        x, P = kf_predict(x, P, F, Q)
        x, P, _, _ = kf_update(x, P, np.zeros(3), H, R_seq[k])
        out[k] = P
    return out
