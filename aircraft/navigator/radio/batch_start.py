"""A filter start over many cycles (navigator side: no truth, no I/O): the batch start of issue 29.

One TDMA cycle of a small array seen from its far field defends little: from 1.5 km out, a 1.8 km,
5-station array's snapshot fix is 80 m / 145 m (horizontal / vertical sigma), and a filter started
there counts the linearization error of that wide prior as repeating (``repeats``) and can stay wide
for 30 s (docs/aircraft.md, "A wide start stalls under the repeat count"). The information is in
many cycles: this start collects the cycles that passed the receiver's start rules
(aircraft/navigator/receiver.py rules 2 and 5) and fits them together, with the aircraft's motion
modelled, by Gauss-Newton on the state at the latest measurement time ``t_ref``:

    rho_k = |p + v tau_k - s_k| + b + d tau_k + e_k,   tau_k = t_k - t_ref <= 0,

``theta = [p (3), v (3), b, d]`` (the ``pr`` layout with the clock rate). The residuals' covariance
``R`` (N, N) over the window is modelled whole, so that the batch's covariance is honest:

* ``sigma_m^2`` white on every range;
* a station's broadcast error (its survey covariance ``C_k`` along the line of sight, plus its clock
  variance as an isotropic term of ``C_k``) persists over a few seconds: fully correlated between two
  ranges of the same station, ``s_k s_l`` with ``s_k = sqrt(u_k^T C_k u_k)`` (not white: counted once
  per station, as one snapshot counts it);
* the constant-velocity model is wrong by the filter's own process noise: the deviation of the
  position at ``t_ref + tau`` from the straight line through ``(p, v)`` at ``t_ref`` is an integrated
  Wiener process backwards in time, ``cov(tau_k, tau_l) = q_acc m^2 (3 M - m) / 6`` per axis
  (``m``, ``M`` the smaller / larger of ``|tau_k|``, ``|tau_l|``), projected on the lines of sight
  (``u_k . u_l``); the clock likewise with ``q_clock min + q_drift m^2 (3 M - m) / 6``.

The velocity and clock rate have the start's priors (``InitConfig.vel_sigma_m_s``,
``Tuning.p0.drift_m_s``: zero mean), the position and clock none (the snapshot fix is only the first
linearization point). The fit's covariance ``(J^T R^-1 J + Lambda_prior)^-1`` at the solution is the
filter's ``P0``; its weighted residual sum of squares is tested against chi-square with ``N - 4``
degrees of freedom (``N`` ranges, 8 unknowns, 4 priors) as the snapshot start is (rule 2).
TDOA filters take the ``[p, v]`` block (the free clock is what differencing removes).

The fit's error is made partly of the stations' persisting errors it counted. A filter that carries
them on as states (``Tuning.survey_bias_tau_s``: the position errors as consider states,
:mod:`.biases`) must start them correlated with its state as the fit left them, not independent
of it (that would count the same errors twice: the filter would first fuse the start and the next
ranges as independent, too confident, then mis-weight them; docs/aircraft.md, "The start's share of
the station errors"). With ``z_j`` station ``j``'s unit position error (its range error
``p_k z_j``, ``p_k = sqrt(u_k^T C_k u_k)`` of the position covariance alone, in ``R``'s persisting
term) the fit's error ``x - theta`` has ``cov(x - theta, z_j) = -P J^T R^-1 d_j`` (``d_j`` (N,):
``p_k`` on station ``j``'s ranges, 0 elsewhere): :attr:`BatchFit.cross`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import solve_triangular

from nav.kalman import chol_solve, symmetrize

from .initializer import InitResult
from .tuning import Tuning


@dataclass(frozen=True)
class BatchStartConfig:
    """When the batch start gives its start. ``target_sigma_m``: as soon as the fit's position sigma
    ``sqrt(tr P_pos)`` is at most this (and the fit passes its test) over at least ``min_cycles``
    cycles; ``window_s``: at the latest once the window spans this long (then from the fit if its sigma
    is at most ``max_sigma_m``, the bar of a snapshot's own covariance, ``InitConfig.max_fix_sigma_m``;
    otherwise, or if the fit fails, from the latest cycle's own start, e.g. the wide prior of a far
    field where the fit's linearization is not to be trusted); ``max_ranges``: the window is full at
    this many ranges too (the fit's cost grows with their cube: seed001's 10 ms slots fill 4 s with 400,
    and its live aircraft, refitting every 40 ms cycle, fell a minute behind and was killed); ``iters`` / ``tol_m``: the
    Gauss-Newton iterations and the step at which it has converged; ``max_step_m``: the largest
    position step of one iteration (a trust region: the first linearization point is one cycle's fix)."""

    target_sigma_m: float = 15.0
    window_s: float = 4.0
    max_sigma_m: float = 300.0
    max_ranges: int = 120
    min_cycles: int = 1
    iters: int = 30
    tol_m: float = 1e-4
    max_step_m: float = 500.0


@dataclass(frozen=True)
class StationCross:
    """The stations' position errors as a start leaves them (module docstring): ``ids`` (k,) station
    ids, ``stations_m`` (k, 3) and ``cov_m2`` (k, 3, 3) each one's latest broadcast position and position
    covariance (clock variance not included), ``cross`` (n, k) ``cov(state error, z_j)`` of the unit
    position error ``z_j`` of each station, in the start's state (``[p v b d]`` or ``[p v]``)."""

    ids: tuple
    stations_m: np.ndarray
    cov_m2: np.ndarray
    cross: np.ndarray


@dataclass
class BatchFit:
    """``x`` (8,) ``[p v b d]`` at ``t_ref_s``, ``P`` (8, 8), ``cost`` the weighted residual sum of
    squares (priors included), ``dof`` its degrees of freedom, ``ok`` whether the fit converged to a
    finite solution with a positive definite information."""

    x: np.ndarray
    P: np.ndarray
    cost: float
    dof: int
    ok: bool
    t_ref_s: float
    cross: StationCross | None = None

    @property
    def sigma_m(self) -> float:
        """Position sigma ``sqrt(tr P_pos)`` (inf where the fit failed)."""
        return float(np.sqrt(np.trace(self.P[:3, :3]))) if self.ok else float("inf")


def _ibm(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Covariance of an integrated unit Wiener process at lags ``a`` (N,) and ``b`` (N,) >= 0 from its
    pinned end: ``m^2 (3 M - m) / 6``, (N, N)."""
    m = np.minimum(a[:, None], b[None, :])
    M = np.maximum(a[:, None], b[None, :])
    return m * m * (3.0 * M - m) / 6.0


def residual_cov(u: np.ndarray, s_m: np.ndarray, same: np.ndarray, lag_s: np.ndarray, tuning: Tuning) -> np.ndarray:
    """The covariance (N, N) of the window's range errors about the constant-velocity model (module
    docstring). ``u`` (N, 3) lines of sight, ``s_m`` (N,) each range's broadcast sigma, ``same`` (N, N)
    bool: the same station, ``lag_s`` (N,) ``t_ref - t_k >= 0``."""
    ibm = _ibm(lag_s, lag_s)
    R = (u @ u.T) * (tuning.q_acc * ibm) + tuning.q_clock * np.minimum(lag_s[:, None], lag_s[None, :]) \
        + tuning.q_drift * ibm + np.where(same, np.outer(s_m, s_m), 0.0)
    R[np.diag_indices_from(R)] += tuning.sigma_m**2
    return R


def _linearize(x, t_s, sta_m, cov_m2, rho_m, same, t_ref_s, tuning):
    """Whitened residuals (N,) and Jacobian (N, 8) of the window at ``x`` (8,), the Cholesky factor
    (N, N) of ``R`` and the lines of sight (N, 3)."""
    tau = t_s - t_ref_s  # (N,) <= 0
    d = x[:3] + x[3:6] * tau[:, None] - sta_m  # (N, 3) station -> aircraft
    r = np.linalg.norm(d, axis=1)
    u = d / r[:, None]
    s = np.sqrt(np.maximum(np.einsum("ki,kij,kj->k", u, cov_m2, u), 0.0))
    L = np.linalg.cholesky(residual_cov(u, s, same, -tau, tuning))
    res = rho_m - (r + x[6] + x[7] * tau)
    J = np.concatenate([u, u * tau[:, None], np.ones((len(tau), 1)), tau[:, None]], axis=1)
    W = solve_triangular(L, np.column_stack([res, J]), lower=True)  # whitened: L^-1 [res J]
    return W[:, 0], W[:, 1:], L, u


def batch_fix(t_s: np.ndarray, sta_m: np.ndarray, cov_m2: np.ndarray, rho_m: np.ndarray, ids: np.ndarray,
              x0: np.ndarray, t_ref_s: float, tuning: Tuning, vel_sigma_m_s: float,
              cfg: BatchStartConfig = BatchStartConfig(), pos_cov_m2: np.ndarray | None = None) -> BatchFit:
    """Gauss-Newton fit of the window (module docstring). ``t_s`` (N,) measurement times, ``sta_m`` (N, 3)
    broadcast station positions, ``cov_m2`` (N, 3, 3) their covariances (clock variance included as an
    isotropic term), ``rho_m`` (N,) pseudoranges, ``ids`` (N,) station ids, ``x0`` (8,) the first
    linearization point at ``t_ref_s``; ``pos_cov_m2`` (N, 3, 3) the position covariances alone (None:
    ``cov_m2``), for :attr:`BatchFit.cross`. Returns a :class:`BatchFit`."""
    t_s, rho_m = np.asarray(t_s, float), np.asarray(rho_m, float)
    sta_m, cov_m2 = np.asarray(sta_m, float), np.asarray(cov_m2, float)
    ids = np.asarray(ids)
    same = ids[:, None] == ids[None, :]
    prior_sd = np.array([vel_sigma_m_s] * 3 + [tuning.p0.drift_m_s])  # v, d: zero-mean priors
    info_prior = np.zeros((8, 8))
    info_prior[[3, 4, 5, 7], [3, 4, 5, 7]] = prior_sd**-2
    x = np.asarray(x0, float).copy()
    n = len(rho_m)
    fail = BatchFit(x, np.full((8, 8), np.inf), float("inf"), n - 4, False, float(t_ref_s))
    try:
        for _ in range(cfg.iters):
            rw, Jw, _, _ = _linearize(x, t_s, sta_m, cov_m2, rho_m, same, t_ref_s, tuning)
            A = Jw.T @ Jw + info_prior
            g = Jw.T @ rw - info_prior @ x
            dx = chol_solve(A, g[:, None])[:, 0]
            step = float(np.linalg.norm(dx[:3]))
            if step > cfg.max_step_m:
                dx = dx * (cfg.max_step_m / step)
            x = x + dx
            if not np.all(np.isfinite(x)):
                return fail
            if step < cfg.tol_m:
                break
        rw, Jw, L, u = _linearize(x, t_s, sta_m, cov_m2, rho_m, same, t_ref_s, tuning)
        P = chol_solve(Jw.T @ Jw + info_prior, np.eye(8))
        cross = _station_cross(P, Jw, L, u, sta_m, cov_m2 if pos_cov_m2 is None else pos_cov_m2, ids)
    except np.linalg.LinAlgError:
        return fail
    cost = float(rw @ rw + np.sum((x[[3, 4, 5, 7]] / prior_sd) ** 2))
    return BatchFit(x, symmetrize(P), cost, n - 4, bool(np.all(np.isfinite(P))), float(t_ref_s), cross)


def _station_cross(P, Jw, L, u, sta_m, pos_cov_m2, ids) -> StationCross:
    """:class:`StationCross` of a fit (module docstring): ``P`` (8, 8), ``Jw`` (N, 8) the whitened
    Jacobian, ``L`` (N, N) the Cholesky factor of ``R``, ``u`` (N, 3) the lines of sight, ``sta_m``
    (N, 3), ``pos_cov_m2`` (N, 3, 3) the position covariances, ``ids`` (N,)."""
    uid, last = np.unique(ids[::-1], return_index=True)
    last = len(ids) - 1 - last  # each station's latest range
    p = np.sqrt(np.maximum(np.einsum("ki,kij,kj->k", u, pos_cov_m2, u), 0.0))
    d = np.where(ids[:, None] == uid[None, :], p[:, None], 0.0)  # (N, k)
    cross = -P @ Jw.T @ solve_triangular(L, d, lower=True)
    return StationCross(tuple(uid.tolist()), sta_m[last], pos_cov_m2[last], cross)


@dataclass
class BatchStart:
    """The window of cycles a filter's start collects (mutable; one per estimator). ``offer`` takes one
    cycle that passed the start rules and returns the start to use now, or None to wait."""

    cfg: BatchStartConfig
    tuning: Tuning
    vel_sigma_m_s: float
    # (t (m,), pos (m, 3), cov (m, 3, 3), rho (m,), ids (m,), pos_cov (m, 3, 3): cov without the clock term)
    cycles: list = field(default_factory=list)
    x: np.ndarray | None = None  # the latest fit (8,) at t_s
    t_s: float | None = None

    def reset(self) -> None:
        self.cycles.clear()
        self.x, self.t_s = None, None

    def offer(self, model: str, t_s: float, t_k: np.ndarray, pos, cov, rho, ids, snap: InitResult,
              consistent, stats, clock_var_m2=None) -> InitResult | None:
        """One more cycle (members' times ``t_k`` (m,), broadcast ``pos`` (m, 3), ``cov`` (m, 3, 3) with
        the clock variances ``clock_var_m2`` (m,) (None: 0) as an isotropic term, ``rho`` (m,), station
        ``ids`` (m,)) and its own snapshot start ``snap``; ``consistent(cost, dof)``: the start test;
        ``stats`` counts ``start_batch_wait`` / ``start_batch_failed``."""
        m = len(rho)
        cov = np.zeros((m, 3, 3)) if cov is None else np.asarray(cov, float)
        cvar = np.zeros(m) if clock_var_m2 is None else np.asarray(clock_var_m2, float)
        self.cycles.append((np.asarray(t_k, float), np.asarray(pos, float), cov, np.asarray(rho, float),
                            np.asarray(ids), cov - cvar[:, None, None] * np.eye(3)))
        x0 = self._guess(model, t_s, snap)
        t, p, c, r, i, pc = (np.concatenate([cy[j] for cy in self.cycles]) for j in range(6))
        fit = batch_fix(t, p, c, r, i, x0, t_s, self.tuning, self.vel_sigma_m_s, self.cfg, pc)
        good = fit.ok and consistent(fit.cost, fit.dof)
        full = t_s - float(self.cycles[0][0].min()) >= self.cfg.window_s or len(r) >= self.cfg.max_ranges
        if good:
            self.x, self.t_s = fit.x, t_s
            if (full and fit.sigma_m <= self.cfg.max_sigma_m) or \
                    (len(self.cycles) >= self.cfg.min_cycles and fit.sigma_m <= self.cfg.target_sigma_m):
                return _as_start(model, fit, snap)
        if full:
            stats["start_batch_failed"] += 1
            return snap
        stats["start_batch_wait"] += 1
        return None

    def _guess(self, model: str, t_s: float, snap: InitResult) -> np.ndarray:
        """The first linearization point at ``t_s``: the latest fit carried along its velocity and clock
        rate, or (no fit yet) this cycle's snapshot fix at rest."""
        if self.x is not None:
            x, dt = self.x.copy(), t_s - self.t_s
            x[:3] += x[3:6] * dt
            x[6] += x[7] * dt
            return x
        x = np.zeros(8)
        x[:3] = snap.fix[:3]
        if model == "pr":
            x[6] = snap.fix[3]
        return x


def _as_start(model: str, fit: BatchFit, snap: InitResult) -> InitResult:
    """The fit as a filter start (the ``pr`` layout with the clock rate, or the ``tdoa`` layout ``[p v]``)."""
    k = 8 if model == "pr" else 6
    fix = fit.x[[0, 1, 2, 6]] if model == "pr" else fit.x[:3]
    c = fit.cross
    cross = None if c is None else StationCross(c.ids, c.stations_m, c.cov_m2, c.cross[:k].copy())
    return InitResult(fit.x[:k].copy(), fit.P[:k, :k].copy(), True, fix, fit.sigma_m, fit.cost, cross)
