"""Monte Carlo simulation of the aircraft estimators on synchronous epochs (seed 001 setup).

The truth (trajectory, clock) and the noise live here; the estimators only receive pseudoranges,
station positions and covariances. Everything is vectorized over ``M`` runs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nav import kalman as kf
from nav.pcrb import augment_biases, pcrb_linear_gaussian, prior_before_first_step

from ..navigator.radio import models as mdl
from ..navigator.radio.fde import FilterFde, protection_levels
from ..navigator.radio.lsq import lsq_pr, lsq_tdoa
from ..navigator.radio.tracker import CvTracker
from ..navigator.radio.tuning import Tuning
from ..world.clock import ReceiverClock
from ..world.trajectory import Track


@dataclass
class RunResult:
    """Errors of one algorithm at one point: ``err_m`` (M, T, 3) position errors over the whole run,
    ``nees``/``nis`` (M, T) for filters (None for LSQ), ``x_hat`` final states."""

    err_m: np.ndarray
    nees: np.ndarray | None = None
    nis: np.ndarray | None = None
    P_pos: np.ndarray | None = None  # (M, T, 3, 3) filter position covariance (filters only)
    hpl_m: np.ndarray | None = None  # (M, T) protection levels (filters with ``fde``)
    vpl_m: np.ndarray | None = None
    fde: object | None = None  # the aircraft.navigator.radio.fde.FilterFde (gate/exclusion record)


def pseudoranges(
    track: Track, stations_m: np.ndarray, clock: ReceiverClock, sigma_m: float, runs: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """Noisy pseudoranges (T, M, m): ``|p(t) - s_j| + c dtau(t) + N(0, sigma^2)`` (seed 001 eq. 5)."""
    r = np.linalg.norm(track.pos_m[:, None, :] - stations_m[None], axis=-1)  # (T, m)
    rho = r + clock.bias_m(track.t_s)[:, None]
    return rho[:, None, :] + sigma_m * rng.standard_normal((track.t_s.size, runs, stations_m.shape[0]))


def true_state(track: Track, clock: ReceiverClock, layout: mdl.StateLayout) -> np.ndarray:
    """True filter states (T, n) along the track."""
    cols = [track.pos_m, track.vel_m_s]
    if layout.kind == "pr":
        cols.append(clock.bias_m(track.t_s)[:, None])
        if layout.drift:
            cols.append(np.full((track.t_s.size, 1), clock.drift_m_s))
    return np.concatenate(cols, axis=1)


def run_algo(
    algo: str, track: Track, stations_m: np.ndarray, rho: np.ndarray, tuning: Tuning, clock: ReceiverClock,
    rng: np.random.Generator, station_cov_m2: np.ndarray | None = None, keep_cov: bool = False,
    lsq_stride: int = 1, clock_var_m2: np.ndarray | float | None = None, fde=None,
    bias_m: np.ndarray | None = None,
) -> RunResult:
    """Run one algorithm over all epochs of ``rho`` (T, M, m); returns the errors against the truth.

    Filters start from the truth plus a draw from their own prior ``N(0, P0)`` (so the posterior
    CRLB with the same ``P0`` applies); LSQ starts its first epoch from the same kind of coarse fix and
    each later epoch from its previous solution. LSQ is a snapshot method, so it may skip epochs
    (``lsq_stride``): its ``err_m`` then has ``ceil(T / lsq_stride)`` samples per run.

    ``clock_var_m2`` (scalar or (m,)): the stations' broadcast clock variances ``c^2 P_theta``. The
    filters carry them as ``tuning.clock_bias`` says (one Gauss-Markov bias state per station, or white
    range variance); LSQ, a snapshot, adds them to each range's variance (one epoch sees each station's
    residual once; stations independent). NEES is that of the navigation states (the filter's first
    ``n`` states), the bias states' marginal excluded.

    ``fde`` (:class:`aircraft.navigator.radio.fde.FdeConfig`): filters gate, test and exclude stations (ids 0..m-1) and
    report HPL/VPL. ``bias_m`` (T, m): a fault added to the ranges (the estimators never see it apart).
    """
    method, model = algo.split("-")
    if bias_m is not None:
        rho = rho + bias_m[:, None, :]
    T, M, m = rho.shape
    err = np.empty((M, T, 3))
    layout = mdl.StateLayout(model, drift=model == "pr")
    xt = true_state(track, clock, layout)
    P0 = tuning.prior_cov(layout)
    x0 = xt[0] + rng.standard_normal((M, layout.n)) @ np.linalg.cholesky(P0).T
    var = tuning.sigma_m**2
    m = stations_m.shape[0]
    cvar = None if clock_var_m2 is None else np.broadcast_to(np.asarray(clock_var_m2, dtype=float), (m,))
    if cvar is not None and method == "lsq":
        var = var + cvar
    if method == "lsq":
        x = x0[:, [0, 1, 2, 6]] if model == "pr" else x0[:, :3]
        centre = stations_m.mean(axis=0)
        ks = range(0, T, lsq_stride)
        err = np.empty((M, len(ks), 3))
        for i, k in enumerate(ks):
            if model == "pr":
                x = lsq_pr(rho[k], stations_m, x, var, station_cov_m2, floor_z_m=tuning.floor_z_m)
            else:
                x = lsq_tdoa(rho[k], stations_m, x, var, station_cov_m2, floor_z_m=tuning.floor_z_m)
            # a run whose iteration left the 100 km world restarts from its coarse initial fix
            bad = ~np.all(np.isfinite(x), axis=-1) | (np.linalg.norm(x[:, :3] - centre, axis=-1) > 1e5)
            if np.any(bad):
                x[bad] = x0[bad][:, : x.shape[1]]
            err[:, i] = x[:, :3] - track.pos_m[k]
        return RunResult(err)
    trk = CvTracker(method, model, x0, tuning, t0_s=float(track.t_s[0]))
    kw = {} if cvar is None else {"bias_ids": list(range(m)), "bias_var_m2": cvar}
    n = layout.n
    nees = np.empty((M, T))
    nis = np.empty((M, T))
    P_pos = np.empty((M, T, 3, 3)) if keep_cov else None
    mon = None if fde is None else FilterFde(fde, (M,))
    hpl = None if fde is None else np.empty((M, T))
    vpl = None if fde is None else np.empty((M, T))
    for k in range(T):
        trk.predict_to(float(track.t_s[k]))
        if mon is not None:
            nu, S = mon.update(trk, stations_m, rho[k], list(range(m)), station_cov_m2, **kw)
        else:
            nu, S = trk.update(stations_m, rho[k], station_cov_m2, **kw)
        x, P = trk.x, trk.P
        e = x[:, :n] - xt[k]
        err[:, k] = e[:, :3]
        nees[:, k] = kf.nees(e, P[:, :n, :n])
        nis[:, k] = kf.nis(nu, S)
        if keep_cov:
            P_pos[:, k] = P[:, :3, :3]
        if mon is not None:
            hpl[:, k], vpl[:, k] = protection_levels(P[:, :3, :3], fde.integrity_risk)
    return RunResult(err, nees, nis, P_pos, hpl, vpl, mon)


def pcrb_track(
    model: str, track: Track, stations_m: np.ndarray, tuning: Tuning, clock: ReceiverClock,
    station_cov_m2: np.ndarray | None = None, clock_var_m2: np.ndarray | float | None = None,
    clock_tau_s: float = 0.0, lost: np.ndarray | None = None,
) -> np.ndarray:
    """Posterior CRLB of the filter's own model along the true track; position bound (T, 3, 3).

    ``clock_var_m2`` (scalar or (m,)) with ``clock_tau_s > 0``: the stations' residual clock errors are
    first-order Gauss-Markov range biases of that stationary variance and correlation time; the bound
    is that of the augmented state ``[x, beta]`` (:func:`nav.pcrb.augment_biases`), i.e. of the world
    with station clocks. ``clock_tau_s == 0``: white, added to the range variance. ``lost`` (T, m) bool:
    measurements not available (their information is left out: e.g. a station from its exclusion on).
    """
    layout = mdl.StateLayout(model, drift=model == "pr")
    xt = true_state(track, clock, layout)
    dt = float(np.median(np.diff(track.t_s)))
    F = mdl.cv_transition(layout.n, dt)
    Q = mdl.cv_noise(layout.n, dt, tuning.q_acc, tuning.q_clock, tuning.q_drift)
    m = stations_m.shape[0]
    white = clock_var_m2 is not None and not clock_tau_s > 0
    sig = np.sqrt(tuning.sigma_m**2 + (np.broadcast_to(clock_var_m2, (m,)) if white else 0.0))
    var = mdl.range_var(xt, stations_m, station_cov_m2, sig)  # (T, m)
    if lost is not None:  # no information: a variance of (100 km)^2 (differences: the others' remain)
        var = np.where(np.asarray(lost, dtype=bool), 1e10, var)
    if model == "pr":
        H = mdl.jac_pr(xt, stations_m)
        R = mdl.r_pr(var)
        D = np.eye(m)
    else:
        H = mdl.jac_tdoa(xt, stations_m, 0)
        R = mdl.r_tdoa(var, 0)
        D = mdl.g_matrix(m, 0)
    P0 = tuning.prior_cov(layout)
    if clock_var_m2 is not None and not white:
        P0, F, Q, H = augment_biases(P0, F, Q, H, D, clock_var_m2, clock_tau_s, dt)
    # the first batch is measured at t0 without a preceding prediction: start one step earlier
    P_start = prior_before_first_step(P0, F, Q)
    P = pcrb_linear_gaussian(P_start, F, Q, H, R)
    return P[:, :3, :3]


def rms_total(err_m: np.ndarray) -> float:
    """Seed 001's total error ``sqrt(sx^2 + sy^2 + sz^2)`` as an RMS over all samples (bias included)."""
    return float(np.sqrt(np.mean(np.sum(err_m**2, axis=-1))))
