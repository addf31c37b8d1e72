"""`larns bench aircraft --envelope`: the aircraft filters against their posterior CRLB over the flight
envelope (heights x horizontal distances x bearings, hover and turn), not only on the glide path.

Every point is one fixed height above the station centroid and one horizontal distance from it at one
bearing; hover stays there, turn (seed 001 trajectory no. 2) starts there at constant height. All
points of a chunk and all Monte Carlo runs ride on the leading axis of one batched filter (the
stations are shared, the filters never see the truth), so the whole envelope costs a few thousand
batched updates per filter. Per point and filter: RMS total error after the warm-up, the PCRB of the
filter's own model along the true track (``nav.pcrb``), their ratio with the 95 % interval from the
run-to-run spread (delta method on the per-run mean squared error), the mean NEES with its 95 % band.
The filters' initial errors are drawn from the prior with each point's draws matched to its second
moment (:func:`prior_draws`; ``--iid-prior`` for independent draws).
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import asdict, dataclass

import numpy as np
from scipy import stats

FILTERS = ("ekf-pr", "ukf-pr", "ekf-tdoa", "ukf-tdoa")
HEIGHTS_M = (50.0, 100.0, 200.0, 300.0, 500.0, 1000.0, 1500.0)
DISTANCES_M = (0.0, 50.0, 100.0, 250.0, 500.0, 1000.0, 2000.0)
# network-frame bearings of seed001: 225 deg is the diameter through transmitter 1 (the paper's X
# axis), 180 deg the diagonal between two transmitters (the square seen edge-on)
BEARINGS_DEG = (225.0, 180.0)
TRAJS = ("hover", "turn")
BAR = {"pr": 1.1, "tdoa": 1.2}
QUICK = dict(heights=(100.0, 500.0), dists=(0.0, 250.0), bearings=(225.0,), trajs=("hover", "turn"),
             runs=4, duration_s=4.0, warmup_s=2.0)


@dataclass(frozen=True)
class Point:
    traj: str
    height_m: float
    dist_m: float
    bearing_deg: float

    @property
    def key(self) -> str:
        return f"{self.traj} h{self.height_m:g} d{self.dist_m:g} az{self.bearing_deg:g}"


def points(heights=HEIGHTS_M, dists=DISTANCES_M, bearings=BEARINGS_DEG, trajs=TRAJS) -> list[Point]:
    """The envelope's points; at distance 0 the bearing only sets the turn's heading, so one suffices."""
    return [Point(tr, float(h), float(d), float(az)) for tr in trajs for h in heights for d in dists
            for az in (bearings[:1] if d == 0 else bearings)]


def _tracks(ac, pts: list[Point], t: np.ndarray):
    from aircraft.world import trajectory

    out = []
    for p in pts:
        cfg = dict(ac.world.trajectories.get(p.traj, {}), kind=p.traj, distance_m=p.dist_m, azimuth_deg=p.bearing_deg)
        out.append(trajectory.from_config(cfg, t, ac.world.centre_m, p.height_m))
    return out


def _pcrb(model: str, tracks, ac, win: np.ndarray) -> np.ndarray:
    """RMS over the window of the position PCRB of the filter's own model, one value per track (K,)."""
    from aircraft.montecarlo import radio as sim
    from aircraft.navigator.radio import models as mdl
    from nav.pcrb import pcrb_linear_gaussian, prior_before_first_step

    tu = ac.nav.tuning
    layout = mdl.StateLayout(model, drift=model == "pr")
    xt = np.stack([sim.true_state(tr, ac.world.clock, layout) for tr in tracks], axis=1)  # (T, K, n)
    dt = float(np.median(np.diff(tracks[0].t_s)))
    F = mdl.cv_transition(layout.n, dt)
    Q = mdl.cv_noise(layout.n, dt, tu.q_acc, tu.q_clock, tu.q_drift)
    var = mdl.range_var(xt, ac.world.stations_m, None, tu.sigma_m)
    if model == "pr":
        H, R = mdl.jac_pr(xt, ac.world.stations_m), mdl.r_pr(var)
    else:
        H, R = mdl.jac_tdoa(xt, ac.world.stations_m, 0), mdl.r_tdoa(var, 0)
    P = pcrb_linear_gaussian(prior_before_first_step(tu.prior_cov(layout), F, Q), F, Q, H, R)
    tr = np.trace(P[win, :, :3, :3], axis1=-2, axis2=-1)  # (Tw, K)
    return np.sqrt(np.mean(tr, axis=0))


