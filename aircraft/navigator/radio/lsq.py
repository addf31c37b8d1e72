"""Snapshot iterative least squares of the radio aircraft (seed 001 eq. 14 with the weights of
eqs. 16 and 18) and their covariance; :func:`mirror_above` (the station plane's mirror image).

Shapes: ``M`` runs, ``m`` stations (shared by all runs).
"""

from __future__ import annotations

import numpy as np

from nav.kalman import chol_solve, symmetrize

from . import models as mdl
from .state import POS, StateLayout

_PR_COLS = StateLayout("pr").pos_clock  # the snapshot pseudorange unknowns [x y z b] of the filter state


def _solve_normal(H: np.ndarray, Rinv_H: np.ndarray, Rinv_dz: np.ndarray) -> np.ndarray:
    """Solve ``(H^T W H) dx = H^T W dz`` given ``W H`` and ``W dz``; (M, n)."""
    Ht = np.swapaxes(H, -1, -2)
    N = symmetrize(Ht @ Rinv_H)
    # Levenberg-Marquardt damping: changes the path, not the fixed point (H^T W dz = 0); keeps the step
    # finite where a column vanishes (aircraft in the station plane: d r / d z = 0)
    d = np.einsum("...ii->...i", N)
    N = N + (1e-9 * d.sum(-1, keepdims=True))[..., None] * np.eye(N.shape[-1])
    g = np.einsum("...ij,...j->...i", Ht, Rinv_dz)
    try:
        return chol_solve(N, g[..., None])[..., 0]
    except np.linalg.LinAlgError:  # a degenerate run: least-norm step for the whole batch
        return np.linalg.lstsq(N, g[..., None], rcond=None)[0][..., 0] if N.ndim == 2 else \
            np.einsum("...ij,...j->...i", np.linalg.pinv(N), g)


def _limit(dx: np.ndarray, max_step_m: float) -> np.ndarray:
    """Scale Gauss-Newton steps so the position part moves at most ``max_step_m`` (trust region)."""
    nrm = np.linalg.norm(dx[..., POS], axis=-1, keepdims=True)
    return dx * np.minimum(1.0, max_step_m / np.maximum(nrm, 1e-300))


