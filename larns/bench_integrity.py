"""`larns bench integrity`: NLOS ranges and faulty / lying stations vs the survey and the stations'
integrity monitoring (in-process simulator, seed 000 world).

Per case and trial: the horizontal RMS of the non-faulty stations 4..n at 40 s and 60 s against the
clean centralized CRLB of the same realized links, their mean NEES (3 dof), and from the stations'
``integrity`` decisions: whether the faulty station was excluded by a non-faulty neighbour, how soon
after the fault's onset, and the false exclusions (a non-faulty station excluding a non-faulty one)
per station-hour.
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
    p.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES), help="cases (default: all)")
    p.add_argument("--estimator", default="dmap", choices=["dmap", "dmap-ls", "seed-ukf"])
    p.add_argument("--duration", type=float, default=60.0, help="simulated seconds per trial (default 60)")
    p.add_argument("--seed", type=int, default=1, help="base seed; trial k uses seed + k (default 1)")
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="worker processes (default: all cores)")
    p.add_argument("--json", metavar="FILE", help="write the results as JSON")
    p.add_argument("--png-dir", metavar="DIR", default="bench-out/integrity", help="PNG directory ('' to skip)")
    p.set_defaults(func=main)


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


def _trial(job: tuple) -> dict:
    from nav.crlb import survey_crlb
    from nav.geometry import frame_free_mask
    from net.scenario import load
    from stations.sim import Simulator

    case, estimator, seed, duration, scenario = job
    over = CASES.get(case, {}) if case else {}
    scn = load(scenario, seed=seed, **{k: (dict(v) if isinstance(v, dict) else v) for k, v in over.items()})
    sim = Simulator(scn, estimator=estimator)
    times = np.array([40.0, duration])
    r = sim.run(duration, times)
    bad = {f.station for f in scn.faults}
    keep = np.array([i >= 4 and i not in bad for i in scn.ids])
    err = (r.pos_m - r.truth_m)[:, keep]
    free = frame_free_mask(len(scn.ids))
    crlb = np.stack([survey_crlb(r.truth_m, r.link_counts[k], scn.channel.sigma_d_m, free, scn.sigma0_m)
                     for k in range(len(times))])[:, keep]
    P = r.cov_m2[:, keep]
    nees = np.einsum("kni,kni->kn", err, np.linalg.solve(P, err[..., None])[..., 0])
    out = {"h2": err[..., 0] ** 2 + err[..., 1] ** 2, "crlb_h2": crlb[..., 0, 0] + crlb[..., 1, 1], "nees": nees}
    out.update(fault_metrics(sim, scn.faults, duration))
    out["faulty"] = bool(scn.faults)
    return out


def summarize(case: str, res: list[dict], faulty: bool) -> dict:
    h2 = np.concatenate([r["h2"] for r in res], axis=1)  # (2, N)
    c2 = np.concatenate([r["crlb_h2"] for r in res], axis=1)
    nees = np.concatenate([r["nees"] for r in res], axis=1)
    from .bench_survey import chi2_band

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


def main(args) -> int:
    from .progress import Progress

    rows = []
    ctx = mp.get_context("fork")
    with ctx.Pool(max(1, args.jobs)) as pool:
        for case in args.cases:
            jobs = [(case, args.estimator, args.seed + k, args.duration, "seed000") for k in range(args.trials)]
            t0 = time.perf_counter()
            bar = Progress(len(jobs), f"integrity {case}")
            res = []
            for r in pool.imap(_trial, jobs):
                res.append(r)
                bar.update(1)
            bar.close()
            row = summarize(case, res, res[0]["faulty"])
            row["times_s"][1] = args.duration
            row["wall_s"] = time.perf_counter() - t0
            rows.append(row)
    print(f"\nestimator={args.estimator}  trials/case={args.trials}  faulty station={FAULTY}  "
          f"(FE/st-h: false exclusions per station-hour by non-faulty stations)")
    print_table(rows)
    if args.png_dir:
        print(f"wrote {plot(rows, Path(args.png_dir))}")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps({"estimator": args.estimator, "runs": rows}, indent=1))
        print(f"wrote {args.json}")
    return 0
