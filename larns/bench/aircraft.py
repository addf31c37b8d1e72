"""`larns bench aircraft`: seed 001's accuracy study (Fig. 4 and 5) against the posterior CRLB.

Six algorithms (lsq-pr, lsq-tdoa, ekf-pr, ekf-tdoa, ukf-pr, ukf-tdoa) on the scenario's transmitters
(seed001: 4 on a circle of R0 = 50 m, sigma 0.5 m, 100 Hz synchronous epochs, receiver clock
drift 20 Hz x 0.03 m). Hover at 50..1500 m and a coordinated turn with jumping angular velocity
starting at 500..2000 m, vectorized over Monte Carlo runs with common random numbers across
algorithms. Prints a table, writes JSON (--json) and PNGs (--png-dir), checks the bar
RMSE <= 1.1 x PCRB for the pseudorange EKF and UKF, runs a height sweep and times the UKF update
against filterpy's UnscentedKalmanFilter.
"""

from __future__ import annotations

import json
import sys
import time

from dataclasses import asdict, replace

import numpy as np

ALGOS = ("lsq-pr", "lsq-tdoa", "ekf-pr", "ekf-tdoa", "ukf-pr", "ukf-tdoa")
FILTERS = ("ekf-pr", "ekf-tdoa", "ukf-pr", "ukf-tdoa")
PAPER = {  # seed 001, conclusions (p. 3): hover and turn at 1000 m
    "hover": {"ukf-pr": {"1000": 10.0}, "ukf-tdoa": {"1000": 20.0}},
    "turn": {"ukf-pr": {"1000": 30.0}, "ukf-tdoa": {"1000": 140.0}},
}
BAR = 1.1
BAR_CLOCKS = 1.15  # issue 10: pseudorange filters with station clocks on, against the PCRB that includes them
# the residual station sync error after the broadcast correction that the stations achieve (docs/sync.md:
# `larns bench sync`, seed000 world, TCXO clocks: 0.66-0.76 ns RMS from 30 s on; correlation time ~6 s)
CLOCKS_SYNC_NS = 0.7
HEIGHT_NOTE = "height: 3 deg glide path toward the circle centre (h = d tan 3 deg) unless --height"


def register(sub) -> None:
    p = sub.add_parser(
        "aircraft",
        help="seed 001 accuracy sweep: 6 algorithms vs distance, PCRB bar, filterpy speed",
        description=__doc__,
    )
    p.add_argument("--scenario", default="seed001", help="scenario name or file (default seed001)")
    p.add_argument("--trials", type=int, default=None, help="Monte Carlo runs per point (default from scenario, 64)")
    p.add_argument("--seed", type=int, default=1, help="RNG seed (default 1)")
    p.add_argument("--json", metavar="FILE", help="write the results as JSON")
    p.add_argument("--png-dir", metavar="DIR", help="write fig4/fig5-like plots and the height sweep here")
    p.add_argument("--height", type=float, default=None, help="fixed aircraft height in m (default: glide path)")
    p.add_argument("--duration", type=float, default=None, help="seconds per run (default from scenario, 30)")
    p.add_argument("--warmup", type=float, default=None, help="seconds discarded at the start (default 10)")
    p.add_argument("--quick", action="store_true", help="small smoke-test version (few runs, short, 2 points each)")
    p.add_argument("--no-sweep", action="store_true", help="skip the height sweep")
    p.add_argument("--no-speed", action="store_true", help="skip the filterpy speed comparison")
    p.add_argument("--no-fde", action="store_true",
                   help="filters without the integrity gate/exclusion (aircraft/navigator/radio/fde.py; default: on)")
    p.add_argument("--sync-ns", type=float, default=None, metavar="NS",
                   help="station clocks on: residual sync error of each station after the broadcast correction "
                        "(1 sigma, ns), broadcast to the aircraft as its clock variance (default 0; --clocks: 0.7)")
    p.add_argument("--sync-tau", type=float, default=None, metavar="S",
                   help="correlation time of the residual sync errors (first-order Gauss-Markov; 0 = white; "
                        "default 0; --clocks: the filters' clock_bias_tau_s, 6 s)")
    p.add_argument("--clocks", action="store_true",
                   help="station clocks on (0.7 ns, 6 s unless --sync-ns/--sync-tau) next to the perfect-clock "
                        "world with the same draws: both tables, bar RMSE <= 1.15 x PCRB (PCRB with the clocks)")
    p.add_argument("--clock-bias", choices=("states", "white"), default=None,
                   help="the filters' model of the residual sync errors (default: the tuning's, states)")
    p.add_argument("--envelope", action="store_true",
                   help="flight envelope instead: heights x distances x bearings, hover and turn, the four "
                        "filters vs their PCRB (table, JSON `envelope`, heat maps; --quick: 8 points)")
    p.add_argument("--iid-prior", action="store_true",
                   help="envelope: independent initial errors per run (default: each point's draws whitened "
                        "so that their second moment is exactly the prior the PCRB starts from)")
    p.add_argument("--without", action="append", default=[], choices=sorted(RULES), metavar="RULE",
                   help="switch one linearization rule of the radio filters off (repeatable), to show which "
                        "cells it holds: " + ", ".join(f"{k} ({v})" for k, v in sorted(RULES.items())))
    p.set_defaults(func=run)


