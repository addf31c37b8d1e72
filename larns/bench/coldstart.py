"""`larns bench cold-start`: the aircraft's cold start, re-flown from recorded fleets.

Every real start is a cold one (docs/aircraft.md, "Cold start"): the aircraft comes up beside stations
whose clocks and positions are still converging. This bench takes fleet recordings that hold an
aircraft journal (``larns fleet --aircraft``, MCAP) and re-flies each aircraft's radio navigator from
``--starts`` start times spread over the first ``--span`` seconds of its journal. A start at ``t0``
sees the recorded broadcasts from ``t0`` on, exactly as a receiver switched on then would: the journal
re-flown whole reproduces the live estimates bit for bit (aircraft/journal.py), so a re-flight is the
live navigator, minus the wait.

Each start is scored on its **last** estimate against the recorded truth: *bad* when it is more than
``--bad-m`` off horizontally or never came (diverged, or stalled far off), *overconfident* when it is
more than ``3 sigma + 1 m`` off in 3-D (``sigma = sqrt(tr P)``), with its 3-D NEES, the time from
``t0`` to its first estimate and to the estimate from which the horizontal error stays under 3 m
(``larns info``'s "<3 m from"). ``--without`` switches a receiver rule
off (``ReceiverConfig``): what the rule holds is the difference.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

SETTLED_M = 3.0
#: receiver rules that can be switched off, as ReceiverConfig changes (aircraft/navigator/receiver.py)
RULES = {
    "survey": {"start_station_sigma_m": math.inf},  # rule 5: start on a surveyed field
    "floor": {"floor_lost_sigma": None},             # rule 3's test under the height floor
}


def register(sub) -> None:
    p = sub.add_parser("cold-start", help="the aircraft's cold start re-flown from fleet recordings: "
                                          "bad and overconfident starts, time to first estimate",
                       description=__doc__)
    p.add_argument("mcap", nargs="+", help="fleet recordings with an aircraft journal (larns fleet --aircraft)")
    p.add_argument("--algo", action="append", default=None, metavar="ALGO",
                   help="radio algorithm to re-fly (repeatable; default ukf-pr and ekf-pr)")
    p.add_argument("--starts", type=int, default=12, help="start times per recording")
    p.add_argument("--span", type=float, default=30.0,
                   help="the starts spread over this many seconds from the journal's earliest broadcast")
    p.add_argument("--bad-m", type=float, default=10.0, help="a start whose last estimate is further off horizontally is bad")
    p.add_argument("--without", action="append", default=[], type=_rules, metavar="RULE[,RULE]",
                   help="also re-fly with these receiver rules off (repeatable; comma-separated: together): "
                        "survey = rule 5, floor = rule 3's test under the height floor")
    p.add_argument("--json", metavar="FILE", help="write the results (every start) as JSON")
    p.add_argument("--png", metavar="FILE", help="final error against start time, per algorithm and variant")
    p.set_defaults(func=run)


def _rules(text: str) -> str:
    """A ``--without`` value: receiver rules of :data:`RULES`, comma-separated."""
    names = [w.strip() for w in text.split(",")]
    bad = [w for w in names if w not in RULES]
    if bad or not names:
        raise argparse.ArgumentTypeError(f"unknown rule {bad[0] if bad else text!r}; choose from {', '.join(sorted(RULES))}")
    return ",".join(names)


def load_journals(path: str) -> list:
    """The radio-navigable aircraft journals of one recording (:class:`AircraftJournal`, with truth)."""
    from larns.analysis.offline import JOURNAL_TOPICS, collect_aircraft
    from larns.log import merge, read_logs

    logs = read_logs([path], topics=[t for t in JOURNAL_TOPICS if t.startswith("larns/aircraft/")])
    return [a for a in collect_aircraft(merge(logs)).values() if a.init is not None and a.truth]


def refly(record: dict, name: str, entries: list[list], algo: str, t0_s: float, changes: dict) -> list[dict]:
    """The ``ac_estimate`` messages of ``algo`` re-flown over the ``m`` entries received from ``t0_s``
    on, with the receiver rules changed by ``changes`` (ReceiverConfig fields)."""
    from aircraft.navigator.radio.estimator import AircraftEstimator
    from aircraft.navigator.receiver import ReceiverConfig
    from aircraft.radio_core import RadioAircraftCore, estimator_config

    core = RadioAircraftCore.from_record(record, name, (algo,))
    if changes:
        cfg = estimator_config(record)
        cfg = replace(cfg, receiver=replace(cfg.receiver or ReceiverConfig(), **changes))
        core.estimators[algo] = AircraftEstimator(algo, cfg)
    out = []
    for e in entries:
        if e[0] == "m" and e[1] >= t0_s:
            out += [ev.to_msg() for ev in core.measurement(*e[1:]) if ev.kind == "ac_estimate"]
    return out


def score(ests: list[dict], truth_at, t0_s: float) -> dict:
    """One start: its last estimate's 3-D and horizontal errors, sigma ``sqrt(tr P)`` and 3-D NEES, the
    time from ``t0_s`` to its first estimate and to the first estimate from which the horizontal error
    stays under :data:`SETTLED_M` (as ``larns info``; NaN where it never did)."""
    from larns.analysis.metrics import first_time_staying_below
    from nav.kalman import nees

    rows = [(e, truth_at(e["t_s"])) for e in ests]
    rows = [(e, p) for e, p in rows if p is not None]
    if not rows:
        return {"t0_s": t0_s, "n": 0, "err_m": math.nan, "eh_m": math.nan, "sigma_m": math.nan,
                "nees": math.nan, "first_s": math.nan, "settled_s": math.nan}
    d = np.array([np.subtract(e["pos_m"], p) for e, p in rows])
    eh = np.hypot(d[:, 0], d[:, 1])
    t = np.array([e["t_s"] for e, _p in rows])
    cov = np.asarray(rows[-1][0]["cov_m2"], float)
    try:
        nees_last = float(nees(d[-1], cov))
    except np.linalg.LinAlgError:
        nees_last = math.inf
    settled = first_time_staying_below(t, eh, SETTLED_M)
    return {"t0_s": t0_s, "n": len(rows), "err_m": float(np.linalg.norm(d[-1])), "eh_m": float(eh[-1]),
            "sigma_m": math.sqrt(max(float(np.trace(cov)), 0.0)), "nees": nees_last,
            "first_s": float(t[0] - t0_s), "settled_s": math.nan if settled is None else settled - t0_s}


def summarize(rows: list[dict], bad_m: float) -> dict:
    """Counts and medians over the starts of one algorithm and variant."""
    err = np.array([r["err_m"] for r in rows])
    sig = np.array([r["sigma_m"] for r in rows])
    none = ~np.isfinite(err)
    bad = none | (np.array([r["eh_m"] for r in rows]) > bad_m)
    over = ~none & (err > 3.0 * sig + 1.0)

    def med(key):
        v = np.array([r[key] for r in rows], float)
        v = v[np.isfinite(v)]
        return float(np.median(v)) if len(v) else math.nan

    fin = np.array([r["eh_m"] for r in rows])[~none]
    return {"starts": len(rows), "no_estimate": int(none.sum()), "bad": int(bad.sum()),
            "overconfident": int(over.sum()), "median_eh_m": med("eh_m"),
            "p90_eh_m": float(np.percentile(fin, 90)) if len(fin) else math.nan,
            "median_nees": med("nees"), "median_first_s": med("first_s"),
            "median_settled_s": med("settled_s"),
            "never_settled": int(sum(not math.isfinite(r["settled_s"]) for r in rows))}


def run(args) -> int:
    from larns.analysis.offline import _truth_at
    from larns.bench.progress import Progress

    algos = args.algo or ["ukf-pr", "ekf-pr"]
    variants = {"rules": {}} | {f"without {w}": {k: v for r in w.split(",") for k, v in RULES[r].items()}
                                for w in args.without}
    flights = []
    for path in args.mcap:
        if not Path(path).is_file():
            print(f"error: {path}: no such file", file=sys.stderr)
            return 2
        try:
            journals = load_journals(path)
        except ValueError as e:  # not an MCAP file: its one line, exit 2
            print(f"error: {e}", file=sys.stderr)
            return 2
        for a in journals:
            entries, _hole, _n = a.contiguous()
            ms = [e[1] for e in entries if e[0] == "m"]
            if ms:
                flights.append((path, a, entries, min(ms)))  # the earliest reception (out-of-order arrivals)
    if not flights:
        print("error: no aircraft journal with truth in " + ", ".join(args.mcap)
              + " (record a fleet with its aircraft: larns fleet --aircraft --record FILE)", file=sys.stderr)
        return 2
    t_wall = time.perf_counter()
    offsets = np.linspace(0.0, args.span, args.starts)
    bar = Progress(len(flights) * len(offsets) * len(algos) * len(variants), "re-flying starts")
    rows: dict[str, dict[str, list]] = {v: {x: [] for x in algos} for v in variants}
    for path, a, entries, t_first in flights:
        truth_at = _truth_at(a.truth)
        for off in offsets:
            for v, changes in variants.items():
                for x in algos:
                    r = score(refly(a.init, a.name, entries, x, t_first + off, changes), truth_at, t_first + off)
                    rows[v][x].append({"recording": path, "aircraft": a.name, "offset_s": float(off), **r})
                    bar.update(1)
    bar.close()
    summary = {v: {x: summarize(rows[v][x], args.bad_m) for x in algos} for v in variants}
    doc = {"recordings": list(args.mcap), "flights": len(flights), "starts": args.starts, "span_s": args.span,
           "bad_m": args.bad_m, "summary": summary, "rows": rows, "wall_s": time.perf_counter() - t_wall}
    _print_table(doc)
    if args.json:
        Path(args.json).write_text(json.dumps(doc, indent=1, allow_nan=True))
        print(f"wrote {args.json}")
    if args.png:
        _plot(doc, args.png)
        print(f"wrote {args.png}")
    return 0


def _print_table(doc: dict) -> None:
    print(f"cold start: {doc['flights']} flight(s) x {doc['starts']} starts over {doc['span_s']:g} s; last estimate: "
          f"bad > {doc['bad_m']:g} m off horizontally (or none), over(confident) > 3 sigma + 1 m off in 3-D; "
          f"first estimate and horizontal error staying < {SETTLED_M:g} m: s after the start (medians)")
    head = (f"{'variant':<21} {'algo':<8} {'starts':>6} {'none':>5} {'bad':>4} {'over':>5} {'med e_h':>8} "
            f"{'p90 e_h':>8} {'med NEES':>9} {'first s':>8} {'<3 m s':>7} {'never':>6}")
    print(head)
    print("-" * len(head))
    for v, per in doc["summary"].items():
        for x, s in per.items():
            print(f"{v:<21} {x:<8} {s['starts']:>6} {s['no_estimate']:>5} {s['bad']:>4} {s['overconfident']:>5} "
                  f"{s['median_eh_m']:>8.2f} {s['p90_eh_m']:>8.2f} {s['median_nees']:>9.2f} "
                  f"{s['median_first_s']:>8.1f} {s['median_settled_s']:>7.1f} {s['never_settled']:>6}")
    print(f"({doc['wall_s']:.0f} s wall)")


def _plot(doc: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    variants = list(doc["rows"])
    algos = list(next(iter(doc["rows"].values())))
    fig, axes = plt.subplots(1, len(algos), figsize=(5 * len(algos), 4), squeeze=False, sharey=True)
    for ax, x in zip(axes[0], algos):
        for k, v in enumerate(variants):
            rows = doc["rows"][v][x]
            off = np.array([r["offset_s"] for r in rows]) + 0.15 * k
            err = np.array([r["eh_m"] if math.isfinite(r["eh_m"]) else 1e4 for r in rows])
            ax.scatter(off, np.maximum(err, 1e-2), s=14, label=v, alpha=0.7)
        ax.axhline(doc["bad_m"], color="k", lw=0.8, ls="--")
        ax.set_yscale("log")
        ax.set_xlabel("start after the first broadcast (s)")
        ax.set_title(x)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("final horizontal error (m; 1e4 = no estimate)")
    axes[0][0].legend(fontsize=8)
    fig.suptitle("aircraft cold start re-flown from recorded fleets")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
