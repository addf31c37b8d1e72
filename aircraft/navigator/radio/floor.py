"""The height floor: the aircraft is above the station plane, one named constraint on the filter.

The filter carries the *untruncated* Gaussian and the floor as a constraint on it: its density is
``N(x; m, P) 1[z >= floor]``, a family closed under linear(ized) measurement updates (the likelihood
multiplies the Gaussian part, the truncation stays), so the floor counts once. The measurements are
linearized (EKF Jacobian, UKF sigma points) over the truncated moments, where the density is; the
filter's ``x``/``P`` report them. Near a plane of (nearly) coplanar transmitters the range is
symmetric in ``z``: linearized at a mean on the plane a filter sees no gradient (EKF) or symmetric
sigma points (UKF); the truncated moments put it on the physical side. Replacing the Gaussian by the
truncated moments after every update (Simon & Simon's truncated filter) would count the floor once
per update and shrink the height variance around a wrong height (docs/aircraft.md, "the floor
counted once").
"""

from __future__ import annotations

import numpy as np
from scipy.special import erfcx

from . import coords as crd
from .state import POS, Z


def truncated_normal(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and variance (k,) of a standard normal truncated to ``[a, inf)``: ``lambda`` and
    ``1 + a lambda - lambda^2`` with ``lambda = phi(a) / (1 - Phi(a))`` (the inverse Mills ratio, by
    ``erfcx``: no underflow far in the tail); beyond ``a = 50`` the variance by its asymptotic series
    ``1/a^2 - 6/a^4 + 50/a^6 - 518/a^8`` (the closed form loses ~a^4 eps there). The variance is kept >= 1e-8."""
    lam = np.sqrt(2.0 / np.pi) / erfcx(a / np.sqrt(2.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        ia2 = 1.0 / a**2
        tail = ia2 * (1.0 - ia2 * (6.0 - ia2 * (50.0 - 518.0 * ia2)))
    var = np.where(a > 50.0, tail, 1.0 + a * lam - lam**2)
    return lam, np.maximum(var, 1e-8)


_SQRT_2_PI = np.sqrt(2.0 / np.pi)
_SQRT_2 = np.sqrt(2.0)


def _truncated_normal_one(a: float) -> tuple[float, float]:
    """:func:`truncated_normal` of one ``a`` (a float): the same operations on float64 scalars."""
    lam = float(_SQRT_2_PI / erfcx(a / _SQRT_2))
    if a > 50.0:
        ia2 = 1.0 / (a * a)
        var = ia2 * (1.0 - ia2 * (6.0 - ia2 * (50.0 - 518.0 * ia2)))
    else:
        var = 1.0 + a * lam - lam * lam
    return lam, var if not var < 1e-8 else 1e-8


class HeightFloor:
    """The constraint ``z >= floor_z_m`` (None: no floor) and the truncated moments of a Gaussian.

    ``trunc_sigma``: runs whose mass below the floor is beyond this many sigma (< 1e-9 at 6) are left
    as they are. :meth:`moments` of the filter's own ``(x, P)`` are cached by identity.
    """

    def __init__(self, floor_z_m: float | None, trunc_sigma: float):
        self.floor_z_m = floor_z_m
        self.trunc_sigma = trunc_sigma
        self._cache: tuple | None = None  # (x, P, truncated x, truncated P)

    def cached(self, x: np.ndarray, P: np.ndarray, inv: np.ndarray, ref: np.ndarray | None):
        """:meth:`moments` of the filter's own ``(x, P)``, computed once per pair of arrays."""
        c = self._cache
        if c is not None and c[0] is x and c[1] is P:
            return c[2], c[3]
        out = self.moments(x, P, inv, ref)
        self._cache = (x, P) + out
        return out

    def depth(self, x: np.ndarray, P: np.ndarray, inv: np.ndarray, ref: np.ndarray | None) -> np.ndarray:
        """How far the floor lies above the mean of ``N(x, P)`` (internal coordinates), in standard
        deviations of the height (...,): ``(floor - z) / sigma_z`` (inverse-range runs: the floor
        taken at the mean, as in :meth:`moments`). Above ~5 the Gaussian has no mass left on the
        physical side. Requires a floor."""
        if x.ndim == 1 and not inv:
            return self._depth_one(x, P)
        n = x.shape[-1]
        xf, Pf = x.reshape(-1, n), P.reshape(-1, n, n)
        fz = self.floor_z_m
        with np.errstate(invalid="ignore"):  # a broken filter (P not PD) is reset by its owner
            s = np.sqrt(Pf[:, Z, Z])
        a = (fz - xf[:, Z]) / s
        if inv.any():
            ai = ((fz - ref[Z]) * np.einsum("ki,ki->k", xf[:, POS], xf[:, POS]) / crd.SCALE_M**2
                  - xf[:, Z]) / s
            a = np.where(inv.reshape(-1), ai, a)
        return a.reshape(x.shape[:-1])

    def _depth_one(self, x: np.ndarray, P: np.ndarray) -> np.ndarray:
        """:meth:`depth` (0-d) of one Cartesian run (``x`` (n,), ``P`` (n, n)): the same float64
        operations on scalars."""
        s2 = P[Z, Z]
        s = np.sqrt(s2) if s2 >= 0.0 else np.float64(np.nan)  # a broken filter is reset by its owner
        return np.asarray((self.floor_z_m - x[Z]) / s)

    def moments(self, x: np.ndarray, P: np.ndarray, inv: np.ndarray, ref: np.ndarray | None):
        """The moments ``(x, P)`` (internal coordinates, (..., n), (..., n, n)) of ``N(x, P)`` truncated to
        above the floor; where no run has mass below it within ``trunc_sigma`` the inputs come back
        unchanged (the same objects). ``inv`` (...,): runs in inverse-range coordinates about ``ref``
        (the floor is then ``q_z >= (floor - c_z) |q|^2 / L^2``, linear if the reference point lies on
        the floor; the right side is taken at the mean)."""
        out = x, P
        if self.floor_z_m is None:
            return out
        if x.ndim == 1:
            return self._moments_one(x, P, inv, ref)
        n = x.shape[-1]
        xf, Pf = x.reshape(-1, n), P.reshape(-1, n, n)
        s2 = Pf[:, Z, Z]
        a = self.depth(x, P, inv, ref).reshape(-1)
        act = a > -self.trunc_sigma
        if np.any(act):
            a, s2 = a[act], s2[act]
            dmu, var_t = truncated_normal(a)  # in units of sigma, sigma^2
            pc = Pf[act, :, Z]  # (k, n)
            xf, Pf = xf.copy(), Pf.copy()
            xf[act] = xf[act] + pc * (dmu / np.sqrt(s2))[:, None]
            Pa = Pf[act] + pc[:, :, None] * pc[:, None, :] * ((var_t - 1.0) / s2)[:, None, None]
            Pf[act] = 0.5 * (Pa + np.swapaxes(Pa, -1, -2))
            out = xf.reshape(x.shape), Pf.reshape(P.shape)
        return out

    def _moments_one(self, x: np.ndarray, P: np.ndarray, inv: np.ndarray, ref: np.ndarray | None):
        """:meth:`moments` of one run (``x`` (n,), ``P`` (n, n)): the same arithmetic without the run
        masks (the live aircraft's filters update one run at 100 Hz)."""
        s2 = P[Z, Z]
        a = self.depth(x, P, inv, ref)
        if not a > -self.trunc_sigma:
            return x, P
        dmu, var_t = _truncated_normal_one(float(a))
        pc = P[:, Z]
        x1 = x + pc * (dmu / np.sqrt(s2))
        Pa = P + pc[:, None] * pc[None, :] * ((var_t - 1.0) / s2)
        return x1, 0.5 * (Pa + Pa.T)