def _one_run_weights(x: np.ndarray, stations_m: np.ndarray, station_cov_m2: np.ndarray | None,
                     sig2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One run's ranges (m,), unit lines of sight station->aircraft (m, 3) and range variances
    ``sigma^2 + u^T P u`` (m,) at position ``x`` (3,): what :func:`models.range_var` and
    :func:`models.jac_pr` compute for many runs, in a few small operations."""
    d = x - stations_m
    r = np.sqrt(np.einsum("ij,ij->i", d, d))
    u = d / r[:, None]
    var = sig2 if station_cov_m2 is None else sig2 + np.einsum("mi,mij,mj->m", u, station_cov_m2, u)
    return r, u, var


def _one_run_step(H: np.ndarray, WH: np.ndarray, Wdz: np.ndarray, max_step_m: float) -> np.ndarray:
    """One run's trust-region Gauss-Newton step (k,) from ``H`` (d, k), ``W H`` and ``W dz``: the
    normal equations of :func:`_solve_normal` (same damping) and :func:`_limit`."""
    N = H.T @ WH
    N = 0.5 * (N + N.T)
    N = N + 1e-9 * np.trace(N) * np.eye(N.shape[0])
    g = H.T @ Wdz
    try:
        dx = chol_solve(N, g[:, None])[:, 0]
    except np.linalg.LinAlgError:
        dx = np.linalg.lstsq(N, g, rcond=None)[0]
    nrm = float(np.linalg.norm(dx[:3]))
    return dx * min(1.0, max_step_m / max(nrm, 1e-300))


def _iterate_one(x: np.ndarray, step, iters: int, tol_m: float, floor_z_m: float | None) -> np.ndarray:
    """The one-run Gauss-Newton loop: ``x += step(x)``, the height mirrored above ``floor_z_m``, until
    every component of the step is below ``tol_m`` or after ``iters`` steps."""
    for _ in range(iters):
        dx = step(x)
        x = x + dx
        if floor_z_m is not None and x[2] < floor_z_m:
            x[2] = 2.0 * floor_z_m - x[2]
        if np.all(np.abs(dx) < tol_m):
            break
    return x


def _lsq_pr_one(rho_m, stations_m, x0, var_m2, station_cov_m2, iters, tol_m, floor_z_m, max_step_m):
    """:func:`lsq_pr` for one run: rho_m (m,), x0 (4,); returns (4,). The same iteration with fewer,
    smaller array operations (results agree to rounding)."""
    sig2 = np.broadcast_to(np.asarray(var_m2, dtype=float), (stations_m.shape[0],))
    H = np.ones((stations_m.shape[0], 4))

    def step(x):
        r, u, var = _one_run_weights(x[:3], stations_m, station_cov_m2, sig2)
        H[:, :3] = u
        return _one_run_step(H, H / var[:, None], (rho_m - r - x[3]) / var, max_step_m)

    return _iterate_one(np.array(x0, dtype=float), step, iters, tol_m, floor_z_m)


def _lsq_tdoa_one(rho_m, stations_m, x0, var_m2, station_cov_m2, base, iters, tol_m, floor_z_m, max_step_m):
    """:func:`lsq_tdoa` for one run: rho_m (m,), x0 (3,); returns (3,). Differences against ``base``
    weighted with ``(G R G^T)^-1`` as there, ``G R G^T = diag(var_j) + var_base`` (j != base)."""
    m = stations_m.shape[0]
    others = np.flatnonzero(np.arange(m) != base)
    z = rho_m[others] - rho_m[base]
    sig2 = np.broadcast_to(np.asarray(var_m2, dtype=float), (m,))

    def step(x):
        r, u, var = _one_run_weights(x, stations_m, station_cov_m2, sig2)
        H = u[others] - u[base]
        S = np.diag(var[others]) + var[base]
        SiHdz = chol_solve(S, np.column_stack([H, z - (r[others] - r[base])]))
        return _one_run_step(H, SiHdz[:, :3], SiHdz[:, 3], max_step_m)

    return _iterate_one(np.array(x0, dtype=float), step, iters, tol_m, floor_z_m)


def mirror_above(x: np.ndarray, floor_z_m: float | None, vel: bool = False) -> np.ndarray:
    """Reflect states whose height is below ``floor_z_m`` (the station plane) to its mirror image.

    With (nearly) coplanar stations the ranges are symmetric about their plane, so the mirror image
    fits the measurements equally well; the aircraft is known to be above. ``vel`` also flips vz.
    Returns the boolean mask of reflected runs (M,); ``x`` is modified in place.
    """
    if floor_z_m is None:
        return np.zeros(x.shape[:-1], dtype=bool)
    below = x[..., 2] < floor_z_m
    x[..., 2] = np.where(below, 2.0 * floor_z_m - x[..., 2], x[..., 2])
    if vel:
        x[..., 5] = np.where(below, -x[..., 5], x[..., 5])
    return below


def lsq_pr(
    rho_m: np.ndarray, stations_m: np.ndarray, x0: np.ndarray, var_m2: np.ndarray | float,
    station_cov_m2: np.ndarray | None = None, iters: int = 10, tol_m: float = 1e-4,
    floor_z_m: float | None = None, max_step_m: float = 200.0,
) -> np.ndarray:
    """Iterative pseudorange LSQ (seed 001 eqs. 14-16).

    Parameters
    ----------
    rho_m : (M, m) pseudoranges. stations_m : (m, 3). x0 : (M, 4) start ``[x y z b]``.
    var_m2 : measurement variance (scalar or (m,)). station_cov_m2 : (m, 3, 3) or None.
    floor_z_m : reflect iterates below this height (see :func:`mirror_above`).
    max_step_m : trust region of one Gauss-Newton step.

    Returns
    -------
    x : (M, 4) estimates ``[x y z b]``. One run (rho_m (m,), x0 (4,)) returns (4,).
    """
    if np.ndim(x0) == 1 and np.ndim(rho_m) == 1:
        return _lsq_pr_one(np.asarray(rho_m, dtype=float), stations_m, x0, var_m2, station_cov_m2, iters, tol_m,
                           floor_z_m, max_step_m)
    x = np.array(x0, dtype=float)
    sigma = np.sqrt(np.broadcast_to(var_m2, (stations_m.shape[0],)))
    for _ in range(iters):
        X = np.concatenate([x[..., POS], np.zeros(x.shape[:-1] + (3,)), x[..., 3:4]], axis=-1)
        H = mdl.jac_pr(X, stations_m)[..., _PR_COLS]
        var = mdl.range_var(X, stations_m, station_cov_m2, sigma)
        dz = rho_m - mdl.h_pr(X, stations_m)
        dx = _limit(_solve_normal(H, H / var[..., None], dz / var), max_step_m)
        x = x + dx
        mirror_above(x, floor_z_m)
        if np.all(np.abs(dx) < tol_m):
            break
    return x


def lsq_tdoa(
    rho_m: np.ndarray, stations_m: np.ndarray, x0: np.ndarray, var_m2: np.ndarray | float,
    station_cov_m2: np.ndarray | None = None, base: int = 0, iters: int = 10, tol_m: float = 1e-4,
    floor_z_m: float | None = None, max_step_m: float = 200.0,
) -> np.ndarray:
    """Iterative range-difference LSQ weighted with ``(G R G^T)^-1`` (seed 001 eqs. 14, 17, 18).

    rho_m : (M, m) pseudoranges (differenced here against ``base``); x0 : (M, 3). Returns (M, 3).
    One run (rho_m (m,), x0 (3,)) returns (3,).
    """
    if np.ndim(x0) == 1 and np.ndim(rho_m) == 1:
        return _lsq_tdoa_one(np.asarray(rho_m, dtype=float), stations_m, x0, var_m2, station_cov_m2, base, iters,
                             tol_m, floor_z_m, max_step_m)
    x = np.array(x0, dtype=float)
    m = stations_m.shape[0]
    G = mdl.g_matrix(m, base)
    z = np.einsum("ij,...j->...i", G, rho_m)
    sigma = np.sqrt(np.broadcast_to(var_m2, (m,)))
    for _ in range(iters):
        X = np.concatenate([x, np.zeros(x.shape[:-1] + (3,))], axis=-1)
        H = mdl.jac_tdoa(X, stations_m, base)[..., POS]
        S = mdl.r_tdoa(mdl.range_var(X, stations_m, station_cov_m2, sigma), base)
        dz = z - mdl.h_tdoa(X, stations_m, base)
        SiH = chol_solve(S, H)
        Sidz = chol_solve(S, dz[..., None])[..., 0]
        dx = _limit(_solve_normal(H, SiH, Sidz), max_step_m)
        x = x + dx
        mirror_above(x, floor_z_m)
        if np.all(np.abs(dx) < tol_m):
            break
    return x


def lsq_cov(
    x: np.ndarray, stations_m: np.ndarray, var_m2: np.ndarray | float, model: str,
    station_cov_m2: np.ndarray | None = None, base: int = 0,
) -> np.ndarray:
    """Covariance ``(H^T W H)^-1`` of a snapshot LSQ solution ``x`` (M, 4) pr / (M, 3) tdoa."""
    m = stations_m.shape[0]
    sigma = np.sqrt(np.broadcast_to(var_m2, (m,)))
    X = np.concatenate([x[..., POS], np.zeros(x.shape[:-1] + (3,)), x[..., 3:]], axis=-1)
    var = mdl.range_var(X, stations_m, station_cov_m2, sigma)
    if model == "pr":
        H = mdl.jac_pr(X, stations_m)[..., _PR_COLS]
        N = np.swapaxes(H, -1, -2) @ (H / var[..., None])
    else:
        H = mdl.jac_tdoa(X, stations_m, base)[..., POS]
        N = np.swapaxes(H, -1, -2) @ chol_solve(mdl.r_tdoa(var, base), H)
    k = N.shape[-1]
    return symmetrize(chol_solve(symmetrize(N), np.broadcast_to(np.eye(k), N.shape).copy()))