# the radio filters' linearization rules (aircraft/navigator/radio/tuning.py: RULES) and the height
# floor: `larns bench aircraft --envelope --without RULE` measures what each one holds
RULES = {
    "floor": "height-floor truncation",
    "iterate": "iterated update",
    "second-order": "EKF second-order range terms",
    "repeats": "linearization error counted as repeating",
    "inverse": "inverse-range coordinates far out",
    "lag": "lagged Jacobian near the array",
    "weakest": "lag along the weakest direction (else the height)",
}


def without(tuning, rules) -> object:
    """``tuning`` with each rule named in ``rules`` switched off (:data:`RULES`; "floor": no floor)."""
    rules = list(rules)
    if not rules:
        return tuning
    out = tuning.without(*rules)
    return replace(out, floor_z_m=None) if "floor" in rules else out


def _progress(msg: str) -> None:
    print(f"[bench aircraft] {msg}", file=sys.stderr, flush=True)


def setup(scenario: str):
    """Stations, clock, tuning and bench settings from the scenario's ``[aircraft]`` table."""
    from aircraft.config import from_scenario
    from net.scenario import load

    sc = load(scenario)
    return sc, from_scenario(sc)


def sync_errors_m(shape: tuple[int, int, int], sync_m: float, tau_s: float, dt_s: float,
                  rng: np.random.Generator) -> np.ndarray:
    """Residual station clock errors after the broadcast correction, as ranges (T, M, m): stationary
    first-order Gauss-Markov with sigma ``sync_m`` and correlation time ``tau_s`` (0: white)."""
    w = rng.standard_normal(shape)
    if tau_s <= 0:
        return sync_m * w
    a = np.exp(-dt_s / tau_s)
    b = np.empty(shape)
    b[0] = w[0]
    for k in range(1, shape[0]):
        b[k] = a * b[k - 1] + np.sqrt(1 - a * a) * w[k]
    return sync_m * b


