"""`larns bench integrity`: NLOS ranges and faulty / lying stations vs the survey and the stations'
integrity monitoring (in-process simulator, seed 000 world).

Per case and trial: the horizontal RMS of the non-faulty stations 4..n at 40 s and 60 s against the
clean centralized CRLB of the same realized links, their mean NEES (3 dof), and from the stations'
``integrity`` decisions: whether the faulty station was excluded by a non-faulty neighbour, how soon
after the fault's onset, and the false exclusions (a non-faulty station excluding a non-faulty one)
per station-hour.

``--aircraft``: snapshot RAIM/FDE (``aircraft/navigator/radio/raim.py``) and the aircraft filters' integrity
(``aircraft/navigator/radio/fde.py``: gate, windowed test, exclusion, HPL/VPL) on the seed001/seed003 worlds with one
station biased by 30 m from t = 20 s (JSON ``aircraft[*].filter_integrity``).
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import time
from pathlib import Path

import numpy as np

FAULTY = 6  # a non-frame station of the seed-000 layout
CASES: dict[str, dict] = {
    "clean": {},
    "nlos5_20m": {"channel": {"nlos_prob": 0.05, "nlos_bias_m": 20.0}},
    "nlos5_5m": {"channel": {"nlos_prob": 0.05, "nlos_bias_m": 5.0}},
    "nlos20_20m": {"channel": {"nlos_prob": 0.20, "nlos_bias_m": 20.0}},
    "liar": {"faults": [{"kind": "liar", "station": FAULTY, "offset_m": [30.0, 0.0, 0.0], "from_s": 20.0}]},
    "range_bias": {"faults": [{"kind": "range_bias", "station": FAULTY, "bias_m": 5.0, "from_s": 20.0}]},
    "clock_jump": {"faults": [{"kind": "clock_jump", "station": FAULTY, "jump_s": 1e-3, "at_s": 20.0}]},
    "bad_fix": {"faults": [{"kind": "bad_fix", "station": FAULTY, "offset_m": [50.0, 0.0, 0.0], "sigma0_m": 10.0}]},
}
DETECT_WITHIN_S = 10.0
RECOVER_WITHIN_S = 20.0  # issue 32: honest stations back to <= RECOVER_RATIO x the fault-free twin's RMS
RECOVER_RATIO = 1.15


def register(sub) -> None:
    p = sub.add_parser(
        "integrity",
        help="NLOS and faulty/lying stations: survey accuracy, NEES, detection, false exclusions",
        description=("Monte Carlo (in-process simulator, seed 000 world) of the robust survey and the stations' "
                     f"integrity monitoring. Cases: {', '.join(CASES)} (faulty station {FAULTY}). Per case: "
                     "horizontal RMS of the non-faulty stations 4..n at 40 s and 60 s vs the clean CRLB, mean "
                     "NEES, detection probability within 10 s, median time to detect, false exclusions per "
                     "station-hour."),
    )
    p.add_argument("--trials", type=int, default=20, help="trials per case (default 20)")
    p.add_argument("--cases", nargs="*", default=list(CASES), choices=list(CASES), help="cases (default: all)")
    p.add_argument("--estimator", default="dmap", choices=["dmap", "dmap-nlos", "dmap-ls", "seed-ukf"])
    p.add_argument("--duration", type=float, default=60.0, help="simulated seconds per trial (default 60)")
    p.add_argument("--seed", type=int, default=1, help="base seed; trial k uses seed + k (default 1)")
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="worker processes (default: all cores)")
    p.add_argument("--json", metavar="FILE", help="write the results as JSON")
    p.add_argument("--png-dir", metavar="DIR", default="bench-out/integrity", help="PNG directory ('' to skip)")
    p.add_argument("--aircraft", nargs="*", metavar="SCENARIO", default=None,
                   help="also run aircraft RAIM/FDE on these scenarios' [aircraft] worlds (default when given "
                        "without names: seed001 seed003): one station biased by 30 m from t = 20 s, and clean")
    p.add_argument("--ac-runs", type=int, default=400,
                   help="aircraft Monte Carlo runs per world (default 400: a run that drifts out of its HPL stays out for "
                        "many epochs, so the 1e-3 per-epoch rates need hundreds of runs)")
    p.add_argument("--ac-filters", nargs="*", default=list(AC_FILTERS), metavar="ALGO",
                   help=f"aircraft filters with integrity monitoring (aircraft/navigator/radio/fde.py) on the same worlds at the "
                        f"scenario's epoch rate, {AC_FILTER_DURATION_S:g} s (default: {' '.join(AC_FILTERS)}; "
                        "none: snapshot RAIM only)")
    p.add_argument("--recovery", action="store_true",
                   help=f"faulty cases: also run each trial's fault-free twin (same seed) and report how the honest "
                        f"stations' horizontal RMS returns to it after the exclusion (bar: <= {RECOVER_RATIO:g} x "
                        f"within {RECOVER_WITHIN_S:g} s, NEES in band)")
    p.set_defaults(func=main)


AC_BIAS_M = 30.0
AC_ONSET_S = 20.0
AC_RATE_HZ = 2.0  # snapshot RAIM epochs per second
AC_P_FA = 1e-3
AC_P_MD = 1e-3


def aircraft_raim(scenario: str, runs: int, seed: int, duration_s: float = 40.0) -> dict:
    """Snapshot RAIM/FDE (``aircraft/navigator/radio/raim.py``) along the scenario's aircraft track, one station's
    pseudoranges biased by ``AC_BIAS_M`` from ``AC_ONSET_S``; the same epochs without the fault for the
    false-alarm and protection-level statistics. Station positions are the true ones (seed 001 setup)."""
    from aircraft.config import from_scenario
    from aircraft.montecarlo import radio as sim
    from aircraft.navigator.radio.raim import raim_fde
    from aircraft.world import trajectory
    from net.scenario import load

    sc = load(scenario)
    world = from_scenario(sc).world  # the truth: stations, track, clock, noise
    t = np.arange(0.0, duration_s, 1.0 / AC_RATE_HZ)
    track = trajectory.from_config(dict(world.trajectory), t, world.centre_m, world.height_m)
    rng = np.random.default_rng([seed, 14])
    rho = sim.pseudoranges(track, world.stations_m, world.clock, world.sigma_m, runs, rng)  # (T, M, m)
    m = world.stations_m.shape[0]
    ids = list(sc.ids)
    bad = m // 2  # a station in the middle of the list
    out = {"scenario": scenario, "stations": m, "runs": runs, "faulty_station": ids[bad], "bias_m": AC_BIAS_M,
           "p_fa": AC_P_FA, "p_md": AC_P_MD, "epochs_per_s": AC_RATE_HZ}
    if m < 6:
        out["note"] = (f"{m} stations: a snapshot pseudorange fix has {m - 4} redundant measurement(s); "
                       "detection needs >= 5 stations and exclusion >= 6")
    after = t >= AC_ONSET_S
    det_t, alarms, exceed_h, exceed_v, n_clean, err_ex, crlb = [], 0, 0, 0, 0, [], []
    keep = np.arange(m) != bad
    for k in range(runs):
        x0 = np.r_[track.pos_m[0] + 50.0, 0.0]
        first = None
        for i in range(len(t)):
            clean = raim_fde(ids, world.stations_m, rho[i, k], world.sigma_m, x0, p_fa=AC_P_FA, p_md=AC_P_MD)
            x0 = np.r_[clean.pos_m, clean.clock_m]
            n_clean += 1
            alarms += clean.fault
            e = clean.pos_m - track.pos_m[i]
            exceed_h += np.hypot(e[0], e[1]) > clean.hpl_m
            exceed_v += abs(e[2]) > clean.vpl_m
            if after[i]:
                r = rho[i, k].copy()
                r[bad] += AC_BIAS_M
                f = raim_fde(ids, world.stations_m, r, world.sigma_m, x0, p_fa=AC_P_FA, p_md=AC_P_MD)
                if first is None and f.excluded == [ids[bad]]:
                    first = t[i] - AC_ONSET_S
                if t[i] >= AC_ONSET_S + 5.0 and m >= 6:
                    err_ex.append(np.sum((f.pos_m - track.pos_m[i]) ** 2))
                    if k == 0 and keep.sum() >= 5:  # snapshot CRLB of the position without the faulty station
                        d = track.pos_m[i] - world.stations_m[keep]
                        H = np.hstack([d / np.linalg.norm(d, axis=1)[:, None], np.ones((keep.sum(), 1))])
                        crlb.append(np.trace(np.linalg.inv(H.T @ H)[:3, :3]) * world.sigma_m**2)
        det_t.append(first)
    found = [d for d in det_t if d is not None]
    out.update(
        detect_exclude_prob_5s=float(np.mean([d is not None and d <= 5.0 for d in det_t])),
        detect_exclude_time_s=float(np.median(found)) if found else None,
        rmse_after_exclusion_m=float(np.sqrt(np.mean(err_ex))) if err_ex else None,
        crlb_without_station_m=float(np.sqrt(np.mean(crlb))) if crlb else None,
        false_alarm_rate=alarms / n_clean, hpl_exceed_rate=exceed_h / n_clean, vpl_exceed_rate=exceed_v / n_clean,
    )
    return out


AC_FILTERS = ("ekf-pr", "ukf-pr", "ukf-tdoa")
AC_FILTER_DURATION_S = 40.0
AC_DETECT_WITHIN_S = 5.0
AC_SETTLE_S = 5.0  # RMSE after exclusion: from onset + this to the end


def run_bootstrap_rate_ci(counts, epochs_per_run: int, rng: np.random.Generator, n_boot: int = 4000,
                          level: float = 0.95) -> list[float]:
    """Percentile interval of a per-epoch event rate from per-run event counts (M,), resampling runs.

    Events within a run are correlated in time (a run that drifts out of its HPL stays out for many
    epochs), so the runs, not the epochs, are the independent samples."""
    counts = np.asarray(counts, dtype=float)
    idx = rng.integers(0, counts.size, size=(n_boot, counts.size))
    rates = counts[idx].sum(axis=1) / (counts.size * epochs_per_run)
    lo, hi = np.quantile(rates, [(1.0 - level) / 2.0, (1.0 + level) / 2.0])
    return [float(lo), float(hi)]


def _filter_case(algo, track, ac, rho, bias, fde, onset_s, bad_id, seed):
    """One filter over the runs with the fault ``bias`` (T, m) or clean (None): detection, errors, PLs."""
    from aircraft.montecarlo import radio as sim

    r = sim.run_algo(algo, track, ac.world.stations_m, rho, ac.nav.tuning, ac.world.clock,
                     np.random.default_rng([seed, 15]), fde=fde, bias_m=bias)
    t = track.t_s
    mon = r.fde
    M = rho.shape[1]
    h = np.hypot(r.err_m[..., 0], r.err_m[..., 1])
    armed = np.arange(t.size) >= fde.arm_after
    first = {}
    for t_e, run, sid, _, _ in mon.events:
        first.setdefault(run, []).append((t_e, sid))
    out = {"false_exclusions": sum(1 for ev in first.values() for te, sid in ev if sid != bad_id or te < onset_s)}
    out["alarms"] = int(mon.alarms.sum())
    out["epochs_tested"] = int(M * armed.sum())
    out["gated"] = int(mon.gated.sum())
    out["hpl_exceed"] = int((h[:, armed] > r.hpl_m[:, armed]).sum())
    per_run = (h[:, armed] > r.hpl_m[:, armed]).sum(axis=1)  # (M,) exceedances per run
    out["hpl_exceed_runs"] = int((per_run > 0).sum())  # exceedances are correlated in time
    out["hpl_exceed_rate_ci95"] = run_bootstrap_rate_ci(per_run, int(armed.sum()), np.random.default_rng([seed, 17]))
    out["vpl_exceed"] = int((np.abs(r.err_m[:, armed, 2]) > r.vpl_m[:, armed]).sum())
    out["hpl_median_m"] = float(np.median(r.hpl_m[:, armed]))
    if bias is not None:
        det = [next((te - onset_s for te, sid in first.get(k, []) if sid == bad_id and te >= onset_s), None)
               for k in range(M)]
        w = t >= onset_s + AC_SETTLE_S
        out["detect_times_s"] = det
        out["rmse_after_m"] = sim.rms_total(r.err_m[:, w])
        out["nees_after"] = float(np.mean(r.nees[:, w]))
    else:
        w = t >= onset_s
        out["rmse_clean_m"] = sim.rms_total(r.err_m[:, w])
        out["nees_clean"] = float(np.mean(r.nees[:, w]))
    return out


def aircraft_filters(scenario: str, runs: int, seed: int, algos=AC_FILTERS,
                     duration_s: float = AC_FILTER_DURATION_S) -> dict:
    """The aircraft filters' integrity (aircraft/navigator/radio/fde.py) on the scenario's track at its epoch rate:
    one station's pseudoranges biased by ``AC_BIAS_M`` from ``AC_ONSET_S`` (detection and exclusion,
    RMSE from onset + 5 s against the PCRB without that station from the onset), and the same draws
    without the fault (false alarms per tested epoch, HPL/VPL exceedances). Filters start like the
    seed-001 bench (truth + a draw from their prior); station positions are the true ones."""
    from aircraft.config import from_scenario
    from aircraft.montecarlo import radio as sim
    from aircraft.navigator.radio.fde import FdeConfig
    from aircraft.world import trajectory
    from net.scenario import load

    sc = load(scenario)
    ac = from_scenario(sc)
    world = ac.world
    fde = FdeConfig()
    t = np.arange(0.0, duration_s, 1.0 / world.rate_hz)
    track = trajectory.from_config(dict(world.trajectory), t, world.centre_m, world.height_m)
    rho = sim.pseudoranges(track, world.stations_m, world.clock, world.sigma_m, runs,
                           np.random.default_rng([seed, 16]))
    m = world.stations_m.shape[0]
    bad = m // 2
    bias = np.zeros((t.size, m))
    bias[t >= AC_ONSET_S, bad] = AC_BIAS_M
    lost = np.zeros((t.size, m), dtype=bool)
    lost[t >= AC_ONSET_S, bad] = True
    w = t >= AC_ONSET_S + AC_SETTLE_S
    out = {"scenario": scenario, "stations": m, "runs": runs, "faulty_station_index": bad, "faulty_station": int(sc.ids[bad]), "bias_m": AC_BIAS_M,
           "onset_s": AC_ONSET_S, "duration_s": duration_s, "epochs_per_s": world.rate_hz,
           "p_gate": fde.p_gate, "p_fa": fde.p_fa, "window": fde.window, "integrity_risk": fde.integrity_risk,
           "filters": {}}
    for algo in algos:
        model = algo.split("-")[1]
        f = _filter_case(algo, track, ac, rho, bias, fde, AC_ONSET_S, bad, seed)
        c = _filter_case(algo, track, ac, rho, None, fde, AC_ONSET_S, bad, seed)
        P = sim.pcrb_track(model, track, world.stations_m, ac.nav.tuning, world.clock, lost=lost)
        P_all = sim.pcrb_track(model, track, world.stations_m, ac.nav.tuning, world.clock)
        det = f.pop("detect_times_s")
        found = [d for d in det if d is not None]
        pcrb = float(np.sqrt(np.mean(np.trace(P[w], axis1=1, axis2=2))))
        out["filters"][algo] = {
            "detect_exclude_prob_5s": float(np.mean([d is not None and d <= AC_DETECT_WITHIN_S for d in det])),
            "detect_exclude_time_s": float(np.median(found)) if found else None,
            "detect_exclude_time_max_s": float(np.max(found)) if found else None,
            "rmse_after_exclusion_m": f["rmse_after_m"], "pcrb_without_station_m": pcrb,
            "ratio": f["rmse_after_m"] / pcrb, "nees_after": f["nees_after"],
            "false_exclusions_fault_runs": f["false_exclusions"],
            "rmse_clean_m": c["rmse_clean_m"], "pcrb_clean_m": float(np.sqrt(np.mean(np.trace(P_all[t >= AC_ONSET_S],
                                                                                              axis1=1, axis2=2)))),
            "nees_clean": c["nees_clean"],
            "false_alarms": c["alarms"], "false_exclusions": c["false_exclusions"], "epochs_tested": c["epochs_tested"],
            "false_alarm_rate": c["alarms"] / c["epochs_tested"], "gated_clean": c["gated"],
            "hpl_exceed_rate": c["hpl_exceed"] / c["epochs_tested"], "vpl_exceed_rate": c["vpl_exceed"] / c["epochs_tested"],
            "hpl_median_m": c["hpl_median_m"], "hpl_exceed_runs": c["hpl_exceed_runs"],
            "hpl_exceed_rate_ci95": c["hpl_exceed_rate_ci95"],
        }
    return out


def fault_metrics(sim, faults, duration_s: float) -> dict:
    """Detection and false exclusions from the cores' integrity decisions (sim: a finished Simulator).

    Times are the deciders' local times (clock offsets are sub-millisecond in these scenarios)."""
    bad = {f.station for f in faults}
    onset = min((f.onset_s for f in faults), default=0.0)
    first = np.inf
    false = 0
    deciders = 0
    for core in sim.cores:
        if core is None or core.id in bad:
            continue
        deciders += 1
        for t, suspect, decision, _ in core.integrity.events:
            if decision != "exclude":
                continue
            if suspect in bad:
                if t >= onset:
                    first = min(first, t - onset)
            else:
                false += 1
    return {"detect_time_s": float(first) if np.isfinite(first) else None,
            "false_exclusions": false, "station_hours": deciders * duration_s / 3600.0}


