"""`larns info run.mcap`: what is in a recording, like ``ros2 bag info``.

Per file: size, whether it was finished cleanly (a SIGKILLed recording is stream-read up to the
damage), duration, start/end, metadata (scenario, epoch, speed). Per topic: message count, rate,
encoding, kinds. Stations and aircraft found (last state, estimator / algorithms). Loss statistics
from the ``seq`` field (per sender and kind: a gap between two recorded sequence numbers is a
message the recorder never got), duplicates, undecodable payloads, and latency ``log_time -
publish_time`` (receive time minus the sender's stamp) per kind.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import Counter, defaultdict
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Sequence


def _pct(v: list[float], q: float) -> float:
    if not v:
        return math.nan
    v = sorted(v)
    return v[min(len(v) - 1, max(0, int(round(q / 100.0 * (len(v) - 1)))))]


def summarize(paths: Sequence[str | Path], logs=None) -> dict[str, Any]:
    """Everything ``larns info`` prints, as a JSON-able dict."""
    from net import messages as M

    from .mcaputil import merge, read_logs

    logs = logs if logs is not None else read_logs(paths)
    msgs = merge(logs)
    files = []
    for lg in logs:
        files.append({"path": str(lg.path), "bytes": lg.path.stat().st_size, "complete": lg.complete,
                      "error": lg.error, "messages": len(lg.messages), "library": lg.library,
                      "metadata": lg.metadata})
    out: dict[str, Any] = {"files": files, "messages": len(msgs)}
    if not msgs:
        out.update(duration_s=0.0, topics={}, stations={}, aircraft={}, loss={}, latency_ms={})
        return out
    t0, t1 = msgs[0].log_time, msgs[-1].log_time
    dur = (t1 - t0) * 1e-9
    out["start"] = datetime.fromtimestamp(t0 * 1e-9, timezone.utc).isoformat()
    out["end"] = datetime.fromtimestamp(t1 * 1e-9, timezone.utc).isoformat()
    out["duration_s"] = dur
    speed = logs[0].speed
    out["speed"] = speed
    out["fleet_duration_s"] = dur * speed
    ep = logs[0].epoch_unix_s
    if ep is not None:  # fleet time (seconds since the fleet epoch) of the first and last message
        out["fleet_start_s"] = (t0 * 1e-9 - ep) * speed
        out["fleet_end_s"] = (t1 * 1e-9 - ep) * speed

    topics: dict[str, dict] = {}
    seqs: dict[tuple, list[int]] = defaultdict(list)
    lat: dict[str, list[float]] = defaultdict(list)
    invalid = Counter()
    stations: dict[int, dict] = {}
    aircraft: dict[str, dict] = {}
    for m in msgs:
        t = topics.get(m.topic)
        if t is None:
            t = topics[m.topic] = {"count": 0, "bytes": 0, "encoding": m.encoding, "kinds": Counter(),
                                   "first_ns": m.log_time, "last_ns": m.log_time}
        t["count"] += 1
        t["bytes"] += len(m.data)
        t["last_ns"] = m.log_time
        if m.encoding != "msgpack":
            t["kinds"][m.schema or m.encoding] += 1
            continue
        try:
            msg, _ = M.decode(m.data)
        except M.MessageError as e:
            invalid[e.reason] += 1
            t["kinds"]["invalid"] += 1
            continue
        kind = msg["kind"]
        t["kinds"][kind] += 1
        seqs[(msg["src"], kind)].append(msg["seq"])
        if m.publish_time != m.log_time:
            lat[kind].append((m.log_time - m.publish_time) * 1e-6)
        src = msg["src"]
        if isinstance(src, int):
            s = stations.setdefault(src, {"messages": 0})
            s["messages"] += 1
            if kind == "estimate":
                s.update(state=msg["state"], estimator=msg["estimator"], n_updates=msg["n_updates"],
                         slot=msg.get("slot"), dropped=msg.get("dropped"), last_t_s=msg["t_s"],
                         sigma_m=math.sqrt(max(sum(msg["cov_m2"][i][i] for i in range(3)), 0.0)),
                         pos_m=msg["pos_m"])
                if "clock_offset_s" in msg:
                    s.setdefault("_clk", {})[msg["stamp_s"]] = (msg["t_s"], msg["clock_offset_s"])
            elif kind == "truth":
                s["truth_m"] = msg["pos_m"]
                if "clock_error_s" in msg:
                    s.setdefault("_clk_true", {})[msg["stamp_s"]] = msg["clock_error_s"]
            elif kind == "nav":
                s["navs"] = s.get("navs", 0) + 1
                s["ranges"] = s.get("ranges", 0) + len(msg["ranges"])
            elif kind in ("core_init", "core_input"):
                s["journal"] = True
            elif kind == "integrity":  # the peers this station excludes now (its latest decision)
                s["excludes"] = sorted(msg.get("excluded", []))
        else:
            a = aircraft.setdefault(src, {"messages": 0, "algos": set()})
            a["messages"] += 1
            if kind == "ac_estimate":
                a["algos"].add(msg["algo"])
    for s in stations.values():
        if "pos_m" in s and "truth_m" in s:
            s["err_m"] = math.dist(s["pos_m"], s["truth_m"])
        sync_summary(s, s.pop("_clk", {}), s.pop("_clk_true", {}))
        if s.get("navs"):
            s["exchanges_pct"] = 100.0 * s["ranges"] / s["navs"]  # own slots whose exchange completed
    for sid, s in stations.items():  # integrity: which stations exclude this one
        by = [o for o, v in stations.items() if sid in v.get("excludes", ())]
        if by:
            s["excluded_by"] = by
    for a in aircraft.values():
        a["algos"] = sorted(a["algos"])
    for name, t in topics.items():
        span = (t["last_ns"] - t["first_ns"]) * 1e-9
        t["rate_hz"] = (t["count"] - 1) / span if span > 0 and t["count"] > 1 else 0.0
        t["kinds"] = dict(t["kinds"])
    loss: dict[str, dict] = {}
    tot = Counter()
    for (src, kind), ss in sorted(seqs.items(), key=lambda kv: (str(kv[0][0]), kv[0][1])):
        uniq = sorted(set(ss))
        expected = uniq[-1] - uniq[0] + 1
        missing = expected - len(uniq)
        dup = len(ss) - len(uniq)
        reordered = sum(1 for a, b in zip(ss, ss[1:]) if b < a)
        d = loss.setdefault(kind, {"senders": 0, "received": 0, "missing": 0, "duplicates": 0,
                                   "reordered": 0, "leading": 0})
        d["senders"] += 1
        d["received"] += len(uniq)
        d["missing"] += missing
        d["duplicates"] += dup
        d["reordered"] += reordered
        d["leading"] += max(0, uniq[0] - 1)  # sent before the recorder heard the sender (if seq starts at 1)
        tot.update(received=len(uniq), missing=missing, duplicates=dup)
    for d in loss.values():
        n = d["received"] + d["missing"]
        d["loss_pct"] = 100.0 * d["missing"] / n if n else 0.0
    out["topics"] = dict(sorted(topics.items()))
    out["stations"] = dict(sorted(stations.items()))
    out["aircraft"] = dict(sorted(aircraft.items()))
    out["loss"] = loss
    n = tot["received"] + tot["missing"]
    out["loss_total"] = {**dict(tot), "loss_pct": 100.0 * tot["missing"] / n if n else 0.0}
    out["invalid"] = dict(invalid)
    out["latency_ms"] = {k: {"n": len(v), "p50": _pct(v, 50), "p99": _pct(v, 99), "max": max(v)}
                         for k, v in sorted(lat.items())}
    return out


def _size(n: float) -> str:
    for u in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or u == "GiB":
            return f"{n:.1f} {u}" if u != "B" else f"{int(n)} B"
        n /= 1024
    return str(n)


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
    st = s["stations"]
    if st:
        L.append(f"Stations:          {len(st)}  ids {','.join(map(str, st))}")
        L.append(f"  {'id':>5} {'state':>9} {'estimator':>9} {'updates':>7} {'sigma m':>8} {'error m':>8} "
                 f"{'journal':>7} {'dropped':>7} {'xchg %':>7} {'sync ns':>8} {'rms60 ns':>8} {'max60 ns':>8}")
        for sid, v in st.items():
            L.append(f"  {sid:>5} {v.get('state', '-'):>9} {v.get('estimator', '-'):>9} {v.get('n_updates', 0):>7} "
                     f"{v.get('sigma_m', math.nan):>8.2f} {v.get('err_m', math.nan):>8.2f} "
                     f"{'yes' if v.get('journal') else 'no':>7} {v.get('dropped') if v.get('dropped') is not None else '-':>7} "
                     f"{v.get('exchanges_pct', math.nan):>7.1f} {v.get('sync_ns', math.nan):>8.2f} "
                     f"{v.get('sync_rms_ns_after_60s', math.nan):>8.2f} "
                     f"{v.get('sync_max_ns_after_60s', math.nan):>8.2f}")
        for sid, v in st.items():
            if v.get("excluded_by"):
                L.append(f"  integrity: station {sid} EXCLUDED by {','.join(map(str, v['excluded_by']))}")
    ac = s["aircraft"]
    L.append(f"Aircraft:          {len(ac)}" + ("  " + ", ".join(f"{k} ({', '.join(v['algos']) or 'no estimates'})"
                                                               for k, v in ac.items()) if ac else ""))
    L.append("Topics:")
    w = max(len(k) for k in s["topics"])
    for k, t in s["topics"].items():
        kinds = ",".join(t["kinds"])
        L.append(f"  {k:<{w}}  {t['count']:>7} msgs  {t['rate_hz']:>8.2f} Hz  {t['encoding']:<8} {kinds}")
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
    if s["latency_ms"]:
        L.append("Latency (log_time - publish_time, wall ms):")
        for k, d in s["latency_ms"].items():
            L.append(f"  {k:<12} n={d['n']:<7} p50={d['p50']:8.2f}  p99={d['p99']:8.2f}  max={d['max']:8.2f}")
    return "\n".join(L)


def cmd_info(args: argparse.Namespace) -> int:
    try:
        s = summarize(args.files)
    except (OSError, ValueError) as e:
        print(f"larns info: {e}", file=sys.stderr)
        return 1
    try:
        if args.json:
            print(json.dumps(s, default=str, indent=1))
        else:
            print(format_info(s))
        sys.stdout.flush()
    except BrokenPipeError:  # `larns info run.mcap | head`
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0


def register(sub) -> None:
    p = sub.add_parser(
        "info", help="summarize an MCAP recording (like ros2 bag info)",
        description="Duration, message counts and rates per key, stations and aircraft found, loss "
                    "(sequence gaps), duplicates and latency. Works on recordings that were killed "
                    "(no summary section): the file is stream-read up to the damage.")
    p.add_argument("files", nargs="+", help="MCAP file(s); several are merged by log time")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=cmd_info)


def sync_summary(s: dict, est: dict, true: dict, after_s: float = 60.0) -> None:
    """Clock sync error of one station from its ``estimate`` and ``truth`` of the same stamp: the last
    (``sync_ns``), the RMS and the largest magnitude after ``after_s`` fleet seconds, in ns."""
    pairs = sorted((est[k][0], (est[k][1] - true[k]) * 1e9) for k in est.keys() & true.keys())
    if not pairs:
        return
    s["sync_ns"] = pairs[-1][1]
    late = [e for t, e in pairs if t >= after_s]
    if late:
        s["sync_max_ns_after_60s"] = max(abs(e) for e in late)
        s["sync_rms_ns_after_60s"] = math.sqrt(sum(e * e for e in late) / len(late))