def run_point(ac, kind: str, dist_m: float, runs: int, duration_s: float, warmup_s: float,
              height_m: float | None, rng: np.random.Generator, algos=ALGOS, lsq_stride: int = 4,
              sync_m: float = 0.0, sync_tau_s: float = 0.0, clock_bias: str | None = None,
              fde: bool = True) -> dict:
    """All algorithms at one point; returns rmse, pcrb (filters), nees/nis means, height, samples, timings.

    ``sync_m``, ``sync_tau_s``: the world's residual station clock errors after the broadcast
    correction (range sigma, m; first-order Gauss-Markov correlation time, s; 0 = white), broadcast
    to the aircraft as the clock variance ``sync_m^2``; the filters model them with the tuning's
    ``clock_bias`` (``clock_bias`` overrides it) and the world's correlation time, the PCRB is that of
    the world (augmented with one bias per station). NEES: navigation states (n dof), mean over the
    window, with its 95 % chi-square band treating the runs as independent. ``fde``: the filters gate,
    test and exclude stations (aircraft/navigator/radio/fde.py, the default; on clean data a gated measurement is rare)."""
    from aircraft.montecarlo import radio as sim
    from aircraft.navigator.radio.fde import FdeConfig
    from aircraft.world import trajectory
    from aircraft.navigator.radio.tuning import CLOCK_BIAS_TAU_S

    dt = 1.0 / ac.world.rate_hz
    t = np.arange(0.0, duration_s, dt)
    cfg = dict(ac.world.trajectories.get(kind, {}), kind=kind, distance_m=dist_m)
    track = trajectory.from_config(cfg, t, ac.world.centre_m, height_m)
    rho = sim.pseudoranges(track, ac.world.stations_m, ac.world.clock, ac.world.sigma_m, runs, rng)
    cvar = None  # the broadcast clock variance c^2 P_theta of every station
    tuning = ac.nav.tuning
    if sync_m > 0:
        rho = rho + sync_errors_m(rho.shape, sync_m, sync_tau_s, dt, rng)
        cvar = sync_m**2
        # the filters' model of the residual: the world's correlation time (white world: white), unless
        # ``clock_bias`` says otherwise ("states" in a white world: the tuning's own time)
        tau = sync_tau_s if clock_bias != "white" else 0.0
        if clock_bias == "states" and tau <= 0:
            tau = ac.nav.tuning.clock_bias_tau_s or CLOCK_BIAS_TAU_S
        tuning = replace(tuning, clock_bias_tau_s=tau)
    win = t >= warmup_s
    out = {"height_m": float(track.pos_m[0, 2] - ac.world.centre_m[2]), "samples": int(runs * win.sum()),
           "rmse_m": {}, "pcrb_m": {}, "nees": {}, "nis": {}, "sec_per_update_run": {}, "samples_by_algo": {},
           "median_m": {}, "rmse_se_m": {}}
    pc_cache = {}
    for algo in algos:
        method, model = algo.split("-")
        t0 = time.perf_counter()
        stride = lsq_stride if method == "lsq" else 1
        res = sim.run_algo(algo, track, ac.world.stations_m, rho, tuning, ac.world.clock, rng, lsq_stride=stride,
                           clock_var_m2=cvar, fde=FdeConfig() if fde and method != "lsq" else None)
        el = time.perf_counter() - t0
        w = win[::stride]
        out["rmse_m"][algo] = sim.rms_total(res.err_m[:, w])
        # runs are independent (epochs within a run are not): standard error of the RMSE from the
        # run-to-run spread of the per-run mean squared error (delta method)
        mse_run = np.mean(np.sum(res.err_m[:, w] ** 2, axis=-1), axis=1)
        out["rmse_se_m"][algo] = float(np.std(mse_run, ddof=1) / np.sqrt(runs) / (2.0 * out["rmse_m"][algo]))
        out["median_m"][algo] = float(np.median(np.linalg.norm(res.err_m[:, w], axis=-1)))
        out["samples_by_algo"][algo] = int(runs * w.sum())
        out["sec_per_update_run"][algo] = el / (res.err_m.shape[1] * runs)
        if method != "lsq":
            if model not in pc_cache:
                P = sim.pcrb_track(model, track, ac.world.stations_m, tuning, ac.world.clock, clock_var_m2=cvar,
                                   clock_tau_s=sync_tau_s)
                pc_cache[model] = float(np.sqrt(np.mean(np.trace(P[win], axis1=1, axis2=2))))
            out["pcrb_m"][algo] = pc_cache[model]
            out["nees"][algo] = float(np.mean(res.nees[:, win]))
            n_dof = 6 + (2 if model == "pr" else 0)
            from scipy import stats

            band = stats.chi2.ppf([0.025, 0.975], runs * n_dof) / runs
            out.setdefault("nees_band", {})[algo] = [float(v) for v in band]
            out["nis"][algo] = float(np.mean(res.nis[:, win]))
    out["samples"] = min(out["samples_by_algo"].values())
    return out


