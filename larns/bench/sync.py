"""`larns bench sync`: Monte Carlo of the stations' network time (clock synchronization).

Each trial draws a fresh random layout and fresh oscillators (the scenario's ``[clock]`` class, TCXO by
default) from its own seed and runs the in-process simulator (the same station cores as the Zenoh
fleet). At every second it compares each station's estimate of its clock offset against network
time (the ensemble of the clocks, ``stations/clocksync.py``; every station, station 1 included) with
the truth (the station's definition of the ensemble on the true clocks), and with the Bayesian bound
of the *same* realized exchanges: the centralized linear Kalman filter of all clocks on the true
exchange times and the true oscillator model (linear Gaussian, so its covariance is the posterior
CRLB), taken on the ensemble of the stations alive (equal weights).

``--founders-leave``: stations 1, 2 and 3 fall silent at 60, 120 and 180 s (300 s run); the bench
adds the largest step of network time at each departure (over stations and trials, against the
true clocks: ``net.clock.ensemble_step_s``).
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import time
from pathlib import Path

import numpy as np

TABLE_TIMES_S = [2, 5, 10, 20, 30, 40, 60, 90, 120, 150, 180, 240, 300, 600]
AFTER_S = 60.0  # each trial's largest error is taken over the samples at and after this time
FOUNDERS_LEAVE_S = {1: 60.0, 2: 120.0, 3: 180.0}  # --founders-leave: station -> time it falls silent


def register(sub) -> None:
    p = sub.add_parser(
        "sync",
        help="network time Monte Carlo (seed 000 world, TCXO clocks): sync error vs time, CRLB, NEES",
        description=(
            "Monte Carlo of the stations' clock synchronization over the ranging exchanges. Prints, at t = "
            "2, 5, 10, 20, 30, 40, 60, 90, 120 s (up to --duration), the RMS of the stations' clock error "
            "against network time (the ensemble of the clocks; every station, ns), the RMS of the centralized "
            "Bayesian bound on the same exchanges, their ratio, the largest error, and the mean NEES (1 dof) with its 95%% band (the band of the statistic with the "
            "stations' correlation through network time, from the centralized filter) and the 95%% interval of "
            "the mean from the trial-to-trial spread. JSON keys: times_s, sync_rms_ns, sync_max_ns (largest "
            "error over stations and trials at each time), sync_trial_max_ns (each trial's largest error over "
            "all stations and samples from 60 s on), sync_spread_ns (largest difference between the stations' "
            "definitions of network time, on the true clocks), sync_crlb_rms_ns, nees_mean, nees_band_95_correlated; "
            "with --founders-leave also departure_step_ns."),
    )
    p.add_argument("--trials", type=int, default=100, help="Monte Carlo trials (default 100)")
    p.add_argument("--sigma-d", type=float, default=0.5, metavar="M", help="range noise sigma_d, m (default 0.5)")
    p.add_argument("--stations", type=int, default=None,
                   help="number of stations of a random layout (default: the scenario's; seed000: 10)")
    p.add_argument("--clock", default="tcxo", help="oscillator preset: tcxo, ocxo (default tcxo)")
    p.add_argument("--duration", type=float, default=None,
                   help="simulated seconds per trial (default 120: a minute after 60 s for sync_trial_max_ns; "
                        "300 with --founders-leave)")
    p.add_argument("--bound-draws", type=int, default=0, metavar="N",
                   help="also N draws of the bound's own filter (clocks of its model, Gaussian transfers) on the "
                        "first trial's exchanges: how often the efficient estimator keeps each trial's largest "
                        "error from 60 s on <= 2 ns, with its binomial 95%% interval (JSON bound_draws)")
    p.add_argument("--founders-leave", action="store_true",
                   help="stations 1, 2, 3 fall silent at 60, 120, 180 s (300 s run): steps of network time")
    p.add_argument("--late-founder", type=float, default=None, metavar="S",
                   help="station 1 (a founder) powers on S s after the others, which meanwhile defined network "
                        "time without it (docs/sync.md, the time scale's steering); bar: the stations' "
                        "definitions of network time within 2 ns of each other from S + 30 s on")
    p.add_argument("--scenario", default="seed000", help="scenario name or TOML path (default seed000)")
    p.add_argument("--ranging", choices=["addressed", "poll"], default=None,
                   help="[tdma] ranging: the addressed exchange or protocol v2's poll (default: the scenario's)")
    p.add_argument("--seed", type=int, default=1, help="base seed; trial k uses seed + k (default 1)")
    p.add_argument("--hops-from", type=float, default=AFTER_S, metavar="S",
                   help="the per-hop table (multi-hop fields) takes the samples from S s on (default 60; "
                        "clipped to the last sample)")
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="worker processes (default: all cores)")
    p.add_argument("--json", metavar="FILE", help="write the results as JSON")
    p.add_argument("--png-dir", metavar="DIR", default="bench-out/sync",
                   help="where to write the PNG figure (default bench-out/sync; '' to skip)")
    p.set_defaults(func=main)


def _true_clocks(model, n: int, event_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Offsets (E, n) of ``n`` independent clocks of ``model`` (the bound's own linear-Gaussian
    world: offset and frequency drawn from their priors, then the exact two-state steps of
    :func:`net.clock.transition`) at the sorted times ``event_s`` (E,)."""
    from net.clock import transition

    x = np.stack([rng.standard_normal(n) * model.offset_sigma_s, rng.standard_normal(n) * model.freq_sigma], 1)
    out = np.empty((len(event_s), n))
    t_prev = 0.0
    for e, t in enumerate(event_s):
        F, Q = transition(t - t_prev, model.q_wf_s, model.q_rw_per_s)
        L = np.linalg.cholesky(Q + 1e-300 * np.eye(2)) if t > t_prev else np.zeros((2, 2))
        x = x @ F.T + rng.standard_normal((n, 2)) @ L.T
        out[e] = x[:, 0]
        t_prev = t
    return out


