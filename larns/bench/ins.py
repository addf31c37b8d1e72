"""`larns bench ins`: the inertial aircraft on the seed 003 field.

1. Seed 003 as the paper has it (eqs. 8-12): the fictitious-station CV filter with DWNA noise from
   sigma_a = 0.015 m/s^2 and the one-cycle CRLB as R, covariance curves over one lap of the ellipse
   at 250 / 500 / 1000 m (the paper's Figs 6 and 7), plus a cycle-length sweep.
2. The full strapdown INS + error-state EKF (``ins-ekf``, IMU preset, default ADIS16480) tightly
   coupled with every pseudorange, a Monte Carlo over the same lap at each height against its
   posterior CRLB, with the mean NEES.
3. LARNS outages of 10 / 30 / 60 s at 1000 m: horizontal error at the end of each and the time to
   re-converge, beside the open-loop drift of the same IMU from a calibrated start.
4. The cost of not knowing the frame's tilt: the same filter with the true tilt given (an oracle
   yardstick only) and with the tilt ignored (frame assumed level).
5. Speed: one hour of one aircraft (IMU 100 Hz, a range every slot) and the batched Monte Carlo.

Prints a table, writes JSON (--json) and a PNG (--png).
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

from larns.analysis.metrics import nees_band  # the chi-square band of a run-mean NEES

BAR_RMSE = 1.15
PAPER_FIG6_M = 0.8
PAPER_FIG7_M = 25.0
HEIGHTS = (250.0, 500.0, 1000.0)
OUTAGES = (10.0, 30.0, 60.0)


def register(sub) -> None:
    p = sub.add_parser("ins", help="seed 003 inertial aircraft: paper Figs 6-7, INS Monte Carlo vs PCRB, outages, speed",
                       description=__doc__)
    p.add_argument("--scenario", default="seed003-text", help="scenario (default seed003-text: the text's heights)")
    p.add_argument("--imu", default="adis16480", help="IMU preset (adis16480, tactical, navigation)")
    p.add_argument("--runs", type=int, default=64, help="Monte Carlo runs (default 64)")
    p.add_argument("--duration", type=float, default=None, help="seconds of flight per run (default one lap)")
    p.add_argument("--heights", type=float, nargs="+", default=list(HEIGHTS), help="flight heights, m")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--warmup", type=float, default=60.0, help="seconds excluded from the RMSE (default 60)")
    p.add_argument("--quick", action="store_true", help="smoke test: 8 runs, 300 s, 1000 m only, short speed test")
    p.add_argument("--no-speed", action="store_true")
    p.add_argument("--no-tilt-cost", action="store_true")
    p.add_argument("--json", metavar="FILE")
    p.add_argument("--png", metavar="FILE")
    p.set_defaults(func=run)


def _progress(msg: str) -> None:
    print(f"[bench ins] {msg}", file=sys.stderr, flush=True)


def world(scenario: str, height_m: float):
    """Field and the seed 003 ellipse from the scenario's ``[aircraft.trajectory]`` at ``height_m``."""
    from aircraft.world.field import Field
    from aircraft.world.motion import Ellipse
    from net.scenario import load

    sc = load(scenario)
    tr = sc.aircraft.get("trajectory", {})
    mo = Ellipse(tuple(tr.get("centre_m", (15000.0, 0.0))), tuple(tr.get("semi_axes_m", (20000.0, 15000.0))),
                 height_m, float(tr.get("speed_m_s", 50.0)), np.radians(float(tr.get("start_angle_deg", 180.0))))
    return sc, Field.from_scenario(sc), mo


def paper_curves(scenario: str, heights, slot_s: float, sigma_m: float) -> dict:
    """Seed 003 Figs 6-7: sigma_h(t), sigma_v(t) of the eq. (12) covariance recursion over one lap."""
    from aircraft.navigator.fict_kf import covariance_curves, cycle_crlb

    out = {}
    for h in heights:
        sc, fld, mo = world(scenario, h)
        m = len(fld.stations_n)
        T = m * slot_s
        t = np.arange(0.0, mo.lap_s, T)
        p, v, _ = fld.truth(mo, t)
        R = cycle_crlb(p, v, fld.stations_n, slot_s, sigma_m)
        P = covariance_curves(R, T)
        out[h] = {"t_s": t, "sigma_h": np.sqrt(P[:, 0, 0] + P[:, 1, 1]), "sigma_v": np.sqrt(P[:, 2, 2]),
                  "crlb_h": np.sqrt(R[:, 0, 0] + R[:, 1, 1]), "crlb_v": np.sqrt(R[:, 2, 2]), "cycle_s": T}
    return out


