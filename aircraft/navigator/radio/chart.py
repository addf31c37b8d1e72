"""The inverse-range chart of the radio filters: which runs carry their position inverted through
the unit sphere about the broadcast station centroid (aircraft/navigator/radio/coords.py), and the conversions.

A run is in inverse coordinates while its position is known well relative to its distance from the
reference point and it is far from the array (``Tuning.inverse_max_rel``, ``Tuning.inverse_min_radii``);
the filter's ``x``/``P`` are Cartesian to the outside, converted on access.
"""

from __future__ import annotations

import numpy as np

from nav.kalman import symmetrize

from . import coords as crd
from .state import POS


class InverseChart:
    """Per-run coordinate chart: Cartesian ``[p, v (, b (, bdot))]`` or inverse-range
    ``[q, v (, beta (, bdot))]``.

    ``inv`` (...,): runs in inverse coordinates (the leading shape of the filter state);
    ``ref`` (3,): reference point (None until known); ``radius``: RMS station distance from it;
    ``clock``: the state carries a clock offset (converted as ``beta = b + |p - c|``).
    """

    def __init__(self, lead_shape: tuple, clock: bool):
        self.clock = clock
        self.ref: np.ndarray | None = None
        self.inv = np.zeros(lead_shape, dtype=bool)
        self.radius = 0.0

    @property
    def inv(self) -> np.ndarray:
        return self._inv

    @inv.setter
    def inv(self, value: np.ndarray) -> None:
        # whether any run is inverted is read at every predict and update: kept as a Python bool beside
        # the mask, which is therefore read-only (assign a new mask, never change it in place)
        self._inv = np.array(value, dtype=bool)
        self._inv.setflags(write=False)
        self._any = bool(self._inv.any())

    def set_reference(self, ref_m, radius_m) -> None:
        self.ref = np.asarray(ref_m, dtype=float)
        self.radius = float(radius_m) if radius_m is not None else 0.0

    def any(self) -> bool:
        return self._any

    def mask(self, X: np.ndarray, extra: int) -> np.ndarray:
        """The run mask shaped to broadcast against X (runs[, sigma], n[, n])."""
        return self.inv.reshape(self.inv.shape + (1,) * (X.ndim - self.inv.ndim - 1 + extra))

    def cart(self, X: np.ndarray) -> np.ndarray:
        """Internal-coordinate states X (runs[, sigma points], n) -> Cartesian."""
        if not self._any:
            return X
        with np.errstate(all="ignore"):
            return np.where(self.mask(X, 1), crd.to_cartesian(X, self.ref, self.clock), X)

    def T(self, X: np.ndarray) -> np.ndarray | None:
        """dx/ds at internal-coordinate states X (..., n, n); None = identity for every run."""
        if not self._any:
            return None
        with np.errstate(all="ignore"):
            return np.where(self.mask(X, 2), crd.jac_to_cartesian(X, self.clock), np.eye(X.shape[-1]))

    def to_internal_x(self, value: np.ndarray) -> np.ndarray:
        """Cartesian states (..., n) -> the runs' own coordinates."""
        if self.inv.any():
            with np.errstate(all="ignore"):
                value = np.where(self.mask(value, 1), crd.to_inverse(value, self.ref, self.clock), value)
        return value

    def to_internal_P(self, value: np.ndarray, x_internal: np.ndarray) -> np.ndarray:
        """Cartesian covariances (..., n, n) -> the runs' own coordinates, at their means ``x_internal``."""
        if self.inv.any():
            with np.errstate(all="ignore"):
                G = np.where(self.mask(x_internal, 2), crd.jac_to_inverse(self.cart(x_internal), self.ref, self.clock),
                             np.eye(value.shape[-1]))
            value = symmetrize(G @ value @ np.swapaxes(G, -1, -2))
        return value

    def to_cartesian_P(self, x_internal: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Covariances in the runs' own coordinates -> Cartesian (first order, ``T P T^T``)."""
        T = self.T(x_internal)
        if T is None:
            return P
        return symmetrize(T @ P @ np.swapaxes(T, -1, -2))

    def switch(self, x_all: np.ndarray, P_all: np.ndarray, max_rel: float, min_radii: float):
        """Move runs between Cartesian and inverse-range coordinates: inverse while the relative
        position uncertainty ``sqrt(tr P_pos) / |p - c|`` is below ``max_rel`` and the run is beyond
        ``min_radii`` array radii from the reference, back to Cartesian above twice that (checked on
        the runs' own coordinates: in inverse ones ``sqrt(tr P_qq) / |q|`` is the same ratio to first
        order). Returns the (possibly new) ``(x, P)``; updates ``inv``."""
        if x_all.ndim == 1 and self._stays_one(x_all, P_all, max_rel, min_radii):
            return x_all, P_all
        n = x_all.shape[-1]
        x = x_all.reshape(-1, n)
        P = P_all.reshape(-1, n, n)
        inv = self.inv.reshape(-1)
        k = max_rel
        d = np.where(inv[:, None], x[:, POS], x[:, POS] - self.ref)
        with np.errstate(all="ignore"):
            rel = np.sqrt(np.einsum("kii->k", P[:, POS, POS]) / np.einsum("ki,ki->k", d, d))
        with np.errstate(all="ignore"):
            r = np.sqrt(np.einsum("ki,ki->k", d, d))
            r = np.where(inv, crd.SCALE_M**2 / r, r)
        far = r > min_radii * self.radius
        new = np.where(inv, rel < 2.0 * k, rel < k) & far
        ch = new != inv
        if not np.any(ch):
            return x_all, P_all
        X = self.cart(x_all).reshape(-1, n)[ch]
        T = self.T(x_all)
        Pc = P[ch] if T is None else symmetrize(T @ P_all @ np.swapaxes(T, -1, -2)).reshape(-1, n, n)[ch]
        to_inv = new[ch]
        with np.errstate(all="ignore"):
            G = crd.jac_to_inverse(X, self.ref, self.clock)
            xs = np.where(to_inv[:, None], crd.to_inverse(X, self.ref, self.clock), X)
            Ps = np.where(to_inv[:, None, None], symmetrize(G @ Pc @ np.swapaxes(G, -1, -2)), Pc)
        x2, P2 = x.copy(), P.copy()
        x2[ch], P2[ch] = xs, Ps
        self.inv = new.reshape(self.inv.shape)
        return x2.reshape(x_all.shape), P2.reshape(P_all.shape)

    def _stays_one(self, x: np.ndarray, P: np.ndarray, k: float, min_radii: float) -> bool:
        """Whether one run (``x`` (n,), ``P`` (n, n)) keeps its coordinates (:meth:`switch`'s test,
        the same float64 operations on scalars)."""
        inv = self._any
        d = x[POS] if inv else x[POS] - self.ref
        dd = np.einsum("i,i->", d, d)
        with np.errstate(all="ignore"):
            rel = np.sqrt(np.einsum("ii->", P[POS, POS]) / dd)
            r = np.sqrt(dd)
            if inv:
                r = crd.SCALE_M**2 / r
        new = bool((rel < 2.0 * k if inv else rel < k) and r > min_radii * self.radius)
        return new == inv

    def predict(self, x: np.ndarray, P: np.ndarray, F: np.ndarray, Q: np.ndarray):
        """The linear step ``(F, Q)`` (Cartesian) carried to the runs' own coordinates by its Jacobian
        ``G1 F T`` (``T = dx/ds`` before, ``G1 = ds/dx`` after); the process noise enters through ``G1``.
        Only for a chart with inverse runs (else the plain Kalman prediction)."""
        ref, clk = self.ref, self.clock
        T = self.T(x)
        x1 = self.cart(x) @ F.T
        with np.errstate(all="ignore"):
            G1 = np.where(self.mask(x, 2), crd.jac_to_inverse(x1, ref, clk), np.eye(F.shape[-1]))
            x_new = np.where(self.mask(x, 1), crd.to_inverse(x1, ref, clk), x1)
        Fs = G1 @ F @ T
        return x_new, symmetrize(Fs @ P @ np.swapaxes(Fs, -1, -2) + G1 @ Q @ np.swapaxes(G1, -1, -2))
