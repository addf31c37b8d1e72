"""The measurement update of the radio filters, as strategies over one measurement model:
:class:`EkfUpdate` (second-order terms, Gauss-Newton iterations) and :class:`UkfUpdate` (sigma points,
iterated posterior linearization). Both linearize over the floor-truncated moments (:mod:`.floor`),
in the runs' own coordinates (:mod:`.chart`), with the lagged direction (:mod:`.lag`), and iterate
only runs whose linearization error over the prior is large: ``tr(R^-1 Omega) >
Tuning.iterate_threshold`` (``Tuning.iterations``: 1 = plain EKF/UKF; k > 1 re-linearizes k - 1 more
times about the latest posterior).

Each strategy is called as ``strategy(trk, model, z, R, k)`` with the tracker ``trk``
(:class:`.tracker.CvTracker`: its prior ``trk._x``, ``trk._P``), the batch's
:class:`.measurements.PseudorangeModel`, the measurement vector ``z``, noise ``R`` and the repeat
count ``k`` of the linearization error (:mod:`.repeats`); it returns ``(x, P, nu, S)``: the posterior
and the innovation and its covariance of the first (plain) linearization.
"""

from __future__ import annotations

import numpy as np

from nav.kalman import chol_solve, ekf_update, kf_update, symmetrize, ukf_update
from nav.ut import unscented_transform

from .repeats import scaled
from .state import POS


def linearized_update(x, P, xi, H, hxi, z, R):
    """Update the prior ``(x, P)`` with ``h`` linearized at ``xi``: ``z - h(xi) - H (x - xi)``."""
    def h_lin(X):
        return hxi + np.einsum("...ij,...j->...i", H, X - xi)

    x1, P1, _, _ = ekf_update(x, P, z, h_lin, H, R)
    return x1, P1


def iplf_step(x, P, xi, Pi, z, h, R, params, dA=None):
    """One iterated posterior linearization step (Garcia-Fernandez et al. 2015): the statistical
    linear regression ``h(X) ~ A X + b + e``, ``e ~ N(0, Omega)`` over the sigma points of the latest
    posterior ``N(xi, Pi)``, then a linear update of the prior ``(x, P)`` with it. The first pass
    (``xi, Pi`` = prior) is exactly the plain UKF update. ``dA``: a change of the slope (the lagged
    direction), the line kept through the mean prediction at ``xi``; the residual covariance stays
    that of the regression."""
    ut = unscented_transform(h, xi, Pi, params)
    At = chol_solve(Pi, ut.cross)  # (n, m): Pi A^T = Pxz
    A = np.swapaxes(At, -1, -2)
    b = ut.mean - np.einsum("...ij,...j->...i", A, xi)
    Om = symmetrize(ut.cov - A @ ut.cross)  # Py - A Pi A^T
    w, V = np.linalg.eigh(Om)  # >= 0 in exact arithmetic; the scaled set's negative W0c can break it
    Om = (V * np.maximum(w, 0.0)[..., None, :]) @ np.swapaxes(V, -1, -2)
    if dA is not None:
        A = A + dA
        b = ut.mean - np.einsum("...ij,...j->...i", A, xi)
    x1, P1, _, _ = kf_update(x, P, z - b, A, R + Om)
    return x1, P1, ut


def needs_iteration(threshold: float, lead_shape, R, omega):
    """Runs whose linearization error over the prior is large: ``tr(R^-1 Omega) > threshold``
    (``omega()`` computes Omega only when needed)."""
    if threshold <= 0:
        return np.ones(lead_shape, dtype=bool)
    Om = omega()
    return np.einsum("...ii->...", chol_solve(R, Om)) > threshold


def select(mask, xi, Pi, x1, P1):
    """Per run: the iterated ``(xi, Pi)`` where ``mask``, else ``(x1, P1)``."""
    if np.ndim(mask) == 0:
        return (xi, Pi) if mask else (x1, P1)
    return np.where(mask[..., None], xi, x1), np.where(mask[..., None, None], Pi, P1)


def _own_coordinates(trk, h, jac=None):
    """``h`` (and ``jac``) of Cartesian states made functions of the runs' own coordinates."""
    if not trk.chart.any():
        return h, jac
    hc, jc = h, jac

    def h_own(X):
        return hc(trk.chart.cart(X))

    if jac is None:
        return h_own, None

    def jac_own(X):
        return jc(trk.chart.cart(X)) @ trk.chart.T(X)

    return h_own, jac_own