def speed_vs_filterpy(ac, steps: int = 400, runs: int = 64) -> dict:
    """Time per UKF-PR update (predict + update) of ours vs filterpy's UnscentedKalmanFilter.

    Same problem (seed001 stations, hover 1000 m, 100 Hz, same tuning, same measurements), with
    filterpy told to redraw sigma points after its prediction (``sigmas_f`` from the predicted x, P) as
    seed 001's correction step does. Returns times and the max state difference.
    """
    from dataclasses import replace

    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    from aircraft.montecarlo import radio as sim
    from aircraft.navigator.radio import models as mdl
    from aircraft.navigator.radio.tracker import CvTracker
    from aircraft.world import trajectory

    # filterpy's UKF is the plain one: compare the same algorithm (no iterated update, no repeated
    # linearization term in R)
    tun = without(ac.nav.tuning, RULES)
    dt = 1.0 / ac.world.rate_hz
    t = np.arange(steps) * dt
    track = trajectory.from_config({"kind": "hover", "distance_m": 1000.0}, t, ac.world.centre_m)
    rng = np.random.default_rng(7)
    rho = sim.pseudoranges(track, ac.world.stations_m, ac.world.clock, ac.world.sigma_m, runs, rng)
    layout = mdl.StateLayout("pr", drift=True)
    x0 = sim.true_state(track, ac.world.clock, layout)[0] + 5.0
    S = ac.world.stations_m
    F = mdl.cv_transition(layout.n, dt)
    Q = mdl.cv_noise(layout.n, dt, tun.q_acc, tun.q_clock, tun.q_drift)

    pts = MerweScaledSigmaPoints(layout.n, alpha=tun.alpha, beta=2.0, kappa=0.0)
    fp = UnscentedKalmanFilter(dim_x=layout.n, dim_z=S.shape[0], dt=dt, points=pts,
                               fx=lambda x, dt_: F @ x, hx=lambda x: mdl.h_pr(x, S))
    fp.x = x0.copy()
    fp.P = tun.prior_cov(layout).copy()
    fp.Q = Q
    fp.R = np.eye(S.shape[0]) * tun.sigma_m**2
    ours = CvTracker("ukf", "pr", x0, tun)  # one run: (n,) state, small-matrix path
    diff = scale = 0.0
    t_fp = t_one = 0.0
    for k in range(steps):
        a = time.perf_counter()
        if k:
            fp.predict()
            fp.sigmas_f = pts.sigma_points(fp.x, fp.P)
        else:
            fp.sigmas_f = pts.sigma_points(fp.x, fp.P)
        fp.update(rho[k, 0])
        b = time.perf_counter()
        ours.predict_to(t[k])
        ours.update(S, rho[k, 0])
        c = time.perf_counter()
        t_fp += b - a
        t_one += c - b
        diff = max(diff, float(np.max(np.abs(ours.x - fp.x))))
        scale = max(scale, float(np.max(np.abs(fp.x))))
    # the bench's own tuning (iterated update, ``iterations`` passes) on one run, for reference
    tun_it = replace(ac.nav.tuning, floor_z_m=None)
    own = CvTracker("ukf", "pr", x0, tun_it)
    a = time.perf_counter()
    for k in range(steps):
        own.predict_to(t[k])
        own.update(S, rho[k, 0])
    t_it = time.perf_counter() - a
    batch = CvTracker("ukf", "pr", np.broadcast_to(x0, (runs, layout.n)), tun)
    a = time.perf_counter()
    for k in range(steps):
        batch.predict_to(t[k])
        batch.update(S, rho[k])
    t_batch = time.perf_counter() - a
    return {"filterpy_s_per_update": t_fp / steps, "ours_single_s_per_update": t_one / steps,
            "ours_batched_s_per_update_run": t_batch / (steps * runs), "batch_runs": runs,
            "speedup_single": t_fp / t_one, "speedup_batched": (t_fp / steps) / (t_batch / (steps * runs)),
            "ours_single_iterated_s_per_update": t_it / steps, "iterations": tun_it.iterations,
            "max_abs_state_diff": diff, "max_rel_state_diff": diff / scale, "steps": steps}


def _grid(args, b: dict):
    """``(runs, duration_s, warmup_s, hover_m, turn_m, sweep_heights_m)`` from the arguments, the
    scenario's ``bench`` section ``b`` and the defaults (``--quick``: a small version)."""
    runs = args.trials or int(b.get("runs", 64))
    duration = args.duration or float(b.get("duration_s", 30.0))
    warmup = args.warmup if args.warmup is not None else float(b.get("warmup_s", 10.0))
    hover_d = [float(d) for d in b.get("hover_m", [50, 100, 250, 500, 1000, 1500])]
    turn_d = [float(d) for d in b.get("turn_m", [500, 1000, 1500, 2000])]
    sweep_h = [float(h) for h in b.get("sweep_heights_m", [10, 25, 52.4, 100, 200, 300, 500])]
    if args.quick:
        runs = args.trials or 4
        duration = args.duration or 6.0
        warmup = args.warmup if args.warmup is not None else 2.0
        hover_d, turn_d, sweep_h = [100.0, 1000.0], [1000.0], [52.4, 300.0]
    return runs, duration, warmup, hover_d, turn_d, sweep_h


