"""`larns bench wire`: messages a station process receives per second against the field's size.

For each ``--sizes`` N a square-ish grid of N stations ``--spacing-m`` apart on flat ground (10 m
masts) with a weak radio (``[radio] tx_power_dbm``: at -7 dBm links reach 2.4 km, 2.4 spacings of the
default grid) is written as a
scenario and run as a real local fleet (``larns fleet``, one process per station, peer mesh or
router) for ``--duration`` fleet seconds at ``--speed``. Each station counts every sample its Zenoh
bus delivers (navs, range requests and replies addressed to it) and prints the count and the fleet
seconds since its power-on in its last line (the navs still waiting in its ring buffers at the stop, at
most a cycle's, are not counted); the table gives the mean over the stations per fleet
second, beside what the geometry predicts (senders on the tiles it subscribes to, itself included,
net/tiles.py) and the radio's real neighbours. With ``--compare`` every field runs a second time
with ``LARNS_NAV_TILES=off`` (every station subscribes to every tile: the wire before tiles).
"""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

_BUS = re.compile(r"\[station (\d+)\] stopped: .*?bus_rx=(\d+) in ([\d.]+) s")


def register(sub) -> None:
    p = sub.add_parser(
        "wire",
        help="messages received per station process per second for fields of N stations (tiles on/off)",
        description=__doc__.split("\n\n")[1].replace("\n", " ")
        + " Run it alone on the machine where possible: a loaded host delays drains, not counts.",
    )
    p.add_argument("--sizes", default="20,40", help="station counts, comma-separated")
    p.add_argument("--spacing-m", type=float, default=1000.0, help="grid spacing, m")
    p.add_argument("--tx-power-dbm", type=float, default=-7.0, help="[radio] tx_power_dbm of the fields")
    p.add_argument("--tile-m", type=float, default=None, help="[radio] tile_m (default: derived, net/tiles.py)")
    p.add_argument("--duration", type=float, default=30.0, help="fleet seconds per run")
    p.add_argument("--speed", type=float, default=0.5, help="fleet speed (below 1 on a small host)")
    p.add_argument("--topology", choices=("peer", "router"), default="peer", help="larns fleet --topology")
    p.add_argument("--compare", action="store_true", help="also run each field with every tile subscribed")
    p.add_argument("--json", metavar="FILE", default="bench-out/wire.json", help="JSON output ('' to skip)")
    p.add_argument("--png-dir", metavar="DIR", default="bench-out/wire", help="PNG folder ('' to skip)")
    p.add_argument("--keep", metavar="DIR", default=None, help="keep the scenarios and logs here")
    p.set_defaults(func=main)


def grid_positions(n: int, spacing_m: float) -> list[list[float]]:
    """``n`` grid points (rows of ``nx``, ``ny = round(sqrt(n / 1.6))`` rows), stations 1-3 on a
    corner (not collinear: they define the network frame)."""
    ny = max(2, int(round(math.sqrt(n / 1.6))))
    nx = math.ceil(n / ny)
    pts = [[i * spacing_m, j * spacing_m, 0.0] for j in range(ny) for i in range(nx)][:n]
    first = [pts[0], pts[1], pts[nx]]
    return first + [p for p in pts if p not in first]


def field_toml(n: int, spacing_m: float, tx_power_dbm: float, tile_m: float | None) -> str:
    lines = [f'name = "wire-{n}"',
             f'description = "larns bench wire: {n} stations on a {spacing_m:g} m grid, {tx_power_dbm:g} dBm radio"',
             "seed = 1", ""]
    for i, p in enumerate(grid_positions(n, spacing_m)):
        lines += ["[[stations]]", f"id = {i + 1}", f"pos_m = [{p[0]:.1f}, {p[1]:.1f}, {p[2]:.1f}]", ""]
    lines += ["[radio]", f"tx_power_dbm = {tx_power_dbm:g}"]
    if tile_m is not None:
        lines.append(f"tile_m = {tile_m:g}")
    return "\n".join(lines) + "\n"


def geometry(path: Path) -> dict:
    """What the field's geometry predicts: per station the radio's neighbours, the tiles it subscribes
    to and the stations on them (itself included: its own navs come back to it)."""
    from net import radio as R
    from net.scenario import load
    from net.tiles import Tiling

    scn = load(path)
    til = Tiling.of(scn)
    pos = np.asarray(scn.pos_m, float)
    exists = R.link(pos[:, None, :], pos[None, :, :], scn.channel.radio).exists
    tiles = [til.tile(p) for p in pos]
    subs = [set(til.subscription_tiles(p) or []) for p in pos]
    return {"stations": len(pos), "tile_m": til.size_m, "reach_m": til.reach_m(pos[0]),
            "neighbours_mean": float(np.mean(exists.sum(axis=0) - 1)),
            "subscribed_tiles_mean": float(np.mean([len(s) for s in subs])),
            "senders_on_tiles_mean": float(np.mean([sum(t in s for t in tiles) for s in subs]))}


