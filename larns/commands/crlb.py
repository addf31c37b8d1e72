"""`larns crlb`: Cramer-Rao bound maps of one TDMA cycle (seed 003, eqs. 1-7).

For every point of a horizontal grid at a fixed height, the Fisher information of the aircraft's
position and velocity at the start of a TDMA cycle (every station transmits once, in its own slot,
while the aircraft moves uniformly) is inverted; the horizontal ``sqrt(var x + var y)`` and vertical
``sqrt(var z)`` bounds are drawn as PNG maps and summarized by distance from the station area.
The numbers are :mod:`larns.analysis.crlb`, the figure :mod:`larns.viz.crlb`; this is the argparse
adapter (defaults from the scenario's ``[aircraft.crlb]``, the printed table, the JSON file).
"""

from __future__ import annotations

import json
import sys

import numpy as np

from nav.geometry import SPEED_OF_LIGHT_M_S


DESCRIPTION = """\
Cramer-Rao bound maps of one TDMA cycle (seed 003, eqs. 1-7): for every point of a horizontal grid
at a fixed height, the best accuracy any unbiased estimator can reach for an aircraft that hears
every station once, in its own slot, while it flies uniformly. Draws the horizontal
sqrt(var x + var y) and vertical sqrt(var z) bounds as a PNG (two maps) and prints them by distance
from the station area (docs/aircraft.md).

Options not given come from the scenario's [aircraft.crlb] table, then from the defaults below;
`larns scenario validate FILE` checks that table."""


def register(sub) -> None:
    from .helptext import add_parser

    p = add_parser(
        sub, "crlb",
        help="CRLB maps (horizontal / vertical) of one TDMA cycle over an area (seed 003)",
        description=DESCRIPTION,
        example=["larns crlb                                   # seed003, 1000 m, position + velocity: crlb.png",
                 "larns crlb --height 3000 --params pos --clock --png crlb_pos.png",
                 "larns crlb --scenario seed000 --step 2000 --png seed000.png --json seed000.json"],
    )
    p.add_argument("--scenario", default="seed003", help="scenario name or file (default seed003)")
    p.add_argument("--height", type=float, default=None, help="aircraft height above station 1, m (default 1000)")
    p.add_argument("--sigma-t-ns", type=float, default=None, help="timing noise, ns (default 3)")
    p.add_argument("--slot-s", type=float, default=None, help="TDMA slot length, s (default: scenario [tdma])")
    p.add_argument("--velocity", type=float, nargs=3, default=None, metavar=("VX", "VY", "VZ"),
                   help="aircraft velocity during the cycle, m/s (default 50 0 0)")
    p.add_argument("--params", choices=("posvel", "pos"), default=None,
                   help="estimated parameters: posvel = position and velocity (seed 003) or pos = position "
                        "only (default posvel)")
    p.add_argument("--clock", action="store_true", help="also estimate a receiver clock offset (pseudoranges)")
    p.add_argument("--extent", type=float, nargs=4, default=None, metavar=("X0", "X1", "Y0", "Y1"),
                   help="map area in the network frame, m (default: station area +- 35 km)")
    p.add_argument("--step", type=float, default=None, help="grid step, m (default 1000)")
    p.add_argument("--png", metavar="FILE", default="crlb.png", help="output PNG (default crlb.png)")
    p.add_argument("--json", metavar="FILE", help="write the grid and the summary as JSON")
    p.set_defaults(func=run)


# [aircraft.crlb] keys: a kind of number, a vector length, or the allowed values
CRLB_KEYS: dict[str, object] = {"height_m": "number", "sigma_t_ns": "positive", "slot_s": "positive",
                                "step_m": "positive", "velocity_m_s": 3, "extent_m": 4,
                                "params": ("posvel", "pos"), "clock": (True, False)}


def _crlb_entry(key: str, v, kind) -> str | None:
    """What is wrong with ``[aircraft.crlb] key = v`` (None: nothing)."""
    def number(x) -> bool:
        return isinstance(x, (int, float)) and not isinstance(x, bool) and bool(np.isfinite(x))

    if isinstance(kind, tuple):
        ok = any(v is c or (isinstance(v, str) and v == c) for c in kind)
        return None if ok else f"got {v!r} (expected one of {', '.join(str(c).lower() for c in kind)})"
    if isinstance(kind, int):
        ok = isinstance(v, list) and len(v) == kind and all(number(x) for x in v)
        if ok and key == "extent_m":
            ok = v[0] < v[1] and v[2] < v[3]
        what = "[X0, X1, Y0, Y1] in m with X0 < X1, Y0 < Y1" if key == "extent_m" else f"{kind} numbers"
        return None if ok else f"got {v!r} (expected {what})"
    if not number(v) or (kind == "positive" and v <= 0):
        return f"got {v!r} (expected {'a number > 0' if kind == 'positive' else 'a finite number'})"
    return None