def _nees(e: np.ndarray, P: np.ndarray) -> np.ndarray:
    """NEES per run (M,); a run whose covariance is not positive definite gets inf (over-confident)."""
    from nav.kalman import nees as nees_fn

    try:
        return nees_fn(e, P)
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(P)
        y = np.einsum("...ji,...j->...i", V, e)
        with np.errstate(divide="ignore", invalid="ignore"):
            out = np.sum(y**2 / w, axis=-1)
        return np.where(np.all(w > 0, axis=-1), out, np.inf)


def prior_draws(rng: np.random.Generator, points: int, runs: int, n: int = 8, matched: bool = True) -> np.ndarray:
    """Standard-normal initial-error draws, ``(points * runs, n)``, point-major.

    ``matched``: each point's ``runs`` draws are whitened so that their second moment is exactly the
    identity (``Z^T Z / runs = I``, Cholesky whitening), so the filters start with errors whose
    second moment is exactly the prior ``P0`` the PCRB starts from. Where the bound is the prior (a
    direction the broadcasts do not observe within the run) an iid draw makes the ratio a ~1-dof
    sample per run; matched draws remove that sampling error and leave the filter's own. The
    whitening is lower-triangular, so any leading block of columns (the TDOA state is the first 6 of
    the 8) is matched too. Needs ``runs > n``; otherwise the draws are iid.
    """
    z = rng.standard_normal((points, runs, n))
    if matched and runs > n:
        from scipy.linalg import solve_triangular

        L = np.linalg.cholesky(np.einsum("kri,krj->kij", z, z) / runs)  # (points, n, n)
        z = np.stack([solve_triangular(Lk, zk.T, lower=True).T for Lk, zk in zip(L, z)])
    return z.reshape(points * runs, n)


