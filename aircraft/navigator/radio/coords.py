"""Inverse-range filter coordinates for the aircraft trackers (pure, vectorized over leading axes).

A small-base system sees the direction to the aircraft well and its range (far field) or height
(overhead) poorly; with a pseudorange the weak coordinate is also nearly collinear with the clock.
In Cartesian coordinates the set of states that fit the measurements is then a *curved* ridge (range +
clock = const, height + clock = const), and an EKF/UKF that stores a Gaussian on it drifts along it
(measured overhead at 300 m: +48 m of mean height error after 20 s; docs/aircraft.md). Inverting the
position through the unit sphere about a reference point ``c`` (the broadcast station centroid)

    q = L^2 (p - c) / |p - c|^2,      p = c + L^2 q / |q|^2,

and carrying the clock as ``beta = b + |p - c|`` makes that ridge nearly straight: with ``w = |q|``
the inverse range, ``|p - s_j| - |p - c| = -u.d_j + w (|d_j|^2 - (u.d_j)^2) / 2 + O(w^2)``
(``u`` the direction, ``d_j = s_j - c``) is linear in ``w`` along a fixed direction and the clock
enters linearly. This is the Cartesian counterpart of the modified-spherical / inverse-depth
coordinates of bearings-only tracking and monocular SLAM, without the zenith and horizon
singularities of angles (the inversion is smooth everywhere except at ``c``).

State layouts follow :class:`aircraft.navigator.radio.models.StateLayout`: ``[q (3), v (3) (, beta (, bdot))]`` in
place of ``[p, v (, b (, bdot))]``; velocity and clock rate stay Cartesian. The length ``L``
(:data:`SCALE_M`) only keeps ``q`` in metres-like magnitudes (``L^2 / r``), so that covariances mixing
it with velocity and clock stay well conditioned.
"""

from __future__ import annotations

import numpy as np

from .state import CLOCK, POS

SCALE_M = 1000.0  # L: q = L^2 (p - c) / |p - c|^2 has |q| = L^2 / r (20 km at 50 m, 333 m at 3 km)


def reference_point(stations_m: np.ndarray) -> np.ndarray:
    """Reference point of the inversion for a set of (broadcast) station positions (m, 3): their
    centroid. In the station plane, so that right above the array the height/clock ridge is
    straight (``|p - s_j| - |p - c| = R0^2 w / 2 + O(w^3)`` with ``w = 1/h``); a point below the plane
    would bend it (``R0^2 w / (2 (1 - D w))``)."""
    return np.asarray(stations_m, dtype=float).reshape(-1, 3).mean(axis=0)


def array_radius(stations_m: np.ndarray) -> float:
    """RMS distance (m) of the stations (m, 3) from their centroid."""
    st = np.asarray(stations_m, dtype=float).reshape(-1, 3)
    return float(np.sqrt(np.mean(np.sum((st - st.mean(axis=0)) ** 2, axis=1))))


def _householder(a: np.ndarray) -> np.ndarray:
    """``I - 2 a a^T / |a|^2`` over leading axes; a (..., 3) -> (..., 3, 3)."""
    a2 = np.einsum("...i,...i->...", a, a)
    return np.eye(3) - 2.0 * a[..., :, None] * a[..., None, :] / a2[..., None, None]


def to_inverse(x: np.ndarray, ref_m: np.ndarray, clock: bool) -> np.ndarray:
    """Cartesian state (..., n) -> inverse-range state (..., n)."""
    d = x[..., POS] - ref_m
    r2 = np.einsum("...i,...i->...", d, d)
    s = np.array(x, dtype=float, copy=True)
    s[..., POS] = d * (SCALE_M**2 / r2)[..., None]
    if clock:
        s[..., CLOCK] = x[..., CLOCK] + np.sqrt(r2)
    return s


def to_cartesian(s: np.ndarray, ref_m: np.ndarray, clock: bool) -> np.ndarray:
    """Inverse-range state (..., n) -> Cartesian state (..., n)."""
    q = s[..., POS]
    w2 = np.einsum("...i,...i->...", q, q)
    x = np.array(s, dtype=float, copy=True)
    x[..., POS] = ref_m + q * (SCALE_M**2 / w2)[..., None]
    if clock:
        x[..., CLOCK] = s[..., CLOCK] - SCALE_M**2 / np.sqrt(w2)
    return x


def jac_to_cartesian(s: np.ndarray, clock: bool) -> np.ndarray:
    """``T = dx/ds`` (..., n, n): ``dp/dq = L^2 (I - 2 q q^T / |q|^2) / |q|^2``, ``db/dq = L^2 q / |q|^3``."""
    n = s.shape[-1]
    q = s[..., POS]
    w2 = np.einsum("...i,...i->...", q, q)
    T = np.broadcast_to(np.eye(n), s.shape[:-1] + (n, n)).copy()
    T[..., POS, POS] = _householder(q) * (SCALE_M**2 / w2)[..., None, None]
    if clock:
        T[..., CLOCK, POS] = q * (SCALE_M**2 / (w2 * np.sqrt(w2)))[..., None]
    return T


def jac_to_inverse(x: np.ndarray, ref_m: np.ndarray, clock: bool) -> np.ndarray:
    """``G = ds/dx`` (..., n, n): ``dq/dp = L^2 (I - 2 d d^T / r^2) / r^2``, ``dbeta/dp = d / r``."""
    n = x.shape[-1]
    d = x[..., POS] - ref_m
    r2 = np.einsum("...i,...i->...", d, d)
    G = np.broadcast_to(np.eye(n), x.shape[:-1] + (n, n)).copy()
    G[..., POS, POS] = _householder(d) * (SCALE_M**2 / r2)[..., None, None]
    if clock:
        G[..., CLOCK, POS] = d / np.sqrt(r2)[..., None]
    return G
