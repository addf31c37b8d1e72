"""Measurement models of the radio filters: one batch of pseudoranges or range differences, each with
value, Jacobian and noise (the formulas are :mod:`.models`'; seed 001 eqs. 10, 13, 15-18).

States are Cartesian ``[x (n), beta (nb)]`` (..., n + nb): the base state of :class:`.state.StateLayout`
and the stations' clock-bias states; ``D`` (m, nb) maps those to the stations of the batch (None: no
bias states). Each measurement may be taken ``dt_s`` (m,) away from the state's time (TDMA).
"""

from __future__ import annotations

import numpy as np

from . import models as mdl
from .state import POS, VEL


class PseudorangeModel:
    """Pseudoranges ``rho_j = |p + v dt_j - s_j| + b (+ bdot dt_j) + D_j beta + v_j`` (..., m)."""

    kind = "pr"

    def __init__(self, stations_m: np.ndarray, n0: int, dt_s: np.ndarray | None = None, D: np.ndarray | None = None):
        self.stations_m, self.n0, self.dt_s = stations_m, n0, dt_s
        self.Db = self.bias_map(D)

    def bias_map(self, D):
        return D

    def base_value(self, X: np.ndarray) -> np.ndarray:
        return mdl.h_pr(X[..., :self.n0], self.stations_m, self.dt_s)

    def base_jacobian(self, X: np.ndarray) -> np.ndarray:
        return mdl.jac_pr(X[..., :self.n0], self.stations_m, self.dt_s)

    def value(self, X: np.ndarray) -> np.ndarray:
        """``h(X)`` (..., rows) for states X (..., n + nb)."""
        if self.Db is None:
            return self.base_value(X)
        return self.base_value(X) + X[..., self.n0:] @ self.Db.T

    def jacobian(self, X: np.ndarray) -> np.ndarray:
        """``dh/dX`` (..., rows, n + nb)."""
        J = self.base_jacobian(X)
        if self.Db is None:
            return J
        Db = self.Db if J.ndim == 2 else np.broadcast_to(self.Db, J.shape[:-1] + self.Db.shape[-1:])
        return np.concatenate([J, Db], axis=-1)

    def z(self, rho_m: np.ndarray) -> np.ndarray:
        """The measurement vector of the pseudoranges ``rho_m`` (..., m)."""
        return rho_m

    def noise(self, X: np.ndarray, station_cov_m2, sigma_m) -> np.ndarray:
        """Noise covariance (..., rows, rows): ``sigma^2 + u^T P_station u`` per range at states X."""
        return mdl.r_pr(mdl.range_var(X, self.stations_m, station_cov_m2, sigma_m, self.dt_s))

    def project(self, c2: np.ndarray, S2: np.ndarray):
        """Per-range terms (..., m), (..., m, m) -> per row."""
        return c2, S2


class RangeDifferenceModel(PseudorangeModel):
    """Range differences ``rho_j - rho_base`` for ``j != base`` (..., m-1): the receiver clock cancels,
    the stations' biases enter as ``G D beta``; noise ``G R G^T``."""

    kind = "tdoa"

    def __init__(self, stations_m, n0, base: int, dt_s=None, D=None):
        self.base = base
        self.G = mdl.g_matrix(stations_m.shape[0], base)
        super().__init__(stations_m, n0, dt_s, D)

    def bias_map(self, D):
        return None if D is None else mdl.g_matrix(self.stations_m.shape[0], self.base) @ D

    def base_value(self, X):
        return mdl.h_tdoa(X[..., :self.n0], self.stations_m, self.base, self.dt_s)

    def base_jacobian(self, X):
        return mdl.jac_tdoa(X[..., :self.n0], self.stations_m, self.base, self.dt_s)

    def z(self, rho_m):
        b = self.base
        return np.delete(rho_m, b, axis=-1) - rho_m[..., b : b + 1]

    def noise(self, X, station_cov_m2, sigma_m):
        return mdl.r_tdoa(mdl.range_var(X, self.stations_m, station_cov_m2, sigma_m, self.dt_s), self.base)

    def project(self, c2, S2):
        G = self.G
        return np.einsum("ij,...j->...i", G, c2), G @ S2 @ G.T


def make_model(kind: str, stations_m: np.ndarray, n0: int, base: int = 0, dt_s=None, D=None) -> PseudorangeModel:
    """The batch's model: ``kind`` "pr" (pseudoranges) or "tdoa" (differences against ``base``)."""
    if kind == "pr":
        return PseudorangeModel(stations_m, n0, dt_s, D)
    return RangeDifferenceModel(stations_m, n0, base, dt_s, D)


def second_order(stations_m: np.ndarray, dt_s: np.ndarray | None, X: np.ndarray, P: np.ndarray):
    """Gaussian second-order terms of the ranges over Cartesian moments ``X`` (..., n), ``P`` (..., n, n):
    mean correction ``c_j = 0.5 tr(M_j C_jj)`` (..., m) and covariance ``0.5 tr(M_i C_ij M_j C_ji)``
    (..., m, m), with ``M_j = (I - u_j u_j^T) / r_j`` the Hessian of range j in the position at its
    measurement time and ``C_ij`` the covariance of those positions (``p + v dt``). Close to a
    transmitter the range's curvature biases a first-order EKF."""
    r, u = mdl.los(X, stations_m, dt_s)  # (..., m), (..., m, 3)
    Mh = (np.eye(3) - u[..., :, None] * u[..., None, :]) / r[..., None, None]  # (..., m, 3, 3)
    Ppp = P[..., None, None, POS, POS]
    if dt_s is None:
        C = np.broadcast_to(Ppp, Mh.shape[:-3] + (Mh.shape[-3],) * 2 + (3, 3))
    else:
        d = np.asarray(dt_s, dtype=float)
        Ppv = P[..., None, None, POS, VEL]
        Pvv = P[..., None, None, VEL, VEL]
        di, dj = d[:, None, None, None], d[None, :, None, None]
        C = Ppp + Ppv * dj + np.swapaxes(Ppv, -1, -2) * di + Pvv * (di * dj)
    MC = Mh[..., :, None, :, :] @ C  # M_i C_ij: (..., m, m, 3, 3)
    c2 = 0.5 * np.einsum("...jjkk->...j", MC)
    S2 = 0.5 * np.einsum("...ijkl,...jilk->...ij", MC, MC)  # tr(M_i C_ij M_j C_ji)
    return c2, S2