def _clock_settings(args):
    """``(clocks, sync_ns, sync_tau_s)``: station clocks on and their residual sync error."""
    from aircraft.navigator.radio.tuning import CLOCK_BIAS_TAU_S

    clocks = bool(getattr(args, "clocks", False))
    sync_ns = args.sync_ns if args.sync_ns is not None else (CLOCKS_SYNC_NS if clocks else 0.0)
    sync_tau = args.sync_tau if args.sync_tau is not None else (CLOCK_BIAS_TAU_S if clocks else 0.0)
    return clocks, sync_ns, sync_tau


def _height_sweep(ac, sweep_h, runs, duration, warmup, rng, fde: bool = True) -> dict:
    """Hover at 1000 m for each height of ``sweep_h``: the four filters."""
    sweep = {}
    for j, h in enumerate(sweep_h):
        _progress(f"height sweep {j + 1}/{len(sweep_h)}: hover 1000 m at h = {h:g} m")
        sweep[f"{h:g}"] = run_point(ac, "hover", 1000.0, runs, duration, warmup, h, rng,
                                    algos=("ekf-pr", "ukf-pr", "ekf-tdoa", "ukf-tdoa"), fde=fde)
    return sweep


def run(args) -> int:
    sc, ac = setup(args.scenario)
    ac = ac.with_tuning(without(ac.nav.tuning, getattr(args, "without", [])))
    if getattr(args, "envelope", False):
        from . import envelope as bench_aircraft_envelope

        return bench_aircraft_envelope.main(ac, args, _progress)
    runs, duration, warmup, hover_d, turn_d, sweep_h = _grid(args, ac.bench)
    if warmup >= duration:
        print("error: --warmup must be shorter than --duration", file=sys.stderr)
        return 2
    clocks, sync_ns, sync_tau = _clock_settings(args)
    if clocks and not sync_ns > 0:
        print("error: --clocks needs --sync-ns > 0", file=sys.stderr)
        return 2
    fde = not getattr(args, "no_fde", False)
    rng = np.random.default_rng(args.seed)
    rng_perfect = np.random.default_rng(args.seed)  # same draws; the clock world adds its biases after them
    t_start = time.perf_counter()
    res = {"hover": {}, "turn": {}}
    res_perfect = {"hover": {}, "turn": {}}
    points = [("hover", d) for d in hover_d] + [("turn", d) for d in turn_d]
    for i, (kind, d) in enumerate(points):
        _progress(f"{i + 1}/{len(points)} {kind} {d:g} m ({runs} runs x {duration:g} s)")
        if clocks:
            res_perfect[kind][f"{d:g}"] = run_point(ac, kind, d, runs, duration, warmup, args.height, rng_perfect,
                                                    fde=fde)
        res[kind][f"{d:g}"] = run_point(ac, kind, d, runs, duration, warmup, args.height, rng,
                                        sync_m=sync_ns * 0.299792458, sync_tau_s=sync_tau,
                                        clock_bias=getattr(args, "clock_bias", None), fde=fde)
    sweep = {} if args.no_sweep else _height_sweep(ac, sweep_h, runs, duration, warmup, rng, fde)
    speed = None if args.no_speed else speed_vs_filterpy(ac, steps=100 if args.quick else 400)
    if speed is not None:
        from .livecpu import live_core_cpu

        _progress("live core CPU")
        speed["live_core"] = live_core_cpu(sc, ac, seconds=5.0 if args.quick else 20.0)
    wall = time.perf_counter() - t_start

    out = _assemble(res, sweep, speed, runs, duration, warmup, args, ac, wall,
                    bar=BAR_CLOCKS if sync_ns > 0 else BAR)
    out["settings"]["sync_ns"], out["settings"]["sync_tau_s"] = sync_ns, sync_tau
    out["settings"]["clock_bias"] = getattr(args, "clock_bias", None) or ac.nav.tuning.clock_bias
    out["settings"]["fde"] = fde
    if clocks:
        out["perfect_clocks"] = _assemble(res_perfect, {}, None, runs, duration, warmup, args, ac, wall)
    _print_table(out)
    if clocks:
        _print_clocks(out)
    write_outputs(out, args, _plots)
    return 0


def write_outputs(doc: dict, args, plots) -> None:
    """``--json`` and ``--png-dir`` of an aircraft bench: the document and ``plots(doc, dir)``."""
    if args.json:
        with open(args.json, "w") as f:
            json.dump(doc, f, indent=1)
        _progress(f"wrote {args.json}")
    if args.png_dir:
        for p in plots(doc, args.png_dir):
            _progress(f"wrote {p}")