def crlb_settings(sc) -> dict:
    """The scenario's ``[aircraft.crlb]`` table, checked: a bad entry raises ``ScenarioError`` naming the
    file and the key (``FILE: [aircraft.crlb] params: got 'both' (expected one of posvel, pos)``)."""
    from net.scenario import ScenarioError

    cfg = sc.aircraft.get("crlb", {})
    if not isinstance(cfg, dict):
        raise ScenarioError(f"[aircraft.crlb]: got {cfg!r} (expected a table)", file=sc.source or None)
    for key, v in cfg.items():
        if key not in CRLB_KEYS:
            raise ScenarioError(f"[aircraft.crlb] {key}: unknown key (expected one of {', '.join(CRLB_KEYS)})",
                                file=sc.source or None)
        wrong = _crlb_entry(key, v, CRLB_KEYS[key])
        if wrong:
            raise ScenarioError(f"[aircraft.crlb] {key}: {wrong}", file=sc.source or None)
    return dict(cfg)


def run(args) -> int:
    from larns.analysis.crlb import compute, summary
    from larns.viz.crlb import plot_maps
    from net.scenario import load

    sc = load(args.scenario)  # a bad file: ScenarioError, one line and exit 2 (larns.cli.main)
    cfg = crlb_settings(sc)
    height = args.height if args.height is not None else float(cfg.get("height_m", 1000.0))
    sigma_t_ns = args.sigma_t_ns if args.sigma_t_ns is not None else float(cfg.get("sigma_t_ns", 3.0))
    slot = args.slot_s if args.slot_s is not None else float(cfg.get("slot_s", sc.tdma.slot_s))
    vel = args.velocity if args.velocity is not None else [float(v) for v in cfg.get("velocity_m_s", [50, 0, 0])]
    params = args.params or str(cfg.get("params", "posvel"))
    clock = bool(args.clock or cfg.get("clock", False))
    S = np.asarray(sc.pos_m, dtype=float)
    lo, hi = S[:, :2].min(axis=0), S[:, :2].max(axis=0)
    ext = args.extent or cfg.get("extent_m") or [lo[0] - 35e3, hi[0] + 35e3, lo[1] - 35e3, hi[1] + 35e3]
    step = args.step or float(cfg.get("step_m", 1000.0))
    if step <= 0 or ext[1] <= ext[0] or ext[3] <= ext[2]:
        print("error: need a positive --step and X0 < X1, Y0 < Y1", file=sys.stderr)
        return 2
    sigma_m = SPEED_OF_LIGHT_M_S * sigma_t_ns * 1e-9
    t_rel = np.arange(len(S)) * slot  # slots in station-id order, one cycle
    x, y, hz, vt, dist = compute(S, S[0, 2] + height, sigma_m, t_rel, vel, params, clock, ext, step)
    summ = summary(hz, vt, dist)
    what = f"{'position+velocity' if params == 'posvel' else 'position'}{' + clock' if clock else ''}"
    print(f"CRLB of one TDMA cycle: {len(S)} stations, {what}, h = {height:g} m, sigma_t = {sigma_t_ns:g} ns "
          f"({sigma_m:.2f} m), slot {slot:g} s, v = {vel} m/s")
    print(f"{'distance from station area':>28} {'horiz median [min..max] m':>30} {'vert median [min..max] m':>30}")
    for s in summ:
        lab = "inside" if s["band_km"][1] == 0 else f"{s['band_km'][0]:g}-{s['band_km'][1]:g} km"
        print(f"{lab:>28} {s['horiz_median_m']:10.2f} [{s['horiz_min_m']:.2f}..{s['horiz_max_m']:.2f}]"
              f"{'':>4}{s['vert_median_m']:10.2f} [{s['vert_min_m']:.2f}..{s['vert_max_m']:.2f}]")
    plot_maps(args.png, x, y, hz, vt, S, f"{sc.name}: {what}, h = {height:g} m (fixed, above station 1), "
          f"sigma_t = {sigma_t_ns:g} ns, slot {slot:g} s, v = {vel} m/s")
    print(f"wrote {args.png}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"scenario": sc.name, "height_m": height, "sigma_t_ns": sigma_t_ns, "slot_s": slot,
                       "velocity_m_s": vel, "params": params, "clock": clock, "x_m": x.tolist(), "y_m": y.tolist(),
                       "horiz_m": np.where(np.isfinite(hz), hz, -1).tolist(),
                       "vert_m": np.where(np.isfinite(vt), vt, -1).tolist(), "summary": summ}, f)
        print(f"wrote {args.json}")
    return 0