def crlb_offset_var(scn, exchange_log, ids, times_s: np.ndarray, corr_eig: list | None = None,
                    stop_s: dict | None = None, rng: np.random.Generator | None = None
                    ) -> tuple[np.ndarray, np.ndarray | None]:
    """Offset variance (K, n) against the ensemble (equal weights over the stations alive, ``stop_s``:
    id -> time it falls silent) of the centralized KF of all clocks on the realized exchanges (true
    times); NaN for a station no longer alive. With ``rng``, also that filter's own errors (K, n), s:
    it is fed the exchanges of clocks drawn from the oscillator model it assumes
    (:func:`_true_clocks`; the variance does not depend on the values), so it is the efficient
    estimator of the bound's world, and its errors show what the bound allows of any statistic of
    them (e.g. each trial's largest error), not only of their variance. Else (var, None).

    ``corr_eig``, if a list, receives per time the eigenvalues of the alive stations' offsets'
    correlation matrix in that filter: how strongly the stations' errors share a common mode."""
    from nav.geometry import SPEED_OF_LIGHT_M_S
    from net.radio import range_var_m2
    from stations.clocksync import ClockEstimator, ClockModel

    ck = scn.clock
    model = ClockModel(ck.q_wf_s, ck.q_rw_per_s, ck.offset_s, ck.freq_sigma)
    kf = ClockEstimator(ids[1], model, 0.0, scn.channel.sigma_d_m)
    # each exchange's transfer noise: (sigma_d / c)^2, or under [radio] its link's at the true geometry
    radio = getattr(scn.channel, "radio", None)
    P = np.asarray([scn.true_pos(sid) for sid in ids], float)
    z_var = (np.full((len(ids), len(ids)), kf.var_z) if radio is None else
             range_var_m2(P[:, None, :], P[None, :, :], radio, scn.channel.sigma_d_m) / SPEED_OF_LIGHT_M_S**2)
    for sid in ids[1:]:
        kf._add(sid)
    stop_s = stop_s or {}
    out = np.full((len(times_s), len(ids)), np.nan)
    err = None if rng is None else np.full((len(times_s), len(ids)), np.nan)
    log = sorted(exchange_log)
    T_ex = np.array([tt - 0.5 * scn.channel.turnaround_s for tt, _a, _b in log])
    if rng is not None:  # the true clocks at every exchange and every sample, in time order
        ev = np.concatenate([T_ex, np.asarray(times_s, float)])
        order = np.argsort(ev, kind="stable")
        theta = np.empty((len(ev), len(ids)))
        theta[order] = _true_clocks(model, len(ids), ev[order], rng)
        theta -= theta[:, :1]  # against station 1, the filter's reference
    i = 0
    for k, t in enumerate(times_s):
        while i < len(log) and log[i][0] <= t:
            _tt, a, b = log[i]
            z = 0.0 if rng is None else theta[i, a] - theta[i, b] + rng.standard_normal() * np.sqrt(z_var[a, b])
            kf.on_exchange(ids[a], ids[b], T_ex[i], z, z_var_s2=z_var[a, b])
            i += 1
        kf.predict(t)
        alive = [j for j, sid in enumerate(ids) if t < stop_s.get(sid, np.inf)]
        q = np.array([2 * kf.index[sid] for sid in ids[1:]])
        cov_th = np.zeros((len(ids), len(ids)))  # offsets against station 1 (the filter's reference)
        cov_th[1:, 1:] = kf.P[np.ix_(q, q)]
        A = np.zeros((len(alive), len(ids)))
        A[:, alive] = -1.0 / len(alive)
        A[np.arange(len(alive)), alive] += 1.0  # offset of each alive station against their mean
        cov = A @ cov_th @ A.T
        out[k, alive] = np.diag(cov)
        if err is not None:
            e = np.zeros(len(ids))
            e[1:] = kf.x[q] - theta[len(log) + k, 1:]
            err[k, alive] = A @ e
        if corr_eig is not None:  # padded to n, scaled so that their sum / n is that of the alive ones
            d = np.sqrt(np.diag(cov))
            lam = np.zeros(len(ids))
            lam[: len(alive)] = np.linalg.eigvalsh(cov / np.outer(d, d)) * len(ids) / len(alive)
            corr_eig.append(lam)
    return out, err