def _world(case: str | None, estimator: str, seed: int, duration: float, scenario: str, times: np.ndarray):
    """One simulated trial: ``(scn, sim, result, keep)``, ``keep`` the honest non-frame stations (4..n,
    not faulty), sampled at ``times``."""
    from net.scenario import load
    from stations.sim import Simulator

    over = CASES.get(case, {}) if case else {}
    scn = load(scenario, seed=seed, **{k: (dict(v) if isinstance(v, dict) else v) for k, v in over.items()})
    sim = Simulator(scn, estimator=estimator)
    r = sim.run(duration, times)
    bad = {f.station for f in scn.faults}
    return scn, sim, r, np.array([i >= 4 and i not in bad for i in scn.ids])


def _h2_nees(r, keep) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal squared error and 3-D NEES of the ``keep`` stations at every sample: (K, n) each."""
    err = (r.pos_m - r.truth_m)[:, keep]
    P = r.cov_m2[:, keep]
    from nav.kalman import nees as nees_of

    nees = nees_of(err, P)
    return err[..., 0] ** 2 + err[..., 1] ** 2, nees


def _trial(job: tuple) -> dict:
    from nav.crlb import poll_exchange_counts, survey_crlb
    from nav.geometry import frame_free_mask

    from .survey import link_sigma_m

    case, estimator, seed, duration, scenario, recovery = (*job, False)[:6]
    at = [40.0, duration]
    t = np.union1d(np.arange(1.0, np.floor(duration) + 1e-9) if recovery else [], at)
    scn, sim, r, keep = _world(case, estimator, seed, duration, scenario, t)
    k_at = np.searchsorted(t, at)
    h2, nees = _h2_nees(r, keep)
    free = frame_free_mask(len(scn.ids))
    fin = r.final_counts  # protocol v2: an exchange closed by its final counts 4/3 (nav.crlb.poll_exchange_counts)
    crlb = np.stack([survey_crlb(r.truth_m, poll_exchange_counts(r.link_counts[k], None if fin is None else fin[k]),
                                 link_sigma_m(scn, r.truth_m, scn.channel.sigma_d_m), free, scn.sigma0_m)
                     for k in k_at])[:, keep]
    out = {"h2": h2[k_at], "crlb_h2": crlb[..., 0, 0] + crlb[..., 1, 1], "nees": nees[k_at]}
    out.update(fault_metrics(sim, scn.faults, duration))
    out["faulty"] = bool(scn.faults)
    if recovery and scn.faults:  # the same world without the fault: same seed, same noise draws
        _s, _sim, r0, _k = _world(None, estimator, seed, duration, scenario, t)
        out["grid_s"], out["grid_h2"], out["grid_nees"] = t, h2, nees
        out["twin_h2"] = _h2_nees(r0, keep)[0]
        out["onset_s"] = min(f.onset_s for f in scn.faults)
    return out


def recovery_summary(res: list[dict], lags_s: np.ndarray) -> dict:
    """How the honest stations return to the fault-free twin after the exclusion (``--recovery``).

    Per lag ``L`` after each trial's first exclusion ``t_x`` (onset + detection time): the horizontal
    RMS over trials and honest stations at ``t_x + L`` against the twin's at the same times, and the
    mean NEES there with its 95 % band (3 dof, trials x stations values). ``recover_s``: the first lag
    from which the ratio stays <= RECOVER_RATIO (to the largest lag every trial reaches)."""
    from .survey import chi2_band

    rows = [r for r in res if r.get("detect_time_s") is not None and "grid_s" in r]
    if not rows:
        return {"trials_excluded": 0}
    t_x = [r["onset_s"] + r["detect_time_s"] for r in rows]
    reach = min(r["grid_s"][-1] - t for r, t in zip(rows, t_x))  # the largest lag every trial has
    lags = [float(lag) for lag in lags_s if lag <= reach]
    ratio, nees, band = [], [], []
    for lag in lags:
        k = [int(np.searchsorted(r["grid_s"], t + lag)) for r, t in zip(rows, t_x)]
        h2f = np.concatenate([r["grid_h2"][i] for r, i in zip(rows, k)])
        h2t = np.concatenate([r["twin_h2"][i] for r, i in zip(rows, k)])
        nq = np.concatenate([r["grid_nees"][i] for r, i in zip(rows, k)])
        ratio.append(float(np.sqrt(np.mean(h2f)) / np.sqrt(np.mean(h2t))))
        nees.append(float(nq.mean()))
        band.append(chi2_band(3, nq.size))
    above = np.flatnonzero(np.array(ratio) > RECOVER_RATIO)
    first = 0 if above.size == 0 else int(above[-1]) + 1
    recover = lags[first] if first < len(lags) else None
    k20 = lags.index(RECOVER_WITHIN_S) if RECOVER_WITHIN_S in lags else None
    bar = (k20 is not None and recover is not None and recover <= RECOVER_WITHIN_S
           and nees[k20] <= band[k20][1])
    return {"trials_excluded": len(rows), "lags_s": lags, "ratio": ratio, "nees_mean": nees, "nees_band_95": band,
            "recover_s": recover, "bar_met": bool(bar)}


def summarize(case: str, res: list[dict], faulty: bool) -> dict:
    h2 = np.concatenate([r["h2"] for r in res], axis=1)  # (2, N)
    c2 = np.concatenate([r["crlb_h2"] for r in res], axis=1)
    nees = np.concatenate([r["nees"] for r in res], axis=1)
    from .survey import chi2_band

    lo, hi = chi2_band(3, nees.shape[1])
    det = [r["detect_time_s"] for r in res]
    ok = [d is not None and d <= DETECT_WITHIN_S for d in det]
    found = [d for d in det if d is not None]
    fe = sum(r["false_exclusions"] for r in res)
    sh = sum(r["station_hours"] for r in res)
    return {
        "case": case, "trials": len(res), "times_s": [40.0, None],
        "horizontal_rms_m": np.sqrt(h2.mean(axis=1)).tolist(),
        "crlb_horizontal_rms_m": np.sqrt(c2.mean(axis=1)).tolist(),
        "crlb_ratio": (np.sqrt(h2.mean(axis=1)) / np.sqrt(c2.mean(axis=1))).tolist(),
        "nees_mean": nees.mean(axis=1).tolist(), "nees_band_95": [lo, hi],
        "fault_detect_prob": float(np.mean(ok)) if faulty else None,
        "fault_detect_time_s": float(np.median(found)) if faulty and found else None,
        "false_exclusions": int(fe), "false_exclusions_per_station_h": fe / sh if sh else None,
    }


def print_table(rows: list[dict]) -> None:
    hdr = ("case", "rms40", "crlb40", "ratio40", "rms60", "ratio60", "NEES40", "NEES_hi", "P_det10s",
           "t_det_s", "FE/st-h")
    print("  ".join(f"{h:>10}" for h in hdr))

    def f(x, fmt="10.3f"):
        return f"{'-':>10}" if x is None else format(x, fmt)

    for r in rows:
        print(f"{r['case']:>10}  " + "  ".join([
            f(r["horizontal_rms_m"][0]), f(r["crlb_horizontal_rms_m"][0]), f(r["crlb_ratio"][0]),
            f(r["horizontal_rms_m"][1]), f(r["crlb_ratio"][1]), f(r["nees_mean"][0]), f(r["nees_band_95"][1]),
            f(r["fault_detect_prob"]), f(r["fault_detect_time_s"]), f(r["false_exclusions_per_station_h"])]))


def plot(rows: list[dict], png_dir: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    png_dir.mkdir(parents=True, exist_ok=True)
    fig, axs = plt.subplots(1, 2, figsize=(11, 4))
    names = [r["case"] for r in rows]
    x = np.arange(len(rows))
    axs[0].bar(x - 0.2, [r["crlb_ratio"][0] for r in rows], 0.4, label="40 s")
    axs[0].bar(x + 0.2, [r["crlb_ratio"][1] for r in rows], 0.4, label="60 s")
    axs[0].axhline(1.3, color="k", ls="--", lw=0.8)
    axs[0].set_ylabel("horizontal RMS / clean CRLB (non-faulty 4..n)")
    axs[1].bar(x, [r["nees_mean"][0] for r in rows], 0.6, color="tab:orange")
    axs[1].axhline(rows[0]["nees_band_95"][1], color="k", ls="--", lw=0.8)
    axs[1].set_ylabel("mean NEES at 40 s (3 dof)")
    for a in axs:
        a.set_xticks(x, names, rotation=30, fontsize=8)
        a.set_yscale("log")
        a.grid(alpha=0.3)
    axs[0].legend()
    fig.suptitle("Integrity: robust survey under NLOS and station faults")
    fig.tight_layout()
    f = png_dir / "integrity.png"
    fig.savefig(f, dpi=110)
    plt.close(fig)
    return f


def print_recovery(rows: list[dict]) -> None:
    """The ``--recovery`` table: the honest stations' RMS against the fault-free twin after the exclusion."""
    print(f"\nrecovery after the exclusion (honest stations 4..n, horizontal RMS / the same world without the fault; "
          f"bar: <= {RECOVER_RATIO:g} within {RECOVER_WITHIN_S:g} s, NEES in band)")
    hdr = ("case", "trials_exc", "ratio@0s", "ratio@10s", "ratio@20s", "NEES@20s", "band_lo", "band_hi", "recover_s",
           "bar")
    print("  ".join(f"{h:>10}" for h in hdr))
    for r in rows:
        v = r["recovery"]
        lags = v["lags_s"]

        def at(key, lag):
            return v[key][lags.index(lag)] if lag in lags else None

        lo, hi = v["nees_band_95"][lags.index(RECOVER_WITHIN_S)] if RECOVER_WITHIN_S in lags else (None, None)
        ok = v["bar_met"]
        vals = [at("ratio", 0.0), at("ratio", 10.0), at("ratio", 20.0), at("nees_mean", 20.0), lo, hi, v["recover_s"]]
        print(f"{r['case']:>10}  {v['trials_excluded']:>10}  " + "  ".join(
            f"{'-':>10}" if x is None else f"{x:10.3f}" for x in vals) + f"  {'met' if ok else 'NOT met':>10}")


