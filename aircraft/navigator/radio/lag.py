"""The lagged Jacobian: for runs in Cartesian coordinates (near the array), the Jacobian (EKF) or the
sigma points' regression slope (UKF) along one direction is taken at a low-passed position.

Where a direction is not observable (right above the array: the height; on a mirror plane of the
square: x, z and the clock) the Jacobian along it, taken at the estimate, is proportional to the
estimate's own error across it, which the innovation also carries, and the noise-driven product
drives the estimate along the ridge (docs/aircraft.md, "the least observable direction lagged").
``Tuning.height_jacobian_lag_s``: the low-pass time (0 = off: at the estimate);
``Tuning.lag_direction``: "weakest" (the least observable position direction from the filter's own
information, low-passed; the position lagged across it, current along it) or "height" (the height
column at the low-passed horizontal position). A run more than 4 sigma (Mahalanobis, across the
lagged direction) from its low-passed position restarts it at its estimate (a moving aircraft).
"""

from __future__ import annotations

import numpy as np

from nav.kalman import nees

from .state import POS, Z


def complement(n: np.ndarray) -> np.ndarray:
    """An orthonormal basis (..., 3, 2) of the plane orthogonal to the unit vectors ``n`` (..., 3)."""
    a = np.where((np.abs(n[..., 0]) < 0.9)[..., None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    e1 = np.cross(n, a)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    return np.stack([e1, np.cross(n, e1)], axis=-1)


def mahalanobis2(d: np.ndarray, P: np.ndarray) -> np.ndarray:
    """``d^T P^-1 d`` (...,) for d (..., k), P (..., k, k); inf where P is not positive definite."""
    try:
        return nees(d, P)
    except np.linalg.LinAlgError:
        return np.full(d.shape[:-1], np.inf)


class LaggedJacobian:
    """State of the rule: ``pos`` the low-passed position (..., 2) ("height": horizontal) or (..., 3)
    ("weakest"); ``info`` the low-passed information of (position, clock); ``dir`` the least
    observable position direction (..., 3) and ``comp`` a basis of its complement (..., 3, 2),
    recomputed every 1/20 of the lag (``dir_t_s``: when last)."""

    def __init__(self, lag_s: float, direction: str):
        self.lag_s = lag_s
        self.direction = direction
        self.pos: np.ndarray | None = None
        self.info: np.ndarray | None = None
        self.dir: np.ndarray | None = None
        self.comp: np.ndarray | None = None
        self.dir_t_s = -np.inf

    def active(self, inv: np.ndarray) -> bool:
        """Whether the rule applies to any run now (``inv``: runs in inverse coordinates, exempt)."""
        return self.pos is not None and self.lag_s > 0 and not inv.all()

    def correction(self, jac, X, J, inv):
        """``(Dp, m)``: the change (runs, rows, 3) of the position columns of ``J = jac(X)`` that takes
        the Jacobian along the lagged direction at the low-passed position, and the mask (runs, 1, 1) of
        the runs it applies to (Cartesian). "height": the height column at the low-passed horizontal
        position. "weakest": along the least observable direction ``n`` (unit, position), at the
        position low-passed across ``n`` and current along it: ``(J(X_l) - J(X)) n n^T``."""
        Xl = X.copy()
        if self.direction == "height" or self.dir is None:  # (weakest: not yet computed)
            Xl[..., :2] = self.pos[..., :2]
            Dp = np.zeros(J.shape[:-1] + (3,))
            Dp[..., Z] = jac(Xl)[..., Z] - J[..., Z]
        else:
            n = self.dir
            p = X[..., POS]
            Xl[..., POS] = self.pos + n * np.einsum("...i,...i->...", n, p - self.pos)[..., None]
            dJn = np.einsum("...ri,...i->...r", jac(Xl)[..., POS] - J[..., POS], n)
            Dp = dJn[..., None] * n[..., None, :]
        near = ~inv
        return Dp, near.reshape(near.shape + (1,) * (Dp.ndim - near.ndim))

    def wrap(self, jac, inv):
        """``jac`` with the lagged direction of the Cartesian runs taken at the low-passed position;
        ``jac`` itself while the rule is not active."""
        if not self.active(inv):
            return jac

        def jac_l(X):
            J = jac(X)
            Dp, m = self.correction(jac, X, J, inv)
            J[..., POS] = np.where(m, J[..., POS] + Dp, J[..., POS])
            return J

        return jac_l

    def update_direction(self, jac, cart_moments, inv, cols, step_s: float, t_s: float) -> None:
        """"weakest": low-pass the information ``A^T A`` of the position and clock columns ``cols`` of
        the Jacobian at the low-passed position, and take ``n`` as the position part of its least
        eigenvector (TDMA: one range per update, the rank builds up). ``cart_moments()``: the
        filter's Cartesian mean (computed only when needed)."""
        if self.direction != "weakest" or self.pos is None or self.lag_s <= 0:
            return
        X = cart_moments().copy()  # Cartesian: the model's own Jacobian
        if X.ndim == 1:
            if not inv:
                X[POS] = self.pos
        else:
            X[..., POS] = np.where(inv[..., None], X[..., POS], self.pos)
        A = jac(X)[..., cols]
        F = np.swapaxes(A, -1, -2) @ A
        a = min(1.0, step_s / self.lag_s) if step_s > 0 else 1.0
        self.info = F if self.info is None else self.info + a * (F - self.info)
        if self.dir is not None and t_s - self.dir_t_s < self.lag_s / 20:
            return  # the direction of an information low-passed over the lag: every 1/20 of it is enough
        w, V = np.linalg.eigh(self.info)
        n = V[..., :3, 0]
        self.dir = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
        self.comp = complement(self.dir)
        self.dir_t_s = t_s

    def advance(self, xc, Pc, cart, T_of, step_s: float) -> None:
        """Low-pass the position (``a = step / lag``): horizontal ("height"), or all three coordinates
        ("weakest"), from the filter's truncated moments ``xc``, ``Pc`` (internal coordinates;
        ``cart``/``T_of`` convert them); a run more than 4 sigma (Mahalanobis, across the lagged
        direction) from it restarts at its estimate."""
        lag = self.lag_s
        if lag <= 0:
            return
        weakest = self.direction == "weakest"
        k = 3 if weakest else 2
        p = cart(xc)[..., :k]
        if self.pos is None:
            self.pos = p.copy()
            return
        d = p - self.pos
        T = T_of(xc)  # the position block only: the position depends on the position states only
        Ph = Pc[..., :k, :k] if T is None else T[..., :k, POS] @ Pc[..., POS, POS] @ np.swapaxes(T[..., :k, POS], -1, -2)
        if not weakest:
            m2 = mahalanobis2(d, Ph)
        elif self.dir is None:  # no direction yet (first update): nothing to test across
            m2 = np.zeros(d.shape[:-1])
        else:  # across n: in the basis E (..., 3, 2) of its complement
            E = self.comp
            m2 = mahalanobis2(np.einsum("...ij,...i->...j", E, d), np.swapaxes(E, -1, -2) @ Ph @ E)
        a = min(1.0, step_s / lag) if step_s > 0 else 1.0
        if d.ndim == 1:  # one run
            self.pos = self.pos + a * d if m2 <= 16.0 else p.copy()
        else:
            self.pos = np.where(~(m2 <= 16.0)[..., None], p, self.pos + a * d)