_BOUND: tuple | None = None  # (scn, exchange_log, ids, times, stop_s) for the --bound-draws workers (fork)


def _bound_draw(k: int) -> float:
    """One draw of the bound's own filter on :data:`_BOUND`'s exchanges: its largest error from
    ``AFTER_S`` on over the stations and samples, ns."""
    scn, log, ids, times, stop_s = _BOUND
    _, err = crlb_offset_var(scn, log, ids, times, None, stop_s, np.random.default_rng([k, 0xB0]))
    return float(np.nanmax(np.abs(err[times >= AFTER_S]))) * 1e9


def bound_draws(job: tuple, draws: int, jobs: int) -> dict:
    """``draws`` draws of the bound's own filter on the exchanges of world ``job`` (a :func:`_trial` job):
    each trial's largest error from ``AFTER_S`` on; the share at most 2 ns with its binomial 95 % interval.
    Cheap (the filter alone, about 25 ms a draw): the trial-maximum bar's bound to a fraction of a percent."""
    global _BOUND
    scn, sim, r, times = _world(job)
    seed, stop_s = job[4], job[6]
    _BOUND = (scn, sim.exchange_log, r.ids, times, stop_s)
    with mp.get_context("fork").Pool(max(1, jobs)) as pool:
        m = np.array(pool.map(_bound_draw, range(draws)))
    ok = float(np.mean(m <= 2.0))
    return {"n": int(draws), "world_seed": int(seed), "trial_max_le_2ns": ok,
            "ci95": 1.96 * float(np.sqrt(ok * (1.0 - ok) / draws)), "median_ns": float(np.median(m)),
            "p99_ns": float(np.percentile(m, 99)), "max_ns": float(m.max())}


def _world(job: tuple):
    """One trial's world run in the simulator: ``(scn, sim, result, times)`` of a :func:`_trial` job
    ``(scenario, clock, sigma_d, n, seed, duration, stop_s, start_s)``, sampled every second."""
    from net.scenario import load
    from stations.sim import Simulator

    scenario, clock, sigma_d, n, seed, duration, stop_s, start_s, *opt = job
    ranging = opt[0] if opt else None  # (jobs without it: the scenario's [tdma] ranging)
    scn = load(scenario, seed=seed, channel={"sigma_d_m": sigma_d}, clock={"model": clock},
               **({"layout": {"n": n}} if n else {}), **({"tdma": {"ranging": ranging}} if ranging else {}))
    sim = Simulator(scn, stop_s=stop_s, start_s=start_s)
    times = np.arange(1.0, duration + 1e-9, 1.0)
    return scn, sim, sim.run(duration, times), times


def hops_from_founders(pairs, n: int, founders=(0, 1, 2)) -> np.ndarray:
    """Hop count (n,) of each station from the founders (indices ``founders``, hop 0) in the realized
    link graph: ``pairs`` the (initiator, responder) station indices of the exchanges that completed
    (a link exists once one exchange completed, either way). -1: never linked to the founders."""
    A = [set() for _ in range(n)]
    for a, b in pairs:
        if a != b:
            A[a].add(b)
            A[b].add(a)
    hop = np.full(n, -1)
    frontier = [f for f in founders if f < n]
    hop[frontier] = 0
    h = 0
    while frontier:
        h += 1
        nxt = sorted({j for i in frontier for j in A[i] if hop[j] < 0})
        hop[nxt] = h
        frontier = nxt
    return hop


