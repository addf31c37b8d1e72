"""`larns bench vehicle`: seed 004's ground vehicle on a mapped route through a 300 s radio outage.

Cases (each ``--runs`` Monte Carlo runs, common random numbers across the filter variants):

* ``paper_case`` - 1000 s on a great circle near Rostov-on-Don (NNE, h = 100 m, 20 m/s), GLONASS-like
  satellites (10 deg mask, 1 s epochs, sigma 15 m / 0.5 m/s), outage 400-700 s, the 11-state
  map-constrained filter, noise read as ``per_sample`` and as ``psd``;
* ``paper_clock`` - the same with a true receiver clock in the pseudoranges and clock states (13);
* ``no_map`` - the unconstrained 15-state filter on the paper case;
* ``no_odometer`` - the 11-state filter without the odometer;
* ``larns_case`` - seed000's stations, a straight level route through the field at 5 m/s, a 300 s
  station outage (400-700 s), pseudoranges + carrier Dopplers, receiver clock states; with the map
  (13 states) and without (17 states).

Per run: the maximum absolute Greenwich velocity / attitude / position component error at the end
(the paper's statistic at 1000 s), median and 95th percentile over runs beside the paper's
0.17 m/s / 1.5' / 9.8 m; the 3-D position error at the end of the outage; NEES on the observable
subspace (mean over runs, with its 95 % band) before, during and after the outage; the hand-over
jump at the first update after the outage in prior sigmas; CPU and wall time, and the process CPU
time (``time.process_time``) of one 1000 s paper run alone (JSON ``speed.single_run_cpu_s``; the
map filter's single-run fast path) against the bar of 10 s.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

PAPER = {"vel_m_s": 0.17, "att_arcmin": 1.5, "pos_m": 9.8}
PAPER_ROUTE = [(47.23, 39.72), (47.40, 39.80)]  # NNE from Rostov-on-Don, ~19.9 km


def register(sub) -> None:
    p = sub.add_parser("vehicle", help="seed 004 vehicle: map-constrained INS/radio/odometer through a 300 s outage",
                       description=__doc__)
    p.add_argument("--runs", type=int, default=50, help="Monte Carlo runs of the paper case, both readings (default 50)")
    p.add_argument("--runs-other", type=int, default=25,
                   help="Monte Carlo runs of the other cases (paper_clock, no_map, no_odometer, larns; default 25)")
    p.add_argument("--seed", type=int, default=4, help="world seed (default 4)")
    p.add_argument("--json", metavar="FILE", help="write the results as JSON")
    p.add_argument("--png-dir", metavar="DIR", help="write errors and 3-sigma bounds vs time here")
    p.add_argument("--quick", action="store_true", help="smoke test: 4 runs, 200 s, outage 80-140 s")
    p.add_argument("--cases", default="all",
                   help="comma list of paper,psd,paper_clock,no_map,no_odometer,larns (default all)")
    p.add_argument("--no-speed", action="store_true", help="skip the single-run timing")
    p.set_defaults(func=run)


def _progress(msg: str) -> None:
    print(f"[bench vehicle] {msg}", file=sys.stderr, flush=True)


def summarize(res, outage: tuple[float, float]) -> dict:
    """Statistics of one case (see the module doc)."""
    from larns.bench.survey import chi2_band
    from vehicle.sim import ARCMIN

    t = res.t_s
    end = -1
    i_out = int(np.searchsorted(t, outage[1]))
    i_beg = int(np.searchsorted(t, outage[0]))
    vel = np.abs(res.err_vel[:, end]).max(-1)
    att = np.abs(res.err_att[:, end]).max(-1) / ARCMIN
    pos = np.abs(res.err_pos[:, end]).max(-1)
    pos_out = np.linalg.norm(res.err_pos[:, i_out], axis=-1)
    M = res.nees.shape[0]
    lo, hi = chi2_band(res.nees_dof, M)
    windows = {"before": (t > 10) & (t < outage[0]), "outage": (t >= outage[0]) & (t <= outage[1]),
               "after": t > outage[1] + 1}
    nees_mean = {w: float(np.nanmean(res.nees[:, m])) for w, m in windows.items()}
    frac_in = {w: float(np.mean((np.nanmean(res.nees[:, m], axis=0) <= hi))) for w, m in windows.items()}
    # hand-over: the first update after the outage, normalized by the prior sigma at the outage's end
    k1 = i_out + 1
    jump = np.abs(res.err_pos[:, k1] - res.err_pos[:, i_out]) / np.maximum(res.sig_pos[:, i_out], 1e-9)
    jump_v = np.abs(res.err_vel[:, k1] - res.err_vel[:, i_out]) / np.maximum(res.sig_vel[:, i_out], 1e-9)
    rms3 = lambda e: float(np.sqrt(np.mean(np.sum(e**2, -1))))  # noqa: E731
    return {
        "vel_m_s": float(np.median(vel)), "att_arcmin": float(np.median(att)), "pos_m": float(np.median(pos)),
        "p95": {"vel_m_s": float(np.percentile(vel, 95)), "att_arcmin": float(np.percentile(att, 95)),
                "pos_m": float(np.percentile(pos, 95))},
        "pos_end_outage_m": float(np.median(pos_out)), "pos_end_outage_p95_m": float(np.percentile(pos_out, 95)),
        "pos_end_outage_rms_m": rms3(res.err_pos[:, i_out]),
        "sigma_pos_end_outage_m": float(np.median(np.linalg.norm(res.sig_pos[:, i_out], axis=-1))),
        "pos_rms_m_at_outage_start": rms3(res.err_pos[:, i_beg]),
        "nees_mean": nees_mean, "nees_dof": res.nees_dof, "nees_band95": [lo, hi],
        "nees_frac_epochs_below_upper": frac_in,
        "handover_jump_sigma": {"pos_max": float(np.nanmax(jump)), "vel_max": float(np.nanmax(jump_v)),
                                "pos_frac_gt3": float(np.mean(jump > 3)), "vel_frac_gt3": float(np.mean(jump_v > 3))},
        "polar_rotation_sigma_arcmin": {"start": float(np.sqrt(np.median(res.var_polar_rot[:, 0])) / ARCMIN),
                                        "end": float(np.sqrt(np.median(res.var_polar_rot[:, -1])) / ARCMIN)},
        "nis_mean_per_dof": float(np.nanmean(res.nis / np.where(res.nis_dof > 0, res.nis_dof, np.nan))),
        "runs": int(M), "wall_s": res.wall_s, "cpu_s": res.cpu_s, "n_states": res.n_states,
        "cpu_s_per_run_1000s": res.cpu_s / M * (1000.0 / t[-1]),
    }


def build_cases(args):
    from vehicle import field, sim
    from vehicle.route import great_circle_route

    dur, outage = (200.0, (80.0, 140.0)) if args.quick else (1000.0, (400.0, 700.0))
    runs = args.runs if not args.quick else min(args.runs, 4)
    other = args.runs_other if not args.quick else min(args.runs_other, 4)
    route = great_circle_route(PAPER_ROUTE, 100.0, [20.0], name="paper")
    base = dict(route=route, duration_s=dur, outage_s=outage, seed=args.seed)
    cases = {
        "paper": sim.Case(**base, runs=runs, convention="per_sample"),
        "psd": sim.Case(**base, runs=runs, convention="psd"),
        "paper_clock": sim.Case(**base, runs=other, convention="per_sample", clock_states=True,
                                clock_in_measurements=True),
        "no_map": sim.Case(**base, runs=other, convention="per_sample", filter="free"),
        "no_odometer": sim.Case(**base, runs=other, convention="per_sample", odometer=False),
    }
    _, phys, _, R, t = field.field_layout("seed000")
    froute, _ = field.field_route(phys, R, t, speed_m_s=5.0 if not args.quick else 20.0)
    lbase = dict(route=froute, duration_s=dur, outage_s=outage, runs=other, seed=args.seed, radio="stations",
                 stations_g=field.stations_greenwich(phys), sigma_rho_m=0.5, sigma_rate_m_s=0.15,
                 station_sigma_m=0.2, clock_states=True, clock_in_measurements=True, convention="per_sample")
    cases["larns"] = sim.Case(**lbase, filter="map")
    cases["larns_free"] = sim.Case(**lbase, filter="free")
    return cases, outage


def run(args) -> int:
    from vehicle import sim

    cases, outage = build_cases(args)
    want = set(cases) if args.cases == "all" else set()
    for c in args.cases.split(",") if args.cases != "all" else []:
        c = c.strip()
        if c == "larns":
            want |= {"larns", "larns_free"}
        elif c in cases:
            want.add(c)
        else:
            print(f"error: unknown case {c!r}", file=sys.stderr)
            return 2
    t0 = time.perf_counter()
    results, summ = {}, {}
    for name, case in cases.items():
        if name not in want:
            continue
        _progress(f"{name}: {case.filter} filter, {case.convention}, {case.runs} runs x {case.duration_s:g} s")
        results[name] = sim.run(case)
        summ[name] = summarize(results[name], outage)
        _progress(f"{name}: {results[name].wall_s:.0f} s")
    speed = None
    if not args.no_speed and not args.quick and "paper" in want:
        one = cases["paper"]
        one.runs = 1
        _progress("single-run timing of the paper case")
        r1 = sim.run(one)
        from vehicle.navigator.cdekf import MapFilter
        from vehicle.navigator.fused import COMPILED

        speed = {"single_run_cpu_s": r1.cpu_s, "single_run_wall_s": r1.wall_s, "steps": r1.steps,
                 "single_run_fast_path": bool(MapFilter.fast),
                 "single_run_kernel": "numba" if COMPILED else "numpy",
                 "batched_cpu_s_per_run": summ["paper"]["cpu_s"] / summ["paper"]["runs"],
                 "batched_wall_s_per_run": summ["paper"]["wall_s"] / summ["paper"]["runs"]}
    out = _assemble(summ, speed, args, outage, time.perf_counter() - t0)
    _print_table(out)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
        _progress(f"wrote {args.json}")
    if args.png_dir:
        for p in _plots(results, outage, args.png_dir):
            _progress(f"wrote {p}")
    return 0


def _keys(s: dict) -> dict:
    return {k: s[k] for k in ("vel_m_s", "att_arcmin", "pos_m")}


def _assemble(summ, speed, args, outage, wall) -> dict:
    out = {"paper": PAPER, "outage_s": list(outage),
           "settings": {"runs": args.runs, "runs_other": args.runs_other, "seed": args.seed,
                        "quick": bool(args.quick), "wall_s": wall}}
    if "paper" in summ or "psd" in summ:
        out["paper_case"] = {}
        if "paper" in summ:
            out["paper_case"]["per_sample"] = _keys(summ["paper"])
        if "psd" in summ:
            out["paper_case"]["psd"] = _keys(summ["psd"])
    if "larns" in summ:
        out["larns_case"] = {"per_sample": _keys(summ["larns"]),
                             "pos_end_outage_m": summ["larns"]["pos_end_outage_m"]}
        if "larns_free" in summ:
            out["larns_case"]["no_map"] = _keys(summ["larns_free"])
            out["larns_case"]["no_map_pos_end_outage_m"] = summ["larns_free"]["pos_end_outage_m"]
    if "no_map" in summ:
        out["no_map"] = _keys(summ["no_map"])
    if "no_odometer" in summ:
        out["no_odometer"] = _keys(summ["no_odometer"])
    out["detail"] = summ
    out["speed"] = speed
    bars = {}
    if "paper" in summ:
        s = summ["paper"]
        bars["paper_per_sample_medians"] = all(s[k] <= PAPER[k] for k in PAPER)
        bars["nees_in_band_outage"] = s["nees_mean"]["outage"] <= s["nees_band95"][1]
        bars["handover_jump_le_3sigma"] = s["handover_jump_sigma"]["pos_max"] <= 3 and s["handover_jump_sigma"]["vel_max"] <= 3
    if "larns" in summ and "paper" in summ:
        bars["larns_end_outage_le_2x_paper"] = summ["larns"]["pos_end_outage_m"] <= 2 * summ["paper"]["pos_end_outage_m"]
    if "larns" in summ and "larns_free" in summ:
        ratio = summ["larns_free"]["pos_end_outage_m"] / max(summ["larns"]["pos_end_outage_m"], 1e-12)
        out["larns_case"]["map_gain_end_outage"] = ratio
        bars["larns_map_gain_ge_3"] = ratio >= 3
    if speed:
        bars["single_run_cpu_le_10s"] = speed["single_run_cpu_s"] <= 10
        bars["batched_cpu_per_run_le_10s"] = speed["batched_cpu_s_per_run"] <= 10
    out["bars"] = bars
    return out


def _print_table(out: dict) -> None:
    d = out["detail"]
    print(f"\nSeed 004 vehicle: max |component error| at the end of the run (median / 95th pct over runs); "
          f"outage {out['outage_s'][0]:g}-{out['outage_s'][1]:g} s")
    hdr = (f"{'case':<13} {'n':>3} {'vel m/s':>15} {'att arcmin':>15} {'pos m':>15} {'pos@outage end':>15} "
           f"{'NEES b/o/a (dof, 95% hi)':>28} {'jump sig p/v':>13} {'cpu s/run':>9}")
    print(hdr)
    print("-" * len(hdr))
    for name, s in d.items():
        ne = s["nees_mean"]
        print(f"{name:<13} {s['n_states']:>3} {s['vel_m_s']:7.3f} /{s['p95']['vel_m_s']:6.3f} "
              f"{s['att_arcmin']:7.2f} /{s['p95']['att_arcmin']:6.2f} {s['pos_m']:7.2f} /{s['p95']['pos_m']:6.2f} "
              f"{s['pos_end_outage_m']:8.2f} m     "
              f"{ne['before']:5.2f}/{ne['outage']:5.2f}/{ne['after']:5.2f} ({s['nees_dof']}, {s['nees_band95'][1]:.2f})  "
              f"{s['handover_jump_sigma']['pos_max']:5.2f}/{s['handover_jump_sigma']['vel_max']:5.2f} "
              f"{s['cpu_s_per_run_1000s']:9.2f}")
    print(f"{'paper (R4)':<13} {'':>3} {PAPER['vel_m_s']:7.3f}         {PAPER['att_arcmin']:7.2f}         "
          f"{PAPER['pos_m']:7.2f}")
    if "psd" in d:
        print(f"\npsd reading: polar-axis rotation sigma {d['psd']['polar_rotation_sigma_arcmin']['end']:.2f}' at the end "
              f"(per_sample: {d['paper']['polar_rotation_sigma_arcmin']['end']:.2f}' )" if "paper" in d else "")
    lc = out.get("larns_case")
    if lc and "map_gain_end_outage" in lc:
        print(f"LARNS field: position error at the end of the outage, map {lc['pos_end_outage_m']:.2f} m vs "
              f"unconstrained {lc['no_map_pos_end_outage_m']:.2f} m (x{lc['map_gain_end_outage']:.1f})")
    sp = out.get("speed")
    if sp:
        print(f"speed (process CPU time of the filter loop; wall on this shared machine in brackets): one 1000 s run "
              f"alone {sp['single_run_cpu_s']:.1f} s ({sp['single_run_wall_s']:.1f} s), {sp['steps']} RK4 steps"
              f"{' (single-run fast path, ' + sp.get('single_run_kernel', '?') + ' kernel)' if sp.get('single_run_fast_path') else ''}; "
              f"vectorized over {d['paper']['runs']} runs {sp['batched_cpu_s_per_run']:.2f} s per run "
              f"({sp['batched_wall_s_per_run']:.2f} s)")
    print("bars: " + ", ".join(f"{k} {'PASS' if v else 'FAIL'}" for k, v in out["bars"].items()))
    print(f"wall time {out['settings']['wall_s']:.0f} s (shared machine)")


def _plots(results: dict, outage, png_dir: str) -> list[str]:
    import os

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from vehicle.sim import ARCMIN

    os.makedirs(png_dir, exist_ok=True)
    paths = []
    for name in ("paper", "psd", "larns", "larns_free", "no_map", "no_odometer", "paper_clock"):
        if name not in results:
            continue
        r = results[name]
        t = r.t_s
        fig, axes = plt.subplots(3, 1, figsize=(10, 9), sharex=True)
        for ax, e, s, lab, sc in ((axes[0], r.err_pos, r.sig_pos, "position error, m", 1.0),
                                  (axes[1], r.err_vel, r.sig_vel, "velocity error, m/s", 1.0),
                                  (axes[2], r.err_att, r.sig_att, "attitude error, arcmin", 1.0 / ARCMIN)):
            for c, col in zip(range(3), ("C0", "C1", "C2")):
                rms = np.sqrt(np.nanmean(e[:, :, c] ** 2, axis=0)) * sc
                sig = np.sqrt(np.nanmean(s[:, :, c] ** 2, axis=0)) * sc
                ax.plot(t, rms, color=col, lw=1, label=f"RMS err comp {c + 1}")
                ax.plot(t, 3 * sig, color=col, lw=0.8, ls="--", label=f"3 sigma comp {c + 1}")
            ax.axvspan(outage[0], outage[1], color="grey", alpha=0.2)
            ax.set_ylabel(lab)
            ax.set_yscale("log")
            ax.grid(True, alpha=0.3, which="both")
        axes[0].legend(fontsize=7, ncol=3)
        axes[2].set_xlabel("t, s")
        fig.suptitle(f"vehicle, case {name}: RMS over {r.err_pos.shape[0]} runs and filter 3 sigma "
                     f"(position/velocity Greenwich xi, eta, zeta; attitude body roll/pitch/yaw); outage shaded", fontsize=9)
        fig.tight_layout()
        p = os.path.join(png_dir, f"vehicle_{name}.png")
        fig.savefig(p, dpi=100)
        plt.close(fig)
        paths.append(p)
    return paths
