"""`larns bench survey`: Monte Carlo of the seed-000 self-survey scenario.

Each trial draws a fresh random layout (10 stations in 2 x 2 km x 80 m by default), coarse fixes,
clocks and range noise from its own seed, runs the in-process simulator (the same station cores
as the Zenoh fleet) and compares the estimates with the truth, with the centralized Bayesian CRLB
of the *same* realized exchanges (``nav.crlb.poll_exchange_counts``), and with the centralized batch
MAP on the initiators' ranges the surveys took (protocol v2: the pollers' single-sided ranges, whose
own bound is one range per exchange, above the exchanges' 4/3).
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import time
from pathlib import Path

import numpy as np

TABLE_TIMES_S = [10, 15, 20, 30, 40, 60]
LONG_TABLE_TIMES_S = [30, 60, 120, 180, 240, 300]  # runs longer than 60 s (large multi-hop fields)
NO_FIX_SIGMA_M = 1000.0  # stations/estimators.py DistributedMap no_fix_sigma_m


def register(sub) -> None:
    p = sub.add_parser(
        "survey",
        help="self-survey Monte Carlo (seed 000 scenario): errors vs time, CRLB, NEES",
        description=(
            "Monte Carlo of the stations' self-survey (seed 000: 10 stations, 2 x 2 km x 80 m, 1 s cycle of "
            "10 ms slots, coarse fix sigma0 = 10 m). Prints, per estimator and sigma_d, a table at "
            "t = 10, 15, 20, 30, 40, 60 s: mean/max horizontal error, mean vertical error, horizontal RMS, "
            "the centralized CRLB horizontal RMS for the same measurements and their ratio, the centralized "
            "batch-MAP horizontal RMS, and the mean NEES with its 95%% chi-square band. Errors are over "
            "stations 4..n; the 'free' columns cover all free coordinates of stations 2..n."
        ),
    )
    p.add_argument("--trials", type=int, default=100, help="Monte Carlo trials per configuration (default 100)")
    p.add_argument("--sigma-d", type=float, nargs="+", default=[0.5, 1.5], metavar="M",
                   help="range noise sigma_d in metres (default: 0.5 1.5)")
    p.add_argument("--stations", type=int, default=None,
                   help="number of stations of a random layout (default: the scenario's, 10 for seed000)")
    p.add_argument("--times", type=float, nargs="+", default=None, metavar="S",
                   help="table times in s (default 10 15 20 30 40 60, or 30 60 120 180 240 300 for runs "
                        "longer than 60 s)")
    p.add_argument("--estimator", nargs="+", default=["dmap", "seed-ukf"], choices=["dmap", "dmap-nlos", "dmap-ls", "seed-ukf"],
                   help="estimators to run (default: dmap seed-ukf; dmap-nlos = dmap hardened for many NLOS legs; dmap-ls = dmap without robust weights)")
    p.add_argument("--duration", type=float, default=60.0, help="simulated seconds per trial (default 60)")
    p.add_argument("--scenario", default="seed000", help="scenario name or TOML path (default seed000)")
    p.add_argument("--ranging", choices=["addressed", "poll"], default=None,
                   help="[tdma] ranging: the addressed exchange or protocol v2's poll (default: the scenario's)")
    p.add_argument("--datum", choices=["founders", "field"], default=None,
                   help="[survey] datum (default: the scenario's; --founders-leave: field). With field the "
                        "errors and NEES are against the truth in the field's own datum from the release on "
                        "(larns.analysis.datum); the CRLB and batch-MAP columns stay in the founders' frame")
    p.add_argument("--seed", type=int, default=1, help="base seed; trial k uses seed + k (default 1)")
    p.add_argument("--clock", default=None, metavar="MODEL",
                   help="station oscillators: perfect, tcxo, ocxo (default: the scenario's [clock])")
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="worker processes (default: all cores)")
    p.add_argument("--no-map", action="store_true", help="skip the centralized batch MAP yardstick")
    p.add_argument("--json", metavar="FILE", help="write the results as JSON")
    p.add_argument("--png-dir", metavar="DIR", default="bench-out/survey",
                   help="where to write PNG figures (default bench-out/survey; '' to skip)")
    p.add_argument("--founders-leave", action="store_true",
                   help="the founders leave (station 1 at 60 s, 2 at 120 s, 3 at 180 s; 300 s run, dmap): each "
                        "trial also runs its twin without departures; reports the survivors' horizontal "
                        "deviation from the twin after each departure and at the end, in metres and in sigma")
    p.set_defaults(func=main)


def link_sigma_m(scn, truth_m: np.ndarray, sigma_d_m: float):
    """The bound's range noise: ``sigma_d``, or under ``[radio]`` (n, n) each link's at the true
    geometry (the timing CRLB of its SNR, :func:`net.radio.range_var_m2`)."""
    from net.radio import range_var_m2

    radio = getattr(scn.channel, "radio", None)
    if radio is None:
        return sigma_d_m
    return np.sqrt(range_var_m2(truth_m[:, None, :], truth_m[None, :, :], radio, sigma_d_m))


def multihop_stats(scn) -> dict:
    """The field's link graph at the true positions (``[radio]``; everyone hears everyone without
    one): degree min / median / max, the share of stations 4..n that hear none of the founders 1-3,
    the number of stations per hop count from the founders, and how many stations have fewer than
    four links (no trilateration without a fix can locate them)."""
    from net.radio import link

    P = scn.pos_m
    n = len(P)
    radio = getattr(scn.channel, "radio", None)
    A = np.ones((n, n), bool) if radio is None else np.asarray(link(P[:, None, :], P[None, :, :], radio).exists)
    A = A & ~np.eye(n, dtype=bool)
    hop = np.full(n, -1)
    hop[:3] = 0
    frontier = [0, 1, 2]
    while frontier:
        nxt = [j for i in frontier for j in np.flatnonzero(A[i]) if hop[j] < 0]
        nxt = sorted(set(nxt))
        hop[nxt] = hop[frontier[0]] + 1
        frontier = nxt
    deg = A.sum(axis=1)
    return {"degree_min": int(deg.min()), "degree_median": float(np.median(deg)), "degree_max": int(deg.max()),
            "hear_no_founder_frac": float((~A[3:, :3].any(axis=1)).mean()) if n > 3 else 0.0,
            "stations_per_hop": np.bincount(hop[hop >= 0]).tolist(), "unreachable": int((hop < 0).sum()),
            "under_4_links": int((deg < 4).sum())}


def load_trial(scenario: str, sigma_d: float, n: int | None, seed: int, clock: str | None, ranging: str | None,
               datum: str | None):
    """A trial's scenario: ``scenario`` with the bench's overrides (None: the scenario's own)."""
    from net.scenario import load

    return load(scenario, seed=seed, channel={"sigma_d_m": sigma_d}, **({"layout": {"n": n}} if n else {}),
                **({"clock": {"model": clock}} if clock else {}), **({"tdma": {"ranging": ranging}} if ranging else {}),
                **({"survey": {"datum": datum}} if datum else {}))


def _trial(job: tuple) -> dict:
    from nav.crlb import poll_exchange_counts, survey_crlb
    from nav.geometry import frame_free_mask
    from stations.estimators import holds_fix
    from stations.sim import Simulator

    from ..analysis.datum import sim_datum_truth, truth_series

    scenario, estimator, sigma_d, n, seed, duration, table_times, with_map, clock, *opt = job
    ranging = opt[0] if opt else None  # (jobs without it: the scenario's [tdma] ranging)
    datum = opt[1] if len(opt) > 1 else None  # (None: the scenario's [survey] datum)
    scn = load_trial(scenario, sigma_d, n, seed, clock, ranging, datum)
    sim = Simulator(scn, estimator=estimator)
    dt = sim_datum_truth(scn, sim) if scn.datum == "field" else None
    times = np.arange(1.0, duration + 1e-9, 1.0)
    r = sim.run(duration, times)
    # the truth in the field's datum from the release on (the founders' frame before, and throughout
    # in the founders' datum)
    truth = r.truth_m if dt is None else truth_series(dt, scn.ids, times)
    err = r.pos_m - truth  # (K, n, 3)
    # a station without a fix (scenario sigma0_m = 0) that has not trilaterated yet is not located:
    # it broadcasts its no-fix prior (stations/estimators.py); its error is not scored
    located = np.array([[holds_fix(c) for c in ck] for ck in r.cov_m2])  # (K, n)
    err = np.where(located[..., None], err, np.nan)
    free = frame_free_mask(len(scn.ids))
    ti = [int(np.argmin(np.abs(times - t))) for t in table_times]
    sig = link_sigma_m(scn, r.truth_m, sigma_d)
    # without a coarse fix the estimators' own weak prior (their no-fix sigma) keeps the bound finite
    # for a station whose links cannot locate it; a located station's bound does not feel it
    s0 = scn.sigma0_m if scn.sigma0_m > 0 else NO_FIX_SIGMA_M
    # the exchanges that happened: one range each, 4/3 for a protocol v2 exchange closed by its final
    fin = r.final_counts
    crlb = np.stack([survey_crlb(r.truth_m, poll_exchange_counts(r.link_counts[k], None if fin is None else fin[k]),
                                 sig, free, s0) for k in ti])
    nees, nees_h = nees_3d_h(err[:, 3:], r.cov_m2[:, 3:])  # stations 4..n (3 and 2 dof each)
    out = {"err": err, "nees": nees, "nees_h": nees_h, "datum_frozen_s": None if dt is None else dt.frozen_s,
           "crlb_diag": np.einsum("knii->kni", crlb), "located": located[ti].mean(axis=1),
           "multihop": multihop_stats(scn)}
    out["crlb_diag"][~located[ti]] = np.nan
    if scn.faults:  # [[faults]]: detection metrics; errors over the stations that are not faulty
        from .integrity import fault_metrics

        out["faults"] = fault_metrics(sim, scn.faults, duration)
        bad = [i for i, sid in enumerate(scn.ids) if sid in {f.station for f in scn.faults}]
        for key in ("err", "crlb_diag"):
            out[key] = out[key].astype(float)
            out[key][:, bad] = np.nan
        out["nees"][:, [b - 3 for b in bad if b >= 3]] = np.nan
        out["nees_h"][:, [b - 3 for b in bad if b >= 3]] = np.nan
    if with_map and scn.sigma0_m > 0:  # (the batch MAP's prior is the coarse fix)
        out["map_err"] = _map_errors(scn, sim, sigma_d, free, times[ti], r.truth_m)
    return out


def _map_errors(scn, sim, sigma_d: float, free: np.ndarray, times_s: np.ndarray, truth_m: np.ndarray) -> np.ndarray:
    """The centralized batch MAP's errors (K, n, 3) at ``times_s`` (K,) on the ranges simulator ``sim``'s
    surveys took, its prior the coarse fixes (in the founders' frame, as ``truth_m`` (n, 3))."""
    from nav.crlb import batch_map
    from net.channel import coarse_fix, station_rng

    prior = np.stack([coarse_fix(scn.pos_m[i], sid, scn.sigma0_m, station_rng(scn.seed, sid, 1))[0]
                      for i, sid in enumerate(scn.ids)])
    log = np.array(sim.range_log) if sim.range_log else np.zeros((0, 4))
    # the ranges the surveys took: not the v2 pollers' ranges gated on unknown clock frequencies
    log = np.delete(log, sorted(sim.gated_log), axis=0)
    maps = []
    for t in times_s:
        sel = log[:, 0] <= t
        X = batch_map(log[sel, 1:3].astype(int), log[sel, 3], sigma_d, free, prior, scn.sigma0_m)
        maps.append(X - truth_m)
    return np.stack(maps)


def nees_3d_h(err_m: np.ndarray, cov_m2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """3-D and horizontal (x, y) NEES (...,) of errors ``err_m`` (..., 3) with covariances ``cov_m2``
    (..., 3, 3); NaN where the error is NaN."""
    e = np.nan_to_num(err_m)
    n3 = np.einsum("...i,...i->...", err_m, np.linalg.solve(cov_m2, e[..., None])[..., 0])
    nh = np.einsum("...i,...i->...", err_m[..., :2], np.linalg.solve(cov_m2[..., :2, :2], e[..., :2, None])[..., 0])
    return n3, nh


def chi2_band(dof: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Two-sided band for the mean of ``n`` independent chi-square(dof) NEES values."""
    from scipy.stats import chi2

    a = (1 - level) / 2
    return float(chi2.ppf(a, dof * n) / n), float(chi2.ppf(1 - a, dof * n) / n)


def summarize(results: list[dict], sigma_d: float, estimator: str, times: np.ndarray,
              table_times: list[float]) -> dict:
    err = np.stack([r["err"] for r in results])  # (T, K, n, 3)
    h = np.hypot(err[..., 3:, 0], err[..., 3:, 1])  # (T, K, n-3)
    v = np.abs(err[..., 3:, 2])
    n = err.shape[2]
    from nav.geometry import frame_free_mask

    free = frame_free_mask(n)
    ti = [int(np.argmin(np.abs(times - t))) for t in table_times]
    crlb = np.stack([r["crlb_diag"] for r in results])  # (T, Kt, n, 3)
    h_mean = np.nanmean(h, axis=(0, 2))
    first = np.flatnonzero(h_mean < sigma_d)
    first2 = np.flatnonzero(h_mean < 2 * sigma_d)
    fe = err[:, ti][..., free]  # (T, Kt, nfree)
    nees = np.stack([r["nees"] for r in results])[:, ti]  # (T, Kt, n-3)
    lo, hi = chi2_band(3, max(int(np.isfinite(nees[:, -1]).sum()), 1))
    nees_h = np.stack([r["nees_h"] for r in results])[:, ti]
    lo_h, hi_h = chi2_band(2, max(int(np.isfinite(nees_h[:, -1]).sum()), 1))
    res = {
        "estimator": estimator,
        "sigma_d_m": sigma_d,
        "trials": len(results),
        "stations": n,
        "times_s": [float(t) for t in table_times],
        "horizontal_mean_m": h_mean[ti].tolist(),
        "horizontal_max_m": np.nanmax(h, axis=(0, 2))[ti].tolist(),
        "vertical_mean_m": np.nanmean(v, axis=(0, 2))[ti].tolist(),
        "horizontal_rms_m": np.sqrt(np.nanmean(h[:, ti] ** 2, axis=(0, 2))).tolist(),
        "crlb_horizontal_rms_m": np.sqrt(np.nanmean(crlb[..., 3:, 0] + crlb[..., 3:, 1], axis=(0, 2))).tolist(),
        "free_rms_m": np.sqrt(np.nanmean(fe**2, axis=(0, 2))).tolist(),
        "crlb_free_rms_m": np.sqrt(np.nanmean(crlb[..., free], axis=(0, 2))).tolist(),
        "nees_mean": np.nanmean(nees, axis=(0, 2)).tolist(),
        "nees_band_95": [lo, hi],
        "nees_h_mean": np.nanmean(nees_h, axis=(0, 2)).tolist(),
        "nees_h_band_95": [lo_h, hi_h],
        "datum_frozen_s": [r["datum_frozen_s"] for r in results],
        "time_to_sigma_d_s": float(times[first[0]]) if len(first) else None,
        "time_to_2sigma_d_s": float(times[first2[0]]) if len(first2) else None,
        "curve_times_s": times.tolist(),
        "curve_horizontal_mean_m": h_mean.tolist(),
        "curve_horizontal_max_m": np.nanmax(h, axis=(0, 2)).tolist(),
        "located_frac": np.mean([r["located"] for r in results], axis=0).tolist(),
        "multihop": results[0]["multihop"],
    }
    if "faults" in results[0]:
        fm = [r["faults"] for r in results]
        det = [f["detect_time_s"] for f in fm]
        found = [d for d in det if d is not None]
        sh = sum(f["station_hours"] for f in fm)
        res["fault_detect_prob"] = float(np.mean([d is not None and d <= 10.0 for d in det]))
        res["fault_detect_time_s"] = float(np.median(found)) if found else None
        res["false_exclusions_per_station_h"] = sum(f["false_exclusions"] for f in fm) / sh
    res["crlb_ratio"] = (np.array(res["horizontal_rms_m"]) / np.array(res["crlb_horizontal_rms_m"])).tolist()
    if "map_err" in results[0]:
        me = np.stack([r["map_err"] for r in results])
        res["map_horizontal_rms_m"] = np.sqrt(np.nanmean(me[..., 3:, 0] ** 2 + me[..., 3:, 1] ** 2, axis=(0, 2))).tolist()
    hf, vf = h[:, -1].ravel(), err[:, -1, 3:, 2].ravel()
    res["final_horizontal_errors_m"] = hf[np.isfinite(hf)].tolist()
    res["final_vertical_errors_m"] = vf[np.isfinite(vf)].tolist()
    return res


def bar_checks(res: dict) -> dict:
    """The issue's bar for the default estimator (evaluated for every configuration)."""
    t = res["times_s"]
    out = {}
    if 40.0 in t:
        k = t.index(40.0)
        out["ratio_at_40s_le_1.2"] = res["crlb_ratio"][k] <= 1.2
        out["mean_at_40s_le_sigma_d"] = res["horizontal_mean_m"][k] <= res["sigma_d_m"]
    if 15.0 in t:
        out["mean_at_15s_lt_2sigma_d"] = res["horizontal_mean_m"][t.index(15.0)] < 2 * res["sigma_d_m"]
    if 300.0 in t:  # issue 33: a large multi-hop field at 300 s
        k = t.index(300.0)
        out["ratio_at_300s_le_1.2"] = res["crlb_ratio"][k] <= 1.2
        out["nees_at_300s_in_or_below_band"] = res["nees_mean"][k] <= res["nees_band_95"][1]
    return out


def print_table(res: dict) -> None:
    print(f"\nestimator={res['estimator']}  sigma_d={res['sigma_d_m']} m  trials={res['trials']}  "
          f"stations={res['stations']}  wall={res.get('wall_s', float('nan')):.1f} s")
    mh = res["multihop"]
    print(f"links at the truth (first trial): degree {mh['degree_min']} / {mh['degree_median']:g} / {mh['degree_max']} (min / "
          f"median / max), {mh['hear_no_founder_frac']:.0%} of stations 4..n hear none of the founders, stations "
          f"per hop from them {mh['stations_per_hop']}, {mh['under_4_links']} with fewer than 4 links")
    hdr = ("t_s", "located", "h_mean", "h_max", "v_mean", "h_rms", "crlb_h", "ratio", "map_h", "free_rms",
           "crlb_free", "NEES", "NEES_h")
    print("  ".join(f"{h:>8}" for h in hdr))
    for k, t in enumerate(res["times_s"]):
        row = [t, res["located_frac"][k], res["horizontal_mean_m"][k], res["horizontal_max_m"][k], res["vertical_mean_m"][k],
               res["horizontal_rms_m"][k], res["crlb_horizontal_rms_m"][k], res["crlb_ratio"][k],
               res["map_horizontal_rms_m"][k] if "map_horizontal_rms_m" in res else float("nan"),
               res["free_rms_m"][k], res["crlb_free_rms_m"][k], res["nees_mean"][k], res["nees_h_mean"][k]]
        print("  ".join(f"{x:8.3f}" if isinstance(x, float) else f"{x:8}" for x in row))
    lo, hi = res["nees_band_95"]
    fz = [t for t in res["datum_frozen_s"] if t is not None]
    if fz:
        print(f"field datum: errors and NEES against the truth in the field's datum from its release "
              f"({min(fz):.1f}-{max(fz):.1f} s; {len(fz)} of {res['trials']} trials released)")
    print(f"NEES_h (2 dof) 95% band for the mean: [{res['nees_h_band_95'][0]:.2f}, {res['nees_h_band_95'][1]:.2f}]")
    print(f"NEES (3 dof) 95% band for the mean: [{lo:.2f}, {hi:.2f}];  "
          f"time to mean h < sigma_d: {res['time_to_sigma_d_s']} s;  < 2 sigma_d: {res['time_to_2sigma_d_s']} s")
    if "fault_detect_prob" in res:
        print(f"faults: detected within 10 s in {res['fault_detect_prob']:.0%} of trials, median time to detect "
              f"{res['fault_detect_time_s']} s, false exclusions {res['false_exclusions_per_station_h']:.2f} per "
              "station-hour (errors above: non-faulty stations only)")
    for name, ok in bar_checks(res).items():
        print(f"  bar {name}: {'PASS' if ok else 'FAIL'}")


def plot(all_res: list[dict], png_dir: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    png_dir.mkdir(parents=True, exist_ok=True)
    files = []
    fig, ax = plt.subplots(figsize=(8, 5))
    for res in all_res:
        t = res["curve_times_s"]
        lbl = f"{res['estimator']} sigma_d={res['sigma_d_m']} m"
        (l,) = ax.plot(t, res["curve_horizontal_mean_m"], label=f"mean, {lbl}")
        ax.plot(t, res["curve_horizontal_max_m"], ls="--", color=l.get_color(), label=f"max, {lbl}")
    ax.set_yscale("log")
    ax.set_xlabel("time, s")
    ax.set_ylabel("horizontal error, m")
    ax.set_title("Self-survey convergence (stations 4..n, Monte Carlo), cf. seed 000 Fig. 3")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    f = png_dir / "survey_convergence.png"
    fig.tight_layout()
    fig.savefig(f, dpi=110)
    plt.close(fig)
    files.append(f)
    for res in all_res:
        fig, axs = plt.subplots(1, 2, figsize=(10, 4))
        axs[0].hist(res["final_horizontal_errors_m"], bins=40, color="tab:blue")
        axs[0].set_xlabel("horizontal error, m")
        axs[1].hist(res["final_vertical_errors_m"], bins=40, color="tab:orange")
        axs[1].set_xlabel("vertical error, m")
        for a in axs:
            a.set_ylabel("count")
            a.grid(alpha=0.3)
        fig.suptitle(f"Errors at t = {res['curve_times_s'][-1]:.0f} s: {res['estimator']}, "
                     f"sigma_d = {res['sigma_d_m']} m (cf. seed 000 Figs. 4, 5)")
        f = png_dir / f"survey_hist_{res['estimator']}_sd{res['sigma_d_m']}.png"
        fig.tight_layout()
        fig.savefig(f, dpi=110)
        plt.close(fig)
        files.append(f)
    return files


FOUNDERS_LEAVE_S = {1: 60.0, 2: 120.0, 3: 180.0}  # --founders-leave: station -> time it falls silent
LEAVE_AFTER_S = 30.0  # each departure is scored this long after it
LEAVE_BAR_M = 0.03  # the bar at the end: within 1 sigma and 3 cm of the twin


def _leave_trial(job: tuple) -> dict:
    """One ``--founders-leave`` trial: the same world with and without the departures. Returns, per
    scoring time, the survivors' horizontal deviation from the twin (m) and their horizontal sigma
    (root of P_xx + P_yy of the run with departures), NaN for stations not alive."""
    from stations.core import rigid_motion
    from stations.sim import Simulator

    from ..analysis.datum import sim_datum_truth, truth_series

    scenario, sigma_d, n, seed, duration, clock, ranging = job
    scn = load_trial(scenario, sigma_d, n, seed, clock, ranging, "field")
    stop = {sid: t for sid, t in FOUNDERS_LEAVE_S.items() if t < duration}
    times = sorted({min(t + LEAVE_AFTER_S, duration) for t in stop.values()} | {duration}
                   | {t - 1.0 for t in stop.values()})
    t0 = time.perf_counter()
    twin = Simulator(scn, estimator="dmap").run(duration, times)
    sim = Simulator(scn, estimator="dmap", stop_s=stop)
    dt = sim_datum_truth(scn, sim)
    gone = sim.run(duration, times)
    d = gone.pos_m - twin.pos_m
    dev = np.hypot(d[..., 0], d[..., 1])  # (K, n)
    sig = np.sqrt(gone.cov_m2[..., 0, 0] + gone.cov_m2[..., 1, 1])
    e = gone.pos_m - gone.truth_m
    # against the truth in the field's datum (fixed at the release): error and NEES, horizontal (2 dof)
    # and 3-D, of every survivor (all free in x, y, z once the founders released the frame)
    ed = gone.pos_m - truth_series(dt, scn.ids, times)
    full = np.all(np.diagonal(gone.cov_m2, axis1=-2, axis2=-1) > 0.0, axis=-1)  # (K, n); False for NaN
    nees3, nees_h = nees_3d_h(np.where(full[..., None], ed, np.nan), np.where(full[..., None, None], gone.cov_m2, np.eye(3)))
    # the same deviation once the rigid motion between the two runs is removed (survivors, weighted by
    # their covariances): what the departures did to the shape, not to the datum
    shape = np.full_like(dev, np.nan)
    for k in range(len(times)):
        ok = np.isfinite(gone.pos_m[k, :, 0])
        if ok.sum() >= 3:
            # (a founder still holding the frame has zero variance on its constrained coordinates)
            tr, w = rigid_motion(gone.pos_m[k, ok], gone.cov_m2[k, ok] + 1e-6 * np.eye(3), twin.pos_m[k, ok])
            r = d[k, ok] - tr - np.cross(w, twin.pos_m[k, ok])
            shape[k, ok] = np.hypot(r[:, 0], r[:, 1])
    info_nees, p_within = _info_loss(d[-1, :, :2], gone.cov_m2[-1, :, :2, :2], twin.cov_m2[-1, :, :2, :2],
                                     np.minimum(sig[-1], LEAVE_BAR_M), np.random.default_rng(seed))
    return {"times": times, "dev_m": dev, "shape_m": shape, "sigma_m": sig, "info_nees": info_nees,
            "p_within": p_within,
            "err_h_m": np.hypot(e[..., 0], e[..., 1]), "err_h_datum_m": np.hypot(ed[..., 0], ed[..., 1]),
            "err_v_datum_m": np.abs(ed[..., 2]), "nees_3d": nees3, "nees_h": nees_h, "datum_frozen_s": dt.frozen_s,
            "wall_s": time.perf_counter() - t0}


def _info_loss(d_m: np.ndarray, p_gone_m2: np.ndarray, p_twin_m2: np.ndarray, radius_m: np.ndarray,
               rng: np.random.Generator, draws: int = 4000) -> tuple[np.ndarray, np.ndarray]:
    """What the departures' lost information alone allows at the end. Two efficient estimators of the
    same world, one with a subset of the other's information, differ by ``d ~ N(0, D)``,
    ``D = P_gone - P_twin`` (the covariance of the difference of nested MAP estimates). Per station
    (n): the deviation's NEES against ``D``, ``d^T D^-1 d`` (mean 2 if the deviation is that loss alone),
    and ``P(|d| <= radius)`` under ``N(0, D)`` (``draws`` samples of ``rng``); NaN where ``D`` is not
    positive definite or the station is not a survivor. ``d_m`` (n, 2), ``p_*_m2`` (n, 2, 2), ``radius_m`` (n,)."""
    n = len(d_m)
    nees, p = np.full(n, np.nan), np.full(n, np.nan)
    z = rng.standard_normal((draws, 2))
    for i in range(n):
        D = p_gone_m2[i] - p_twin_m2[i]
        if not (np.all(np.isfinite(d_m[i])) and np.all(np.isfinite(D))):
            continue
        try:
            L = np.linalg.cholesky(D)
        except np.linalg.LinAlgError:
            continue
        y = np.linalg.solve(L, d_m[i])
        nees[i] = float(y @ y)
        p[i] = float(np.mean(np.hypot(*(z @ L.T).T) <= radius_m[i]))
    return nees, p


def _datum_numbers(err_h: np.ndarray, err_v: np.ndarray, nees3: np.ndarray, nees_h: np.ndarray) -> dict:
    """At one scoring time, over trials x stations (T, n): horizontal RMS and mean absolute vertical
    error against the truth in the field's datum, and the mean NEES (3-D, horizontal) of the stations
    whose covariance is full rank, with the 95 % chi-square bands of those means."""
    ok = np.isfinite(nees3)
    m = max(int(ok.sum()), 1)
    eh = err_h[np.isfinite(err_h)]
    return {"err_h_datum_rms_m": float(np.sqrt(np.mean(eh**2))) if eh.size else None,
            "err_v_datum_mean_m": float(np.nanmean(err_v)) if np.isfinite(err_v).any() else None,
            "nees_3d_mean": float(np.mean(nees3[ok])) if ok.any() else None, "nees_3d_band_95": chi2_band(3, m),
            "nees_h_mean": float(np.mean(nees_h[ok])) if ok.any() else None, "nees_h_band_95": chi2_band(2, m)}


def leave_summary(results: list[dict], sigma_d: float) -> dict:
    """Per scoring time (just before and 30 s after each departure, the end): the survivors'
    horizontal deviation from the twin over trials and stations (median, 95th percentile, max, in m)
    and in units of their sigma; at the end, the share of trials whose every survivor is within
    1 sigma and 3 cm of its twin (the issue's bar)."""
    times = results[0]["times"]
    dev = np.stack([r["dev_m"] for r in results])  # (T, K, n)
    sig = np.stack([r["sigma_m"] for r in results])
    err = np.stack([r["err_h_m"] for r in results])
    shp = np.stack([r["shape_m"] for r in results])
    errd = np.stack([r["err_h_datum_m"] for r in results])
    errv = np.stack([r["err_v_datum_m"] for r in results])
    n3 = np.stack([r["nees_3d"] for r in results])
    nh = np.stack([r["nees_h"] for r in results])
    rows = []
    for k, t in enumerate(times):
        dv, rt = dev[:, k].ravel(), (dev[:, k] / sig[:, k]).ravel()
        ok = np.isfinite(dv)
        dv, rt, eh, sh = dv[ok], rt[ok], err[:, k].ravel()[ok], shp[:, k].ravel()[ok]
        rows.append({"t_s": float(t), "survivors": int(ok.sum() // max(len(results), 1)),
                     "dev_median_m": float(np.median(dv)), "dev_p95_m": float(np.percentile(dv, 95)),
                     "dev_max_m": float(dv.max()), "dev_sigma_p95": float(np.percentile(rt, 95)),
                     "dev_sigma_max": float(rt.max()), "sigma_h_median_m": float(np.median(sig[:, k].ravel()[ok])),
                     "err_h_rms_m": float(np.sqrt(np.mean(eh**2))),
                     "shape_p95_m": float(np.percentile(sh, 95)) if np.isfinite(sh).all() else None,
                     **_datum_numbers(errd[:, k], errv[:, k], n3[:, k], nh[:, k])})
    end = dev[:, -1]
    within = np.all((end <= sig[:, -1]) & (end <= LEAVE_BAR_M) | ~np.isfinite(end), axis=1)
    # the bar's share if the survivors' deviations were the lost information alone (independent
    # survivors): per trial the product of their chances, averaged (_info_loss)
    pw = np.stack([r["p_within"] for r in results])
    surv = np.isfinite(end)
    expected = np.prod(np.where(surv, np.nan_to_num(pw, nan=0.0), 1.0), axis=1)
    info_nees = np.stack([r["info_nees"] for r in results])[surv]
    return {"sigma_d_m": sigma_d, "trials": len(results), "founders_leave_s": {str(k): v for k, v in FOUNDERS_LEAVE_S.items()},
            "scored_after_s": LEAVE_AFTER_S, "rows": rows, "end_within_1sigma_and_3cm_frac": float(within.mean()),
            "end_within_if_info_loss_frac": float(expected.mean()),
            "end_dev_info_nees_mean": float(np.nanmean(info_nees)) if np.isfinite(info_nees).any() else None,
            "end_dev_info_nees_defined": int(np.isfinite(info_nees).sum()), "end_survivors": int(surv.sum()),
            "trial_wall_s_mean": float(np.mean([r["wall_s"] for r in results])),
            "datum_frozen_s": [r["datum_frozen_s"] for r in results]}


def print_leave(res: dict) -> None:
    print(f"\nfounders leave (1 @ 60 s, 2 @ 120 s, 3 @ 180 s), dmap, sigma_d={res['sigma_d_m']} m, "
          f"trials={res['trials']}: survivors' horizontal deviation from the same trial without departures")
    hdr = ("t_s", "alive", "med_m", "p95_m", "max_m", "p95_sig", "max_sig", "shape_p95", "sigma_h", "err_rms")
    print("  ".join(f"{h:>9}" for h in hdr))
    for r in res["rows"]:
        print("  ".join(f"{x:9.3f}" if isinstance(x, float) else f"{x!s:>9}" for x in
                        (r["t_s"], r["survivors"], r["dev_median_m"], r["dev_p95_m"], r["dev_max_m"],
                         r["dev_sigma_p95"], r["dev_sigma_max"], r["shape_p95_m"], r["sigma_h_median_m"],
                         r["err_h_rms_m"])))
    print("  (med/p95/max: horizontal deviation from the twin over trials x survivors, m; _sig: in units of the "
          "survivor's horizontal sigma; shape_p95: after removing the rigid motion between the runs; err_rms: "
          "horizontal error against the truth in the founders' frame)")
    fz = [t for t in res["datum_frozen_s"] if t is not None]
    print(f"against the truth in the field's datum (released {min(fz, default=float('nan')):.1f}-"
          f"{max(fz, default=float('nan')):.1f} s, {len(fz)} of {res['trials']} trials; every station alive with a "
          "full-rank covariance):")
    hdr = ("t_s", "err_h_rms", "err_v_mean", "NEES_h", "band_h", "NEES_3d", "band_3d")
    print("  ".join(f"{h:>11}" for h in hdr))
    for r in res["rows"]:
        cells = [f"{r['t_s']:11.1f}"]
        for key in ("err_h_datum_rms_m", "err_v_datum_mean_m", "nees_h_mean", "nees_h_band_95", "nees_3d_mean",
                    "nees_3d_band_95"):
            v = r[key]
            cells.append(f"{'-':>11}" if v is None else f"{v[0]:5.2f}-{v[1]:<5.2f}" if isinstance(v, (tuple, list))
                         else f"{v:11.3f}")
        print("  ".join(cells))
    print(f"  bar end_within_1sigma_and_3cm (every survivor of a trial): {res['end_within_1sigma_and_3cm_frac']:.0%} "
          f"of trials;  mean wall per trial {res['trial_wall_s_mean']:.1f} s (twin included)")
    nees = res["end_dev_info_nees_mean"]
    print(f"  if the deviations were the lost information alone (D = P_gone - P_twin, efficient estimators): "
          f"{res['end_within_if_info_loss_frac']:.0%} of trials; the deviations' NEES against D "
          f"{'-' if nees is None else f'{nees:.2f}'} (2 if so; D positive definite for "
          f"{res['end_dev_info_nees_defined']} of {res['end_survivors']} survivors)")


def leave_main(args) -> int:
    from .progress import progress

    duration = args.duration if args.duration > 60.0 else 300.0
    out = []
    with mp.get_context("fork").Pool(max(1, args.jobs)) as pool:
        for sd in args.sigma_d:
            jobs = [(args.scenario, sd, args.stations, args.seed + k, duration, getattr(args, "clock", None),
                     getattr(args, "ranging", None)) for k in range(args.trials)]
            res = leave_summary(list(progress(pool.imap(_leave_trial, jobs), f"founders-leave sigma_d={sd}",
                                              total=len(jobs))), sd)
            res["ranging"] = getattr(args, "ranging", None)
            print_leave(res)
            out.append(res)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out[0] if len(out) == 1 else {"runs": out}, indent=1))
        print(f"wrote {args.json}")
    return 0


def main(args) -> int:
    from .progress import progress

    if getattr(args, "founders_leave", False):
        return leave_main(args)

    default_times = TABLE_TIMES_S if args.duration <= 60.0 else LONG_TABLE_TIMES_S
    table_times = [t for t in (args.times or default_times) if t <= args.duration]
    times = np.arange(1.0, args.duration + 1e-9, 1.0)
    all_res = []
    ctx = mp.get_context("fork")
    with ctx.Pool(max(1, args.jobs)) as pool:
        for est in args.estimator:
            for sd in args.sigma_d:
                jobs = [(args.scenario, est, sd, args.stations, args.seed + k, args.duration, table_times,
                         not args.no_map, getattr(args, "clock", None), getattr(args, "ranging", None),
                         getattr(args, "datum", None))
                        for k in range(args.trials)]
                t0 = time.perf_counter()
                results = list(progress(pool.imap(_trial, jobs), f"survey {est} sigma_d={sd}", total=len(jobs)))
                res = summarize(results, sd, est, times, table_times)
                res["wall_s"] = time.perf_counter() - t0
                res["jobs"] = args.jobs
                res["ranging"] = getattr(args, "ranging", None)
                res["bar"] = bar_checks(res)
                print_table(res)
                all_res.append(res)
    if args.png_dir:
        for f in plot(all_res, Path(args.png_dir)):
            print(f"wrote {f}")
    if args.json:
        slim = [{k: v for k, v in r.items() if not k.startswith("final_")} for r in all_res]
        doc = slim[0] if len(slim) == 1 else {"runs": slim}
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(doc, indent=1))
        print(f"wrote {args.json}")
    return 0