def common_time_errors(est_offset_s: np.ndarray, x_true_s: np.ndarray) -> np.ndarray:
    """Each station's error (K, n) against *one* network time for the whole field.

    ``est_offset_s`` (K, n): the stations' estimated offsets against network time (each against its own
    definition, NaN: not alive); ``x_true_s`` (K, n): the true clock phases. Network time is a paper
    clock (its definition is a choice), so the common part of ``d = est - x`` over the stations alive is
    the field's choice, not an error; what is left, ``d - mean(d)``, is each station's error against
    the field's common time (its definition's disagreement with the others' included). The bound
    (:func:`crlb_offset_var`: the centralized filter's variance of ``theta_m - mean theta`` over the
    stations alive) bounds exactly this statistic."""
    d = est_offset_s - x_true_s
    return d - np.nanmean(d, axis=1, keepdims=True)


def per_hop_table(err_s: np.ndarray, bound_var_s2: np.ndarray, var_s2: np.ndarray, hop: np.ndarray,
                  sel: np.ndarray) -> list[dict]:
    """Clock error per hop count from the founders.

    Parameters
    ----------
    err_s : (T, K, n) errors (trials, times, stations), s; NaN: not alive.
    bound_var_s2 : (T, K, n) the bound's variance of the same errors, s^2.
    var_s2 : (T, K, n) the stations' own stated variance, s^2.
    hop : (T, n) hop count of each station in its trial (-1: not linked).
    sel : (K,) bool, the samples taken.

    Returns
    -------
    One row per hop present: ``hop``, ``stations`` (station-trials), ``rms_ns``, ``bound_ns``
    (RMS of the bound), ``ratio``, ``nees`` (mean of ``e^2 / var``), ``growth_ns`` and
    ``bound_growth_ns`` (increase of the RMS and of the bound from the previous hop present).
    """
    rows = []
    for h in sorted(set(hop[hop >= 0].tolist())):
        m = (hop == h)[:, None, :] & sel[None, :, None]  # (T, K, n)
        e, b, v = err_s[m], bound_var_s2[m], var_s2[m]
        ok = np.isfinite(e) & np.isfinite(b)
        if not ok.any():
            continue
        rms, bnd = float(np.sqrt(np.mean(e[ok] ** 2))) * 1e9, float(np.sqrt(np.mean(b[ok]))) * 1e9
        good = ok & (v > 0)
        row = {"hop": int(h), "stations": int((hop == h).sum()), "rms_ns": rms, "bound_ns": bnd,
               "ratio": rms / bnd if bnd > 0 else float("nan"),
               "nees": float(np.mean(e[good] ** 2 / v[good])) if good.any() else float("nan")}
        if rows:
            row["growth_ns"], row["bound_growth_ns"] = rms - rows[-1]["rms_ns"], bnd - rows[-1]["bound_ns"]
        rows.append(row)
    return rows


def _trial(job: tuple) -> dict:
    from net.clock import ensemble_step_s

    seed, stop_s = job[4], job[6]
    scn, sim, r, times = _world(job)
    eig: list = []
    crlb, bound_err = crlb_offset_var(scn, sim.exchange_log, r.ids, times, eig, stop_s,
                                      np.random.default_rng([seed, 0x5C]))
    steps = {}  # departed station -> largest |step| of network time over the stations' scales, s
    clocks = sim.true_clocks()
    spread = sim.definition_spread_s(r, times)
    x = np.array([[clocks[sid].error_s(t) for sid in r.ids] for t in times])  # (K, n) true phases
    common = common_time_errors(r.clock_err_s + r.clock_true_s, x)
    hop = hops_from_founders([(a, b) for _t, a, b in sim.exchange_log], len(r.ids))
    for sid, log in r.time_scales.items():
        if sid in stop_s:
            continue
        for prev, sc in zip(log, log[1:]):
            for gone in (set(prev.w) - set(sc.w)) & set(stop_s):  # (a late founder adopting the field's
                # time leaves its own one-clock scale: not a departure)
                steps[gone] = max(steps.get(gone, 0.0), abs(ensemble_step_s(clocks, prev, sc)))
    return {"err_s": r.clock_err_s, "var_s2": r.clock_var_s2, "crlb_s2": crlb, "bound_err_s": bound_err,
            "corr_eig": eig, "steps_s": steps, "spread_s": spread, "common_err_s": common, "hop": hop,
            "n_states": [len(c.clk.index) for c in sim.cores if c is not None]}


