"""What is in a recording (``larns info``, like ``ros2 bag info``), from its decoded series.

Per file: size, whether it was finished cleanly (a SIGKILLed recording is stream-read up to the
damage), duration, start/end, metadata (scenario, epoch, speed). Per topic: message count, rate,
encoding, kinds. Stations, aircraft and ground vehicles found (last state, estimator / algorithms; a
vehicle's position error against its truth). Loss statistics
from the ``seq`` field (per sender and kind: a gap between two recorded sequence numbers is a
message the recorder never got), duplicates, undecodable payloads, and latency ``log_time -
publish_time`` (receive time minus the sender's stamp) per kind.
"""

from __future__ import annotations

import json
import math
import re
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Sequence

#: topic groups of ``larns info``, in print order (:func:`topic_group`)
TOPIC_GROUPS = ("stations", "aircraft", "vehicle", "other")


def json_safe(x: Any) -> Any:
    """``x`` with every value JSON can hold strictly: non-finite floats become None (``null``, not
    ``NaN`` / ``Infinity``), numpy scalars and arrays plain numbers and lists, tuples lists, keys
    that are not str/int/float/bool strings, anything else its ``str``."""
    if x is None or isinstance(x, (bool, str)):
        return x
    if isinstance(x, dict):
        return {(k if isinstance(k, (str, int, float, bool)) else str(k)): json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, set, frozenset)):
        return [json_safe(v) for v in x]
    if hasattr(x, "tolist") and hasattr(x, "dtype"):  # numpy array or scalar
        return json_safe(x.tolist())
    if isinstance(x, int):
        return int(x)
    if isinstance(x, float):
        return float(x) if math.isfinite(x) else None
    return str(x)


def dumps_strict(obj: Any, **kw) -> str:
    """``json.dumps`` of :func:`json_safe` (``obj``) with ``allow_nan=False``: valid JSON (RFC 8259)
    that a strict parser reads."""
    return json.dumps(json_safe(obj), allow_nan=False, **kw)


def natural_key(s: str) -> list:
    """Sort key that orders the numbers inside a string by value: ``station/2`` before ``station/10``."""
    return [(0, int(p), "") if p.isdigit() else (1, 0, p) for p in re.split(r"(\d+)", s) if p]


def topic_group(topic: str) -> str:
    """Which group of :data:`TOPIC_GROUPS` a key belongs to: ``larns/station/...``, ``larns/aircraft/...``,
    ``larns/vehicle/...`` (wire traffic of a station, an aircraft, a ground vehicle); everything else
    (the Foxglove view channels, trust, liveliness) is ``other``."""
    parts = topic.split("/")
    if len(parts) > 2 and parts[0] == "larns":
        return {"station": "stations", "aircraft": "aircraft", "vehicle": "vehicle"}.get(parts[1], "other")
    return "other"


def summarize(paths: Sequence[str | Path], logs=None, rec=None, keystore=None) -> dict[str, Any]:
    """Everything ``larns info`` prints, as a JSON-able dict (from the decoded series of
    :mod:`larns.log.series`; pass ``rec`` to reuse an already decoded recording). Messages are
    attributed by key; with ``keystore`` (a :class:`net.security.Keystore`) also by signer; the
    ones refused are in ``refused`` (:func:`refused_table`) and nowhere else."""
    from ..log.reader import read_logs
    from ..log.series import Recording

    if rec is None:
        check = None
        if keystore is not None:
            from .verify import signer_check

            check = signer_check(keystore)
        rec = Recording.from_logs(logs if logs is not None else read_logs(paths), check)
    out: dict[str, Any] = {"files": [_file_info(lg) for lg in rec.logs], "messages": len(rec.messages)}
    if not rec.messages:
        out.update(duration_s=0.0, topics={}, stations={}, aircraft={}, vehicles={}, loss={}, latency_ms={})
        return out
    out.update(_times(rec))
    out["topics"] = _topics(rec.net.topics)
    out["stations"] = station_table(rec)
    out["aircraft"] = {name: aircraft_row(a) for name, a in sorted(rec.aircraft.items())}
    out["vehicles"] = {name: vehicle_row(v) for name, v in sorted(rec.vehicles.items())}
    out["loss"], out["loss_total"] = rec.net.loss()
    out["invalid"] = dict(rec.net.invalid)
    out["refused"] = refused_table(rec.net.refused)
    out["verified"] = keystore is not None
    out["latency_ms"] = rec.net.latency_summary()
    return out


