"""`larns info run.mcap`: what is in a recording, like ``ros2 bag info`` (numbers from
:func:`larns.analysis.summary.summarize`)."""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any


def _size(n: float) -> str:
    for u in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or u == "GiB":
            return f"{n:.1f} {u}" if u != "B" else f"{int(n)} B"
        n /= 1024
    return str(n)


def aircraft_lines(ac: dict) -> list[str]:
    """The aircraft found, then one line per aircraft algorithm (:func:`aircraft_line`)."""
    head = f"Aircraft:          {len(ac)}" + ("  " + ", ".join(f"{k} ({', '.join(v['algos']) or 'no estimates'})"
                                                             for k, v in ac.items()) if ac else "")
    return [head] + [aircraft_line(name, algo, r) for name, v in ac.items() for algo, r in v.get("accuracy", {}).items()]


def aircraft_line(name: str, algo: str, r: dict) -> str:
    """One aircraft algorithm: first estimate, time to 10 m / 3 m horizontal, final and worst (from 30 s)
    horizontal error, NEES from 30 s, statuses."""
    def t(v):
        return "-" if v is None else f"{v:.1f}s"

    st = " ".join(f"{k}={n}" for k, n in r.get("statuses", {}).items())
    if not r.get("n"):
        return f"  {name} {algo}: no estimate published  [{st}]"
    late = ("max from 30 s -, NEES - (run shorter than 30 s)" if r.get("max_eh_window_m") is None else
            f"max from 30 s {r['max_eh_window_m']:.2f} m, NEES {_num(r.get('nees_mean'), '.2f', 0)}")
    return (f"  {name} {algo}: {r['n']} estimates, first at {t(r.get('first_t_s'))}, <10 m from {t(r.get('t_10m_s'))}, "
            f"<3 m from {t(r.get('t_3m_s'))}, final horizontal {r['final_eh_m']:.2f} m (sigma {r['final_sigma_h_m']:.2f}), "
            f"{late}  [{st}]")


def vehicle_line(name: str, v: dict) -> str:
    """One ground vehicle of ``larns info``: its position error against its truth."""
    if "rms_err_m" not in v:
        return f"Vehicle {name}:      {v['estimates']} estimates, none matched with a truth"
    return (f"Vehicle {name}:      {v['estimates']} estimates to t = {v['t_end_s']:.1f} s; position error RMS "
            f"{v['rms_err_m']:.2f} m (second half {v['rms_err_second_half_m']:.2f} m), p95 {v['p95_err_m']:.2f} m, "
            f"max {v['max_err_m']:.2f} m, final {v['final_err_m']:.2f} m (sigma {v['final_sigma_m']:.2f} m); "
            f"journal {'yes' if v['journal'] else 'no'}")


SYNC_AFTER_S = 60.0  # the window of the rms60 / max60 columns (larns.analysis.summary.sync_summary)


def _num(v: Any, fmt: str, width: int) -> str:
    """``v`` formatted, or ``-`` (right-aligned in ``width``) when it is missing or not finite."""
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return f"{'-':>{width}}"
    return f"{v:>{width}{fmt}}"


def station_lines(s: dict[str, Any]) -> list[str]:
    """The station table: one row per station. The ``rms60`` / ``max60`` columns (clock error after
    60 s fleet time) say ``run shorter than 60 s`` when the station's recorded clock series ends
    before then (a 60 s run's last sample is at 59.x s)."""
    st = s["stations"]
    if not st:
        return []
    L = [f"Stations:          {len(st)}  ids {','.join(map(str, st))}",
         f"  {'id':>5} {'state':>9} {'estimator':>9} {'updates':>7} {'sigma m':>8} {'error m':>8} "
         f"{'journal':>7} {'dropped':>7} {'xchg %':>7} {'sync ns':>8} {'rms60 ns':>8} {'max60 ns':>8}"]
    for sid, v in st.items():
        if "sync_rms_ns_after_60s" in v:
            late = f"{_num(v['sync_rms_ns_after_60s'], '.2f', 8)} {_num(v['sync_max_ns_after_60s'], '.2f', 8)}"
        elif v.get("sync_t_s", SYNC_AFTER_S) < SYNC_AFTER_S:
            late = "  run shorter than 60 s"
        else:
            late = f"{'-':>8} {'-':>8}"
        L.append(f"  {sid:>5} {v.get('state', '-'):>9} {v.get('estimator', '-'):>9} {v.get('n_updates', 0):>7} "
                 f"{_num(v.get('sigma_m'), '.2f', 8)} {_num(v.get('err_m'), '.2f', 8)} "
                 f"{'yes' if v.get('journal') else 'no':>7} {v.get('dropped') if v.get('dropped') is not None else '-':>7} "
                 f"{_num(v.get('exchanges_pct'), '.1f', 7)} {_num(v.get('sync_ns'), '.2f', 8)} {late}")
    polls = {sid: v["polls_complete_pct"] for sid, v in st.items() if v.get("polls")}
    if polls:
        worst = min(polls, key=polls.get)
        L.append(f"  exchanges complete (a poll answered by every member it named; a request answered): "
                 f"{min(polls.values()):.1f} % (station {worst}) .. {max(polls.values()):.1f} %")
    for sid, v in st.items():
        if v.get("excluded_by"):
            L.append(f"  integrity: station {sid} EXCLUDED by {','.join(map(str, v['excluded_by']))}")
    return L