def ins_mc(scenario, h, preset, runs, duration, seed, outages=(), tilt="estimate", pcrb=True):
    from aircraft.montecarlo.ins import InsRun, simulate

    sc, fld, mo = world(scenario, h)
    cfg = InsRun(runs=runs, duration_s=duration or mo.lap_s, slot_s=sc.tdma.slot_s, cycle_s=sc.tdma.cycle_s,
                 sigma_m=float(sc.aircraft.get("sigma_m", sc.channel.sigma_d_m)), tilt=tilt,
                 outages=list(outages), seed=seed, pcrb=pcrb)
    t0 = time.perf_counter()
    res = simulate(fld, mo, preset, cfg, progress=lambda s: _progress(f"h={h:g} m {tilt}: {s}"))
    return res, time.perf_counter() - t0, fld, mo


def run(args) -> int:
    from aircraft.world.imu import preset as get_preset

    pre = get_preset(args.imu)
    heights = [1000.0] if args.quick else list(args.heights)
    runs = 8 if args.quick else args.runs
    duration = 300.0 if args.quick else args.duration
    sc, _, mo0 = world(args.scenario, heights[0])
    sigma_m = float(sc.aircraft.get("sigma_m", sc.channel.sigma_d_m))
    doc: dict = {"scenario": args.scenario, "imu": pre.name, "runs": runs, "seed": args.seed,
                 "slot_s": sc.tdma.slot_s, "cycle_s": sc.tdma.cycle_s, "sigma_m": sigma_m,
                 "lap_s": mo0.lap_s, "warmup_s": args.warmup}
    from aircraft.navigator.ins_start import StartConfig

    sc_ = StartConfig()  # the honest in-flight start (docs/ins.md): the EKF starts at the window's end
    doc["start"] = {"window_s": sc_.window_s, "accel_sigma_m_s2": sc_.accel_sigma_m_s2, "crab_sigma_rad": sc_.crab_sigma_rad}
    # 1. paper ------------------------------------------------------------------------------------
    _progress("paper Figs 6-7 (covariance recursion)")
    pc = paper_curves(args.scenario, HEIGHTS, sc.tdma.slot_s, sigma_m)
    w = lambda c: c["t_s"] >= args.warmup  # noqa: E731  (the first fix's transient, as for the INS)
    doc["paper_fig6_max_sigma_h_m"] = {f"{h:g}": float(pc[h]["sigma_h"][w(pc[h])].max()) for h in HEIGHTS}
    doc["paper_fig7_max_sigma_v_m"] = {f"{h:g}": float(pc[h]["sigma_v"][w(pc[h])].max()) for h in HEIGHTS}
    doc["paper_median_sigma_h_m"] = {f"{h:g}": float(np.median(pc[h]["sigma_h"][w(pc[h])])) for h in HEIGHTS}
    sweep = {}
    for slot in (0.1, 0.075, 0.05, 0.01):
        c = paper_curves(args.scenario, HEIGHTS, slot, sigma_m)
        sweep[f"{8 * slot:g}"] = {"max_sigma_h_m": max(float(c[h]["sigma_h"][w(c[h])].max()) for h in HEIGHTS),
                                  "max_sigma_v_m": max(float(c[h]["sigma_v"][w(c[h])].max()) for h in HEIGHTS)}
    doc["paper_cycle_sweep"] = sweep
    # 2. INS Monte Carlo per height ---------------------------------------------------------------
    doc["ins_rmse_h_m"], doc["ins_pcrb_h_m"], doc["ins_ratio"], doc["ins_mean_nees"] = {}, {}, {}, {}
    doc["ins_nees_frac_in_or_below_band"] = {}
    doc["ins_mean_nees8"], doc["ins_yaw_sigma_end_mrad"] = {}, {}
    curves = {}
    mc_wall, mc_flight, mc_cpu = 0.0, 0.0, 0.0
    lo, hi = nees_band(runs, 9)
    doc["nees_band_9dof"] = [lo, hi]
    doc["nees_band_8dof"] = list(nees_band(runs, 8))
    for h in heights:
        res, wall, fld, mo = ins_mc(args.scenario, h, pre, runs, duration, args.seed)
        mc_wall += wall
        mc_cpu += res.cpu_s
        mc_flight += res.flight_s * res.runs
        k = res.t_s >= args.warmup
        rm = float(np.sqrt(np.mean(res.rmse_h()[k] ** 2)))
        pb = float(np.sqrt(np.mean(res.pcrb_h()[k] ** 2)))
        key = f"{h:g}"
        doc["ins_rmse_h_m"][key] = rm
        doc["ins_pcrb_h_m"][key] = pb
        doc["ins_ratio"][key] = rm / pb
        mn = res.nees[:, k].mean(axis=0)
        doc["ins_mean_nees"][key] = float(mn.mean())
        doc["ins_nees_frac_in_or_below_band"][key] = float(np.mean(mn <= hi))
        doc["ins_mean_nees8"][key] = float(res.nees8[:, k].mean())
        # heading: filter sigma, posterior CRLB and RMS error over the last 10 % of the flight
        e = res.t_s >= res.t_s[-1] * 0.9
        doc["ins_yaw_sigma_end_mrad"][key] = {
            "filter": float(1e3 * np.sqrt(res.var9[:, e, 8].mean())), "pcrb": float(1e3 * np.sqrt(res.pcrb9[e, 8].mean())),
            "rms_error": float(1e3 * np.sqrt((res.nsq[:, e, 8] * res.var9[:, e, 8]).mean()))}
        curves[h] = (res.t_s, res.rmse_h(), res.pcrb_h(), np.sqrt(np.mean(res.P_pos[..., 0, 0] + res.P_pos[..., 1, 1], axis=0)))
    doc["mc_flight_s"] = mc_flight
    doc["mc_wall_s"] = mc_wall
    # 3. outages ----------------------------------------------------------------------------------
    from aircraft.montecarlo.ins import open_loop_drift

    h_out = 1000.0
    dur = duration or mo0.lap_s
    starts = [float(round(dur * f)) for f in (0.3, 0.55, 0.8)]  # whole seconds: a record falls on each end
    outs = list(zip(starts, OUTAGES))
    res_o, wall, fld, mo = ins_mc(args.scenario, h_out, pre, runs, dur, args.seed + 1, outages=outs)
    mc_wall += wall
    mc_cpu += res_o.cpu_s
    mc_flight += res_o.flight_s * res_o.runs
    rh = res_o.rmse_h()
    ph = res_o.pcrb_h()
    doc["outage_drift_h_m"], doc["outage_pcrb_h_m"], doc["outage_reconverge_s"] = {}, {}, {}
    doc["outage_open_loop_h_m"] = {}
    for (a, L) in outs:
        i_end = int(np.searchsorted(res_o.t_s, a + L + 1e-6)) - 1  # last record before the broadcasts return
        pre_i = (res_o.t_s >= a - 60.0) & (res_o.t_s < a)
        level = float(np.sqrt(np.mean(rh[pre_i] ** 2)))
        after = np.nonzero((res_o.t_s > a + L))[0]
        sm = np.convolve(rh ** 2, np.ones(5) / 5.0, mode="same") ** 0.5
        back = [i for i in after if sm[i] <= 1.2 * level]
        key = f"{L:g}"
        doc["outage_drift_h_m"][key] = float(rh[i_end])
        doc["outage_pcrb_h_m"][key] = float(ph[i_end])
        doc["outage_reconverge_s"][key] = float(res_o.t_s[back[0]] - (a + L)) if back else None
        doc["outage_open_loop_h_m"][key] = open_loop_drift(fld, mo, pre, L, runs=max(runs, 64), seed=args.seed, t0_s=a)
    doc["outage_times_s"] = outs
    # 4. tilt cost --------------------------------------------------------------------------------
    if not args.no_tilt_cost:
        tdur = min(dur, 600.0)
        truns = min(runs, 32)
        doc["tilt_cost"] = {"duration_s": tdur, "runs": truns, "height_m": 1000.0}
        for mode in ("estimate", "oracle", "ignore"):
            r, wall, _, _ = ins_mc(args.scenario, 1000.0, pre, truns, tdur, args.seed + 2, tilt=mode, pcrb=(mode != "ignore"))
            k = r.t_s >= args.warmup
            doc["tilt_cost"][mode] = {"rmse_h_m": float(np.sqrt(np.mean(r.rmse_h()[k] ** 2))),
                                      "mean_nees": float(r.nees[:, k].mean()),
                                      "pcrb_h_m": float(np.sqrt(np.mean(r.pcrb_h()[k] ** 2))) if r.pcrb_pos is not None else None}
    # 5. speed ------------------------------------------------------------------------------------
    speed = {"batched_runs": runs, "batched_flight_s": mc_flight, "batched_wall_s": mc_wall,
             "batched_cpu_s": mc_cpu, "batched_x_real_time": mc_flight / mc_cpu,
             "batched_x_real_time_wall": mc_flight / mc_wall,
             "note": "x real time per CPU second of the filter loop (one core); wall times on a shared 2-core machine"}
    if not args.no_speed:
        one = 600.0 if args.quick else 3600.0
        r1, wall1, _, _ = ins_mc(args.scenario, 1000.0, pre, 1, one, args.seed + 3, pcrb=False)
        speed.update({"one_run_flight_s": one, "one_run_wall_s": wall1, "one_run_cpu_s": r1.cpu_s,
                      "one_run_imu_hz": pre.rate_hz, "one_run_updates": int(one / sc.tdma.slot_s),
                      "one_run_x_real_time": one / r1.cpu_s, "one_hour_cpu_s": r1.cpu_s * 3600.0 / one})
    doc["speed"] = speed
    _table(doc, heights)
    if args.png:
        _plot(args.png, pc, curves, res_o, outs, doc)
        print(f"wrote {args.png}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(doc, f, indent=1)
        print(f"wrote {args.json}")
    return 0


def _table(doc, heights) -> None:
    print(f"seed 003 world '{doc['scenario']}': TDMA slot {doc['slot_s']} s, cycle {doc['cycle_s']} s, "
          f"sigma {doc['sigma_m']} m, lap {doc['lap_s']:.0f} s, IMU {doc['imu']}, {doc['runs']} runs, "
          f"start from the first {doc['start']['window_s']:g} s of broadcasts and IMU")
    print(f"\n1. paper model (eqs. 8-12: CV filter, DWNA sigma_a = 0.015, R = one-cycle CRLB), after {doc['warmup_s']:g} s")
    print(f"{'height m':>9} {'max sigma_h m':>14} {'median sigma_h':>15} {'max sigma_v m':>14}   bar: <= 0.8 / <= 25")
    for h in HEIGHTS:
        k = f"{h:g}"
        print(f"{k:>9} {doc['paper_fig6_max_sigma_h_m'][k]:14.3f} {doc['paper_median_sigma_h_m'][k]:15.3f} "
              f"{doc['paper_fig7_max_sigma_v_m'][k]:14.2f}")
    print("   cycle sweep (max over heights): " + ", ".join(
        f"{c} s: {v['max_sigma_h_m']:.2f} / {v['max_sigma_v_m']:.1f} m" for c, v in doc["paper_cycle_sweep"].items()))
    lo, hi = doc["nees_band_9dof"]
    print(f"\n2. ins-ekf Monte Carlo ({doc['runs']} runs, after {doc['warmup_s']:g} s); NEES of [p v phi], "
          f"9 dof, 95% band of the run mean [{lo:.2f}, {hi:.2f}]")
    lo8, hi8 = doc["nees_band_8dof"]
    print(f"   NEES8 = [p v phi_x phi_y] (8 dof, band [{lo8:.2f}, {hi8:.2f}]); heading (phi_z) sigma of the filter, "
          f"its PCRB and the RMS error over the last 10 % of the flight, mrad")
    print(f"{'height m':>9} {'RMSE_h m':>9} {'PCRB_h m':>9} {'ratio':>6} {'NEES9':>7} {'t in/below':>11} {'NEES8':>7}"
          f" {'yaw filter/PCRB/err mrad':>25}")
    for h in heights:
        k = f"{h:g}"
        y = doc["ins_yaw_sigma_end_mrad"][k]
        print(f"{k:>9} {doc['ins_rmse_h_m'][k]:9.3f} {doc['ins_pcrb_h_m'][k]:9.3f} {doc['ins_ratio'][k]:6.3f} "
              f"{doc['ins_mean_nees'][k]:7.2f} {100 * doc['ins_nees_frac_in_or_below_band'][k]:10.1f}% "
              f"{doc['ins_mean_nees8'][k]:7.2f} {y['filter']:9.0f} /{y['pcrb']:5.0f} /{y['rms_error']:5.0f}")
    print("\n3. LARNS outages at 1000 m: RMS horizontal error at the end, PCRB there, re-convergence, "
          "open-loop drift from a calibrated start")
    print(f"{'outage s':>9} {'at t s':>7} {'RMSE_h end':>11} {'PCRB_h end':>11} {'reconv s':>9} {'open loop':>10}")
    for (a, L) in doc["outage_times_s"]:
        k = f"{L:g}"
        rc = doc["outage_reconverge_s"][k]
        print(f"{k:>9} {a:7.0f} {doc['outage_drift_h_m'][k]:11.2f} {doc['outage_pcrb_h_m'][k]:11.2f} "
              f"{'-' if rc is None else f'{rc:.0f}':>9} {doc['outage_open_loop_h_m'][k]:10.2f}")
    if "tilt_cost" in doc:
        tc = doc["tilt_cost"]
        print(f"\n4. frame tilt ({tc['runs']} runs, {tc['duration_s']:g} s, 1000 m): RMSE_h / PCRB_h / mean NEES")
        for mode in ("estimate", "oracle", "ignore"):
            d = tc[mode]
            pb = "-" if d["pcrb_h_m"] is None else f"{d['pcrb_h_m']:.3f}"
            print(f"{mode:>10}: {d['rmse_h_m']:.3f} / {pb} / {d['mean_nees']:.1f}")
    s = doc["speed"]
    print(f"\n5. speed ({s['note']}): batched {s['batched_runs']} runs: {s['batched_flight_s']:.0f} s of flight in "
          f"{s['batched_cpu_s']:.1f} s CPU = {s['batched_x_real_time']:.0f} x real time "
          f"(wall {s['batched_wall_s']:.1f} s, {s['batched_x_real_time_wall']:.0f} x)")
    if "one_run_wall_s" in s:
        print(f"   one run, {s['one_run_flight_s']:.0f} s at {s['one_run_imu_hz']:g} Hz with {s['one_run_updates']} "
              f"range updates: {s['one_run_cpu_s']:.1f} s CPU ({s['one_run_x_real_time']:.0f} x real time; "
              f"wall {s['one_run_wall_s']:.1f} s)")


def _plot(path, pc, curves, res_o, outs, doc) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 2, figsize=(12, 8))
    for h, c in pc.items():
        ax[0, 0].plot(c["t_s"], c["sigma_h"], label=f"h = {h:g} m")
        ax[0, 1].plot(c["t_s"], c["sigma_v"], label=f"h = {h:g} m")
    ax[0, 0].set_ylim(0, 1.2)
    ax[0, 0].axhline(PAPER_FIG6_M, color="k", lw=0.6, ls=":")
    ax[0, 0].set_title(f"paper model (Fig. 6): horizontal sigma, cycle {doc['cycle_s']} s", fontsize=9)
    ax[0, 1].set_title("paper model (Fig. 7): vertical sigma", fontsize=9)
    ax[0, 1].axhline(PAPER_FIG7_M, color="k", lw=0.6, ls=":")
    for h, (t, rm, pb, fs) in curves.items():
        l, = ax[1, 0].plot(t, rm, lw=0.8, label=f"RMSE h = {h:g} m")
        ax[1, 0].plot(t, pb, color=l.get_color(), ls="--", lw=0.8, label=f"PCRB h = {h:g} m")
    ax[1, 0].set_ylim(0, 2.0)
    ax[1, 0].set_title(f"ins-ekf ({doc['imu']}), {doc['runs']} runs: horizontal RMSE vs posterior CRLB", fontsize=9)
    ax[1, 1].semilogy(res_o.t_s, res_o.rmse_h(), lw=0.8, label="RMSE")
    ax[1, 1].semilogy(res_o.t_s, res_o.pcrb_h(), lw=0.8, ls="--", label="PCRB")
    for a, L in outs:
        ax[1, 1].axvspan(a, a + L, color="r", alpha=0.2)
    ax[1, 1].set_title("LARNS outages 10 / 30 / 60 s at 1000 m", fontsize=9)
    for a in ax.ravel():
        a.set_xlabel("T, s")
        a.set_ylabel("m")
        a.legend(fontsize=7)
        a.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