def _assemble(res, sweep, speed, runs, duration, warmup, args, ac, wall, bar: float = BAR) -> dict:
    BAR = bar  # noqa: N806 - the bar of this table
    out = {"rmse_m": {}, "median_m": {}, "pcrb_m": {}, "ratio": {}, "nees": {}, "nis": {}, "height_m": {}, "samples": {},
           "paper_m": PAPER, "bar": {"factor": BAR, "algos": ["ekf-pr", "ukf-pr"], "violations": [], "significant": [],
                                     "nees_above_band": []},
           "ratio_se": {}, "nees_band": {}}
    for kind, pts in res.items():
        for key in ("rmse_m", "median_m", "pcrb_m", "ratio", "ratio_se", "nees", "nis", "nees_band"):
            out[key][kind] = {}
        out["height_m"][kind] = {d: p["height_m"] for d, p in pts.items()}
        out["samples"][kind] = {d: p["samples"] for d, p in pts.items()}
        for d, p in pts.items():
            for algo, v in p["rmse_m"].items():
                out["rmse_m"][kind].setdefault(algo, {})[d] = v
            for algo, v in p["median_m"].items():
                out["median_m"][kind].setdefault(algo, {})[d] = v
            for algo, v in p["pcrb_m"].items():
                out["pcrb_m"][kind].setdefault(algo, {})[d] = v
                r = p["rmse_m"][algo] / v
                se = p["rmse_se_m"][algo] / v
                out["ratio"][kind].setdefault(algo, {})[d] = r
                out["ratio_se"][kind].setdefault(algo, {})[d] = se
                if algo in ("ekf-pr", "ukf-pr") and r > BAR:
                    out["bar"]["violations"].append(f"{kind} {d} m {algo}: {r:.3f} +- {1.96 * se:.3f}")
                    if r - 1.96 * se > BAR:
                        out["bar"]["significant"].append(f"{kind} {d} m {algo}")
            for algo, v in p["nees"].items():
                out["nees"][kind].setdefault(algo, {})[d] = v
                out["nis"][kind].setdefault(algo, {})[d] = p["nis"][algo]
                band = p["nees_band"][algo]
                out["nees_band"][kind].setdefault(algo, {})[d] = band
                if algo in ("ekf-pr", "ukf-pr") and v > band[1]:
                    out["bar"]["nees_above_band"].append(f"{kind} {d} m {algo}: {v:.1f} > {band[1]:.1f}")
    out["bar"]["pass"] = not out["bar"]["violations"]
    out["bar"]["pass_within_95ci"] = not out["bar"]["significant"]
    out["height_sweep"] = {
        "distance_m": 1000.0,
        "rmse_m": {h: p["rmse_m"] for h, p in sweep.items()},
        "pcrb_m": {h: p["pcrb_m"] for h, p in sweep.items()},
    }
    out["speed"] = speed
    tu = ac.nav.tuning
    out["settings"] = {
        "scenario": args.scenario, "runs": runs, "duration_s": duration, "warmup_s": warmup, "seed": args.seed,
        "rate_hz": ac.world.rate_hz, "sigma_m": ac.world.sigma_m, "clock_drift_m_s": ac.world.clock.drift_m_s,
        "height": "fixed %g m" % args.height if args.height is not None else "3 deg glide path",
        "tuning": asdict(tu),
        "quick": bool(args.quick), "wall_s": wall,
        "samples_note": "samples = runs x epochs after warm-up; epochs within a run are correlated",
    }
    return out


