"""The radio aircraft's tracking filter: :class:`CvTracker`, EKF or UKF on the constant-velocity model
with pseudorange or TDOA measurements, batched over Monte Carlo runs on the leading axis.

Prediction is the linear CV step (``nav.kalman.kf_predict``; the unscented transform of a linear map
is exact, so the UKF's prediction equals it); updates are the strategies of :mod:`.update` over the
models of :mod:`.measurements`, with the scaled sigma points of ``nav.ut`` (alpha, beta = 2, kappa = 0).
The tracker composes the parts: :class:`.chart.InverseChart` (coordinates), :class:`.floor.HeightFloor`
(the floor constraint), :class:`.lag.LaggedJacobian`, :class:`.repeats.RepeatCount` and
:class:`.biases.ClockBiases`.
"""

from __future__ import annotations

import numpy as np

from nav.kalman import kf_predict, symmetrize
from nav.ut import SigmaParams

from . import coords as crd
from . import models as mdl
from .biases import POS_ERROR, ClockBiases
from .chart import InverseChart
from .floor import HeightFloor
from .lag import LaggedJacobian
from .measurements import make_model, second_order
from .repeats import RepeatCount
from .snapshot import TrackerSnapshot
from .state import POS, StateLayout
from .tuning import Tuning
from .update import STRATEGIES