class EkfUpdate:
    """EKF update with the Gaussian second-order terms of the ranges (``Tuning.ekf_second_order``:
    mean correction ``0.5 tr(M_j P)`` and innovation covariance ``0.5 tr(M_i P M_j P)``, the latter
    counted ``k`` times), Gauss-Newton iterated (Bell & Cathey 1993) for runs with large
    linearization error."""

    def __call__(self, trk, model, z, R, k=1.0):
        tu = trk.tuning
        h, jac = _own_coordinates(trk, model.value, model.jacobian)
        xl, Pl = trk._constrained()  # linearize where the density is: above the floor
        jac = trk.lag.wrap(jac, trk.chart.inv)
        if tu.ekf_second_order:
            c2, S2 = model.project(*trk._second_order(model.stations_m, model.dt_s, xl, Pl))
            h1, R = h, R + scaled(S2, k)

            def h(X):
                return h1(X) + c2

        if xl is trk._x:  # nothing truncated: the plain EKF
            x1, P1, nu, S = ekf_update(trk._x, trk._P, z, h, jac(trk._x), R)
        else:
            H, hxl = jac(xl), h(xl)
            x1, P1 = linearized_update(trk._x, trk._P, xl, H, hxl, z, R)
            nu, S = z - hxl, symmetrize(H @ Pl @ np.swapaxes(H, -1, -2) + R)
        if tu.iterations > 1:
            om = ((lambda: S2) if tu.ekf_second_order  # already computed above
                  else (lambda: omega_ekf(trk, model, xl, Pl)))
            mask = needs_iteration(tu.iterate_threshold, trk._x.shape[:-1], R, om)
            if np.any(mask):
                xi, Pi = x1, P1
                for _ in range(tu.iterations - 1):
                    xi = trk._constrained(xi, Pi)[0]
                    xi, Pi = linearized_update(trk._x, trk._P, xi, jac(xi), h(xi), z, R)
                x1, P1 = select(mask, xi, Pi, x1, P1)
        return x1, P1, nu, S


def omega_ekf(trk, model, X, P):
    """The second-order innovation covariance over the moments ``(X, P)``, per measurement row."""
    return model.project(*trk._second_order(model.stations_m, model.dt_s, X, P))[1]


class UkfUpdate:
    """UKF update, by iterated posterior linearization for runs with large linearization error. With
    ``Tuning.linearization_corr_s > 0`` the analytic second-order term over the prior (the EKF's)
    enters ``R`` times its repeats ``k``, as in the EKF: the sigma points alone do not carry it (with
    the small spread, ``alpha`` = 0.1, points at +-0.28 sigma, they probe the ranges locally, and the
    iterated linearization re-evaluates them over the narrower posterior; docs/aircraft.md). With
    ``linearization_corr_s = 0`` this is the textbook UKF (filterpy comparison)."""

    def __call__(self, trk, model, z, R, k=None):
        tu = trk.tuning
        xl, Pl = trk._constrained()  # sigma points where the density is: above the floor
        if k is not None and tu.linearization_corr_s > 0:
            R = R + scaled(omega_ekf(trk, model, xl, Pl), k)
        h, _ = _own_coordinates(trk, model.value)
        jac = model.jacobian
        dA = None  # the regression slope moved along the lagged direction as the EKF's Jacobian
        if trk.lag.active(trk.chart.inv):
            J = jac(xl)
            Dp, m = trk.lag.correction(jac, xl, J, trk.chart.inv)
            dA = np.zeros_like(J)
            dA[..., POS] = np.where(m, Dp, 0.0)
        ut = None  # the sigma points' transform over (xl, Pl), when the update has it
        if xl is trk._x and dA is None:  # nothing truncated, no lag: the plain UKF
            x1, P1, nu, S = ukf_update(trk._x, trk._P, z, h, R, trk.params)
        else:  # statistical linearization over the truncated moments, applied to the filter's Gaussian
            x1, P1, ut = iplf_step(trk._x, trk._P, xl, Pl, z, h, R, trk.params, dA)
            nu, S = z - ut.mean, symmetrize(ut.cov + R)
        if tu.iterations > 1:
            def om():
                u = ut if ut is not None else unscented_transform(h, xl, Pl, trk.params)
                return u.cov - np.swapaxes(u.cross, -1, -2) @ chol_solve(Pl, u.cross)
            mask = needs_iteration(tu.iterate_threshold, trk._x.shape[:-1], R, om)
            if np.any(mask):
                xi, Pi = x1, P1
                for _ in range(tu.iterations - 1):
                    xi, Pi, _ = iplf_step(trk._x, trk._P, *trk._constrained(xi, Pi), z, h, R, trk.params)
                x1, P1 = select(mask, xi, Pi, x1, P1)
        return x1, P1, nu, S


STRATEGIES = {"ekf": EkfUpdate(), "ukf": UkfUpdate()}