def plot_recovery(rows: list[dict], png_dir: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    png_dir.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for r in rows:
        v = r["recovery"]
        ax[0].plot(v["lags_s"], v["ratio"], marker=".", label=r["case"])
        ax[1].plot(v["lags_s"], v["nees_mean"], marker=".", label=r["case"])
        ax[1].fill_between(v["lags_s"], [b[0] for b in v["nees_band_95"]], [b[1] for b in v["nees_band_95"]],
                           alpha=0.15)
    ax[0].axhline(RECOVER_RATIO, color="k", ls="--", lw=0.8)
    ax[0].axvline(RECOVER_WITHIN_S, color="k", ls=":", lw=0.8)
    ax[0].set(xlabel="s after the exclusion", ylabel="RMS / fault-free twin", title="honest stations' horizontal RMS")
    ax[1].set(xlabel="s after the exclusion", ylabel="mean NEES (3 dof)", title="NEES and its 95 % band")
    for a in ax:
        a.legend()
        a.grid(alpha=0.3)
    fig.tight_layout()
    out = png_dir / "integrity_recovery.png"
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def print_filter_table(ac_rows: list[dict]) -> None:
    """The aircraft filters' integrity table (one row per world and filter)."""
    f0 = ac_rows[0]["filter_integrity"]
    print(f"\naircraft filters with integrity monitoring (aircraft/navigator/radio/fde.py: gate p = {f0['p_gate']:g} per measurement, "
          f"window test p_fa = {f0['p_fa']:g} per epoch over {f0['window']} epochs, HPL/VPL for integrity risk "
          f"{f0['integrity_risk']:g} per epoch; station biased {AC_BIAS_M:g} m from t = {AC_ONSET_S:g} s; "
          f"RMSE from onset + {AC_SETTLE_S:g} s vs the PCRB without that station)")
    hdr = ("world", "filter", "P_exc5s", "t_exc_s", "rmse_m", "pcrb_m", "ratio", "NEES", "FA_rate", "FA_n",
           "HPL_exc", "VPL_exc", "HPL_med_m", "exc_runs", "HPL_exc_95%_runs")
    print("  ".join(f"{h:>9}" for h in hdr))
    for r in ac_rows:
        fi = r["filter_integrity"]
        for algo, v in fi["filters"].items():
            vals = [v["detect_exclude_prob_5s"], v["detect_exclude_time_s"], v["rmse_after_exclusion_m"],
                    v["pcrb_without_station_m"], v["ratio"], v["nees_after"], v["false_alarm_rate"]]
            print(f"{fi['scenario']:>9}  {algo:>9}  " + "  ".join(f"{'-':>9}" if x is None else f"{x:9.4g}" for x in vals)
                  + f"  {v['false_alarms']:>4}/{v['epochs_tested']:<6}" + "  ".join(
                      f"{x:9.2e}" for x in (v["hpl_exceed_rate"], v["vpl_exceed_rate"])) + f"  {v['hpl_median_m']:9.3g}"
                  + f"  {v.get('hpl_exceed_runs', '-'):>4}/{fi['runs']}"
                  + ("  [{:.1e}, {:.1e}]".format(*v["hpl_exceed_rate_ci95"]) if "hpl_exceed_rate_ci95" in v else ""))


def plot_filters(ac_rows: list[dict], png_dir: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    png_dir.mkdir(parents=True, exist_ok=True)
    labels, pdet, ratio, hex_, risk = [], [], [], [], None
    for r in ac_rows:
        fi = r["filter_integrity"]
        risk = fi["integrity_risk"]
        for algo, v in fi["filters"].items():
            labels.append(f"{fi['scenario']}\n{algo}")
            pdet.append(v["detect_exclude_prob_5s"])
            ratio.append(v["ratio"])
            hex_.append(max(v["hpl_exceed_rate"], 1e-7))
    x = np.arange(len(labels))
    fig, axs = plt.subplots(1, 3, figsize=(13, 4))
    axs[0].bar(x, pdet, 0.6)
    axs[0].axhline(0.95, color="k", ls="--", lw=0.8)
    axs[0].set_ylabel("P(detected and excluded within 5 s)")
    axs[1].bar(x, ratio, 0.6, color="tab:green")
    axs[1].axhline(1.2, color="k", ls="--", lw=0.8)
    axs[1].set_ylabel("RMSE after exclusion / PCRB without the station")
    axs[2].bar(x, hex_, 0.6, color="tab:red")
    axs[2].axhline(risk, color="k", ls="--", lw=0.8)
    axs[2].set_yscale("log")
    axs[2].set_ylabel("clean: P(horizontal error > HPL) (1e-7 = none)")
    for a in axs:
        a.set_xticks(x, labels, fontsize=7)
        a.grid(alpha=0.3)
    fig.suptitle(f"Aircraft filters: one station biased {AC_BIAS_M:g} m from {AC_ONSET_S:g} s; clean runs for HPL")
    fig.tight_layout()
    f = png_dir / "integrity_aircraft.png"
    fig.savefig(f, dpi=110)
    plt.close(fig)
    return f


def station_rows(args) -> list[dict]:
    """The station cases of ``args.cases`` (with ``--recovery``, their twins): one summary row each."""
    from .progress import progress

    rows = []
    ctx = mp.get_context("fork")
    with ctx.Pool(max(1, args.jobs)) as pool:
        for case in args.cases or []:
            rec = bool(getattr(args, "recovery", False)) and bool(CASES.get(case, {}).get("faults"))
            jobs = [(case, args.estimator, args.seed + k, args.duration, "seed000", rec) for k in range(args.trials)]
            t0 = time.perf_counter()
            res = list(progress(pool.imap(_trial, jobs), f"integrity {case}", total=len(jobs)))
            row = summarize(case, res, res[0]["faulty"])
            row["times_s"][1] = args.duration
            if rec:
                row["recovery"] = recovery_summary(res, np.arange(0.0, 31.0))
            row["wall_s"] = time.perf_counter() - t0
            rows.append(row)
    return rows


def main(args) -> int:
    rows = station_rows(args)
    print(f"\nestimator={args.estimator}  trials/case={args.trials}  faulty station={FAULTY}  "
          f"(FE/st-h: false exclusions per station-hour by non-faulty stations)")
    if rows:
        print_table(rows)
    rec_rows = [r for r in rows if r.get("recovery", {}).get("lags_s")]
    if rec_rows:
        print_recovery(rec_rows)
    if args.png_dir and rows:
        print(f"wrote {plot(rows, Path(args.png_dir))}")
    if args.png_dir and rec_rows:
        print(f"wrote {plot_recovery(rec_rows, Path(args.png_dir))}")
    ac_rows = []
    if args.aircraft is not None:
        for scn in args.aircraft or ["seed001", "seed003"]:
            ac_rows.append(aircraft_raim(scn, args.ac_runs, args.seed))
        print(f"\naircraft snapshot RAIM/FDE (p_fa = {AC_P_FA:g} per epoch, p_md = {AC_P_MD:g}; {AC_RATE_HZ:g} epochs/s; "
              f"station biased {AC_BIAS_M:g} m from t = {AC_ONSET_S:g} s)")
        hdr = ("world", "stations", "P_det+exc5s", "t_det_s", "rmse_exc_m", "crlb_m", "ratio", "FA_rate",
               "HPL_exceed", "VPL_exceed")
        print("  ".join(f"{h:>11}" for h in hdr))
        for r in ac_rows:
            ratio = (r["rmse_after_exclusion_m"] / r["crlb_without_station_m"]
                     if r["rmse_after_exclusion_m"] and r["crlb_without_station_m"] else None)
            vals = [r["detect_exclude_prob_5s"], r["detect_exclude_time_s"], r["rmse_after_exclusion_m"],
                    r["crlb_without_station_m"], ratio, r["false_alarm_rate"], r["hpl_exceed_rate"], r["vpl_exceed_rate"]]
            print(f"{r['scenario']:>11}  {r['stations']:>11}  " + "  ".join(
                f"{'-':>11}" if v is None else f"{v:11.4f}" for v in vals))
            if "note" in r:
                print(f"  note: {r['note']}")
    if ac_rows and args.ac_filters:
        for r in ac_rows:
            r["filter_integrity"] = aircraft_filters(r["scenario"], args.ac_runs, args.seed, tuple(args.ac_filters))
        print_filter_table(ac_rows)
        if args.png_dir:
            print(f"wrote {plot_filters(ac_rows, Path(args.png_dir))}")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps({"estimator": args.estimator, "runs": rows, "aircraft": ac_rows},
                                              indent=1))
        print(f"wrote {args.json}")
    return 0