def topic_lines(topics: dict[str, dict]) -> list[str]:
    """The topics grouped (stations, aircraft, vehicle, other; :func:`larns.analysis.summary.topic_group`),
    each group in natural order (1, 2, 10)."""
    from larns.analysis.summary import TOPIC_GROUPS, natural_key, topic_group

    if not topics:
        return ["Topics:            none"]
    groups: dict[str, list[str]] = {g: [] for g in TOPIC_GROUPS}
    for k in topics:
        groups[topic_group(k)].append(k)
    w = max(len(k) for k in topics)
    L = [f"Topics:            {len(topics)}  (" + ", ".join(f"{g} {len(v)}" for g, v in groups.items() if v) + ")"]
    for g, keys in groups.items():
        if not keys:
            continue
        L.append(f"  {g}:")
        for k in sorted(keys, key=natural_key):
            t = topics[k]
            L.append(f"    {k:<{w}}  {t['count']:>7} msgs  {t['rate_hz']:>8.2f} Hz  {t['encoding']:<8} "
                     + ",".join(t["kinds"]))
    return L


def format_info(s: dict[str, Any]) -> str:
    L = []
    for f in s["files"]:
        state = "complete" if f["complete"] else f"INCOMPLETE (stream-read up to the damage: {f['error']})"
        L.append(f"Files:             {f['path']}  {_size(f['bytes'])}  {f['messages']} messages  {state}")
        md = f["metadata"].get("larns", {})
        if md:
            L.append("Metadata:          " + ", ".join(f"{k}={v}" for k, v in sorted(md.items())))
    L.append(f"Messages:          {s['messages']}")
    if not s["messages"]:
        return "\n".join(L)
    L.append(f"Duration:          {s['duration_s']:.3f} s wall  ({s['fleet_duration_s']:.1f} s fleet time at speed "
             f"{s['speed']:g})")
    if "fleet_start_s" in s:
        L.append(f"Fleet time:        {s['fleet_start_s']:.2f} s .. {s['fleet_end_s']:.2f} s since the fleet epoch")
    L.append(f"Start:             {s['start']}")
    L.append(f"End:               {s['end']}")
    L += station_lines(s)
    L += aircraft_lines(s["aircraft"])
    L += [vehicle_line(name, v) for name, v in s.get("vehicles", {}).items()]
    L += topic_lines(s["topics"])
    L.append("Loss (sequence gaps per sender and kind):")
    L.append(f"  {'kind':<12} {'senders':>7} {'received':>8} {'missing':>7} {'loss %':>7} {'dup':>5} "
             f"{'reorder':>7} {'leading':>7}")
    for k, d in s["loss"].items():
        L.append(f"  {k:<12} {d['senders']:>7} {d['received']:>8} {d['missing']:>7} {d['loss_pct']:>7.2f} "
                 f"{d['duplicates']:>5} {d['reordered']:>7} {d['leading']:>7}")
    lt = s["loss_total"]
    L.append(f"  {'total':<12} {'':>7} {lt['received']:>8} {lt['missing']:>7} {lt['loss_pct']:>7.2f} "
             f"{lt['duplicates']:>5}")
    if s["invalid"]:
        L.append("Undecodable:       " + ", ".join(f"{k}: {v}" for k, v in s["invalid"].items()))
    L += refused_lines(s.get("refused", []), s.get("verified", False))
    if s["latency_ms"]:
        L.append("Latency (log_time - publish_time, wall ms):")
        for k, d in s["latency_ms"].items():
            L.append(f"  {k:<12} n={d['n']:<7} p50={d['p50']:8.2f}  p99={d['p99']:8.2f}  max={d['max']:8.2f}")
    return "\n".join(L)


def refused_lines(refused: list[dict], verified: bool) -> list[str]:
    """Messages attributed to nobody: their ``src`` is not the key's publisher, or (with
    ``--keystore``) their signature does not hold."""
    how = "by key and signer" if verified else "by key (--keystore DIR: also by signer)"
    if not refused:
        return [f"Attribution:       every message {how}"]
    L = [f"Refused:           {sum(r['count'] for r in refused)} messages not attributed ({how}):"]
    L += [f"  {r['key']}  src {r['src']}: {r['reason']} x{r['count']}" for r in refused[:20]]
    if len(refused) > 20:
        L.append(f"  ... {len(refused) - 20} more (--json)")
    return L


def cmd_info(args: argparse.Namespace) -> int:
    from larns.analysis.summary import dumps_strict, summarize

    ks = None
    if getattr(args, "keystore", None):
        from net.security import Keystore, KeystoreError

        try:
            ks = Keystore(args.keystore)
        except KeystoreError as e:
            print(f"larns info --keystore: {e}", file=sys.stderr)
            return 2
    try:
        s = summarize(args.files, keystore=ks)
    except (OSError, ValueError) as e:
        print(f"larns info: {e}", file=sys.stderr)
        return 1
    try:
        if args.json:
            print(dumps_strict(s, indent=1))
        else:
            print(format_info(s))
        sys.stdout.flush()
    except BrokenPipeError:  # `larns info run.mcap | head`
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0


def register(sub) -> None:
    from .helptext import Formatter, examples

    p = sub.add_parser(
        "info", help="summarize an MCAP recording (like ros2 bag info)",
        description="Duration, message counts and rates per key, stations and aircraft found, loss "
                    "(sequence gaps), duplicates and latency. Works on recordings that were killed "
                    "(no summary section): the file is stream-read up to the damage.",
        formatter_class=Formatter, epilog=examples(
            "larns info runs/demo.mcap",
            "larns info --json runs/a.mcap runs/b.mcap",
        ))
    p.add_argument("files", nargs="+", help="MCAP file(s); several are merged by log time")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--keystore", metavar="DIR", default=None,
                   help="also attribute messages by signer: refuse those whose signature does not hold "
                        "against DIR's CA and certificates (docs/security.md)")
    p.set_defaults(func=cmd_info)