def run_chunk(ac, pts: list[Point], runs: int, duration_s: float, warmup_s: float, rng: np.random.Generator,
              algos=FILTERS, nees_stride: int = 5, matched_prior: bool = True) -> list[dict]:
    """All filters at the points ``pts`` (one batched filter per algorithm: K points x runs).

    Returns one dict per (point, algo) with the envelope's fields.
    """
    from aircraft.montecarlo import radio as sim
    from aircraft.navigator.radio import models as mdl
    from aircraft.navigator.radio.tracker import CvTracker
    dt = 1.0 / ac.world.rate_hz
    t = np.arange(0.0, duration_s, dt)
    win = t >= warmup_s
    K, T, S = len(pts), t.size, ac.world.stations_m
    tracks = _tracks(ac, pts, t)
    # pseudoranges (T, K*runs, m), point-major on the run axis
    rho = np.concatenate([sim.pseudoranges(tr, S, ac.world.clock, ac.world.sigma_m, runs, rng) for tr in tracks],
                         axis=1)
    idx = np.repeat(np.arange(K), runs)
    z0 = prior_draws(rng, K, runs, 8, matched_prior)  # common random numbers for the filters' initial errors
    pc = {m: _pcrb(m, tracks, ac, win) for m in sorted({a.split("-")[1] for a in algos})}
    out = []
    for algo in algos:
        method, model = algo.split("-")
        layout = mdl.StateLayout(model, drift=model == "pr")
        xt = np.stack([sim.true_state(tr, ac.world.clock, layout) for tr in tracks], axis=0)[idx]  # (M, T, n)
        P0 = ac.nav.tuning.prior_cov(layout)
        x0 = xt[:, 0] + z0[:, : layout.n] @ np.linalg.cholesky(P0).T
        trk = CvTracker(method, model, x0, ac.nav.tuning, t0_s=float(t[0]))
        sse = np.zeros(K * runs)
        nees_sum = np.zeros(K * runs)
        n_nees = 0
        t0 = time.perf_counter()
        for k in range(T):
            trk.predict_to(float(t[k]))
            trk.update(S, rho[k])
            if win[k]:
                e = trk.x - xt[:, k]
                sse += np.einsum("mi,mi->m", e[:, :3], e[:, :3])
                if k % nees_stride == 0:
                    nees_sum += _nees(e, trk.P)
                    n_nees += 1
        el = time.perf_counter() - t0
        mse = (sse / win.sum()).reshape(K, runs)
        nees_run = (nees_sum / max(n_nees, 1)).reshape(K, runs)
        lo, hi = stats.chi2.ppf([0.025, 0.975], runs * layout.n) / runs
        for i, p in enumerate(pts):
            rmse = float(np.sqrt(mse[i].mean()))
            se = float(np.std(mse[i], ddof=1) / np.sqrt(runs) / (2.0 * rmse)) if runs > 1 else float("nan")
            b = float(pc[model][i])
            r = rmse / b
            out.append({
                "traj": p.traj, "height_m": p.height_m, "dist_m": p.dist_m, "bearing_deg": p.bearing_deg,
                "algo": algo, "rmse_m": rmse, "pcrb_m": b, "ratio": r,
                "ratio_ci": [r - 1.96 * se / b, r + 1.96 * se / b],
                "nees_mean": float(nees_run[i].mean()), "nees_band": [float(lo), float(hi)], "n_states": layout.n,
                "nees_max_run": float(nees_run[i].max()), "runs": runs,
                "sec_per_update_run": el / (T * K * runs),
            })
    return out


def check_bar(entries: list[dict]) -> dict:
    """Bar of issue 17: RMSE <= 1.1 x PCRB (pr; no violation significant at 95 %), mean NEES inside
    its band or below (pr filters); difference filters RMSE <= 1.2 x PCRB."""
    viol, sig, nees_bad = [], [], []
    for e in entries:
        model = e["algo"].split("-")[1]
        f = BAR[model]
        tag = f"{e['traj']} h{e['height_m']:g} d{e['dist_m']:g} az{e['bearing_deg']:g} {e['algo']}"
        if e["ratio"] > f:
            viol.append(f"{tag}: {e['ratio']:.2f} [{e['ratio_ci'][0]:.2f}, {e['ratio_ci'][1]:.2f}]")
            if e["ratio_ci"][0] > f:
                sig.append(tag)
        if model == "pr" and e["nees_mean"] > e["nees_band"][1]:
            nees_bad.append(f"{tag}: NEES {e['nees_mean']:.1f} > {e['nees_band'][1]:.1f}")
    return {"factor": BAR, "violations": viol, "significant": sig, "nees_above_band": nees_bad,
            "pass": not viol and not nees_bad, "pass_within_95ci": not sig and not nees_bad}


