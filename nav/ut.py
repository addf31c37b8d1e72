"""Unscented transform: sigma points and weights, vectorized over leading axes.

Shapes follow the project convention: a state is ``(..., n)``, a covariance ``(..., n, n)``;
sigma points are ``(..., 2n+1, n)`` with the sigma axis just before the state axis, so any
number of leading Monte Carlo / batch axes can ride along.

Two parameterizations are provided:

* Julier & Uhlmann (2004), used by seed 000 eq. (9): ``W0 = kappa/(n+kappa)``,
  ``Wi = 1/(2(n+kappa))`` with the rule of thumb ``n + kappa = 3``.
* The scaled set (seed 001, eqs. for ``W^(m)``, ``W^(c)``): ``lambda = alpha^2 (n+kappa) - n``,
  ``W0m = lambda/(n+lambda)``, ``W0c = W0m + 1 - alpha^2 + beta``, ``Wi = 1/(2(n+lambda))``.

Julier's set is the scaled set with ``alpha = 1, beta = 0``; both go through one code path.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.linalg.lapack import dpotrf


@dataclass(frozen=True)
class SigmaParams:
    """Sigma-point parameters (alpha, beta, kappa); ``kappa=None`` means Julier's ``3 - n``."""

    alpha: float = 1.0
    beta: float = 0.0
    kappa: float | None = None

    @classmethod
    def julier(cls, kappa: float | None = None) -> "SigmaParams":
        """Julier's symmetric set; ``kappa=None`` applies the rule ``n + kappa = 3``."""
        return cls(alpha=1.0, beta=0.0, kappa=kappa)

    @classmethod
    def scaled(cls, alpha: float = 1e-3, beta: float = 2.0, kappa: float = 0.0) -> "SigmaParams":
        """Scaled set (seed 001): ``1e-4 <= alpha <= 1``, ``beta = 2`` for Gaussians, ``kappa = 0``."""
        return cls(alpha=alpha, beta=beta, kappa=kappa)

    def weights(self, n: int) -> tuple[np.ndarray, np.ndarray, float]:
        """Mean weights ``(2n+1,)``, covariance weights ``(2n+1,)`` and the spread ``sqrt(n+lambda)``.

        Cached per ``(params, n)``; the arrays are read-only (copy them to modify).
        """
        return _weights(self, int(n))


@functools.lru_cache(maxsize=128)
def _weights(params: SigmaParams, n: int) -> tuple[np.ndarray, np.ndarray, float]:
    kappa = 3.0 - n if params.kappa is None else params.kappa
    lam = params.alpha**2 * (n + kappa) - n
    c = n + lam
    if c <= 0:
        raise ValueError(f"n + lambda must be positive, got {c} (n={n}, params={params})")
    wm = np.full(2 * n + 1, 0.5 / c)
    wc = wm.copy()
    wm[0] = lam / c
    wc[0] = lam / c + 1.0 - params.alpha**2 + params.beta
    wm.setflags(write=False)
    wc.setflags(write=False)
    return wm, wc, float(np.sqrt(c))


def chol_lower(P: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of one SPD matrix (n, n) via LAPACK ``potrf`` (low call overhead).

    Raises ``numpy.linalg.LinAlgError`` if ``P`` is not positive definite (like ``np.linalg.cholesky``).
    """
    L, info = dpotrf(P, lower=1, clean=1)
    if info != 0 or not math.isfinite(L[-1, -1]):  # NaN input: potrf may succeed with NaN output
        raise np.linalg.LinAlgError("matrix is not positive definite" if info > 0 else f"potrf info {info}")
    return L


def sigma_points(x: np.ndarray, P: np.ndarray, params: SigmaParams) -> np.ndarray:
    """Symmetric sigma points around ``x`` with covariance ``P``.

    Parameters
    ----------
    x : (..., n) mean.
    P : (..., n, n) covariance (symmetric positive definite).
    params : sigma-point parameterization.

    Returns
    -------
    X : (..., 2n+1, n); ``X[..., 0, :] = x``, ``X[..., i, :] = x + gamma S[:, i-1]``,
        ``X[..., n+i, :] = x - gamma S[:, i-1]`` with ``S S^T = P`` (seed 000 eq. 9).
    """
    x = np.asarray(x, dtype=float)
    n = x.shape[-1]
    _, _, gamma = params.weights(n)
    if x.ndim == 1 and np.ndim(P) == 2:  # one state: small-matrix fast path
        cols = gamma * chol_lower(np.asarray(P, dtype=float)).T
        X = np.empty((2 * n + 1, n))
        X[0] = x
        np.add(x, cols, out=X[1 : n + 1])
        np.subtract(x, cols, out=X[n + 1 :])
        return X
    S = np.linalg.cholesky(P)  # (..., n, n) lower
    cols = gamma * np.swapaxes(S, -1, -2)  # row i = column i of S
    X = np.concatenate([x[..., None, :], x[..., None, :] + cols, x[..., None, :] - cols], axis=-2)
    return X


@dataclass
class UTResult:
    """Outputs of :func:`unscented_transform` (shapes for an ``m``-dimensional output)."""

    mean: np.ndarray  # (..., m)
    cov: np.ndarray  # (..., m, m), without added noise
    cross: np.ndarray  # (..., n, m), Pxz
    sigma_x: np.ndarray  # (..., 2n+1, n)
    sigma_y: np.ndarray  # (..., 2n+1, m)


def unscented_transform(
    f: Callable[[np.ndarray], np.ndarray],
    x: np.ndarray,
    P: np.ndarray,
    params: SigmaParams,
) -> UTResult:
    """Propagate ``(x, P)`` through ``f`` with sigma points (seed 000 eq. 10).

    ``f`` maps sigma points ``(..., 2n+1, n)`` to ``(..., 2n+1, m)`` in one vectorized call.
    """
    x = np.asarray(x, dtype=float)
    n = x.shape[-1]
    wm, wc, _ = params.weights(n)
    X = sigma_points(x, P, params)
    Y = np.asarray(f(X), dtype=float)
    if Y.ndim == 2 and x.ndim == 1:  # one state: matmul instead of einsum
        y = wm @ Y
        dY = Y - y
        dYw = (dY * wc[:, None]).T  # (m, 2n+1)
        Py = dYw @ dY
        Pxy = ((X - x) * wc[:, None]).T @ dY
        return UTResult(mean=y, cov=0.5 * (Py + Py.T), cross=Pxy, sigma_x=X, sigma_y=Y)
    y = np.einsum("k,...km->...m", wm, Y)
    dY = Y - y[..., None, :]
    dX = X - x[..., None, :]
    Py = np.einsum("k,...ki,...kj->...ij", wc, dY, dY)
    Pxy = np.einsum("k,...ki,...kj->...ij", wc, dX, dY)
    return UTResult(mean=y, cov=0.5 * (Py + np.swapaxes(Py, -1, -2)), cross=Pxy, sigma_x=X, sigma_y=Y)