def _print_table(out: dict) -> None:
    print(f"\nRMS total position error [m] vs distance; in brackets RMSE/PCRB. {HEIGHT_NOTE}")
    for kind in ("hover", "turn"):
        ds = list(out["height_m"][kind])
        if not ds:
            continue
        print(f"\n{kind:<6} {'dist m':>7} {'h m':>6} {'samples':>8} " + " ".join(f"{a:>16}" for a in ALGOS))
        for d in ds:
            cells = []
            for a in ALGOS:
                v = out["rmse_m"][kind].get(a, {}).get(d)
                r = out["ratio"][kind].get(a, {}).get(d)
                cells.append(f"{v:9.2f}" + (f" ({r:4.2f})" if r is not None else "       ") if v is not None else " " * 16)
            print(f"{'':<6} {d:>7} {out['height_m'][kind][d]:6.1f} {out['samples'][kind][d]:8d} " + " ".join(cells))
    print("\nPCRB of the filter model [m]:")
    for kind in ("hover", "turn"):
        for a in ("ekf-pr", "ekf-tdoa"):
            m = "pr" if a.endswith("pr") else "tdoa"
            vals = out["pcrb_m"][kind].get(a, {})
            if vals:
                print(f"  {kind:<6} {m:<5} " + "  ".join(f"{d}: {v:.2f}" for d, v in vals.items()))
    print("\nPaper (seed 001) vs ours at 1000 m:")
    for kind in ("hover", "turn"):
        for a in ("ukf-pr", "ukf-tdoa"):
            ours = out["rmse_m"][kind].get(a, {}).get("1000")
            ptxt = PAPER[kind][a]["1000"]
            print(f"  {kind:<6} {a:<9} paper ~{ptxt:5.0f} m   ours " + (f"{ours:7.2f} m" if ours else "   n/a"))
    hs = out["height_sweep"]["rmse_m"]
    if hs:
        print("\nHeight sweep, hover at 1000 m: RMSE [m] (PCRB)")
        for h, r in hs.items():
            pc = out["height_sweep"]["pcrb_m"][h]
            print(f"  h = {h:>5} m  " + "  ".join(f"{a} {r[a]:7.2f} ({pc[a]:.2f})" for a in r))
    if out["speed"]:
        _print_speed(out["speed"])
    bar = out["bar"]
    BAR = bar["factor"]  # noqa: N806
    print(f"\nBar: RMSE <= {BAR} x PCRB for ekf-pr and ukf-pr at every point: "
          + ("PASS" if bar["pass"] else "FAIL: " + "; ".join(bar["violations"])))
    print("     (+- = 95 % interval of the ratio from the run-to-run spread; "
          + ("no violation is significant" if bar["pass_within_95ci"]
             else "significant: " + "; ".join(bar["significant"])) + ")")
    print("     mean NEES above its 95 % band (pr filters): "
          + ("none" if not bar["nees_above_band"] else "; ".join(bar["nees_above_band"])))
    print(f"wall time {out['settings']['wall_s']:.0f} s")



def _print_speed(sp: dict) -> None:
    """The speed section: UKF-PR against filterpy, and the live core's CPU."""
    print(f"\nUKF-PR update (predict+update): filterpy {sp['filterpy_s_per_update'] * 1e6:.0f} us, "
          f"ours single {sp['ours_single_s_per_update'] * 1e6:.0f} us (x{sp['speedup_single']:.1f}), "
          f"ours batched {sp['ours_batched_s_per_update_run'] * 1e6:.1f} us/run over {sp['batch_runs']} runs "
          f"(x{sp['speedup_batched']:.0f}); max |x_ours - x_filterpy| = {sp['max_abs_state_diff']:.2e} m "
          f"(relative {sp['max_rel_state_diff']:.1e}) over {sp['steps']} steps")
    if sp.get("ours_single_iterated_s_per_update"):
        print(f"  ours single with the bench tuning ({sp['iterations']} update passes): "
              f"{sp['ours_single_iterated_s_per_update'] * 1e6:.0f} us")
    lc = sp.get("live_core")
    if lc:
        print(f"Live core (larns/bench/livecpu.py, no Zenoh shell), {lc['broadcasts_per_s']:.0f} broadcasts/s: "
              f"{' + '.join(lc['algos'])} {lc['all_pct_of_core']:.1f} % of one core "
              f"({lc['messages_per_s']:.0f} messages/s); alone: "
              + ", ".join(f"{a} {v:.1f} %" for a, v in lc["each_pct_of_core"].items()))