class CvTracker:
    """EKF / UKF on the constant-velocity model, batched over ``M`` runs.

    Parameters
    ----------
    kind : "ekf" or "ukf". model : "pr" or "tdoa". x0 : (M, n) initial means, or (n,) for one run.
    tuning : :class:`Tuning`. t0_s : time of ``x0``. base : TDOA base station index within each batch.
    P0 : (n, n) or (M, n, n) initial covariance; None = the tuning's prior ``tuning.p0``.
    ref_m : (3,) reference point of the inverse-range coordinates (``tuning.coords == "inverse"``):
        :func:`aircraft.navigator.radio.coords.reference_point` of the broadcast stations; None = that of the first
        update's stations. ref_radius_m : RMS distance of the stations from ``ref_m``
        (:func:`aircraft.navigator.radio.coords.array_radius`).

    ``x`` and ``P`` are always Cartesian (``[p, v (, b (, bdot))]`` and the clock biases); with inverse
    coordinates the filter works on ``(q, v, beta, bdot)`` internally and converts on access
    (covariance to first order, ``T P T^T``). Both are the moments of the density above the floor.
    """

    def __init__(self, kind: str, model: str, x0: np.ndarray, tuning: Tuning, t0_s: float = 0.0, base: int = 0,
                 P0: np.ndarray | None = None, ref_m: np.ndarray | None = None,
                 ref_radius_m: float | None = None, station_cross=None):
        if kind not in ("ekf", "ukf"):
            raise ValueError(f"unknown filter {kind!r} (ekf or ukf)")
        self.kind = kind
        self.layout = StateLayout(model, drift=model == "pr")
        self.tuning = tuning
        x0 = np.asarray(x0, dtype=float)  # (M, n) batched, or (n,) for one run (faster small-matrix path)
        if x0.shape[-1] != self.layout.n:
            raise ValueError(f"x0 must have {self.layout.n} states for {model}, got {x0.shape}")
        self.n_base = self.layout.n  # states after these: the stations' clock biases (bias_ids order)
        self.biases = ClockBiases(self.n_base, tuning.clock_bias_tau_s, tuning.clock_bias_drop_s,
                                  tuning.survey_bias_tau_s)
        self._x = x0.copy()
        P0 = tuning.prior_cov(self.layout) if P0 is None else np.asarray(P0, dtype=float)
        self._P = np.broadcast_to(P0, x0.shape[:-1] + (self.layout.n,) * 2).copy()
        self.chart = InverseChart(x0.shape[:-1], clock=self.layout.has_clock)
        if station_cross is not None:  # (Cartesian still: the chart switches below)
            self._start_position_errors(station_cross, t0_s)
        self.floor = HeightFloor(tuning.floor_z_m, tuning.trunc_sigma)
        self.lag = LaggedJacobian(tuning.height_jacobian_lag_s, tuning.lag_direction)
        self.repeats = RepeatCount(tuning.linearization_corr_s, t0_s)
        if tuning.coords == "inverse" and ref_m is not None:
            self.chart.set_reference(ref_m, ref_radius_m)
            self._switch()
        self.t_s = float(t0_s)
        self.base = base
        self.params = SigmaParams.scaled(alpha=tuning.alpha, beta=2.0, kappa=0.0)
        self.strategy = STRATEGIES[kind]
        self._fq: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        self._last_dt: float | None = None
        self._last_fq: tuple[np.ndarray, np.ndarray] | None = None
        self._step_s = 0.0  # the latest prediction step: updates per linearization_corr_s
        self._r_key: tuple | None = None
        self._r: np.ndarray | None = None

    def _start_position_errors(self, start, t0_s: float) -> None:
        """The stations' position-error states of a start that counted those errors (``start``:
        :class:`.batch_start.StationCross`, ``cross`` (n, k) against unit errors): each ``beta_j`` of
        stationary variance ``v_j`` (:meth:`_position_errors` at ``x0``) is ``sqrt(v_j) z_j``, so its
        covariance with the state is ``cross_j sqrt(v_j)``; the consider block is its prior
        ``diag(v)``. Added independent instead, the start's share of those errors would be counted twice
        (docs/aircraft.md, "The start's share of the station errors")."""
        if not (self.tuning.survey_bias_tau_s > 0 and self.tuning.clock_bias == "states") or not start.ids:
            return
        v = self._position_errors(start.stations_m, list(start.ids), start.cov_m2)
        keep = None if v is None else v > 0
        if keep is None or not keep.any():
            return
        v, cross = v[keep], np.asarray(start.cross, float)[:, keep]
        n, k = self.n_base, len(v)
        x = np.concatenate([self._x, np.zeros(self._x.shape[:-1] + (k,))], axis=-1)
        P = np.zeros(self._P.shape[:-2] + (n + k, n + k))
        P[..., :n, :n] = self._P
        P[..., :n, n:] = cross * np.sqrt(v)
        P[..., n:, :n] = np.swapaxes(P[..., :n, n:], -1, -2)
        P[..., n:, n:] = np.diag(v)
        self._x, self._P = x, P
        b = self.biases
        b.ids = [(POS_ERROR, sid) for sid, kp in zip(start.ids, keep) if kp]
        b.var, b.t = v, np.full(k, float(t0_s))

    # -- the clock-bias states (names kept for callers)
    @property
    def bias_ids(self) -> list:
        return self.biases.ids

    @bias_ids.setter
    def bias_ids(self, value) -> None:
        self.biases.ids = value

    @property
    def _bias_var(self) -> np.ndarray:
        return self.biases.var

    @_bias_var.setter
    def _bias_var(self, value) -> None:
        self.biases.var = value

    @property
    def _bias_t(self) -> np.ndarray:
        return self.biases.t

    @_bias_t.setter
    def _bias_t(self, value) -> None:
        self.biases.t = value

    # -- coordinates
    def _cart(self, X: np.ndarray) -> np.ndarray:
        return self.chart.cart(X)

    def _T(self, X: np.ndarray) -> np.ndarray | None:
        return self.chart.T(X)

    def _constrained(self, x: np.ndarray | None = None, P: np.ndarray | None = None):
        """The moments ``(x, P)`` (internal coordinates) of the filter's Gaussian (default its own,
        cached) truncated to above the floor (:class:`.floor.HeightFloor`)."""
        if x is None:
            return self.floor.cached(self._x, self._P, self.chart.inv, self.chart.ref)
        return self.floor.moments(x, P, self.chart.inv, self.chart.ref)

    def floor_depth(self) -> np.ndarray:
        """How many height sigmas the floor lies above the filter's own (untruncated) Gaussian (...,);
        -inf without a floor (:meth:`.floor.HeightFloor.depth`)."""
        if self.floor.floor_z_m is None:
            return np.full(self._x.shape[:-1], -np.inf)
        return self.floor.depth(self._x, self._P, self.chart.inv, self.chart.ref)

    @property
    def x(self) -> np.ndarray:
        """Cartesian state (..., n): the mean of the filter's density above the floor (truncated)."""
        return self._cart(self._constrained()[0])

    @x.setter
    def x(self, value: np.ndarray) -> None:
        self._x = self.chart.to_internal_x(np.asarray(value, dtype=float))

    @property
    def P(self) -> np.ndarray:
        """Cartesian covariance (..., n, n) of the density above the floor (first-order conversion
        ``T P T^T`` for inverse-coordinate runs)."""
        xc, Pc = self._constrained()
        return self.chart.to_cartesian_P(xc, Pc)

    @P.setter
    def P(self, value: np.ndarray) -> None:
        self._P = self.chart.to_internal_P(np.asarray(value, dtype=float), self._x)

    def _switch(self) -> None:
        tu = self.tuning
        self._x, self._P = self.chart.switch(self._x, self._P, tu.inverse_max_rel, tu.inverse_min_radii)

    # -- process model
    def _FQ(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        if dt == self._last_dt:  # synchronous epochs: the same step every time
            return self._last_fq
        key = round(dt, 12)
        if key not in self._fq:
            n, tu = self.layout.n, self.tuning
            if len(self._fq) > 64:
                self._fq.clear()
            F = mdl.cv_transition(n, dt)
            Q = mdl.cv_noise(n, dt, tu.q_acc, tu.q_clock, tu.q_drift)
            self._fq[key] = self.biases.process(F, Q, dt)
        self._last_dt, self._last_fq = dt, self._fq[key]
        return self._last_fq

    def _bias_changed(self) -> None:
        self._fq.clear()
        self._last_dt = self._last_fq = None

    def predict_to(self, t_s: float) -> None:
        """Propagate to ``t_s`` (no-op if ``t_s <= t``: measurements are never processed backwards)."""
        dt = t_s - self.t_s
        if dt <= 0.0:
            return
        F, Q = self._FQ(dt)
        self._step_s = dt
        if not self.chart.any():
            self._x, self._P = kf_predict(self._x, self._P, F, Q)
        else:
            self._x, self._P = self.chart.predict(self._x, self._P, F, Q)
        self.t_s = float(t_s)

    # -- save / restore
    def save(self) -> TrackerSnapshot:
        """The filter's state (what an update changes) for :meth:`restore`."""
        lag, rep, b = self.lag, self.repeats, self.biases
        return TrackerSnapshot(self._x, self._P, self.chart.inv, self.chart.ref, self.chart.radius, tuple(b.ids),
                               b.var.copy(), b.t.copy(), self.t_s, rep.memory, dict(rep.last_seen), lag.pos,
                               lag.info, lag.dir, lag.comp, lag.dir_t_s)

    def restore(self, s: TrackerSnapshot) -> None:
        """Back to a :meth:`save`d state (an update re-run with other measurements: aircraft/navigator/radio/fde.py)."""
        self._x, self._P, self.t_s = s.x, s.P, s.t_s
        self.chart.inv, self.chart.ref, self.chart.radius = s.inverse, s.ref_m, s.radius_m
        self.repeats.memory, self.repeats.last_seen = s.memory, dict(s.last_seen)
        lag = self.lag
        lag.pos, lag.info, lag.dir, lag.comp, lag.dir_t_s = s.lag_pos, s.lag_info, s.lag_dir, s.lag_comp, s.lag_dir_t_s
        self.biases.ids, self.biases.var, self.biases.t = list(s.bias_ids), s.bias_var_m2.copy(), s.bias_t_s.copy()
        self._bias_changed()
        self._r_key = None

    # -- measurement update
    def measurement_model(self, stations_m: np.ndarray, dt_s: np.ndarray | None = None,
                          D: np.ndarray | None = None):
        """``(h, jac)`` of one batch on Cartesian states ``[x (n), beta (nb)]`` (..., n + nb)
        (:mod:`.measurements`); ``D`` (m, nb) maps the clock-bias states to the stations of the batch
        (None: no bias states). ``jac`` returns (..., m or m-1, n + nb)."""
        mod = make_model(self.layout.kind, stations_m, self.n_base, self.base, dt_s, D)
        return mod.value, mod.jacobian

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
        if self.chart.ref is None and self.tuning.coords == "inverse":
            self.chart.set_reference(crd.reference_point(stations_m), crd.array_radius(stations_m))
            self._switch()
        sig = self.tuning.sigma_m if sigma_m is None else sigma_m
        D, sig, station_cov_m2 = self._bias_map(stations_m, sig, bias_ids, bias_var_m2, station_cov_m2)
        model = make_model(self.layout.kind, stations_m, self.n_base, self.base, dt_s, D)
        R, z = self._noise(model, station_cov_m2, sig), model.z(rho_m)
        self.lag.update_direction(model.jacobian, lambda: self._cart(self._constrained()[0]), self.chart.inv,
                                  self.layout.pos_clock, self._step_s, self.t_s)
        keys = self.repeats.keys(stations_m, bias_ids)
        k = self.repeats.count(keys, self.t_s, self._step_s, self.base if self.layout.kind == "tdoa" else None)
        x1, P1, nu, S = self.strategy(self, model, z, R, k)
        c = self.biases.consider()
        if c.size:  # Schmidt: the consider states keep their prior mean and covariance
            x1[..., c] = self._x[..., c]
            P1[..., c[:, None], c] = self._P[..., c[:, None], c]
        self.repeats.record(keys, self.t_s, self._P, P1)
        self._x, self._P = x1, P1
        if self.chart.ref is not None:
            self._switch()
        if self.lag.lag_s > 0:
            self.lag.advance(*self._constrained(), self._cart, self._T, self._step_s)
        return nu, S  # innovation and its covariance of the first (plain) linearization

    def _bias_map(self, stations_m, sig, bias_ids, bias_var_m2, station_cov_m2=None):
        """``(D, sig, station_cov_m2)`` of one batch: the map (m, nb) of the bias states to its stations
        (None: no bias states), the range sigma (the broadcast clock variance added with ``"white"``)
        and the station covariances still to be counted as white range noise (None where the
        position-error states carry them)."""
        D = None
        if bias_ids is not None and bias_var_m2 is not None:
            if self.tuning.clock_bias == "states":
                ids, var = bias_ids, bias_var_m2
                pe = self._position_errors(stations_m, bias_ids, station_cov_m2)
                if pe is not None:
                    m = len(bias_ids)
                    ids = list(bias_ids) + [None if sid is None else (POS_ERROR, sid) for sid in bias_ids]
                    var = np.concatenate([np.broadcast_to(np.asarray(bias_var_m2, float), (m,)), pe])
                    station_cov_m2 = None
                self._x, self._P, D, changed = self.biases.use(self._x, self._P, ids, var, self.t_s)
                if pe is not None:
                    D = D[:m] + D[m:]
                if changed:
                    self._bias_changed()
            else:
                sig = np.sqrt(np.asarray(sig, dtype=float) ** 2 + np.asarray(bias_var_m2, dtype=float))
        if D is None and self.bias_ids:
            D = np.zeros((stations_m.shape[0], len(self.bias_ids)))
        if D is not None and D.shape[-1] == 0:
            D = None
        return D, sig, station_cov_m2

    def _position_errors(self, stations_m, bias_ids, station_cov_m2) -> np.ndarray | None:
        """The stationary variances (m,) ``u^T C_j u`` of the stations' position errors along the lines
        of sight from the filter's estimate (the mean of its runs), on a grid of 2^(1/8) steps (a
        variance that changes rescales its state: :meth:`.biases.ClockBiases.use`); None without
        position-error states (``survey_bias_tau_s`` 0, no covariances, a station without an id)."""
        if not self.tuning.survey_bias_tau_s > 0 or station_cov_m2 is None or any(s is None for s in bias_ids):
            return None
        p = self._cart(self._x)[..., POS].reshape(-1, 3).mean(axis=0)
        d = p - stations_m
        u = d / np.linalg.norm(d, axis=1)[:, None]
        v = np.einsum("mi,mij,mj->m", u, np.asarray(station_cov_m2, float), u)
        return np.where(v > 0, np.exp2(np.round(np.log2(np.maximum(v, 1e-300)) * 8.0) / 8.0), 0.0)

    def _noise(self, model, station_cov_m2, sig) -> np.ndarray:
        """The batch's noise covariance; cached while it does not depend on the state (pseudoranges
        without station covariances, one sigma)."""
        if model.kind == "pr" and station_cov_m2 is None and (isinstance(sig, float) or np.ndim(sig) == 0):
            key = (model.stations_m.shape[0], float(sig), self._x.shape[:-1])
            if self._r_key != key:
                self._r_key, self._r = key, model.noise(self._x, None, sig)
            return self._r
        return model.noise(self.x, station_cov_m2, sig)

    def _second_order(self, stations_m, dt_s, X, P):
        """Second-order terms of the ranges (:func:`.measurements.second_order`) over the moments
        ``X``, ``P`` in the runs' own coordinates: those of the converted Cartesian moments (the
        Hessian in the inverse coordinates themselves, much smaller far out, leaves more runs
        over-confident: docs/aircraft.md, "the floor counted once")."""
        T = self._T(X)
        if T is not None:  # Cartesian moments (the inverse-coordinate runs converted)
            X, P = self._cart(X), symmetrize(T @ P @ np.swapaxes(T, -1, -2))
        return second_order(stations_m, dt_s, X, P)