def refused_table(refused) -> list[dict[str, Any]]:
    """Messages not attributed (``Recording.net.refused``), largest count first: ``[{"key",
    "src" (what the message claimed), "reason", "count"}]``."""
    return [{"key": k, "src": src, "reason": why, "count": n}
            for (k, src, why), n in sorted(refused.items(), key=lambda kv: (-kv[1], kv[0]))]


def aircraft_row(a) -> dict[str, Any]:
    """An aircraft's line of ``larns info``: per algorithm its accuracy against its own truth topic
    (:func:`larns.analysis.metrics.aircraft_accuracy`: first estimate, time to 10 m / 3 m horizontal,
    final errors, largest error and NEES from 30 s on) and how often it reported each status."""
    from .metrics import aircraft_accuracy

    tt = a.truth_track()
    acc = {}
    for algo in sorted(set(a.estimates) | set(a.statuses)):
        row = aircraft_accuracy(a.track(algo), tt) if algo in a.estimates and tt is not None else {"n": 0}
        row.pop("nees_band", None)
        counts: dict[str, int] = {}
        for st in a.statuses.get(algo, ()):
            counts[st["state"]] = counts.get(st["state"], 0) + 1
        acc[algo] = {**row, "statuses": counts}
    return {"messages": a.messages, "algos": a.algos, "accuracy": acc}


