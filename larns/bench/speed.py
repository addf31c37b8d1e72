"""`larns bench speed`: does the fleet's physics hold when it runs faster than real time?

For each world (the scenario with ``seed = k``) and each ``--speed``, a real fleet of station processes
runs for ``--duration`` fleet seconds with the recorder on; the survey's horizontal RMS error of
stations 4..n at the end is read from the MCAP alone (estimates and truth topics), and compared with
the same world at speed 1 and in the in-process simulator (the same cores and the same keyed air draws:
``net/channel.py``). Each station's own counters come from its final line (``--logs``): exchanges its
core lost (a reply not heard by the slot's end), replies handed over behind the core's clock
(``host_late``, still used) and missed slots. The table is per speed, over the worlds; so is the JSON.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

_STOPPED = re.compile(r"\[station (\d+)\] stopped: updates=(\d+) .*?host_late=(\d+) lost=(\d+) missed_slots=(\d+)")


def register(sub) -> None:
    p = sub.add_parser(
        "speed",
        help="fleet at several --speed values vs speed 1 and the simulator (same worlds, from the MCAP)",
        description=__doc__.split("\n\n")[1].replace("\n", " ")
        + " Run it alone on the machine: the fleet's timing is the quantity measured.",
    )
    p.add_argument("--scenario", default="seed000", help="scenario name or TOML path (default seed000)")
    p.add_argument("--worlds", default="1,2,3,4", help="world seeds, comma-separated (default 1,2,3,4)")
    p.add_argument("--speeds", default="1,2,5,10", help="fleet speeds, comma-separated (default 1,2,5,10)")
    p.add_argument("--stations", type=int, default=None, help="station count of the random layout")
    p.add_argument("--duration", type=float, default=60.0, help="fleet seconds per run (default 60)")
    p.add_argument("--json", metavar="FILE", default="bench-out/speed.json", help="JSON output")
    p.add_argument("--png-dir", metavar="DIR", default="bench-out/speed", help="PNG folder ('' to skip)")
    p.add_argument("--keep", metavar="DIR", default=None, help="keep the recordings and logs here")
    p.set_defaults(func=main)


def world_file(scenario: str, seed: int, stations: int | None, d: Path) -> Path:
    """The scenario's TOML with ``seed = seed`` (and ``n = stations`` in ``[layout]``) written to ``d``."""
    from net.scenario import load, resolve

    text = Path(resolve(scenario)).read_text()
    text, k = re.subn(r"(?m)^seed\s*=.*$", f"seed = {int(seed)}", text, count=1)
    if k == 0:
        text = f"seed = {int(seed)}\n" + text
    if stations is not None:
        text, k = re.subn(r"(?m)^(\[layout\][^\[]*?)^n\s*=.*$", rf"\g<1>n = {int(stations)}", text, count=1)
        if k != 1:
            raise ValueError(f"{scenario}: no 'n' key under [layout] to set the station count")
    path = d / f"world{seed}.toml"
    path.write_text(text)
    load(path)  # a clear error here rather than in ten processes
    return path


def horizontal_rms_m(pos_m: np.ndarray, truth_m: np.ndarray) -> float:
    """RMS horizontal error over stations (rows) of ``pos_m`` (n, 3) against ``truth_m`` (n, 3)."""
    e = np.asarray(pos_m, float)[:, :2] - np.asarray(truth_m, float)[:, :2]
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def fleet_run(world: Path, speed: float, duration_s: float, d: Path) -> dict:
    """One fleet run; the survey result from its MCAP and each station's final counters."""
    from larns.analysis.summary import mcap_station_summary
    from net.scenario import load

    tag = f"{world.stem}_s{speed:g}"
    rec, logs = d / f"{tag}.mcap", d / f"{tag}_logs"
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "larns", "fleet", "--scenario", str(world), "--duration", str(duration_s),
                        "--speed", str(speed), "--record", str(rec), "--no-table", "--logs", str(logs)],
                       capture_output=True, text=True, timeout=600 + 3 * duration_s)
    wall_s = time.perf_counter() - t0
    scn = load(world)
    free = [i for i in scn.ids if i >= 4]
    summ = mcap_station_summary(rec) if rec.exists() else {}
    got = [i for i in free if i in summ]
    rms = (horizontal_rms_m(np.array([summ[i]["pos_m"][-1] for i in got]), np.array([summ[i]["truth_m"] for i in got]))
           if got else float("nan"))
    counters = {}
    for f in sorted(logs.glob("*")) if logs.exists() else []:
        for m in _STOPPED.finditer(f.read_text(errors="replace")):
            sid, upd, host_late, lost, missed = (int(x) for x in m.groups())
            counters[sid] = {"updates": upd, "host_late": host_late, "lost": lost, "missed_slots": missed}
    return {"world": world.stem, "speed": speed, "rc": r.returncode, "wall_s": wall_s, "rms_h_m": rms,
            "stations_seen": len(got), "stations_free": len(free), "counters": counters}


def sim_rms_m(world: Path, duration_s: float) -> float:
    from net.scenario import load
    from stations.sim import Simulator

    scn = load(world)
    r = Simulator(scn).run(duration_s, [duration_s])
    k = [j for j, i in enumerate(r.ids) if i >= 4]
    return horizontal_rms_m(r.pos_m[-1, k], r.truth_m[k])