def fleet_run(path: Path, args, tiles: bool, d: Path) -> dict:
    """One fleet run; every station's bus count from its last log line."""
    tag = f"{path.stem}_{'tiles' if tiles else 'all'}"
    logs = d / f"{tag}_logs"
    env = {**os.environ, "LARNS_NAV_TILES": "on" if tiles else "off"}
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "larns", "fleet", "--scenario", str(path), "--duration", str(args.duration),
                        "--speed", str(args.speed), "--topology", args.topology, "--no-table", "--logs", str(logs),
                        "--fleet-file", str(d / f"{tag}.fleet.json")],
                       capture_output=True, text=True, timeout=900 + 4 * args.duration / args.speed, env=env)
    wall_s = time.perf_counter() - t0
    per = {}
    for f in sorted(logs.glob("*")) if logs.exists() else []:
        for m in _BUS.finditer(f.read_text(errors="replace")):
            n, s = int(m[2]), float(m[3])
            per[int(m[1])] = {"bus_rx": n, "bus_s": s, "per_s": n / s if s > 0 else float("nan")}
    rates = [v["per_s"] for v in per.values()]
    return {"field": path.stem, "tiles": tiles, "rc": r.returncode, "wall_s": wall_s, "stations_reported": len(per),
            "per_s_mean": float(np.mean(rates)) if rates else float("nan"),
            "per_s_min": float(np.min(rates)) if rates else float("nan"),
            "per_s_max": float(np.max(rates)) if rates else float("nan"),
            "per_station": per, "stderr_tail": r.stderr[-1500:] if r.returncode else ""}


def print_table(runs: list[dict], geo: dict, meta: dict) -> None:
    print(f"\nlarns bench wire: {meta['spacing_m']:g} m grid, {meta['tx_power_dbm']:g} dBm, {meta['duration_s']:g} "
          f"fleet-s at speed {meta['speed']:g}, topology {meta['topology']} (messages the bus delivered to a "
          "station process, per fleet second, mean over its stations)")
    hdr = ("N", "tiles", "tile_m", "sub_tiles", "on_tiles", "neighbours", "msg/s", "min", "max", "xN0", "rc")
    print("  ".join(f"{h:>10}" for h in hdr))
    base = {}
    for r in runs:
        g = geo[r["field"]]
        key = r["tiles"]
        base.setdefault(key, r["per_s_mean"])
        vals = [f"{g['stations']:10d}", f"{'on' if r['tiles'] else 'off':>10}", f"{g['tile_m']:10.0f}",
                f"{g['subscribed_tiles_mean'] if r['tiles'] else float('nan'):10.1f}",
                f"{g['senders_on_tiles_mean'] if r['tiles'] else g['stations']:10.1f}",
                f"{g['neighbours_mean']:10.1f}", f"{r['per_s_mean']:10.2f}", f"{r['per_s_min']:10.2f}",
                f"{r['per_s_max']:10.2f}", f"{r['per_s_mean'] / base[key]:10.2f}", f"{r['rc']:10d}"]
        print("  ".join(vals))


def plot(runs: list[dict], geo: dict, png_dir: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    png_dir.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for tiles, style, label in ((True, "o-", "tiles (net/tiles.py)"), (False, "s--", "every tile (LARNS_NAV_TILES=off)")):
        rs = [r for r in runs if r["tiles"] == tiles]
        if rs:
            ax.plot([geo[r["field"]]["stations"] for r in rs], [r["per_s_mean"] for r in rs], style, label=label)
    ax.set_xlabel("stations in the field (same density)")
    ax.set_ylabel("messages received per station process per fleet s")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=8)
    fig.tight_layout()
    out = png_dir / "wire.png"
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def main(args) -> int:
    sizes = [int(x) for x in args.sizes.split(",") if x.strip()]
    keep = Path(args.keep) if args.keep else None
    with tempfile.TemporaryDirectory(prefix="larns-wire-") as tmp:
        d = keep or Path(tmp)
        d.mkdir(parents=True, exist_ok=True)
        files = {}
        for n in sizes:
            files[n] = d / f"wire-{n}.toml"
            files[n].write_text(field_toml(n, args.spacing_m, args.tx_power_dbm, args.tile_m))
        geo = {f.stem: geometry(f) for f in files.values()}
        runs = []
        for tiles in ((True, False) if args.compare else (True,)):
            for n in sizes:
                print(f"fleet: {n} stations, tiles {'on' if tiles else 'off'} ...", file=sys.stderr, flush=True)
                runs.append(fleet_run(files[n], args, tiles, d))
    meta = {"sizes": sizes, "spacing_m": args.spacing_m, "tx_power_dbm": args.tx_power_dbm, "tile_m": args.tile_m,
            "duration_s": args.duration, "speed": args.speed, "topology": args.topology}
    print_table(runs, geo, meta)
    for r in runs:
        if r["rc"] != 0 or r["stations_reported"] != geo[r["field"]]["stations"]:
            print(f"{r['field']} tiles={r['tiles']}: exit {r['rc']}, {r['stations_reported']} stations reported\n"
                  f"{r['stderr_tail']}", file=sys.stderr)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps({**meta, "geometry": geo, "runs": runs}, indent=1))
        print(f"wrote {args.json}")
    if args.png_dir:
        print(f"wrote {plot(runs, geo, Path(args.png_dir))}")
    ok = all(r["rc"] == 0 for r in runs)
    return 0 if ok else 1