def run_envelope(ac, runs: int, duration_s: float, warmup_s: float, seed: int, heights=HEIGHTS_M,
                 dists=DISTANCES_M, bearings=BEARINGS_DEG, trajs=TRAJS, algos=FILTERS, chunk: int = 16,
                 progress=None, matched_prior: bool = True) -> dict:
    """The whole envelope, chunk by chunk; returns the JSON document (``envelope`` list + ``bar``)."""
    rng = np.random.default_rng(seed)
    pts = points(heights, dists, bearings, trajs)
    entries = []
    t0 = time.perf_counter()
    for c in range(0, len(pts), chunk):
        part = pts[c : c + chunk]
        if progress:
            progress(f"envelope {c + 1}-{c + len(part)}/{len(pts)} ({runs} runs x {duration_s:g} s, "
                     f"{time.perf_counter() - t0:.0f} s so far)")
        entries += run_chunk(ac, part, runs, duration_s, warmup_s, rng, algos, matched_prior=matched_prior)
    wall = time.perf_counter() - t0
    return {"envelope": entries, "bar": check_bar(entries),
            "settings": {"runs": runs, "duration_s": duration_s, "warmup_s": warmup_s, "seed": seed,
                         "heights_m": list(heights), "dists_m": list(dists), "bearings_deg": list(bearings),
                         "trajs": list(trajs), "algos": list(algos), "rate_hz": ac.world.rate_hz,
                         "sigma_m": ac.world.sigma_m,
                         "tuning": asdict(ac.nav.tuning),
                         "wall_s": wall, "points": len(pts),
                         "prior_draws": "matched" if matched_prior and runs > 8 else "iid",
                         "ratio_ci": "95 % from the run-to-run spread (delta method on per-run MSE); with "
                                     "matched prior draws conservative (the spread still holds the prior "
                                     "draw that the matching takes out of the mean)",
                         "nees_band": "chi2 95 % band of the mean of `runs` independent NEES (n dof each)"}}


def print_table(doc: dict, file=sys.stdout) -> None:
    """One block per trajectory and bearing: rows height, columns distance, cells ratio per filter."""
    env = doc["envelope"]
    s = doc["settings"]
    algos = s["algos"]
    print(f"\nEnvelope: RMSE / PCRB per filter ({', '.join(algos)}); {s['runs']} runs x {s['duration_s']:g} s, "
          f"warm-up {s['warmup_s']:g} s, {s.get('prior_draws', 'iid')} prior draws; '*' = above the bar, "
          "'!' = significant at 95 %, '#' = mean NEES above its band", file=file)
    look = {(e["traj"], e["height_m"], e["dist_m"], e["bearing_deg"], e["algo"]): e for e in env}
    for traj in s["trajs"]:
        for az in s["bearings_deg"]:
            print(f"\n{traj}, bearing {az:g} deg (distance 0: bearing {s['bearings_deg'][0]:g})", file=file)
            print(f"{'h m':>6} {'d m':>6} " + " ".join(f"{a:>15}" for a in algos) + f" {'PCRB pr':>9} {'PCRB tdoa':>9}",
                  file=file)
            for h in s["heights_m"]:
                for d in s["dists_m"]:
                    a0 = s["bearings_deg"][0] if d == 0 else az
                    if d == 0 and az != s["bearings_deg"][0]:
                        continue
                    cells, pcs = [], {}
                    for a in algos:
                        e = look.get((traj, h, d, a0, a))
                        if e is None:
                            cells.append(" " * 15)
                            continue
                        m = a.split("-")[1]
                        pcs[m] = e["pcrb_m"]
                        flag = ("!" if e["ratio_ci"][0] > BAR[m] else "*" if e["ratio"] > BAR[m] else " ")
                        flag += "#" if e["nees_mean"] > e["nees_band"][1] else " "
                        cells.append(f"{e['ratio']:5.2f}{flag} n{e['nees_mean']:6.1f}")
                    print(f"{h:6g} {d:6g} " + " ".join(cells)
                          + f" {pcs.get('pr', float('nan')):9.2f} {pcs.get('tdoa', float('nan')):9.2f}", file=file)
    bar = doc["bar"]
    print(f"\nBar (pr RMSE <= {BAR['pr']} x PCRB, tdoa <= {BAR['tdoa']} x, pr mean NEES <= band): "
          + ("PASS" if bar["pass"] else f"{len(bar['violations'])} ratio violations, "
             f"{len(bar['significant'])} significant at 95 %, {len(bar['nees_above_band'])} NEES above band"),
          file=file)
    for v in bar["violations"]:
        print(f"  ratio {v}", file=file)
    for v in bar["nees_above_band"]:
        print(f"  {v}", file=file)
    print(f"envelope wall time {s['wall_s']:.0f} s ({s['points']} points)", file=file)