def summarize(runs: list[dict], sims: dict[str, float], speeds: list[float]) -> list[dict]:
    """Per speed: RMS over worlds (root of the mean square), ratios to speed 1 and to the simulator."""
    def over(rs):
        return float(np.sqrt(np.mean([r["rms_h_m"] ** 2 for r in rs]))) if rs else float("nan")

    worlds = sorted({r["world"] for r in runs})
    sim = float(np.sqrt(np.mean([sims[w] ** 2 for w in worlds])))
    base = over([r for r in runs if r["speed"] == 1.0]) if 1.0 in speeds else float("nan")
    rows = []
    for s in speeds:
        rs = [r for r in runs if r["speed"] == s]
        c = [v for r in rs for v in r["counters"].values()]
        rms = over(rs)
        rows.append({
            "speed": s, "worlds": len(rs), "rms_h_m": rms, "sim_rms_h_m": sim,
            "ratio_speed1": rms / base if base == base else None, "ratio_sim": rms / sim,
            "per_world_rms_h_m": {r["world"]: r["rms_h_m"] for r in rs},
            "updates_min": min((v["updates"] for v in c), default=0),
            "updates_max": max((v["updates"] for v in c), default=0),
            "lost": sum(v["lost"] for v in c), "host_late": sum(v["host_late"] for v in c),
            "missed_slots": sum(v["missed_slots"] for v in c),
            "all_exit_0": all(r["rc"] == 0 for r in rs),
            # within 20 % of the simulator (and of speed 1 when it ran)
            "within_20pct": bool(abs(rms / sim - 1) <= 0.2 and (base != base or abs(rms / base - 1) <= 0.2)),
        })
    return rows


def print_table(rows: list[dict], meta: dict) -> None:
    print(f"\nscenario={meta['scenario']}  stations={meta['stations']}  worlds={meta['worlds']}  "
          f"duration={meta['duration_s']:g} s  (horizontal RMS of stations 4..n at the end, from the MCAP)")
    hdr = ("speed", "rms_m", "/speed1", "/sim", "upd_min", "upd_max", "lost", "host_late", "missed", "<=20%")
    print("  ".join(f"{h:>9}" for h in hdr))
    for r in rows:
        ok = "yes" if r["within_20pct"] else "NO"
        vals = [f"{r['speed']:9g}", f"{r['rms_h_m']:9.3f}",
                f"{r['ratio_speed1']:9.2f}" if r["ratio_speed1"] is not None else f"{'-':>9}",
                f"{r['ratio_sim']:9.2f}", f"{r['updates_min']:9d}", f"{r['updates_max']:9d}", f"{r['lost']:9d}",
                f"{r['host_late']:9d}", f"{r['missed_slots']:9d}", f"{ok:>9}"]
        print("  ".join(vals))
    print(f"simulator, same worlds: {rows[0]['sim_rms_h_m']:.3f} m")


def plot(rows: list[dict], meta: dict, png_dir: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    png_dir.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    sp = [r["speed"] for r in rows]
    for w in sorted(rows[0]["per_world_rms_h_m"]):
        ax.plot(sp, [r["per_world_rms_h_m"].get(w, np.nan) for r in rows], "o-", lw=0.8, alpha=0.5, label=w)
    ax.plot(sp, [r["rms_h_m"] for r in rows], "ks-", lw=2, label="over worlds")
    ax.axhline(rows[0]["sim_rms_h_m"], color="C3", ls="--", label="simulator (same worlds)")
    ax.axhspan(0.8 * rows[0]["sim_rms_h_m"], 1.2 * rows[0]["sim_rms_h_m"], color="C3", alpha=0.1)
    ax.set_xscale("log")
    ax.set_xlabel("fleet speed (x real time)")
    ax.set_ylabel("horizontal RMS, stations 4..n (m)")
    ax.set_title(f"{meta['scenario']}, {meta['stations']} stations, {meta['duration_s']:g} s: physics vs host speed")
    ax.legend(fontsize=8)
    fig.tight_layout()
    out = png_dir / f"speed_{meta['stations']}.png"
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def main(args) -> int:
    from net.scenario import load

    from .progress import progress

    worlds = [int(x) for x in args.worlds.split(",") if x.strip()]
    speeds = [float(x) for x in args.speeds.split(",") if x.strip()]
    keep = Path(args.keep) if args.keep else None
    with tempfile.TemporaryDirectory(prefix="larns-speed-") as tmp:
        d = keep or Path(tmp)
        d.mkdir(parents=True, exist_ok=True)
        files = {w: world_file(args.scenario, w, args.stations, d) for w in worlds}
        n = len(load(files[worlds[0]]).ids)
        sims = {f.stem: sim_rms_m(f, args.duration) for f in files.values()}
        jobs = [(w, s) for s in speeds for w in worlds]
        runs = [fleet_run(files[w], s, args.duration, d) for w, s in progress(jobs, "fleet runs", total=len(jobs))]
    meta = {"scenario": args.scenario, "stations": n, "worlds": worlds, "duration_s": args.duration}
    rows = summarize(runs, sims, speeds)
    print_table(rows, meta)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps({**meta, "speeds": rows, "runs": runs, "sim_rms_h_m": sims}, indent=1))
        print(f"wrote {args.json}")
    if args.png_dir:
        print(f"wrote {plot(rows, meta, Path(args.png_dir))}")
    return 0