def _print_clocks(out: dict) -> None:
    """Perfect clocks beside station clocks: RMSE/PCRB (each world's own PCRB), PCRB, mean NEES."""
    pf, st = out["perfect_clocks"], out["settings"]
    print(f"\nStation clocks on ({st['sync_ns']:g} ns, Gauss-Markov tau {st['sync_tau_s']:g} s, filters: "
          f"{st['clock_bias']}) beside perfect clocks, same draws. RMSE/PCRB (+- 95 %), PCRB m, mean NEES [band]")
    hdr = (f"{'point':<12} {'algo':<9} {'perfect':>14} {'PCRB':>7} {'NEES':>7}   "
           f"{'clocks':>14} {'PCRB':>7} {'NEES':>7} {'band':>13}")
    print(hdr)
    for kind in ("hover", "turn"):
        for d in out["height_m"][kind]:
            for a in FILTERS:
                c = [o["ratio"][kind].get(a, {}).get(d) for o in (pf, out)]
                if c[1] is None:
                    continue
                se = [o["ratio_se"][kind][a][d] * 1.96 for o in (pf, out)]
                pc = [o["pcrb_m"][kind][a][d] for o in (pf, out)]
                ne = [o["nees"][kind][a][d] for o in (pf, out)]
                band = out["nees_band"][kind][a][d]
                print(f"{kind + ' ' + d:<12} {a:<9} {c[0]:6.2f} +-{se[0]:5.2f} {pc[0]:7.2f} {ne[0]:7.1f}   "
                      f"{c[1]:6.2f} +-{se[1]:5.2f} {pc[1]:7.2f} {ne[1]:7.1f} [{band[0]:.1f}, {band[1]:.1f}]")


def _plots(out: dict, png_dir: str) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import os

    import matplotlib.pyplot as plt

    os.makedirs(png_dir, exist_ok=True)
    paths = []
    for kind, fig_no in (("hover", 4), ("turn", 5)):
        ds = list(out["height_m"][kind])
        if not ds:
            continue
        x = [float(d) for d in ds]
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.8))
        for a in ALGOS:
            y = [out["rmse_m"][kind][a][d] for d in ds]
            (a2 if a.startswith("lsq") else a1).plot(x, y, "o-", label=a)
            if a.startswith("lsq") and out.get("median_m", {}).get(kind, {}).get(a):
                a2.plot(x, [out["median_m"][kind][a][d] for d in ds], "s--", lw=0.8, label=f"{a} median |e|")
            if a in ("ekf-pr", "ekf-tdoa"):
                pc = [out["pcrb_m"][kind][a][d] for d in ds]
                a1.plot(x, pc, "k--" if a.endswith("pr") else "k:", lw=1, label=f"PCRB {a.split('-')[1]}")
        for a, mk in (("ukf-pr", "*"), ("ukf-tdoa", "X")):
            a1.plot([1000.0], [PAPER[kind][a]["1000"]], mk, ms=12, color="red", label=f"paper {a}")
        a1.set_title(f"filters ({kind}, cf. seed 001 Fig. {fig_no}a)")
        a2.set_title("snapshot LSQ")
        a2.set_yscale("log")
        for ax in (a1, a2):
            ax.set_xlabel("distance from the circle centre, m")
            ax.set_ylabel("RMS total error, m")
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=7)
        fig.suptitle(f"{kind}: {HEIGHT_NOTE}; {out['settings']['runs']} runs x "
                     f"{out['settings']['duration_s']:g} s", fontsize=9)
        p = os.path.join(png_dir, f"aircraft_fig{fig_no}_{kind}.png")
        fig.tight_layout()
        fig.savefig(p, dpi=110)
        plt.close(fig)
        paths.append(p)
    hs = out["height_sweep"]
    if hs["rmse_m"]:
        hh = [float(h) for h in hs["rmse_m"]]
        fig, ax = plt.subplots(figsize=(7, 4.8))
        for a in next(iter(hs["rmse_m"].values())):
            ax.plot(hh, [hs["rmse_m"][h][a] for h in hs["rmse_m"]], "o-", label=a)
        for m, ls in (("ekf-pr", "--"), ("ekf-tdoa", ":")):
            ax.plot(hh, [hs["pcrb_m"][h][m] for h in hs["pcrb_m"]], "k" + ls, lw=1, label=f"PCRB {m.split('-')[1]}")
        ax.axvline(1000.0 * np.tan(np.radians(3.0)), color="grey", lw=0.8)
        ax.text(1000.0 * np.tan(np.radians(3.0)), ax.get_ylim()[1] * 0.9, " 3 deg glide", fontsize=8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("aircraft height above the station plane, m")
        ax.set_ylabel("RMS total error, m")
        ax.set_title("hover at 1000 m: error vs height (seed 001 geometry)", fontsize=10)
        ax.grid(True, alpha=0.3, which="both")
        ax.legend(fontsize=8)
        p = os.path.join(png_dir, "aircraft_height_sweep.png")
        fig.tight_layout()
        fig.savefig(p, dpi=110)
        plt.close(fig)
        paths.append(p)
    return paths