def correlated_band(corr_eig: np.ndarray, level: float = 0.95, draws: int = 20000) -> tuple[np.ndarray, np.ndarray]:
    """Band of the mean NEES when a trial's stations are correlated.

    The statistic at one time is ``mean over trials and stations of e_i^2 / sigma_i^2``. If the errors
    are Gaussian with the claimed variances and correlation matrix ``R`` (that of the centralized
    filter on the same exchanges: the stations share network time's wander), one trial's mean over
    its ``n`` stations is ``z^T R z / n = sum_k lambda_k chi2_1 / n`` (``lambda``: eigenvalues of ``R``),
    and the trials are independent. The band is drawn from that law (seeded; exact up to the draws).

    Parameters
    ----------
    corr_eig : (T, K, n) eigenvalues per trial and time.

    Returns
    -------
    lo, hi : (K,) band per time.
    """
    rng = np.random.default_rng(20261125)
    T, K, n = corr_eig.shape
    lo, hi = np.zeros(K), np.zeros(K)
    a = (1 - level) / 2
    for k in range(K):
        lam = np.clip(corr_eig[:, k, :], 0.0, None).ravel()  # (T n,)
        stat = np.zeros(draws)
        for chunk in np.array_split(np.arange(lam.size), max(1, lam.size // 256)):
            stat += rng.chisquare(1.0, (draws, chunk.size)) @ lam[chunk]
        stat /= T * n
        lo[k], hi[k] = np.quantile(stat, [a, 1 - a])
    return lo, hi


def summarize(results: list[dict], times: np.ndarray, table_times: list[float], meta: dict) -> dict:
    from .survey import chi2_band

    err = np.stack([r["err_s"] for r in results]) * 1e9  # (T, K, n) ns; NaN: station not alive
    var = np.stack([r["var_s2"] for r in results]) * 1e18
    crlb = np.stack([r["crlb_s2"] for r in results]) * 1e18
    rms = np.sqrt(np.nanmean(err**2, axis=(0, 2)))
    crlb_rms = np.sqrt(np.nanmean(crlb, axis=(0, 2)))
    with np.errstate(invalid="ignore", divide="ignore"):  # var 0: station 1 while it alone is network time
        nees_trial = np.nanmean(np.where(var > 0, err**2 / var, np.nan), axis=2)  # (T, K): a trial's stations
        # share a common mode
    nees = nees_trial.mean(axis=0)
    # 95 % confidence interval of the mean NEES from the trial-to-trial spread (trials are independent,
    # a trial's stations are not: the chi-square band below assumes they are)
    nees_ci = 1.96 * nees_trial.std(axis=0, ddof=1) / np.sqrt(max(len(results), 1))
    ti = [int(np.argmin(np.abs(times - t))) for t in table_times]
    after = times >= AFTER_S
    # largest spread over trials of the stations' definitions of network time (on the true clocks)
    spread = np.stack([r["spread_s"] for r in results]).max(axis=0) * 1e9 if "spread_s" in results[0] \
        else np.full(len(times), np.nan)
    trial_max = np.nanmax(np.abs(err[:, after, :]), axis=(1, 2)) if after.any() else np.full(len(results), np.nan)
    lo, hi = chi2_band(1, int(np.isfinite(err[:, -1, :]).sum()))
    band_lo, band_hi = correlated_band(np.stack([r["corr_eig"] for r in results])[:, ti, :])
    below = np.flatnonzero(rms <= 1.0)
    res = dict(meta)
    res.update({
        "trials": len(results),
        "times_s": [float(t) for t in table_times],
        "sync_rms_ns": rms[ti].tolist(),
        "sync_crlb_rms_ns": crlb_rms[ti].tolist(),
        "crlb_ratio": (rms[ti] / crlb_rms[ti]).tolist(),
        "sync_max_ns": np.nanmax(np.abs(err), axis=(0, 2))[ti].tolist(),
        "sync_spread_ns": spread[ti].tolist(),
        "sync_trial_max_ns": trial_max.tolist(),
        "sync_after_s": AFTER_S,
        "sync_rms_after_ns": float(np.sqrt(np.nanmean(err[:, after, :] ** 2))) if after.any() else None,
        "nees_mean": nees[ti].tolist(),
        "nees_band_95": [lo, hi],
        "nees_band_95_correlated": [[float(a), float(b)] for a, b in zip(band_lo, band_hi)],
        "nees_ci95": [[float(nees[i] - nees_ci[i]), float(nees[i] + nees_ci[i])] for i in ti],
        "time_to_1ns_s": float(times[below[0]]) if len(below) else None,
        "curve_times_s": times.tolist(),
        "curve_sync_rms_ns": rms.tolist(),
        "curve_sync_crlb_rms_ns": crlb_rms.tolist(),
    })
    steps = [r.get("steps_s", {}) for r in results]
    gone = sorted({g for st in steps for g in st})
    if gone:
        res["departure_step_ns"] = {str(g): float(max(st.get(g, 0.0) for st in steps) * 1e9) for g in gone}
    if after.any() and all(r.get("bound_err_s") is not None for r in results):
        # the centralized filter on exchanges of the model's own clocks: what the bound allows of the same
        # statistics (crlb_offset_var)
        be = np.stack([r["bound_err_s"] for r in results]) * 1e9
        res["bound_trial_max_ns"] = np.nanmax(np.abs(be[:, after, :]), axis=(1, 2)).tolist()
        res["bound_rms_after_ns"] = float(np.sqrt(np.nanmean(be[:, after, :] ** 2)))
    if "common_err_s" in results[0]:
        _multihop_summary(res, results, times, crlb, var)
    res["bar"] = _bars(res, trial_max, hi)
    return res


def _multihop_summary(res: dict, results: list[dict], times: np.ndarray, crlb_ns2: np.ndarray,
                      var_ns2: np.ndarray) -> None:
    """Into ``res``: the error against the field's one network time per table time
    (``sync_common_rms_ns``), and per hop count from the founders (``per_hop``: :func:`per_hop_table`
    over the samples from ``hops_from_s`` on, clipped to the last sample)."""
    common = np.stack([r["common_err_s"] for r in results]) * 1e9
    ti = [int(np.argmin(np.abs(times - t))) for t in res["times_s"]]
    res["sync_common_rms_ns"] = np.sqrt(np.nanmean(common**2, axis=(0, 2)))[ti].tolist()
    res["curve_sync_common_rms_ns"] = np.sqrt(np.nanmean(common**2, axis=(0, 2))).tolist()
    t0 = min(float(res.get("hops_from_s") or AFTER_S), float(times[-1]))
    sel = times >= t0
    hop = np.stack([r["hop"] for r in results])
    res["hops_from_s"] = t0
    res["per_hop"] = per_hop_table(common * 1e-9, crlb_ns2 * 1e-18, var_ns2 * 1e-18, hop, sel)
    own = per_hop_table(np.stack([r["err_s"] for r in results]), crlb_ns2 * 1e-18, var_ns2 * 1e-18, hop, sel)
    for row in res["per_hop"]:  # the error against the station's own definition, for comparison
        row["own_rms_ns"] = next((o["rms_ns"] for o in own if o["hop"] == row["hop"]), float("nan"))
    res["clock_states_max"] = int(max(max(r["n_states"]) for r in results))
    res["clock_states_median"] = float(np.median(np.concatenate([r["n_states"] for r in results])))


def _bars(res: dict, trial_max: np.ndarray, nees_hi: float) -> dict[str, bool]:
    """The bench's bars on the summary ``res`` (``nees_hi``: top of the independent chi-square band)."""
    t = res["times_s"]
    bar = {}
    if 30.0 in t:
        bar["rms_at_30s_le_1ns"] = res["sync_rms_ns"][t.index(30.0)] <= 1.0
    if 60.0 in t:
        bar["rms_at_60s_le_1.2_crlb"] = res["crlb_ratio"][t.index(60.0)] <= 1.2
    # issue 30: RMS <= 0.6 ns at 60 s and beyond; each trial's largest error from 60 s on <= 2 ns in 99 %
    late = [i for i, x in enumerate(t) if x >= AFTER_S]
    if late:
        bar["rms_from_60s_le_0.6ns"] = all(res["sync_rms_ns"][i] <= 0.6 for i in late)
        bar["trial_max_from_60s_le_2ns_in_99pct"] = float(np.mean(trial_max <= 2.0)) >= 0.99
    late = res.get("late_founder_s")
    if late is not None:  # every station's network time agrees with the others' once the founder is in
        after = [i for i, x in enumerate(t) if x >= late + 30.0]
        if after:
            bar["late_founder_spread_le_2ns_from_30s_after"] = all(res["sync_spread_ns"][i] <= 2.0 for i in after)
    if "departure_step_ns" in res:
        bar["departure_steps_le_0.3ns"] = all(v <= 0.3 for v in res["departure_step_ns"].values())
    # the band of the statistic as it is (stations correlated through network time), at every time
    bar["nees_in_band_or_below"] = all(x <= b[1] for x, b in zip(res["nees_mean"], res["nees_band_95_correlated"]))
    bar["nees_in_independent_band_or_below"] = all(x <= nees_hi for x in res["nees_mean"][1:])
    # the same with the band from the trials' own spread: the 95 % CI of the mean NEES reaches 1 or lies below
    bar["nees_ci_contains_1_or_below"] = all(c[0] <= 1.0 for c in res["nees_ci95"][1:])
    return bar


def print_table(res: dict) -> None:
    print(f"\nclock={res['clock']}  sigma_d={res['sigma_d_m']} m  trials={res['trials']}  stations={res['stations']}  "
          f"wall={res.get('wall_s', float('nan')):.1f} s")
    hdr = ("t_s", "rms_ns", "crlb_ns", "ratio", "max_ns", "NEES", "band_lo", "band_hi", "CI_lo", "CI_hi", "spread",
           "common")
    print("  ".join(f"{h:>8}" for h in hdr))
    for k, t in enumerate(res["times_s"]):
        row = [t, res["sync_rms_ns"][k], res["sync_crlb_rms_ns"][k], res["crlb_ratio"][k], res["sync_max_ns"][k],
               res["nees_mean"][k], *res["nees_band_95_correlated"][k], *res["nees_ci95"][k],
               res["sync_spread_ns"][k], res.get("sync_common_rms_ns", [np.nan] * (k + 1))[k]]
        print("  ".join(f"{x:8.3f}" for x in row))
    lo, hi = res["nees_band_95"]
    print(f"band_lo/hi: 95% band of the mean NEES (1 dof) with the stations' correlation (centralized filter); "
          f"taken as independent it would be [{lo:.3f}, {hi:.3f}]; CI_lo/hi: 95% CI of the mean from the "
          f"trial-to-trial spread;  time to RMS <= 1 ns: {res['time_to_1ns_s']} s; spread: largest difference "
          f"(over trials) between the stations' network times, each station's definition on the true clocks, ns; "
          f"common: RMS error against the field's one network time (common mode removed), ns")
    tm = np.asarray(res["sync_trial_max_ns"], float)
    if np.isfinite(tm).any():
        print(f"from {res['sync_after_s']:.0f} s on: RMS {res['sync_rms_after_ns']:.3f} ns; each trial's largest "
              f"error (ns): median {np.nanmedian(tm):.3f}, max {np.nanmax(tm):.3f}, "
              f"<= 2 ns in {100 * np.mean(tm <= 2.0):.1f} % of trials")
    bm = np.asarray(res.get("bound_trial_max_ns", []), float)
    if bm.size:
        print(f"  the bound's own filter (centralized KF, same exchanges, clocks of its model): RMS "
              f"{res['bound_rms_after_ns']:.3f} ns; each trial's largest error: median {np.median(bm):.3f}, max "
              f"{bm.max():.3f}, <= 2 ns in {100 * np.mean(bm <= 2.0):.1f} % of trials")
    bd = res.get("bound_draws")
    if bd:
        print(f"  the bound's own filter, {bd['n']} draws on world {bd['world_seed']}'s exchanges: each trial's largest "
              f"error median {bd['median_ns']:.3f}, p99 {bd['p99_ns']:.3f}, max {bd['max_ns']:.3f} ns; <= 2 ns in "
              f"{100 * bd['trial_max_le_2ns']:.1f} +- {100 * bd['ci95']:.1f} % of trials (what the bound allows)")
    for sid, v in res.get("departure_step_ns", {}).items():
        print(f"station {sid} left: largest step of network time (stations, trials) {v:.3f} ns")
    if res.get("per_hop"):
        print_per_hop(res)
    for name, ok in res["bar"].items():
        print(f"  bar {name}: {'PASS' if ok else 'FAIL'}")


def print_per_hop(res: dict) -> None:
    """The per-hop table of :func:`per_hop_table` (``res['per_hop']``)."""
    print(f"\nper hop from the founders (realized links), samples from {res['hops_from_s']:.0f} s on; error against the "
          f"field's one network time (common mode of the stations removed), bound: centralized KF, same exchanges")
    hdr = ("hop", "n", "rms_ns", "bound_ns", "ratio", "growth", "b_growth", "NEES", "own_ns")
    print("  ".join(f"{h:>8}" for h in hdr))
    for row in res["per_hop"]:
        vals = [row["hop"], row["stations"], row["rms_ns"], row["bound_ns"], row["ratio"],
                row.get("growth_ns", float("nan")), row.get("bound_growth_ns", float("nan")), row["nees"],
                row["own_rms_ns"]]
        print("  ".join(f"{v:8d}" if isinstance(v, int) else f"{v:8.3f}" for v in vals))
    print(f"own_ns: against the station's own definition (what rms_ns above measures); clock states per station: "
          f"median {res['clock_states_median']:.0f}, max {res['clock_states_max']}")


def plot(res: dict, png_dir: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    png_dir.mkdir(parents=True, exist_ok=True)
    hops = res.get("per_hop") or []
    fig, axes = plt.subplots(1, 2 if hops else 1, figsize=(13 if hops else 8, 5), squeeze=False)
    ax = axes[0, 0]
    t = res["curve_times_s"]
    ax.plot(t, res["curve_sync_rms_ns"], label="RMS clock error vs network time")
    if "curve_sync_common_rms_ns" in res:
        ax.plot(t, res["curve_sync_common_rms_ns"], label="RMS vs the field's one network time")
    ax.plot(t, res["curve_sync_crlb_rms_ns"], ls="--", label="centralized bound (same exchanges)")
    ax.axhline(1.0, color="grey", lw=0.8)
    ax.set_yscale("log")
    ax.set_xlabel("time, s")
    ax.set_ylabel("clock error, ns")
    ax.set_title(f"Network time: {res['clock']} clocks, {res['stations']} stations, {res['trials']} trials")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    if hops:
        ax2 = axes[0, 1]
        h = [r["hop"] for r in hops]
        ax2.plot(h, [r["rms_ns"] for r in hops], "o-", label="RMS vs the field's one network time")
        ax2.plot(h, [r["bound_ns"] for r in hops], "s--", label="centralized bound")
        ax2.set_xlabel("hops from the founders (realized links)")
        ax2.set_ylabel("clock error, ns")
        ax2.set_yscale("log")
        ax2.set_title(f"per hop, from {res['hops_from_s']:.0f} s")
        ax2.grid(True, alpha=0.3)
        ax2.legend()
    f = png_dir / "sync_convergence.png"
    fig.tight_layout()
    fig.savefig(f, dpi=110)
    plt.close(fig)
    return f


def main(args) -> int:
    from .progress import progress

    if args.duration is None:
        args.duration = 300.0 if args.founders_leave else 120.0
    stop_s = dict(FOUNDERS_LEAVE_S) if args.founders_leave else {}
    start_s = {1: float(args.late_founder)} if args.late_founder else {}
    table_times = [t for t in TABLE_TIMES_S if t <= args.duration]
    times = np.arange(1.0, args.duration + 1e-9, 1.0)
    jobs = [(args.scenario, args.clock, args.sigma_d, args.stations, args.seed + k, args.duration, stop_s, start_s,
             getattr(args, "ranging", None)) for k in range(args.trials)]
    t0 = time.perf_counter()
    ctx = mp.get_context("fork")
    with ctx.Pool(max(1, args.jobs)) as pool:
        results = list(progress(pool.imap(_trial, jobs), f"sync {args.clock}", total=len(jobs)))
    res = summarize(results, times, table_times, {"clock": args.clock, "sigma_d_m": args.sigma_d,
                                                   "stations": args.stations, "scenario": args.scenario,
                                                   "ranging": getattr(args, "ranging", None),
                                                   "founders_leave_s": {str(k): v for k, v in stop_s.items()},
                                                   "late_founder_s": args.late_founder,
                                                   "hops_from_s": args.hops_from})
    if res["stations"] is None:
        res["stations"] = int(len(results[0]["hop"]))
    if args.bound_draws > 0 and args.duration > AFTER_S:
        res["bound_draws"] = bound_draws(jobs[0], args.bound_draws, args.jobs)
    res["wall_s"] = time.perf_counter() - t0
    print_table(res)
    if args.png_dir:
        print(f"wrote {plot(res, Path(args.png_dir))}")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(res, indent=1))
        print(f"wrote {args.json}")
    return 0