def vehicle_row(v) -> dict[str, Any]:
    """A ground vehicle's estimates against its truth of the same time: count, RMS / 95th percentile /
    max / final 3-D position error, final sigma, and the RMS over the second half of the run."""
    import numpy as np

    e = v.errors()
    err, sig = e["err_m"], e["sigma_m"]
    row: dict[str, Any] = {"messages": v.messages, "estimates": len(v.estimates), "matched": int(err.size),
                           "journal": v.init is not None and 1 in v.inputs}
    if err.size:
        half = err[err.size // 2:]
        row.update(rms_err_m=float(np.sqrt(np.mean(err**2))), p95_err_m=float(np.percentile(err, 95)),
                   max_err_m=float(err.max()), final_err_m=float(err[-1]), final_sigma_m=float(sig[-1]),
                   rms_err_second_half_m=float(np.sqrt(np.mean(half**2))), t_end_s=float(e["t_s"][-1]))
    return row


def _file_info(lg) -> dict[str, Any]:
    return {"path": str(lg.path), "bytes": lg.path.stat().st_size, "complete": lg.complete,
            "error": lg.error, "messages": len(lg.messages), "library": lg.library, "metadata": lg.metadata}


def _times(rec) -> dict[str, Any]:
    """Start / end (UTC), wall and fleet duration, fleet time of the first and last message."""
    t0, t1 = rec.messages[0].log_time, rec.messages[-1].log_time
    tb = rec.timebase
    dur = (t1 - t0) * 1e-9
    out = {"start": datetime.fromtimestamp(t0 * 1e-9, timezone.utc).isoformat(),
           "end": datetime.fromtimestamp(t1 * 1e-9, timezone.utc).isoformat(),
           "duration_s": dur, "speed": tb.speed, "fleet_duration_s": dur * tb.speed}
    if tb.epoch_unix_s is not None:  # fleet time (seconds since the fleet epoch) of the first and last message
        out["fleet_start_s"] = tb.fleet_s(t0)
        out["fleet_end_s"] = tb.fleet_s(t1)
    return out


def _topics(topics: dict[str, dict]) -> dict[str, dict]:
    """Per topic its count, rate and kinds, in natural order (``station/2`` before ``station/10``)."""
    out = {}
    for name, t in sorted(topics.items(), key=lambda kv: natural_key(kv[0])):
        t = dict(t)
        span = (t["last_ns"] - t["first_ns"]) * 1e-9
        t["rate_hz"] = (t["count"] - 1) / span if span > 0 and t["count"] > 1 else 0.0
        t["kinds"] = dict(t["kinds"])
        out[name] = t
    return out


def station_row(s) -> dict[str, Any]:
    """One station's line of ``larns info`` (and the fleet's final table): last estimate, error
    against the last truth, exchanges, clock sync against network time."""
    from ..log.series import sigma_m

    row: dict[str, Any] = {"messages": s.messages}
    e = s.last
    if e is not None:
        row.update(state=e["state"], estimator=e["estimator"], n_updates=e["n_updates"], slot=e.get("slot"),
                   dropped=e.get("dropped"), last_t_s=e["t_s"], sigma_m=float(sigma_m(e["cov_m2"])),
                   pos_m=e["pos_m"])
    if s.truth_m is not None:
        row["truth_m"] = s.truth_m
    if s.navs:
        row.update(navs=s.navs, ranges=s.ranges)
    if s.journal:
        row["journal"] = True
    if s.excludes is not None:
        row["excludes"] = s.excludes
    if "pos_m" in row and "truth_m" in row:
        row["err_m"] = math.dist(row["pos_m"], row["truth_m"])
    sync_summary(row, s.clock())
    if s.navs and not s.polled:  # (protocol v2: station_table's, from its polls)
        row["exchanges_pct"] = 100.0 * s.ranges / s.navs  # own slots whose exchange completed
    return row


def station_table(rec, scn=None) -> dict[int, dict]:
    """:func:`station_row` of every station, with who excludes whom (integrity). A field that holds
    its own datum (``[survey] datum = "field"``: ``scn``'s, else the recording's) is judged against
    the truth in that datum (:mod:`larns.analysis.datum`): ``truth_m`` is then that truth,
    ``truth_founders_m`` the recorded one, and ``datum`` is ``"field"``."""
    from .datum import recording_datum_truth
    from .metrics import tdma_numbers

    stations = {sid: station_row(s) for sid, s in sorted(rec.stations.items())}
    dt = recording_datum_truth(rec, scn)
    if dt is not None:
        for sid, row in stations.items():
            if "truth_m" in row:
                row.update(truth_founders_m=row["truth_m"], truth_m=dt.truth(sid).tolist(), datum="field",
                           datum_frozen_s=dt.frozen_s)
                if "pos_m" in row:
                    row["err_m"] = math.dist(row["pos_m"], row["truth_m"])
    if rec.range_requests:  # its polls (a request is a poll of one) answered by every member named
        for sid, n in tdma_numbers(rec.range_requests, rec.range_replies)["by_station"].items():
            if sid in stations:
                stations[sid].update(polls=n["polls"], polls_complete_pct=n["complete_pct"])
                if rec.stations[sid].polled:  # protocol v2: the replies its recorded polls got
                    stations[sid]["exchanges_pct"] = n["answered_pct"]
    for sid, s in stations.items():
        by = [o for o, v in stations.items() if sid in v.get("excludes", ())]
        if by:
            s["excluded_by"] = by
    return stations


def sync_summary(s: dict, clock, after_s: float = 60.0) -> None:
    """Clock sync error of one station (rows ``[t_s, error_ns, ...]`` of its estimate against the
    truth of the same stamp, :meth:`StationSeries.clock`): the last (``sync_ns``, at fleet time
    ``sync_t_s``), the RMS and the largest magnitude after ``after_s`` fleet seconds, in ns (absent
    when the station's clock series ends before then)."""
    if len(clock) == 0:
        return
    s["sync_ns"] = float(clock[-1][1])
    s["sync_t_s"] = float(clock[-1][0])
    late = [float(e) for t, e in ((r[0], r[1]) for r in clock) if t >= after_s]
    if late:
        s["sync_max_ns_after_60s"] = max(abs(e) for e in late)
        s["sync_rms_ns_after_60s"] = math.sqrt(sum(e * e for e in late) / len(late))


def mcap_station_summary(path: str | Path, rec=None) -> dict[int, dict]:
    """Per station from a recording alone (the fleet's final table in the tests): truth, the
    estimate time series in log order and the final error. ``{id: {"truth_m", "t_s" (K,), "pos_m"
    (K,3), "cov_m2" (K,3,3), "n_updates" (K,), "state", "log_time_ns" (K,), "err_m" (final),
    "sigma_m" (final)}}``. Killed recordings work too (stream-read up to the damage)."""
    import numpy as np

    from ..log.series import load, sigma_m

    rec = rec if rec is not None else load([path])
    out: dict[int, dict] = {}
    for sid, s in sorted(rec.stations.items()):
        if not s.estimates:
            continue
        tr = np.asarray(s.truth_m if s.truth_m is not None else [np.nan] * 3, float)
        d = s.track(order="log_time_ns")
        out[sid] = {"truth_m": tr, **{k: d[k] for k in ("t_s", "pos_m", "cov_m2", "n_updates", "state",
                                                        "log_time_ns")},
                    "err_m": float(np.linalg.norm(d["pos_m"][-1] - tr)), "sigma_m": float(sigma_m(d["cov_m2"][-1]))}
    return out
