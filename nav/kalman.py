"""Kalman filter steps shared by stations and aircraft (vectorized over leading axes).

Gains are formed with Cholesky solves of the innovation covariance, never with an explicit
inverse; covariances are symmetrized after every update.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from scipy.linalg.lapack import dpotrs

from .ut import SigmaParams, chol_lower, unscented_transform


def symmetrize(P: np.ndarray) -> np.ndarray:
    """``(P + P^T) / 2`` over the last two axes."""
    return 0.5 * (P + np.swapaxes(P, -1, -2))


def chol_solve(S: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Solve ``S X = B`` for symmetric positive definite ``S`` (..., m, m), ``B`` (..., m, k)."""
    if S.ndim == 2 and B.ndim == 2:  # one system: LAPACK potrf/potrs directly (low call overhead)
        X, info = dpotrs(chol_lower(S), B, lower=1)
        if info != 0:
            raise np.linalg.LinAlgError(f"potrs info {info}")
        return X
    L = np.linalg.cholesky(S)
    Y = np.linalg.solve(L, B)
    return np.linalg.solve(np.swapaxes(L, -1, -2), Y)


def gain(Pxz: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Kalman gain ``K = Pxz S^-1`` (seed 000 eq. 12) via ``S K^T = Pxz^T``; (..., n, m)."""
    return np.swapaxes(chol_solve(S, np.swapaxes(Pxz, -1, -2)), -1, -2)


def update(
    x: np.ndarray, P: np.ndarray, nu: np.ndarray, S: np.ndarray, Pxz: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Generic update (seed 000 eq. 13): ``x + K nu``, ``P - K S K^T``.

    Parameters
    ----------
    x : (..., n); P : (..., n, n); nu : (..., m) innovation; S : (..., m, m); Pxz : (..., n, m).
    """
    K = gain(Pxz, S)
    if K.ndim == 2 and np.ndim(x) == 1:  # one state: matmul fast path
        P_new = P - K @ (S @ K.T)
        return x + K @ nu, 0.5 * (P_new + P_new.T)
    x_new = x + np.einsum("...ij,...j->...i", K, nu)
    P_new = P - K @ S @ np.swapaxes(K, -1, -2)
    return x_new, symmetrize(P_new)


def kf_predict(x, P, F, Q):
    """Linear prediction ``F x``, ``F P F^T + Q``; F (..., n, n)."""
    if F.ndim == 2 and getattr(x, "ndim", None) == 1 and getattr(P, "ndim", None) == 2:  # one state
        Pn = F @ P @ F.T + Q
        return F @ x, 0.5 * (Pn + Pn.T)
    x_new = np.einsum("...ij,...j->...i", F, x)
    return x_new, symmetrize(F @ P @ np.swapaxes(F, -1, -2) + Q)


def kf_update(x, P, z, H, R):
    """Linear update in Joseph form; H (..., m, n), R (..., m, m). Returns x, P, nu, S."""
    nu = z - np.einsum("...ij,...j->...i", H, x)
    Ht = np.swapaxes(H, -1, -2)
    S = symmetrize(H @ P @ Ht + R)
    K = gain(P @ Ht, S)
    x_new = x + np.einsum("...ij,...j->...i", K, nu)
    return x_new, joseph(P, K, H, R), nu, S


def joseph(P: np.ndarray, K: np.ndarray, H: np.ndarray, R: np.ndarray, diagonal: bool = False) -> np.ndarray:
    """Joseph-form posterior covariance ``(I - K H) P (I - K H)^T + K R K^T`` (symmetrized), valid for any
    gain ``K`` (..., n, m); ``H`` (..., m, n); ``R`` (..., m, m), or with ``diagonal`` its diagonal
    (..., m) (independent measurements). The covariance update of every linear(ized) filter of the
    tree; the scalar error-state updates use its rank-one form (:func:`scalar_update`)."""
    IKH = np.eye(P.shape[-1]) - K @ H
    KR = K * R[..., None, :] if diagonal else K @ R
    return symmetrize(IKH @ P @ np.swapaxes(IKH, -1, -2) + KR @ np.swapaxes(K, -1, -2))


def scalar_update(P: np.ndarray, h: np.ndarray, r: np.ndarray | float, nu: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One scalar measurement ``z = h^T dx + v``, ``v ~ N(0, r)``, innovation ``nu`` (...,).

    Gain ``K = P h / s`` with ``s = h^T P h + r`` (the 1x1 Cholesky solve is a division) and the
    Joseph form ``(I - K h^T) P (I - K h^T)^T + r K K^T`` evaluated by rank-one terms:
    ``P - K (Ph)^T - (Ph) K^T + (h^T P h + r) K K^T`` (valid for any gain, O(n^2)).

    Returns the error-state estimate ``dx = K nu`` (..., n), the new ``P`` and ``s`` (...,).
    """
    Ph = np.einsum("...ij,...j->...i", P, h)
    s = np.einsum("...i,...i->...", h, Ph) + r
    K = Ph / s[..., None]
    KPh = K[..., :, None] * Ph[..., None, :]
    Pn = P - KPh - np.swapaxes(KPh, -1, -2) + s[..., None, None] * (K[..., :, None] * K[..., None, :])
    Pn = 0.5 * (Pn + np.swapaxes(Pn, -1, -2))
    return K * nu[..., None], Pn, s


def ekf_update(x, P, z, h: Callable, H: np.ndarray, R):
    """EKF update with measurement function ``h(x) -> (..., m)`` and its Jacobian ``H`` at ``x``."""
    nu = z - h(x)
    Ht = np.swapaxes(H, -1, -2)
    S = symmetrize(H @ P @ Ht + R)
    x_new, P_new = update(x, P, nu, S, P @ Ht)
    return x_new, P_new, nu, S


def ukf_predict(x, P, f: Callable, Q, params: SigmaParams):
    """Unscented prediction through ``f`` (vectorized over sigma points); returns x, P."""
    ut = unscented_transform(f, x, P, params)
    return ut.mean, symmetrize(ut.cov + Q)


def ukf_update(x, P, z, h: Callable, R, params: SigmaParams):
    """Unscented update (seed 000 eqs. 10-13). Returns x, P, nu, S."""
    if getattr(x, "ndim", None) == 1 and getattr(P, "ndim", None) == 2 and getattr(R, "ndim", None) == 2:
        return _ukf_update_one(x, P, z, h, R, params)  # one state: few, small numpy calls
    ut = unscented_transform(h, x, P, params)
    S = symmetrize(ut.cov + R)
    nu = z - ut.mean
    x_new, P_new = update(x, P, nu, S, ut.cross)
    return x_new, P_new, nu, S


def _ukf_update_one(x, P, z, h, R, params):
    """:func:`ukf_update` for one state (n,): the same algebra with few, small numpy calls.

    The sigma points are ``x``, ``x +- gamma L[:, i]`` (:func:`nav.ut.sigma_points`), so the cross
    covariance is ``Pxz = wc_1 gamma L (Y_+ - Y_-)`` (the centre point has ``X_0 - x = 0``).
    """
    n = x.shape[-1]
    wm, wc, gamma = params.weights(n)
    cols = gamma * chol_lower(P)  # column i = i-th sigma direction
    X = np.empty((2 * n + 1, n))
    X[0] = x
    np.add(x, cols.T, out=X[1 : n + 1])
    np.subtract(x, cols.T, out=X[n + 1 :])
    Y = h(X)  # (2n+1, m)
    y = wm @ Y
    dY = Y - y
    S = (dY.T * wc) @ dY + R
    S = 0.5 * (S + S.T)
    Pxz = cols @ ((Y[1 : n + 1] - Y[n + 1 :]) * wc[1])  # (n, m)
    Kt, info = dpotrs(chol_lower(S), Pxz.T, lower=1)  # S K^T = Pxz^T
    if info != 0:
        raise np.linalg.LinAlgError(f"potrs info {info}")
    nu = z - y
    P_new = P - Kt.T @ Pxz.T  # K S K^T = K Pxz^T (S K^T = Pxz^T)
    return x + nu @ Kt, 0.5 * (P_new + P_new.T), nu, S


def nis(nu: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Normalized innovation squared ``nu^T S^-1 nu`` (...,) of ``nu`` (..., m), ``S`` (..., m, m): the
    squared norm of the whitened innovation ``L^-1 nu`` (``S = L L^T``; raises ``LinAlgError`` unless
    ``S`` is positive definite). The one NIS / NEES of the tree."""
    w = np.linalg.solve(np.linalg.cholesky(S), nu[..., None])[..., 0]
    return np.einsum("...i,...i->...", w, w)


def nees(err: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Normalized estimation error squared ``e^T P^-1 e`` (...,) of ``err`` (..., n), ``P`` (..., n, n)."""
    return nis(err, P)
