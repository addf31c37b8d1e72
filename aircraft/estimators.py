"""Aircraft position estimators (sans-I/O, vectorized over Monte Carlo runs on the leading axis).

* :func:`lsq_pr`, :func:`lsq_tdoa` - snapshot iterative least squares (seed 001 eq. 14 with the
  weights of eqs. 16 and 18).
* :class:`CvTracker` - EKF or UKF on the constant-velocity model, pseudorange or TDOA measurements.
  Prediction is the linear CV step (``nav.kalman.kf_predict``; the unscented transform of a linear map
  is exact, so the UKF's prediction equals it); updates are ``nav.kalman.ekf_update`` /
  ``nav.kalman.ukf_update`` with the scaled sigma points of ``nav.ut`` (alpha, beta = 2, kappa = 0).
* :class:`AircraftEstimator` - the small message-level API the aircraft node, the bench and a replay
  share: ``on_measurement`` (one TDMA slot), ``on_epoch`` (synchronous epoch), ``estimate()``.

Shapes: ``M`` runs, ``m`` stations in a batch, ``n`` states. Stations are shared by all runs.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy.special import erfcx

from nav.kalman import chol_solve, ekf_update, kf_predict, kf_update, nees, symmetrize, ukf_update
from nav.pcrb import gauss_markov_block
from nav.ut import SigmaParams, unscented_transform

from . import coords as crd
from . import models as mdl
from .fde import FdeConfig, FilterFde, fault_vectors, protection_levels, snooping
from .navigator import receiver as rx

if TYPE_CHECKING:  # aircraft.initializer imports this module: annotation only, no import cycle
    from .initializer import InitConfig

ALGOS = mdl.ALGOS
# correlation time of a station's residual sync error after the broadcast correction, s (measured with
# the station clock filter on the seed000 world, TCXO clocks: docs/sync.md)
CLOCK_BIAS_TAU_S = 6.0


# --------------------------------------------------------------------------- snapshot LSQ
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
    nrm = np.linalg.norm(dx[..., :3], axis=-1, keepdims=True)
    return dx * np.minimum(1.0, max_step_m / np.maximum(nrm, 1e-300))


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
    x : (M, 4) estimates ``[x y z b]``.
    """
    x = np.array(x0, dtype=float)
    sigma = np.sqrt(np.broadcast_to(var_m2, (stations_m.shape[0],)))
    for _ in range(iters):
        X = np.concatenate([x[..., :3], np.zeros(x.shape[:-1] + (3,)), x[..., 3:4]], axis=-1)
        H = mdl.jac_pr(X, stations_m)[..., [0, 1, 2, 6]]
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
    """
    x = np.array(x0, dtype=float)
    m = stations_m.shape[0]
    G = mdl.g_matrix(m, base)
    z = np.einsum("ij,...j->...i", G, rho_m)
    sigma = np.sqrt(np.broadcast_to(var_m2, (m,)))
    for _ in range(iters):
        X = np.concatenate([x, np.zeros(x.shape[:-1] + (3,))], axis=-1)
        H = mdl.jac_tdoa(X, stations_m, base)[..., :3]
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
    X = np.concatenate([x[..., :3], np.zeros(x.shape[:-1] + (3,)), x[..., 3:]], axis=-1)
    var = mdl.range_var(X, stations_m, station_cov_m2, sigma)
    if model == "pr":
        H = mdl.jac_pr(X, stations_m)[..., [0, 1, 2, 6]]
        N = np.swapaxes(H, -1, -2) @ (H / var[..., None])
    else:
        H = mdl.jac_tdoa(X, stations_m, base)[..., :3]
        N = np.swapaxes(H, -1, -2) @ chol_solve(mdl.r_tdoa(var, base), H)
    k = N.shape[-1]
    return symmetrize(chol_solve(symmetrize(N), np.broadcast_to(np.eye(k), N.shape).copy()))


# --------------------------------------------------------------------------- filters
@dataclass(frozen=True)
class Tuning:
    """One filter tuning (shared by all trajectories).

    ``q_acc`` white-acceleration density (m^2/s^3), ``q_acc_z`` its vertical one; ``q_clock`` clock random walk (m^2/s);
    ``q_drift`` clock-rate random walk (m^2/s^3, drift state only); ``alpha`` UKF spread;
    ``sigma_m`` nominal pseudorange noise; ``p0_*`` initial standard deviations.
    """

    q_acc: float = 1.0
    q_acc_z: float | None = None  # vertical white-acceleration density; None = q_acc
    q_clock: float = 1e-4
    q_drift: float = 1e-4
    drift_state: bool = True
    alpha: float = 1e-1
    sigma_m: float = 0.5
    p0_pos_m: float = 20.0
    p0_vel_m_s: float = 5.0
    p0_clock_m: float = 20.0
    p0_drift_m_s: float = 1.0
    floor_z_m: float | None = 0.0  # station plane: LSQ mirrors below it, filters truncate (None: off)
    trunc_sigma: float = 6.0
    sequential: bool = False  # pseudorange epochs as sequential scalar updates (else one vector update)
    # iterated measurement update: 1 = plain EKF/UKF; k > 1 re-linearizes k - 1 more times about the
    # latest posterior (EKF: Gauss-Newton IEKF; UKF: iterated posterior linearization, the statistical
    # linear regression of h over the latest posterior's sigma points)
    iterations: int = 2
    # ... only for runs whose linearization error over the prior is large: tr(R^-1 Omega) > this, with
    # Omega the statistical-linearization error covariance of h over the prior (UKF: Py - Pxz^T P^-1 Pxz;
    # EKF: its second-order term 0.5 tr(M_i P M_j P), with R already including that term when
    # ekf_second_order is on). 0 = always iterate.
    iterate_threshold: float = 1.0
    # EKF: Gaussian second-order terms of the range (Hessian (I - u u^T) / r): mean correction
    # 0.5 tr(M_j P) and innovation covariance 0.5 tr(M_i P M_j P). Close to a transmitter the range's
    # curvature biases a first-order EKF (the UKF captures it through its sigma points).
    ekf_second_order: bool = True
    # ... and that term's covariance is not white: it is a function of the state error, which changes
    # slowly (the stations' clock biases, the hover), so the same linearization error repeats at every
    # update. It enters R scaled by the number of times it repeats: the longer of the filter's memory
    # time and the time since its start, at most this long, over the station's own measurement interval
    # (CvTracker._repeats; 0 = white, the textbook second-order EKF); the UKF gets the same term.
    # Far from the transmitters it is negligible; 2.6 m above one (seed001 hover 50 m) it keeps the
    # filters from reading curvature as information (docs/aircraft.md, "Linearization error").
    linearization_corr_s: float = 10.0
    # filter coordinates: "inverse" = position inverted through the unit sphere about the broadcast
    # station centroid and the clock carried as b + range to it (aircraft/coords.py: straightens the
    # height/clock and range/clock ridges of a small-base system); "cartesian" = [p, v, b, bdot]
    coords: str = "inverse"
    # ... per run, only while the position is known well relative to its distance from the reference:
    # sqrt(tr P_pos) < inverse_max_rel * |p - c| (back to Cartesian above twice that; near the
    # array the inversion of a wide Gaussian is itself far from Gaussian). Checked after every update.
    inverse_max_rel: float = 0.15
    # ... and only beyond this many array radii (RMS station distance from the centroid) from the
    # reference: close to the array the ranges to single stations dominate the nonlinearity
    inverse_min_radii: float = 3.0
    # runs in Cartesian coordinates (near the array): the Jacobian (EKF) or the sigma points'
    # regression slope (UKF) along one direction is taken at the position low-passed over this many
    # seconds (restarted at the estimate beyond 4 sigma: a moving aircraft). Where a direction is not
    # observable (right above the array: the height; on a mirror plane of the square: x, z and the
    # clock) the Jacobian along it, taken at the estimate, is proportional to the estimate's own error
    # across it, which the innovation also carries, and the noise-driven product drove the estimate
    # along the ridge (~2 m/s up at hover 100 m overhead, docs/aircraft.md). 0 = at the estimate.
    height_jacobian_lag_s: float = 2.0
    # ... which direction: "weakest" (the least observable position direction from the filter's own
    # information, low-passed; the position lagged across it, current along it) or "height" (the
    # height column at the low-passed horizontal position, as until 2026-11-26)
    lag_direction: str = "weakest"
    # residual station clock errors after the broadcast clock correction (docs/sync.md): "states" = one
    # first-order Gauss-Markov range bias per station heard, stationary variance = the broadcast clock
    # variance c^2 P_theta, correlation time ``clock_bias_tau_s`` (added as a station is first heard,
    # dropped after ``clock_bias_drop_s`` without a measurement); "white" = the broadcast variance added
    # to each range's variance as if independent between measurements (wrong for a slowly varying
    # sync error: 4-8 x the bound, docs/sync.md)
    clock_bias: str = "states"
    clock_bias_tau_s: float = CLOCK_BIAS_TAU_S
    clock_bias_drop_s: float = 60.0

    def p0(self, layout: mdl.StateLayout) -> np.ndarray:
        d = [self.p0_pos_m] * 3 + [self.p0_vel_m_s] * 3
        if layout.kind == "pr":
            d.append(self.p0_clock_m)
            if layout.drift:
                d.append(self.p0_drift_m_s)
        return np.diag(np.square(d))


class CvTracker:
    """EKF / UKF on the constant-velocity model, batched over ``M`` runs.

    Parameters
    ----------
    kind : "ekf" or "ukf". model : "pr" or "tdoa". x0 : (M, n) initial means. tuning : :class:`Tuning`.
    t0_s : time of ``x0``. base : TDOA base station index within each batch.
    P0 : (n, n) or (M, n, n) initial covariance; None = the tuning's prior ``tuning.p0``.
    ref_m : (3,) reference point of the inverse-range coordinates (``tuning.coords == "inverse"``):
        :func:`aircraft.coords.reference_point` of the broadcast stations; None = that of the first
        update's stations. ref_radius_m : RMS distance of the stations from ``ref_m``
        (:func:`aircraft.coords.array_radius`).

    ``x`` and ``P`` are always Cartesian (``[p, v (, b (, bdot))]``); with inverse coordinates the
    filter works on ``(q, v, beta, bdot)`` internally and converts on access (covariance to first
    order, ``T P T^T``).
    """

    def __init__(self, kind: str, model: str, x0: np.ndarray, tuning: Tuning, t0_s: float = 0.0, base: int = 0,
                 P0: np.ndarray | None = None, ref_m: np.ndarray | None = None,
                 ref_radius_m: float | None = None):
        if kind not in ("ekf", "ukf"):
            raise ValueError(f"unknown filter {kind!r} (ekf or ukf)")
        self.kind = kind
        self.layout = mdl.StateLayout(model, drift=tuning.drift_state and model == "pr")
        self.tuning = tuning
        x0 = np.asarray(x0, dtype=float)  # (M, n) batched, or (n,) for one run (faster small-matrix path)
        if x0.shape[-1] != self.layout.n:
            raise ValueError(f"x0 must have {self.layout.n} states for {model}, got {x0.shape}")
        if tuning.coords not in ("inverse", "cartesian"):
            raise ValueError(f"unknown coords {tuning.coords!r} (inverse or cartesian)")
        if tuning.lag_direction not in ("weakest", "height"):
            raise ValueError(f"unknown lag_direction {tuning.lag_direction!r} (weakest or height)")
        if tuning.clock_bias not in ("states", "white"):
            raise ValueError(f"unknown clock_bias {tuning.clock_bias!r} (states or white)")
        self.n_base = self.layout.n  # states after these: the stations' clock biases (bias_ids order)
        self.bias_ids: list = []
        self._bias_var = np.zeros(0)  # their stationary variances (latest broadcast), m^2
        self._bias_t = np.zeros(0)  # time each was last measured
        self._x = x0.copy()
        P0 = tuning.p0(self.layout) if P0 is None else np.asarray(P0, dtype=float)
        self._P = np.broadcast_to(P0, x0.shape[:-1] + (self.layout.n,) * 2).copy()
        self._clock = self.layout.kind == "pr"
        self._ref: np.ndarray | None = None  # reference point of the inverse-range coordinates
        self._inv = np.zeros(x0.shape[:-1], dtype=bool)  # runs whose internal state is inverse-range
        self._radius = 0.0  # RMS distance of the stations from the reference point
        if tuning.coords == "inverse" and ref_m is not None:
            self._ref = np.asarray(ref_m, dtype=float)
            self._radius = float(ref_radius_m) if ref_radius_m is not None else 0.0
            self._switch()
        self.t_s = float(t0_s)
        self._memory = 1.0  # updates the filter averages over (per run), from the latest update
        self._last_seen: dict = {}  # station (id, or position to 0.1 m) -> time of its latest measurement
        self._t_start_s = float(t0_s)
        self.base = base
        self.params = SigmaParams.scaled(alpha=tuning.alpha, beta=2.0, kappa=0.0)
        self._fq: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        self._last_dt: float | None = None
        self._last_fq: tuple[np.ndarray, np.ndarray] | None = None
        self._step_s = 0.0  # the latest prediction step: updates per linearization_corr_s
        self._r_key: tuple | None = None
        self._r: np.ndarray | None = None
        self._tcache: tuple | None = None  # (x, P, truncated x, truncated P): see _constrained
        self._hlag: np.ndarray | None = None  # low-passed horizontal positions (..., 2): height_jacobian_lag_s
        self._lagF: np.ndarray | None = None  # low-passed information of (position, clock) ("weakest")
        self._ndir: np.ndarray | None = None  # the least observable position direction (..., 3) ("weakest")
        self._ncomp: np.ndarray | None = None  # an orthonormal basis of its complement (..., 3, 2)
        self._ndir_t_s = -np.inf  # when it was last computed

    # -- coordinates
    def _mask(self, X: np.ndarray, extra: int) -> np.ndarray:
        """The inverse-coordinate run mask shaped to broadcast against X (runs[, sigma], n[, n])."""
        return self._inv.reshape(self._inv.shape + (1,) * (X.ndim - self._x.ndim + extra))

    def _cart(self, X: np.ndarray) -> np.ndarray:
        """Internal-coordinate states X (runs[, sigma points], n) -> Cartesian."""
        if not self._inv.any():
            return X
        with np.errstate(all="ignore"):
            return np.where(self._mask(X, 1), crd.to_cartesian(X, self._ref, self._clock), X)

    def _T(self, X: np.ndarray) -> np.ndarray | None:
        """dx/ds at internal-coordinate states X (..., n, n); None = identity for every run."""
        if not self._inv.any():
            return None
        with np.errstate(all="ignore"):
            return np.where(self._mask(X, 2), crd.jac_to_cartesian(X, self._clock), np.eye(X.shape[-1]))

    @property
    def x(self) -> np.ndarray:
        """Cartesian state (..., n): the mean of the filter's density above the floor (truncated)."""
        return self._cart(self._constrained()[0])

    @x.setter
    def x(self, value: np.ndarray) -> None:
        value = np.asarray(value, dtype=float)
        if self._inv.any():
            with np.errstate(all="ignore"):
                value = np.where(self._mask(value, 1), crd.to_inverse(value, self._ref, self._clock), value)
        self._x = value

    @property
    def P(self) -> np.ndarray:
        """Cartesian covariance (..., n, n) of the density above the floor (first-order conversion
        ``T P T^T`` for inverse-coordinate runs)."""
        xc, Pc = self._constrained()
        T = self._T(xc)
        if T is None:
            return Pc
        return symmetrize(T @ Pc @ np.swapaxes(T, -1, -2))

    @P.setter
    def P(self, value: np.ndarray) -> None:
        value = np.asarray(value, dtype=float)
        if self._inv.any():
            with np.errstate(all="ignore"):
                G = np.where(self._mask(self._x, 2), crd.jac_to_inverse(self._cart(self._x), self._ref, self._clock),
                             np.eye(value.shape[-1]))
            value = symmetrize(G @ value @ np.swapaxes(G, -1, -2))
        self._P = value

    def _switch(self) -> None:
        """Move runs between Cartesian and inverse-range coordinates: inverse while the relative
        position uncertainty ``sqrt(tr P_pos) / |p - c|`` is below ``inverse_max_rel``, back to
        Cartesian above twice that (checked on the runs' own coordinates: in inverse ones
        ``sqrt(tr P_qq) / |q|`` is the same ratio to first order)."""
        n = self._x.shape[-1]
        x = self._x.reshape(-1, n)
        P = self._P.reshape(-1, n, n)
        inv = self._inv.reshape(-1)
        k = self.tuning.inverse_max_rel
        d = np.where(inv[:, None], x[:, :3], x[:, :3] - self._ref)
        with np.errstate(all="ignore"):
            rel = np.sqrt(np.einsum("kii->k", P[:, :3, :3]) / np.einsum("ki,ki->k", d, d))
        with np.errstate(all="ignore"):
            r = np.sqrt(np.einsum("ki,ki->k", d, d))
            r = np.where(inv, crd.SCALE_M**2 / r, r)
        far = r > self.tuning.inverse_min_radii * self._radius
        new = np.where(inv, rel < 2.0 * k, rel < k) & far
        ch = new != inv
        if not np.any(ch):
            return
        X = self._cart(self._x).reshape(-1, n)[ch]
        T = self._T(self._x)
        Pc = P[ch] if T is None else symmetrize(T @ self._P @ np.swapaxes(T, -1, -2)).reshape(-1, n, n)[ch]
        to_inv = new[ch]
        with np.errstate(all="ignore"):
            G = crd.jac_to_inverse(X, self._ref, self._clock)
            xs = np.where(to_inv[:, None], crd.to_inverse(X, self._ref, self._clock), X)
            Ps = np.where(to_inv[:, None, None], symmetrize(G @ Pc @ np.swapaxes(G, -1, -2)), Pc)
        x2, P2 = x.copy(), P.copy()
        x2[ch], P2[ch] = xs, Ps
        self._x = x2.reshape(self._x.shape)
        self._P = P2.reshape(self._P.shape)
        self._inv = new.reshape(self._inv.shape)

    def _FQ(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        if dt == self._last_dt:  # synchronous epochs: the same step every time
            return self._last_fq
        key = round(dt, 12)
        if key not in self._fq:
            n, tu = self.layout.n, self.tuning
            if len(self._fq) > 64:
                self._fq.clear()
            F = mdl.cv_transition(n, dt)
            Q = mdl.cv_noise(n, dt, tu.q_acc, tu.q_clock, tu.q_drift, tu.q_acc_z)
            nb = len(self.bias_ids)
            if nb:  # the stations' clock biases: independent first-order Gauss-Markov
                A, Qb = gauss_markov_block(nb, self._bias_var, tu.clock_bias_tau_s, dt)
                F = np.block([[F, np.zeros((n, nb))], [np.zeros((nb, n)), A]])
                Q = np.block([[Q, np.zeros((n, nb))], [np.zeros((nb, n)), Qb]])
            self._fq[key] = (F, Q)
        self._last_dt, self._last_fq = dt, self._fq[key]
        return self._last_fq

    def _bias_changed(self) -> None:
        self._fq.clear()
        self._last_dt = self._last_fq = None

    def _use_biases(self, ids, var_m2, t_s: float) -> np.ndarray:
        """Clock-bias states for the stations ``ids`` (m,) with broadcast variances ``var_m2`` (m,):
        adds a state ``N(0, var)`` (independent of the rest) for a station heard for the first time,
        keeps the latest broadcast variance as its stationary variance, drops (marginalizes) the states
        of stations unheard for ``clock_bias_drop_s``. Returns ``D`` (m, nb): measurement j sees bias
        ``D[j] @ beta``. A station id ``None`` or a variance <= 0 (no clock correction broadcast):
        no bias for that measurement (row of zeros)."""
        var_all = np.broadcast_to(np.asarray(var_m2, dtype=float), (len(ids),))
        rows = [j for j, (sid, v) in enumerate(zip(ids, var_all)) if sid is not None and v > 0]
        m_all = len(var_all)
        ids = [ids[j] for j in rows]
        var = var_all[rows]
        stale = [k for k, sid in enumerate(self.bias_ids)
                 if sid not in ids and t_s - self._bias_t[k] > self.tuning.clock_bias_drop_s]
        if stale:
            keep = np.setdiff1d(np.arange(self._x.shape[-1]), self.n_base + np.array(stale))
            self._x = self._x[..., keep]
            self._P = self._P[..., keep[:, None], keep]
            self.bias_ids = [sid for k, sid in enumerate(self.bias_ids) if k not in stale]
            kb = np.setdiff1d(np.arange(len(self._bias_var)), stale)
            self._bias_var, self._bias_t = self._bias_var[kb], self._bias_t[kb]
            self._bias_changed()
        new = [(sid, v) for sid, v in zip(ids, var) if sid not in self.bias_ids]
        if new:
            k, n = len(new), self._x.shape[-1]
            vn = np.array([v for _, v in new])
            self._x = np.concatenate([self._x, np.zeros(self._x.shape[:-1] + (k,))], axis=-1)
            P = np.zeros(self._P.shape[:-2] + (n + k, n + k))
            P[..., :n, :n] = self._P
            P[..., n:, n:] = np.diag(vn)
            self._P = P
            self.bias_ids += [sid for sid, _ in new]
            self._bias_var = np.concatenate([self._bias_var, vn])
            self._bias_t = np.concatenate([self._bias_t, np.full(k, t_s)])
            self._bias_changed()
        idx = np.array([self.bias_ids.index(sid) for sid in ids], dtype=int)
        if not np.array_equal(self._bias_var[idx], var):
            self._bias_var[idx] = var
            self._bias_changed()
        self._bias_t[idx] = t_s
        D = np.zeros((m_all, len(self.bias_ids)))
        D[rows, idx] = 1.0
        return D

    def save(self) -> tuple:
        """The filter's state (mean, covariance, coordinates, clock-bias states) for :meth:`restore`."""
        return (self._x, self._P, self._inv, list(self.bias_ids), self._bias_var.copy(), self._bias_t.copy(),
                self._ref, self._radius, self.t_s, self._memory, dict(self._last_seen), self._hlag,
                self._lagF, self._ndir, self._ncomp, self._ndir_t_s)

    def restore(self, saved: tuple) -> None:
        """Back to a :meth:`save`d state (an update re-run with other measurements: aircraft/fde.py)."""
        (self._x, self._P, self._inv, ids, bv, bt, self._ref, self._radius, self.t_s, self._memory, seen,
         self._hlag, self._lagF, self._ndir, self._ncomp, self._ndir_t_s) = saved
        self._last_seen = dict(seen)
        self.bias_ids, self._bias_var, self._bias_t = list(ids), bv.copy(), bt.copy()
        self._bias_changed()
        self._r_key = None

    def predict_to(self, t_s: float) -> None:
        """Propagate to ``t_s`` (no-op if ``t_s <= t``: measurements are never processed backwards)."""
        dt = t_s - self.t_s
        if dt <= 0.0:
            return
        F, Q = self._FQ(dt)
        self._step_s = dt
        if not self._inv.any():
            self._x, self._P = kf_predict(self._x, self._P, F, Q)
        else:
            # the CV step in Cartesian coordinates, carried to the inverse-range runs by its Jacobian
            # G1 F T (T = dx/ds before, G1 = ds/dx after); the process noise enters through G1
            ref, clk = self._ref, self._clock
            T = self._T(self._x)
            x1 = self._cart(self._x) @ F.T
            with np.errstate(all="ignore"):
                G1 = np.where(self._mask(self._x, 2), crd.jac_to_inverse(x1, ref, clk), np.eye(F.shape[-1]))
                self._x = np.where(self._mask(self._x, 1), crd.to_inverse(x1, ref, clk), x1)
            Fs = G1 @ F @ T
            self._P = symmetrize(Fs @ self._P @ np.swapaxes(Fs, -1, -2) + G1 @ Q @ np.swapaxes(G1, -1, -2))
        self.t_s = float(t_s)

    def measurement_model(self, stations_m: np.ndarray, dt_s: np.ndarray | None = None,
                          D: np.ndarray | None = None):
        """``(h, jac)`` of one batch on Cartesian states ``[x (n), beta (nb)]`` (..., n + nb).

        Pseudoranges ``h_pr(x) + D beta`` or differences against ``self.base``
        ``h_tdoa(x) + G D beta``; ``D`` (m, nb) maps the clock-bias states to the stations of the batch
        (None: no bias states). ``jac`` returns (..., m or m-1, n + nb).
        """
        n0 = self.n_base
        if self.layout.kind == "pr":
            Db = D

            def h0(X):
                return mdl.h_pr(X[..., :n0], stations_m, dt_s)

            def j0(X):
                return mdl.jac_pr(X[..., :n0], stations_m, dt_s)
        else:
            b = self.base
            Db = None if D is None else mdl.g_matrix(stations_m.shape[0], b) @ D

            def h0(X):
                return mdl.h_tdoa(X[..., :n0], stations_m, b, dt_s)

            def j0(X):
                return mdl.jac_tdoa(X[..., :n0], stations_m, b, dt_s)
        if Db is None:
            return h0, j0

        def h(X):
            return h0(X) + X[..., n0:] @ Db.T

        def jac(X):
            J = j0(X)
            return np.concatenate([J, np.broadcast_to(Db, J.shape[:-1] + Db.shape[-1:])], axis=-1)

        return h, jac

    def update(
        self, stations_m: np.ndarray, rho_m: np.ndarray, station_cov_m2: np.ndarray | None = None,
        dt_s: np.ndarray | None = None, sigma_m: float | np.ndarray | None = None,
        bias_ids=None, bias_var_m2: np.ndarray | float | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """One batch update with pseudoranges ``rho_m`` (M, m) from ``stations_m`` (m, 3).

        ``dt_s`` (m,) are the measurement times relative to the filter time (TDMA batches).
        TDOA: the batch is differenced against ``self.base`` (needs m >= 2). Returns (nu, S).
        ``bias_ids`` (m,) station ids and ``bias_var_m2`` (m,) their broadcast clock variances
        ``c^2 P_theta``: with ``tuning.clock_bias == "states"`` each station's residual clock error is a
        Gauss-Markov state (``rho_j = h_j(x) + beta_j + v_j``; differences see ``G beta``), with
        ``"white"`` its variance is added to the range's.
        """
        stations_m = np.asarray(stations_m, dtype=float)
        if self._ref is None and self.tuning.coords == "inverse":
            self._ref = crd.reference_point(stations_m)
            self._radius = crd.array_radius(stations_m)
            self._switch()
        sig = self.tuning.sigma_m if sigma_m is None else sigma_m
        D, sig = self._bias_map(stations_m, sig, bias_ids, bias_var_m2)
        R, z = self._noise_and_z(stations_m, rho_m, station_cov_m2, sig, dt_s)
        h, jac = self.measurement_model(stations_m, dt_s, D)
        self._update_lag_direction(jac)
        repeats_on = self.tuning.linearization_corr_s > 0  # else no station bookkeeping at all
        keys = ([] if not repeats_on else [("id", sid) for sid in bias_ids] if bias_ids is not None
                else [("pos", *row) for row in np.round(stations_m, 1).tolist()])
        k = self._repeats(keys)
        if self.kind == "ekf":
            x1, P1, nu, S = self._update_ekf(stations_m, dt_s, z, h, jac, R, k)
        else:
            x1, P1, nu, S = self._update_ukf(z, h, R, stations_m, dt_s, k, jac)
        for key in keys:
            self._last_seen[key] = self.t_s
        if len(self._last_seen) > 64:  # positions as keys move as the survey does: forget old ones
            old = self.t_s - max(self.tuning.linearization_corr_s, 0.0)
            self._last_seen = {key: t for key, t in self._last_seen.items() if t >= old}
        if repeats_on:
            # the filter's memory in updates: prior variance over what one update removes (per run)
            tr0 = np.einsum("...ii->...", self._P)
            gain = tr0 - np.einsum("...ii->...", P1)
            self._memory = tr0 / np.maximum(gain, 1e-9 * tr0)
        self._x, self._P = x1, P1
        if self._ref is not None:
            self._switch()
        self._advance_hlag()
        return nu, S  # innovation and its covariance of the first (plain) linearization

    def _bias_map(self, stations_m, sig, bias_ids, bias_var_m2):
        """``(D, sig)`` of one batch: the map (m, nb) of the clock-bias states to its stations (None:
        no bias states) and the range sigma (the broadcast clock variance added with ``"white"``)."""
        D = None
        if bias_ids is not None and bias_var_m2 is not None:
            if self.tuning.clock_bias == "states":
                D = self._use_biases(bias_ids, bias_var_m2, self.t_s)
            else:
                sig = np.sqrt(np.asarray(sig, dtype=float) ** 2 + np.asarray(bias_var_m2, dtype=float))
        if D is None and self.bias_ids:
            D = np.zeros((stations_m.shape[0], len(self.bias_ids)))
        if D is not None and D.shape[-1] == 0:
            D = None
        return D, sig

    def _noise_and_z(self, stations_m, rho_m, station_cov_m2, sig, dt_s):
        """``(R, z)``: the measurement covariance and vector (pseudoranges, or TDOA differences
        against ``self.base``)."""
        if self.layout.kind == "pr":
            if station_cov_m2 is None and np.ndim(sig) == 0:  # R does not depend on the state: cache it
                key = (stations_m.shape[0], float(sig), self._x.shape[:-1])
                if self._r_key != key:
                    self._r_key, self._r = key, mdl.r_pr(mdl.range_var(self._x, stations_m, None, sig))
                R = self._r
            else:
                R = mdl.r_pr(mdl.range_var(self.x, stations_m, station_cov_m2, sig, dt_s))
            z = rho_m
        else:
            b = self.base
            R = mdl.r_tdoa(mdl.range_var(self.x, stations_m, station_cov_m2, sig, dt_s), b)
            z = np.delete(rho_m, b, axis=-1) - rho_m[..., b : b + 1]
        return R, z

    def _update_ekf(self, stations_m, dt_s, z, h, jac, R, k=1.0):
        """EKF update (second-order terms, iterated for runs with large linearization error);
        returns ``(x, P, nu, S)``."""
        if self._inv.any():  # measurement model and Jacobian in the runs' own coordinates
            hc, jc = h, jac

            def h(X):
                return hc(self._cart(X))

            def jac(X):
                return jc(self._cart(X)) @ self._T(X)

        xl, Pl = self._constrained()  # linearize where the density is: above the floor
        jac = self._lagged_jac(jac)
        if self.tuning.ekf_second_order:
            # Gaussian second-order terms of the ranges, from those moments
            c2, S2 = self._second_order(stations_m, dt_s, xl, Pl)
            if self.layout.kind == "tdoa":
                G = mdl.g_matrix(stations_m.shape[0], self.base)
                c2, S2 = np.einsum("ij,...j->...i", G, c2), G @ S2 @ G.T
            h1, R = h, R + _scaled(S2, k)

            def h(X):
                return h1(X) + c2

        if xl is self._x:  # nothing truncated: the plain EKF
            x1, P1, nu, S = ekf_update(self._x, self._P, z, h, jac(self._x), R)
        else:
            H, hxl = jac(xl), h(xl)
            x1, P1 = self._linearized_update(xl, H, hxl, z, R)
            nu, S = z - hxl, symmetrize(H @ Pl @ np.swapaxes(H, -1, -2) + R)
        if self.tuning.iterations > 1:
            om = ((lambda: S2) if self.tuning.ekf_second_order  # already computed above
                  else (lambda: self._om_ekf(stations_m, dt_s, xl, Pl)))
            mask = self._needs_iteration(R, om)
            if np.any(mask):
                xi, Pi = x1, P1
                for _ in range(self.tuning.iterations - 1):
                    xi, Pi = self._iekf_step(self._constrained(xi, Pi)[0], z, h, jac, R)
                x1, P1 = self._select(mask, xi, Pi, x1, P1)
        return x1, P1, nu, S

    def _repeats(self, keys: list) -> np.ndarray:
        """How many times one linearization error enters the estimate, per measurement row (..., rows)
        (or a scalar), at most ``Tuning.linearization_corr_s`` worth of that station's measurements.

        The error repeats while the estimation error it comes from persists: over the filter's memory
        time (its memory in updates, prior variance over what an update removes, times the update
        step) or the time since the start, whichever is longer. While a filter converges from a wide
        first prior its error changes at every update (counted as repeating then, the prior would hold
        the measurements off); once either has grown, the same error comes back. Within that time a
        station's range comes once per its own measurement interval (``keys``: the stations of this
        update; one update step in synchronous epochs, one TDMA cycle when the stations take turns).
        Counting updates instead over-counted TDMA ranges by the number of stations in the rotation,
        and the inflated noise then kept the memory long: a live aircraft 1.5 km out started from a
        100-140 m wide prior was still 50 m wide after 30 s (docs/aircraft.md)."""
        corr = self.tuning.linearization_corr_s
        if corr <= 0 or self._step_s <= 0:
            return np.ones(())
        t, step = self.t_s, self._step_s
        # a station not heard within the window (or never) counts once: its error has not repeated
        dtj = np.array([max(step, t - self._last_seen.get(key, -np.inf)) for key in keys])
        if self.layout.kind == "tdoa":  # rows are differences against the base station
            dtj = np.delete(dtj, self.base)
        tau = np.maximum(np.asarray(self._memory) * step, t - self._t_start_s)
        return np.clip(tau[..., None] / dtj, 1.0, np.maximum(1.0, corr / dtj))

    def _update_ukf(self, z, h, R, stations_m=None, dt_s=None, k=None, jac=None):
        """UKF update (iterated posterior linearization for runs with large linearization error);
        returns ``(x, P, nu, S)``. With ``Tuning.linearization_corr_s > 0`` the analytic second-order
        term over the prior (the EKF's, :meth:`_second_order`) enters ``R`` times its repeats, as in
        the EKF. The sigma points alone do not carry it: with the small spread (``alpha`` = 0.1, points
        at +-0.28 sigma) they probe the ranges locally, and the iterated linearization re-evaluates
        them over the narrower posterior. Counting only the repeats beyond one (the sigma points
        taken for the first) left single runs near the transmitters over-confident from the first
        update of a 20 m prior (envelope hover/turn 50 m overhead: NEES 10^2-10^4, docs/aircraft.md).
        With ``linearization_corr_s = 0`` this is the textbook UKF (filterpy comparison)."""
        xl, Pl = self._constrained()  # sigma points where the density is: above the floor
        if stations_m is not None and k is not None and self.tuning.linearization_corr_s > 0:
            R = R + _scaled(self._om_ekf(stations_m, dt_s, xl, Pl), k)
        if self._inv.any():
            hc = h

            def h(X):
                return hc(self._cart(X))

        dA = None  # the regression slope moved along the lagged direction as the EKF's Jacobian
        if jac is not None and self._lags():
            J = jac(xl)
            Dp, m = self._lag_correction(jac, xl, J)
            dA = np.zeros_like(J)
            dA[..., :3] = np.where(m, Dp, 0.0)
        if xl is self._x and dA is None:  # nothing truncated, no lag: the plain UKF
            x1, P1, nu, S = ukf_update(self._x, self._P, z, h, R, self.params)
        else:  # statistical linearization over the truncated moments, applied to the filter's Gaussian
            x1, P1, ut = self._iplf_step(xl, Pl, z, h, R, dA)
            nu, S = z - ut.mean, symmetrize(ut.cov + R)
        if self.tuning.iterations > 1:
            def om():
                ut = unscented_transform(h, xl, Pl, self.params)
                return ut.cov - np.swapaxes(ut.cross, -1, -2) @ chol_solve(Pl, ut.cross)
            mask = self._needs_iteration(R, om)
            if np.any(mask):
                xi, Pi = x1, P1
                for _ in range(self.tuning.iterations - 1):
                    xi, Pi, _ = self._iplf_step(*self._constrained(xi, Pi), z, h, R)
                x1, P1 = self._select(mask, xi, Pi, x1, P1)
        return x1, P1, nu, S

    def _needs_iteration(self, R, omega):
        """Runs whose linearization error over the prior is large: ``tr(R^-1 Omega) > threshold``."""
        th = self.tuning.iterate_threshold
        if th <= 0:
            return np.ones(self._x.shape[:-1], dtype=bool)
        Om = omega()
        return np.einsum("...ii->...", chol_solve(R, Om)) > th

    def _om_ekf(self, stations_m, dt_s, X, P):
        S2 = self._second_order(stations_m, dt_s, X, P)[1]
        if self.layout.kind == "tdoa":
            G = mdl.g_matrix(stations_m.shape[0], self.base)
            S2 = G @ S2 @ G.T
        return S2

    @staticmethod
    def _select(mask, xi, Pi, x1, P1):
        if np.ndim(mask) == 0:
            return (xi, Pi) if mask else (x1, P1)
        return np.where(mask[..., None], xi, x1), np.where(mask[..., None, None], Pi, P1)

    def _second_order(self, stations_m, dt_s, X, P):
        """Second-order terms of the pseudoranges at the current estimate: mean correction
        ``c_j = 0.5 tr(M_j C_jj)`` (..., m) and covariance ``0.5 tr(M_i C_ij M_j C_ji)`` (..., m, m), with
        ``M_j = (I - u_j u_j^T) / r_j`` the Hessian of range j in the position at its measurement time
        and ``C_ij`` the covariance of those positions (``p + v dt``). ``X`` (..., n), ``P`` (..., n, n):
        the moments in the runs' own coordinates (the filter's, truncated to above the floor). For
        inverse-coordinate runs the terms are those of the converted Cartesian moments: the Hessian in
        the runs' own coordinates (much smaller far out) was tried and left more runs over-confident
        (docs/aircraft.md, "the floor counted once")."""
        T = self._T(X)
        if T is not None:  # Cartesian moments (the inverse-coordinate runs converted)
            X, P = self._cart(X), symmetrize(T @ P @ np.swapaxes(T, -1, -2))
        r, u = mdl.los(X, stations_m, dt_s)  # (..., m), (..., m, 3)
        Mh = (np.eye(3) - u[..., :, None] * u[..., None, :]) / r[..., None, None]  # (..., m, 3, 3)
        Ppp = P[..., None, None, 0:3, 0:3]
        if dt_s is None:
            C = np.broadcast_to(Ppp, Mh.shape[:-3] + (Mh.shape[-3],) * 2 + (3, 3))
        else:
            d = np.asarray(dt_s, dtype=float)
            Ppv = P[..., None, None, 0:3, 3:6]
            Pvv = P[..., None, None, 3:6, 3:6]
            di, dj = d[:, None, None, None], d[None, :, None, None]
            C = Ppp + Ppv * dj + np.swapaxes(Ppv, -1, -2) * di + Pvv * (di * dj)
        MC = Mh[..., :, None, :, :] @ C  # M_i C_ij: (..., m, m, 3, 3)
        c2 = 0.5 * np.einsum("...jjkk->...j", MC)
        S2 = 0.5 * np.einsum("...ijkl,...jilk->...ij", MC, MC)  # tr(M_i C_ij M_j C_ji)
        return c2, S2

    def _iekf_step(self, xi, z, h, jac, R):
        """One Gauss-Newton step of the iterated EKF (Bell & Cathey 1993): linearize ``h`` at the
        current iterate ``xi`` and update the prior ``(x, P)`` with ``z - h(xi) - H (x - xi)``."""
        return self._linearized_update(xi, jac(xi), h(xi), z, R)

    def _linearized_update(self, xi, H, hxi, z, R):
        """Update the prior ``(x, P)`` with ``h`` linearized at ``xi``: ``z - h(xi) - H (x - xi)``."""
        def h_lin(X):
            return hxi + np.einsum("...ij,...j->...i", H, X - xi)

        x1, P1, _, _ = ekf_update(self._x, self._P, z, h_lin, H, R)
        return x1, P1

    def _iplf_step(self, xi, Pi, z, h, R, dA=None):
        """One iterated posterior linearization step (Garcia-Fernandez et al. 2015): the statistical
        linear regression ``h(X) ~ A X + b + e``, ``e ~ N(0, Omega)`` over the sigma points of the
        latest posterior ``N(xi, Pi)``, then a linear update of the prior ``(x, P)`` with it. The first
        pass (``xi, Pi`` = prior) is exactly the plain UKF update. ``dA``: a change of the slope (the
        lagged direction, :meth:`_lagged_jac`), the line kept through the mean prediction at
        ``xi``; the residual covariance stays that of the regression."""
        ut = unscented_transform(h, xi, Pi, self.params)
        At = chol_solve(Pi, ut.cross)  # (n, m): Pi A^T = Pxz
        A = np.swapaxes(At, -1, -2)
        b = ut.mean - np.einsum("...ij,...j->...i", A, xi)
        Om = symmetrize(ut.cov - A @ ut.cross)  # Py - A Pi A^T
        w, V = np.linalg.eigh(Om)  # >= 0 in exact arithmetic; the scaled set's negative W0c can break it
        Om = (V * np.maximum(w, 0.0)[..., None, :]) @ np.swapaxes(V, -1, -2)
        if dA is not None:
            A = A + dA
            b = ut.mean - np.einsum("...ij,...j->...i", A, xi)
        x1, P1, _, _ = kf_update(self._x, self._P, z - b, A, R + Om)
        return x1, P1, ut

    def update_sequential(
        self, stations_m: np.ndarray, rho_m: np.ndarray, station_cov_m2: np.ndarray | None = None,
        bias_ids=None, bias_var_m2: np.ndarray | float | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Pseudorange epoch as sequential scalar updates (re-linearized / sigma points redrawn after
        each). Equivalent to the batch update for a linear model; for ranges it reduces the EKF's
        linearization error close to a transmitter. Returns the stacked (nu (..., m), S diag (..., m))."""
        if self.layout.kind != "pr":
            raise ValueError("sequential scalar updates need independent pseudoranges (pr model)")
        nus, Ss = [], []
        m = stations_m.shape[0]
        bv = None if bias_var_m2 is None else np.broadcast_to(np.asarray(bias_var_m2, dtype=float), (m,))
        for j in range(m):
            c = None if station_cov_m2 is None else station_cov_m2[j : j + 1]
            kw = ({} if bias_ids is None or bv is None
                  else {"bias_ids": [list(bias_ids)[j]], "bias_var_m2": bv[j : j + 1]})
            nu, S = self.update(stations_m[j : j + 1], rho_m[..., j : j + 1], c, **kw)
            nus.append(nu[..., 0])
            Ss.append(S[..., 0, 0])
        return np.stack(nus, axis=-1), np.stack(Ss, axis=-1)

    def _lags(self) -> bool:
        return self._hlag is not None and self.tuning.height_jacobian_lag_s > 0 and not self._inv.all()

    def _lag_correction(self, jac, X, J):
        """``(Dp, m)``: the change (runs, rows, 3) of the position columns of ``J = jac(X)`` that takes
        the Jacobian along the lagged direction at the low-passed position, and the mask (runs, 1, 1) of
        the runs it applies to (Cartesian). "height": the height column at the low-passed horizontal
        position. "weakest": along the least observable direction ``n`` (unit, position), at the
        position low-passed across ``n`` and current along it: ``(J(X_l) - J(X)) n n^T``."""
        Xl = X.copy()
        if self.tuning.lag_direction == "height" or self._ndir is None:  # (weakest: not yet computed)
            Xl[..., :2] = self._hlag[..., :2]
            Dp = np.zeros(J.shape[:-1] + (3,))
            Dp[..., 2] = jac(Xl)[..., 2] - J[..., 2]
        else:
            n = self._ndir
            p = X[..., :3]
            Xl[..., :3] = self._hlag + n * np.einsum("...i,...i->...", n, p - self._hlag)[..., None]
            dJn = np.einsum("...ri,...i->...r", jac(Xl)[..., :3] - J[..., :3], n)
            Dp = dJn[..., None] * n[..., None, :]
        near = ~self._inv
        return Dp, near.reshape(near.shape + (1,) * (Dp.ndim - near.ndim))

    def _lagged_jac(self, jac):
        """``jac`` with the lagged direction of the Cartesian runs taken at the low-passed position
        (``Tuning.height_jacobian_lag_s``, ``Tuning.lag_direction``); ``jac`` itself while there is none."""
        if not self._lags():
            return jac

        def jac_l(X):
            J = jac(X)
            Dp, m = self._lag_correction(jac, X, J)
            J[..., :3] = np.where(m, J[..., :3] + Dp, J[..., :3])
            return J

        return jac_l

    def _update_lag_direction(self, jac) -> None:
        """"weakest": low-pass (over ``height_jacobian_lag_s``) the information ``A^T A`` of the
        position and clock columns of the Jacobian at the low-passed position, and take ``n`` as the
        position part of its least eigenvector (TDMA: one range per update, the rank builds up)."""
        if self.tuning.lag_direction != "weakest" or self._hlag is None or self.tuning.height_jacobian_lag_s <= 0:
            return
        X = self._cart(self._constrained()[0]).copy()  # Cartesian: the model's own Jacobian
        X[..., :3] = np.where(self._inv[..., None], X[..., :3], self._hlag)
        cols = [0, 1, 2] + ([6] if self._clock else [])  # [p, v, b, ...]
        A = jac(X)[..., cols]
        F = np.swapaxes(A, -1, -2) @ A
        a = min(1.0, self._step_s / self.tuning.height_jacobian_lag_s) if self._step_s > 0 else 1.0
        self._lagF = F if self._lagF is None else self._lagF + a * (F - self._lagF)
        if self._ndir is not None and self.t_s - self._ndir_t_s < self.tuning.height_jacobian_lag_s / 20:
            return  # the direction of an information low-passed over the lag: every 1/20 of it is enough
        w, V = np.linalg.eigh(self._lagF)
        n = V[..., :3, 0]
        self._ndir = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
        self._ncomp = _complement(self._ndir)
        self._ndir_t_s = self.t_s

    def _advance_hlag(self) -> None:
        """Low-pass the position (``a = step / height_jacobian_lag_s``): horizontal ("height"), or all
        three coordinates ("weakest"); a run more than 4 sigma (Mahalanobis, across the lagged
        direction) from it restarts at its estimate (2 sigma: hover 100 m overhead 23.0 m RMS height
        error at 16 s, 4 sigma 20.6 m, never 21.1 m; seed 2, 24 runs)."""
        lag = self.tuning.height_jacobian_lag_s
        if lag <= 0:
            return
        weakest = self.tuning.lag_direction == "weakest"
        k = 3 if weakest else 2
        xc, Pc = self._constrained()
        p = self._cart(xc)[..., :k]
        if self._hlag is None:
            self._hlag = p.copy()
            return
        d = p - self._hlag
        T = self._T(xc)  # the position block only: the position depends on the position states only
        Ph = Pc[..., :k, :k] if T is None else T[..., :k, :3] @ Pc[..., :3, :3] @ np.swapaxes(T[..., :k, :3], -1, -2)
        if not weakest:
            m2 = _mahalanobis2(d, Ph)
        elif self._ndir is None:  # no direction yet (first update): nothing to test across
            m2 = np.zeros(d.shape[:-1])
        else:  # across n: in the basis E (..., 3, 2) of its complement
            E = self._ncomp
            m2 = _mahalanobis2(np.einsum("...ij,...i->...j", E, d), np.swapaxes(E, -1, -2) @ Ph @ E)
        a = min(1.0, self._step_s / lag) if self._step_s > 0 else 1.0
        self._hlag = np.where(~(m2 <= 16.0)[..., None], p, self._hlag + a * d)

    def _constrained(self, x: np.ndarray | None = None, P: np.ndarray | None = None):
        """The moments ``(x, P)`` (internal coordinates) of the Gaussian ``N(x, P)`` truncated to above
        the station plane (``floor_z_m``); default the filter's own ``(self._x, self._P)``, cached.
        Where no run has mass below the floor within ``trunc_sigma`` the inputs come back unchanged
        (the same objects).

        The filter carries the *untruncated* Gaussian and the floor as a constraint on it: its density
        is ``N(x; m, P) 1[z >= floor]``, a family closed under linear(ized) measurement updates (the
        likelihood multiplies the Gaussian part, the truncation stays), so the floor counts once. The
        measurements are linearized (EKF Jacobian, UKF sigma points) over the truncated moments, where
        the density is; ``x``/``P`` report them. Near a plane of (nearly) coplanar transmitters the
        range is symmetric in ``z``: linearized at a mean on the plane a filter sees no gradient (EKF) or
        symmetric sigma points (UKF); the truncated moments put it on the physical side. The earlier
        filter replaced its Gaussian by the truncated moments after every update (Simon & Simon's
        truncated filter): at 100 Hz near the plane that counted the floor once per update and shrank
        the height variance around a wrong height (docs/aircraft.md).
        """
        own = x is None
        if own:
            c = self._tcache
            if c is not None and c[0] is self._x and c[1] is self._P:
                return c[2], c[3]
            x, P = self._x, self._P
        out = x, P
        fz = self.tuning.floor_z_m
        if fz is not None:
            n = x.shape[-1]
            xf, Pf = x.reshape(-1, n), P.reshape(-1, n, n)
            s2 = Pf[:, 2, 2]
            with np.errstate(invalid="ignore"):  # a broken filter (P not PD) is reset by its owner
                s = np.sqrt(s2)
            a = (fz - xf[:, 2]) / s
            if self._inv.any():
                # inverse coordinates: z >= floor  <=>  q_z >= (floor - c_z) |q|^2 / L^2 (linear if the
                # reference point lies on the floor; the right side is taken at the mean)
                ai = ((fz - self._ref[2]) * np.einsum("ki,ki->k", xf[:, :3], xf[:, :3]) / crd.SCALE_M**2
                      - xf[:, 2]) / s
                a = np.where(self._inv.reshape(-1), ai, a)
            act = a > -self.tuning.trunc_sigma  # 6 sigma: mass below the floor > 1e-9
            if np.any(act):
                a, s2 = a[act], s2[act]
                dmu, var_t = _truncated_normal(a)  # in units of sigma, sigma^2
                pc = Pf[act, :, 2]  # (k, n)
                xf, Pf = xf.copy(), Pf.copy()
                xf[act] = xf[act] + pc * (dmu / np.sqrt(s2))[:, None]
                Pa = Pf[act] + pc[:, :, None] * pc[:, None, :] * ((var_t - 1.0) / s2)[:, None, None]
                Pf[act] = 0.5 * (Pa + np.swapaxes(Pa, -1, -2))
                out = xf.reshape(x.shape), Pf.reshape(P.shape)
        if own:
            self._tcache = (self._x, self._P) + out
        return out


def _complement(n: np.ndarray) -> np.ndarray:
    """An orthonormal basis (..., 3, 2) of the plane orthogonal to the unit vectors ``n`` (..., 3)."""
    a = np.where((np.abs(n[..., 0]) < 0.9)[..., None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    e1 = np.cross(n, a)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    return np.stack([e1, np.cross(n, e1)], axis=-1)


def _mahalanobis2(d: np.ndarray, P: np.ndarray) -> np.ndarray:
    """``d^T P^-1 d`` (...,) for d (..., k), P (..., k, k); inf where P is not positive definite."""
    try:
        return nees(d, P)
    except np.linalg.LinAlgError:
        return np.full(d.shape[:-1], np.inf)


def _truncated_normal(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def _scaled(S2: np.ndarray, k) -> np.ndarray:
    """``K^1/2 S2 K^1/2`` with ``K = diag(k)``, ``k`` (..., m) or a scalar: a covariance whose row ``j``
    counts ``k_j`` times (stays positive semi-definite)."""
    q = np.sqrt(np.asarray(k, dtype=float))
    if q.ndim == 0:
        return S2 * q**2
    return S2 * q[..., :, None] * q[..., None, :]


# --------------------------------------------------------------------------- message-level API
def _init_config():
    from .initializer import InitConfig  # the initializer imports this module

    return InitConfig()


@dataclass
class EstimatorConfig:
    """Configuration of one :class:`AircraftEstimator` (defaults = the bench's shared tuning)."""

    tuning: Tuning = field(default_factory=Tuning)
    min_stations: int = 4
    # coarse external fix (like a station's init.sigma0_m): if set, filters start from the guess with
    # this position sigma instead of a snapshot LSQ fix (needed in the far field of a small-base system,
    # where one epoch's fix is off by kilometres)
    guess_sigma_m: float | None = None
    max_batch_age_s: float = 5.0  # TDMA: measurements older than this are dropped from a batch
    # start from the broadcasts alone (aircraft/initializer.py): snapshot fix or wide prior
    init: InitConfig | None = None
    # filters: innovation gate, windowed residual test, exclusion, HPL/VPL (aircraft/fde.py); None = off
    fde: FdeConfig | None = field(default_factory=FdeConfig)
    # the receiver rules (aircraft/navigator/receiver.py): usable broadcasts, consistent start,
    # divergence restart, publishable estimates; None = off (the benches feed synthetic epochs)
    receiver: rx.ReceiverConfig | None = field(default_factory=rx.ReceiverConfig)


class AircraftEstimator:
    """One algorithm for one aircraft, fed by messages; no I/O, no clocks, no truth.

    ``on_measurement(t_s, station_id, station_pos_m, station_cov_m2, rho_m, clock_var_m2)`` takes one
    TDMA slot; ``on_epoch(t_s, station_pos_m, station_cov_m2, rho_m, station_ids, clock_var_m2)`` a
    synchronous epoch. ``clock_var_m2``: the broadcast clock variance ``c^2 P_theta`` of the station
    (:func:`net.clock.broadcast_clock_var_m2`): the filters carry each station's residual clock
    error as ``tuning.clock_bias`` says (a Gauss-Markov bias state per station by default); snapshot
    LSQ and the filter start add it to the range variance (one epoch sees each residual once).
    Filters start from a snapshot LSQ fix of the first complete batch. ``estimate()`` returns a dict
    or None.
    """

    def __init__(self, algo: str, config: EstimatorConfig | None = None, x0_guess_m: np.ndarray | None = None):
        if algo not in ALGOS:
            raise ValueError(f"unknown algorithm {algo!r}; choose from {', '.join(ALGOS)}")
        self.algo = algo
        self.method, self.model = algo.split("-")
        self.cfg = config or EstimatorConfig()
        self.tracker: CvTracker | None = None
        self.fix: np.ndarray | None = None  # LSQ state (4,) or (3,)
        self.t_s: float | None = None
        self.guess = np.array([0.0, 0.0, 1000.0]) if x0_guess_m is None else np.asarray(x0_guess_m, float)
        self._pending: dict[int, tuple[float, np.ndarray, np.ndarray, float, float]] = {}
        self._last_geom: tuple[np.ndarray, np.ndarray | None] | None = None  # LSQ covariance
        self.n_updates = 0
        self.n_dropped = 0
        self.n_resets = 0
        self.n_deferred = 0  # batches set aside in a row at the start (InitConfig.defer_batches)
        self.init = None  # the InitResult of the latest start (broadcast initializer)
        self.fde = None if self.cfg.fde is None else FilterFde(self.cfg.fde)
        rcfg = self.cfg.receiver
        self.monitor = None if rcfg is None else rx.DivergenceMonitor(rcfg)
        self.stats: Counter[str] = Counter()  # broadcasts not used, refused starts, restarts (by reason)
        self.status = rx.WAITING

    # -- input
    def on_epoch(self, t_s: float, station_pos_m, station_cov_m2, rho_m, station_ids=None,
                 clock_var_m2=None) -> None:
        pos = np.asarray(station_pos_m, float)
        cov = None if station_cov_m2 is None else np.asarray(station_cov_m2, float)
        rho = np.asarray(rho_m, float)
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(rho))) or pos.shape[0] != rho.shape[0]:
            self.n_dropped += 1
            return
        m = len(rho)
        ids = list(range(m)) if station_ids is None else list(station_ids)
        cvar = np.zeros(m) if clock_var_m2 is None else np.broadcast_to(np.asarray(clock_var_m2, float), (m,))
        if not np.all(np.isfinite(cvar)) or len(ids) != m:
            self.n_dropped += 1
            return
        self._batch(t_s, pos, cov, rho, np.zeros(m), ids, cvar)

    def on_measurement(self, t_s: float, station_id: int, station_pos_m, station_cov_m2, rho_m: float,
                       clock_var_m2: float = 0.0) -> None:
        pos = np.asarray(station_pos_m, float).reshape(3)
        cov = np.zeros((3, 3)) if station_cov_m2 is None else np.asarray(station_cov_m2, float).reshape(3, 3)
        cvar = float(clock_var_m2 or 0.0)
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(cov)) and np.isfinite(rho_m)
                and np.isfinite(cvar) and cvar >= 0):
            self.n_dropped += 1
            return
        why = None if self.cfg.receiver is None else rx.unusable_reason(cvar, cov, self.cfg.receiver)
        if why is not None:  # not yet synchronized / surveyed to a usable level: not used at all
            self.stats[why] += 1
            return
        if self.tracker is not None and self.model == "pr":
            # sequential scalar update at the slot's own time
            try:
                self.tracker.predict_to(t_s)
                self._update(pos[None], np.array([rho_m]), cov[None], None, [station_id],
                             bias_ids=[station_id], bias_var_m2=np.array([cvar]))
            except np.linalg.LinAlgError:
                self._reset()
                return
            if self.tracker is None:  # the divergence monitor restarted it
                return
            self.t_s = t_s
            self.n_updates += 1
            return
        # batch: LSQ, TDOA, and filter initialisation collect one cycle (a station repeats -> flush)
        if station_id in self._pending:
            self._flush(t_s)
        self._pending[station_id] = (t_s, pos, cov, float(rho_m), cvar)
        self._pending = {k: v for k, v in self._pending.items() if t_s - v[0] <= self.cfg.max_batch_age_s}

    def _flush(self, t_now: float) -> None:
        items = sorted(self._pending.items(), key=lambda kv: kv[1][0])
        self._pending.clear()
        if len(items) < self.cfg.min_stations:
            return
        t_last = items[-1][1][0]
        pos = np.array([v[1] for _, v in items])
        cov = np.array([v[2] for _, v in items])
        rho = np.array([v[3] for _, v in items])
        cvar = np.array([v[4] for _, v in items])
        dt = np.array([v[0] for _, v in items]) - t_last
        self._batch(t_last, pos, cov, rho, dt, [k for k, _ in items], cvar)

    def _batch(self, t_s, pos, cov, rho, dt, ids=None, cvar=None) -> None:
        m = len(rho)
        bias_kw, cov_trk = {}, cov
        if cvar is not None and np.any(cvar > 0):
            bias_kw = {"bias_ids": list(ids), "bias_var_m2": cvar}
            # snapshot uses (LSQ, the filter start): each residual seen once, as range variance
            # (an isotropic term on the station covariance: u^T (P + s I) u = u^T P u + s)
            cov = (np.zeros((m, 3, 3)) if cov is None else cov) + cvar[:, None, None] * np.eye(3)
        if self.method == "lsq" and self.cfg.receiver is not None and dt is not None and np.any(dt):
            # a snapshot of a TDMA batch: the aircraft's unknown motion over each member's dt is noise
            # to it (the start's velocity prior), in its weights and in the covariance it reports
            v_sig = (self.cfg.init or _init_config()).vel_sigma_m_s
            cov = (np.zeros((m, 3, 3)) if cov is None else cov) + ((v_sig * np.asarray(dt, float)) ** 2)[:, None, None] * np.eye(3)
        self._last_geom = (pos, cov)
        if m < self.cfg.min_stations:
            self.n_dropped += 1
            return
        if self.tracker is None:
            self._start(t_s, pos, cov, rho, dt)
            return
        try:
            self.tracker.predict_to(t_s)
            if self.cfg.tuning.sequential and self.model == "pr" and not np.any(dt):
                self._watch(*self.tracker.update_sequential(pos, rho, cov_trk, **bias_kw), ids)
            else:
                self._update(pos, rho, cov_trk, dt if np.any(dt) else None, ids, **bias_kw)
        except np.linalg.LinAlgError:
            self._reset()
            return
        if self.tracker is None:  # the divergence monitor restarted it
            return
        if not np.all(np.isfinite(self.tracker.x)):
            self._reset()
            return
        self.t_s = t_s
        self.n_updates += 1

    def _update(self, pos, rho, cov, dt, ids, **bias_kw) -> None:
        """One filter update, through the integrity monitor when there is one; the divergence monitor
        sees its innovation."""
        if self.fde is None:
            nu, S = self.tracker.update(pos, rho, cov, dt, **bias_kw)
        else:
            nu, S = self.fde.update(self.tracker, pos, rho, list(range(len(rho))) if ids is None else ids, cov,
                                    dt, **bias_kw)
        self._watch(nu, S, ids)

    def _watch(self, nu, S, ids) -> None:
        """Feed one update's innovation ``nu`` (d,) and covariance ``S`` (d, d), or its diagonal (d,) for
        sequential scalar updates, to the divergence monitor with each station's normalized innovation
        (aircraft/fde.py ``snooping``); a lost filter restarts."""
        if self.monitor is None:
            return
        nu = np.atleast_1d(np.asarray(nu, dtype=float))
        S = np.asarray(S, dtype=float)
        S = np.diag(S) if S.ndim == 1 else np.atleast_2d(S)
        ids = list(range(nu.size + (self.model != "pr"))) if ids is None else list(ids)
        try:
            q, w = snooping(nu, S, fault_vectors(self.model, len(ids), self.tracker.base))
        except np.linalg.LinAlgError:
            q, w = np.inf, np.zeros(len(ids))
        if self.monitor.push(float(q), nu.size, dict(zip(ids, np.atleast_1d(w).tolist()))):
            self.stats["diverged"] += 1
            self._reset()
            self.status = rx.RESTARTING

    def _start(self, t_s, pos, cov, rho, dt=None) -> None:
        """No filter yet: a snapshot fix from the batch (LSQ), or the filter's start."""
        if self.cfg.guess_sigma_m is None and (self.fix is None or self.method != "lsq"):
            self._start_from_broadcasts(t_s, pos, cov, rho, dt)
            return
        tu = self.cfg.tuning
        var = tu.sigma_m**2
        first = self.fix is None
        if first:
            self.fix = np.append(self.guess, 0.0) if self.model == "pr" else self.guess.copy()
        # the first fix may start far away: more iterations and a wide trust region
        kw = dict(floor_z_m=tu.floor_z_m, iters=50 if first else 10, max_step_m=5000.0 if first else 200.0)
        if self.model == "pr":
            x0 = self.fix if self.fix.size == 4 else np.append(self.fix, 0.0)
            self.fix = lsq_pr(rho[None], pos, x0[None], var, cov, **kw)[0]
        else:
            self.fix = lsq_tdoa(rho[None], pos, self.fix[:3][None], var, cov, **kw)[0]
        self.t_s = t_s
        self.n_updates += 1
        if self.method == "lsq":
            return
        self._start_from_guess(t_s, pos, rho)

    def _start_from_broadcasts(self, t_s, pos, cov, rho, dt=None) -> None:
        """Start from the broadcasts alone: multi-start snapshot fix (or a wide prior), from a batch that
        passes the start test when the receiver rules are on."""
        from .initializer import InitConfig, initial_state

        tu = self.cfg.tuning
        init = initial_state(self.model, tu, pos, cov, rho, self.cfg.init)
        if self.cfg.receiver is not None:
            init = self._consistent_start(init, pos, cov, rho, dt)
            if init is None:
                return
        if not init.snapshot and len(rho) <= 4 and self.n_deferred < (self.cfg.init or InitConfig()).defer_batches:
            self.n_deferred += 1  # no redundancy, no snapshot: wait for a batch with more stations
            return
        self.n_deferred = 0
        self.fix = init.fix.copy()
        self.init = init
        self.t_s = t_s
        self.n_updates += 1
        self.status = rx.TRACKING
        if self.method != "lsq":
            self.tracker = CvTracker(self.method, self.model, init.x0, tu, t0_s=t_s, P0=init.P0,
                                     ref_m=crd.reference_point(pos),
                                     ref_radius_m=crd.array_radius(pos))

    def _consistent_start(self, init, pos, cov, rho, dt=None):
        """The start test (aircraft/navigator/receiver.py rule 2): the batch's weighted residual sum of
        squares at the fix against chi-square with ``m - 4`` dof; a failing batch is refused unless
        leaving out exactly one station makes it pass. The test allows for the aircraft's own motion
        across a TDMA batch: a member ``dt`` seconds before the last gets the range variance
        ``(vel_sigma_m_s dt)^2`` more (the start's velocity prior), so a moving aircraft's batch is not
        mistaken for an inconsistent one. Returns the start to use, or None."""
        from .initializer import InitConfig, batch_cost, initial_state

        rcfg, m = self.cfg.receiver, len(rho)
        cov_t = cov
        if dt is not None and np.any(dt):
            v_sig = (self.cfg.init or InitConfig()).vel_sigma_m_s
            cov_t = (np.zeros((m, 3, 3)) if cov is None else cov) \
                + ((v_sig * np.asarray(dt, float)) ** 2)[:, None, None] * np.eye(3)

        def cost(r, k):
            c = None if cov_t is None else cov_t[k]
            return float(batch_cost(self.model, r.fix, pos[k], c, rho[k], self.cfg.tuning.sigma_m)[0])

        if rx.consistent(cost(init, np.arange(m)), m - 4, rcfg.p_start):
            return init
        if m - 5 >= 1:
            keep = [np.flatnonzero(np.arange(m) != j) for j in range(m)]
            subs = [initial_state(self.model, self.cfg.tuning, pos[k], None if cov is None else cov[k], rho[k],
                                  self.cfg.init) for k in keep]
            j = rx.leave_one_out(np.array([cost(r, k) for r, k in zip(subs, keep)]), m - 5, rcfg.p_start)
            if j is not None:
                self.stats["start_left_one_out"] += 1
                return subs[j]
        self.stats["start_inconsistent"] += 1
        return None

    def _start_from_guess(self, t_s, pos, rho) -> None:
        """External coarse fix (``guess_sigma_m``): the filter starts from the guess with that sigma; the
        clock from the ranges to the guessed position."""
        tu = self.cfg.tuning
        gs = self.cfg.guess_sigma_m
        self.fix[:3] = self.guess
        C = np.diag([gs**2] * 3 + ([(tu.p0_clock_m + gs) ** 2] if self.model == "pr" else []))
        if self.model == "pr":
            self.fix[3] = float(np.mean(rho - np.linalg.norm(self.guess - pos, axis=1)))
        x0 = np.concatenate([self.fix[:3], np.zeros(3)])
        if self.model == "pr":
            x0 = np.append(x0, self.fix[3])
            if tu.drift_state:
                x0 = np.append(x0, 0.0)
        P0 = tu.p0(self.tracker_layout())
        idx = [0, 1, 2, 6] if self.model == "pr" else [0, 1, 2]
        P0[np.ix_(idx, idx)] = C
        self.tracker = CvTracker(self.method, self.model, x0, tu, t0_s=t_s, P0=P0, ref_m=crd.reference_point(pos),
                                 ref_radius_m=crd.array_radius(pos))

    def tracker_layout(self) -> mdl.StateLayout:
        return mdl.StateLayout(self.model, drift=self.cfg.tuning.drift_state and self.model == "pr")

    def _reset(self) -> None:
        """A filter whose covariance lost positive definiteness restarts from the next batch's fix."""
        if self.tracker is not None:
            self.guess = np.asarray(self.tracker.x[:3], dtype=float).copy()
        self.tracker = None
        self.fix = None
        self.n_resets += 1
        self._pending.clear()
        if self.monitor is not None:
            self.monitor.reset()
        if self.fde is not None:  # exclusions stand; the new filter's transient passes before the gate
            self.fde.restart()

    def tracker_or_fix(self) -> bool:
        """Whether there is anything to estimate from (a running filter, or an LSQ fix)."""
        return self.tracker is not None or (self.method == "lsq" and self.fix is not None)

    # -- output
    def estimate(self) -> dict | None:
        """Latest estimate: ``t_s``, ``pos_m`` [3], ``cov_m2`` [3][3] (LSQ: its ``(H^T W H)^-1``), ``vel_m_s``,
        ``clock_m``, ``n_updates``; filters with integrity monitoring (``config.fde``) add ``hpl_m``,
        ``vpl_m`` (aircraft/fde.py) and ``excluded`` (station ids)."""
        if self.t_s is None:
            return None
        if self.tracker is None:
            if self.method != "lsq" or self.fix is None:
                return None
            C = None
            if self._last_geom is not None:
                try:
                    C = lsq_cov(self.fix[None], self._last_geom[0], self.cfg.tuning.sigma_m**2, self.model,
                                self._last_geom[1])[0, :3, :3].tolist()
                except np.linalg.LinAlgError:
                    C = None
            return {"t_s": self.t_s, "pos_m": self.fix[:3].tolist(), "cov_m2": C, "vel_m_s": None,
                    "clock_m": float(self.fix[3]) if self.fix.size == 4 else None, "n_updates": self.n_updates}
        x, P = self.tracker.x, self.tracker.P
        out = {"t_s": self.tracker.t_s, "pos_m": x[:3].tolist(), "cov_m2": P[:3, :3].tolist(),
               "vel_m_s": x[3:6].tolist(), "clock_m": float(x[6]) if x.size > 6 else None,
               "n_updates": self.n_updates}
        if self.fde is not None:
            hpl, vpl = protection_levels(P[:3, :3], self.fde.cfg.integrity_risk)
            out.update(hpl_m=float(hpl), vpl_m=float(vpl), excluded=self.fde.excluded())
        return out