def heatmaps(doc: dict, png_dir: str) -> list[str]:
    """One PNG per filter: RMSE / PCRB over height x distance, a panel per trajectory and bearing."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import TwoSlopeNorm

    os.makedirs(png_dir, exist_ok=True)
    s = doc["settings"]
    look = {(e["traj"], e["height_m"], e["dist_m"], e["bearing_deg"], e["algo"]): e for e in doc["envelope"]}
    H, D = s["heights_m"], s["dists_m"]
    paths = []
    panels = [(tr, az) for tr in s["trajs"] for az in s["bearings_deg"]]
    for algo in s["algos"]:
        f = BAR[algo.split("-")[1]]
        fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 4.2), squeeze=False)
        im = None
        for ax, (tr, az) in zip(axes[0], panels):
            A = np.full((len(H), len(D)), np.nan)
            for i, h in enumerate(H):
                for j, d in enumerate(D):
                    e = look.get((tr, h, d, s["bearings_deg"][0] if d == 0 else az, algo))
                    if e is not None:
                        A[i, j] = e["ratio"]
                        ax.text(j, i, f"{e['ratio']:.2f}", ha="center", va="center", fontsize=7,
                                fontweight="bold" if e["ratio_ci"][0] > f else "normal")
            im = ax.imshow(A, origin="lower", cmap="RdBu_r", norm=TwoSlopeNorm(1.0, 0.5, 2.0), aspect="auto")
            ax.set_xticks(range(len(D)), [f"{d:g}" for d in D])
            ax.set_yticks(range(len(H)), [f"{h:g}" for h in H])
            ax.set_xlabel("horizontal distance from the centroid, m")
            ax.set_ylabel("height, m")
            ax.set_title(f"{tr}, bearing {az:g} deg", fontsize=9)
        fig.colorbar(im, ax=axes[0].tolist(), shrink=0.8, label="RMSE / PCRB")
        fig.suptitle(f"{algo}: RMSE / PCRB (bar {f}); bold = above the bar at 95 %; {s['runs']} runs x "
                     f"{s['duration_s']:g} s", fontsize=10)
        p = os.path.join(png_dir, f"aircraft_envelope_{algo}.png")
        fig.savefig(p, dpi=100)
        plt.close(fig)
        paths.append(p)
    return paths


def main(ac, args, progress) -> int:
    """Entry from ``larns bench aircraft --envelope``."""
    b = ac.bench
    if args.quick:
        q = QUICK
        kw = dict(heights=q["heights"], dists=q["dists"], bearings=q["bearings"], trajs=q["trajs"])
        runs = args.trials or q["runs"]
        duration = args.duration or q["duration_s"]
        warmup = args.warmup if args.warmup is not None else q["warmup_s"]
    else:
        kw = dict(heights=tuple(float(x) for x in b.get("envelope_heights_m", HEIGHTS_M)),
                  dists=tuple(float(x) for x in b.get("envelope_dists_m", DISTANCES_M)),
                  bearings=tuple(float(x) for x in b.get("envelope_bearings_deg", BEARINGS_DEG)))
        runs = args.trials or int(b.get("envelope_runs", 12))
        duration = args.duration or float(b.get("envelope_duration_s", 16.0))
        warmup = args.warmup if args.warmup is not None else float(b.get("envelope_warmup_s", 6.0))
    if warmup >= duration:
        print("error: --warmup must be shorter than --duration", file=sys.stderr)
        return 2
    doc = run_envelope(ac, runs, duration, warmup, args.seed, progress=progress,
                       matched_prior=not getattr(args, "iid_prior", False), **kw)
    doc["settings"]["scenario"] = args.scenario
    doc["settings"]["quick"] = bool(args.quick)
    print_table(doc)
    from .aircraft import write_outputs

    write_outputs(doc, args, heatmaps)
    return 0
