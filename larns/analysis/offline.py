"""Deterministic offline re-estimation of a recording (``larns replay --offline``).

No Zenoh and no sleeping: the recorded **core journal** (``docs/protocol.md``, "Core journal") holds,
per station, the core's construction record (``larns/station/<id>/init``, kind ``core_init``) and
everything the core consumed, in order (``larns/station/<id>/input``, kind ``core_input``: timer
calls and received messages with their local reception times). Rebuilding each core with
:meth:`stations.core.StationCore.from_init_record` and feeding it the journal reproduces the
recorded ``estimate`` messages bit for bit when the recorded estimator is re-run; with
``--estimator NAME`` the same inputs drive another survey estimator.

Re-estimation is *open loop*: a station's inputs contain its peers' broadcast estimates as they
were recorded, so re-running station A with another estimator does not change what A heard from
B. That is exactly "another estimator on the same measurements".

The aircraft and the ground vehicle journal their navigators' inputs the same way
(``larns/aircraft/<name>/init`` + ``input``: aircraft/journal.py; ``larns/vehicle/<name>/init`` +
``input``): every recorded one is re-flown from its journal alone (no scenario, no seeds) and
compared field by field with its recorded estimates; other aircraft algorithms run on the same
journal. Every re-run reports its accuracy against the recording's truth beside the recorded
estimates' (:func:`accuracy`).

A journal needs every ``core_input`` from seq 1 on: a station whose first inputs were not recorded
(recorder started late) cannot be rebuilt; a hole in the sequence (a sample lost under load) stops
that station's re-estimation at the hole. Both are reported, never silently papered over.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from ..log import LogFile, LogWriter, Msg, merge, read_logs
from ..log.series import Journal, collect_journals, decoded

JOURNAL_TOPICS = ["larns/station/*/init", "larns/station/*/input", "larns/station/*/estimate", "larns/station/*/truth",
                  "larns/vehicle/*/init", "larns/vehicle/*/input", "larns/vehicle/*/estimate", "larns/vehicle/*/truth",
                  "larns/aircraft/*/init", "larns/aircraft/*/input", "larns/aircraft/*/estimate/*",
                  "larns/aircraft/*/truth"]
VEHICLE_FIELDS = ("t_s", "pos_m", "cov_m2", "vel_m_s", "vel_cov", "algo", "n_updates", "extra", "seq", "stamp_s")
ESTIMATE_FIELDS = ("t_s", "pos_m", "cov_m2", "n_updates", "estimator", "state", "seq", "stamp_s")


@dataclass
class StationResult:
    id: int
    estimator: str
    n_inputs: int = 0
    n_entries: int = 0
    estimates: list[tuple[int, int, dict]] = field(default_factory=list)  # (log_time, publish_time, msg)
    missing_from: int | None = None  # first missing input seq
    error: str | None = None
    compared: int = 0
    equal: int = 0
    first_mismatch: dict | None = None
    recorded_estimator: str | None = None  # the estimator of the recorded estimates
    rerun: dict = field(default_factory=dict)     # accuracy of the re-run estimates (:func:`accuracy`)
    recorded_accuracy: dict = field(default_factory=dict)  # ... of the recorded ones

    @property
    def bit_exact(self) -> bool:
        return self.compared > 0 and self.equal == self.compared

    @property
    def same_estimator(self) -> bool:
        """Whether the re-run ran the recorded estimator (then it must reproduce it bit for bit)."""
        return self.recorded_estimator is None or self.recorded_estimator == self.estimator


def same_estimate(a: dict, b: dict) -> bool:
    """Bit-for-bit equality of the core's estimate fields (floats compared exactly)."""
    return all(a.get(k) == b.get(k) for k in ESTIMATE_FIELDS)


def reestimate_station(j: Journal, estimator: str | None = None, epoch_unix_s: float | None = None,
                       speed: float = 1.0) -> StationResult:
    """Rebuild station ``j.id``'s core from its init record and replay its journal."""
    from stations.core import StationCore
    from stations.shell import PublishPolicy

    res = StationResult(j.id, estimator or "")
    if j.init is None:
        res.error = "no core_init record in the log"
        return res
    inputs, res.missing_from = j.contiguous()
    if not inputs:
        res.error = ("no core_input records" if not j.inputs else
                     f"journal starts at input {min(j.inputs)} (inputs from 1 not recorded)")
        return res
    rec = dict(j.init)
    rec["cfg"] = dict(rec["cfg"])
    if estimator:
        rec["cfg"]["estimator"] = estimator
    try:
        core = StationCore.from_init_record(rec)
    except Exception as e:  # a bad record must not kill the whole run
        res.error = f"cannot rebuild core: {type(e).__name__}: {e}"
        return res
    res.estimator = core.est.name
    res.recorded_estimator = next((m["estimator"] for _r, m in j.estimates.values()), None)
    policy = PublishPolicy(j.id)
    for m, entries in inputs:
        res.n_inputs += 1
        res.n_entries += len(entries)
        try:
            outs = core.replay(entries)
        except Exception as e:
            res.error = f"replay failed at input seq {res.n_inputs}: {type(e).__name__}: {e}"
            break
        for o in outs:
            if o["kind"] != "estimate":
                continue
            o = policy.estimate(o, core.slot)  # as the station's shell published it (no drop count)
            pub = m.log_time
            if epoch_unix_s is not None:
                t = epoch_unix_s + o["stamp_s"] / speed
                if 0.0 < t < 4e9:
                    pub = int(round(t * 1e9))
            res.estimates.append((m.log_time, pub, o))
    # compare with what was recorded (same seq)
    for _lt, _pt, o in res.estimates:
        rec_est = j.estimates.get(o["seq"])
        if rec_est is None:
            continue
        res.compared += 1
        if same_estimate(o, rec_est[1]):
            res.equal += 1
        elif res.first_mismatch is None:
            res.first_mismatch = {"seq": o["seq"], "recorded": {k: rec_est[1].get(k) for k in ESTIMATE_FIELDS},
                                  "replayed": {k: o.get(k) for k in ESTIMATE_FIELDS}}
    return res


def station_accuracy(results: dict[int, StationResult], journals: dict[int, Journal], msgs: Sequence[Msg]) -> None:
    """Each re-estimated station's accuracy against its recorded truth (``truth`` topic: the last true
    position), for the re-run and for the recorded estimates (:func:`accuracy`)."""
    truth: dict[int, list] = {}
    mine = (m for m in msgs if m.encoding == "msgpack" and m.topic.startswith("larns/station/")
            and m.topic.endswith("/truth"))
    for _m, msg, _phy in decoded(mine):
        if msg["kind"] == "truth":
            truth[msg["src"]] = msg["pos_m"]
    for sid, r in results.items():
        p = truth.get(sid)
        at = (lambda t, p=p: p) if p is not None else (lambda t: None)
        new = [o for _lt, _pt, o in r.estimates]
        rec = [msg for _m, msg in journals[sid].estimates.values()]
        t_from = half_time(new, rec)
        r.rerun, r.recorded_accuracy = accuracy(new, at, t_from), accuracy(rec, at, t_from)


@dataclass
class OfflineResult:
    stations: dict[int, StationResult]
    messages_in: int
    fleet_span_s: float
    wall_s: float = 0.0
    cpu_s: float = 0.0  # CPU time of this process (robust against other load on the machine)
    output: str | None = None
    aircraft: dict[str, Any] = field(default_factory=dict)
    vehicles: dict[str, Any] = field(default_factory=dict)

    @property
    def speedup(self) -> float:
        return self.fleet_span_s / self.wall_s if self.wall_s > 0 else math.inf

    @property
    def speedup_cpu(self) -> float:
        return self.fleet_span_s / self.cpu_s if self.cpu_s > 0 else math.inf

    def as_dict(self) -> dict[str, Any]:
        return {"messages_in": self.messages_in, "fleet_span_s": self.fleet_span_s, "wall_s": self.wall_s,
                "cpu_s": self.cpu_s, "speedup": self.speedup, "speedup_cpu": self.speedup_cpu, "output": self.output,
                "stations": {sid: {"estimator": r.estimator, "inputs": r.n_inputs, "entries": r.n_entries,
                                   "estimates": len(r.estimates), "compared": r.compared, "equal": r.equal,
                                   "bit_exact": r.bit_exact, "missing_from": r.missing_from, "error": r.error,
                                   "same_estimator": r.same_estimator, "rerun": r.rerun,
                                   "recorded_accuracy": r.recorded_accuracy}
                             for sid, r in self.stations.items()},
                "aircraft": {k: {a: {kk: vv for kk, vv in v.items() if kk not in ("estimates", "first_mismatch")}
                                 for a, v in d.items()} for k, d in self.aircraft.items()},
                "vehicles": {k: {kk: vv for kk, vv in v.items() if kk != "estimates"} for k, v in self.vehicles.items()}}


def fleet_span_s(logs: Sequence[LogFile], msgs: Sequence[Msg]) -> float:
    if not msgs:
        return 0.0
    speed = logs[0].speed if logs else 1.0
    return (msgs[-1].log_time - msgs[0].log_time) * 1e-9 * speed


def run_offline(paths: Sequence[str | Path], output: str | Path | None = None, estimator: str | None = None,
                stations: Sequence[int] | None = None, strict: bool = True, logs: Sequence[LogFile] | None = None,
                progress: bool = False, algos: Sequence[str] | None = None) -> OfflineResult:
    """Re-estimate every station, aircraft and vehicle with a journal (``algos``: other aircraft
    algorithms on the same inputs); optionally write ``output`` (all recorded messages with the
    estimates replaced by the re-estimated ones)."""
    import time

    from aircraft.navigator.radio.models import ALGOS

    bad = [a for a in (algos or ()) if a not in ALGOS + ("ins-ekf", "triad")]
    if bad:
        raise ValueError(f"unknown aircraft algorithm {bad[0]!r}; choose from {', '.join(ALGOS + ('ins-ekf', 'triad'))}")
    t0 = time.perf_counter()
    c0 = time.process_time()
    if logs is None:
        # without an output file, only the journal, estimate and truth channels are needed
        logs = read_logs(paths, topics=None if output is not None else JOURNAL_TOPICS)
    logs = list(logs)
    msgs = merge(logs)
    journals = collect_journals(msgs, strict=strict)
    ep = logs[0].epoch_unix_s if logs else None
    speed = logs[0].speed if logs else 1.0
    results: dict[int, StationResult] = {}
    ids = sorted(journals) if not stations else [s for s in sorted(journals) if s in set(stations)]
    bar = None
    if progress:
        from ..bench.progress import Progress

        bar = Progress(len(ids), "re-estimating stations")
    for sid in ids:
        results[sid] = reestimate_station(journals[sid], estimator, ep, speed)
        if bar:
            bar.update(1)
    if bar:
        bar.close()
    station_accuracy(results, journals, msgs)
    res = OfflineResult(results, len(msgs), fleet_span_s(logs, msgs))
    res.aircraft = reestimate_aircraft(msgs, algos, ep, speed)
    res.vehicles = reestimate_vehicles(msgs, ep, speed)
    if output is not None:
        write_output(output, logs, msgs, results, estimator, res.aircraft, res.vehicles)
        res.output = str(output)
    res.wall_s = time.perf_counter() - t0
    res.cpu_s = time.process_time() - c0
    return res


def write_output(output: str | Path, logs: Sequence[LogFile], msgs: Sequence[Msg],
                 results: dict[int, StationResult], estimator: str | None,
                 aircraft: dict[str, dict] | None = None, vehicles: dict[str, dict] | None = None) -> None:
    """The recording with the re-estimated stations' ``estimate`` topics replaced."""
    import heapq

    from net import messages as M

    md = {name: dict(v) for lg in reversed(list(logs)) for name, v in lg.metadata.items()}
    md.setdefault("larns", {})
    md["larns_offline"] = {"sources": ",".join(str(lg.path) for lg in logs),
                           "estimator": estimator or "recorded",
                           "stations": ",".join(str(s) for s, r in results.items() if r.estimates)}
    replaced = {f"larns/station/{sid}/estimate" for sid, r in results.items() if r.estimates}
    new = []
    for sid, r in results.items():
        for lt, pt, o in r.estimates:
            new.append(Msg(M.key_for(o), lt, pt, o["seq"], M.encode(o)))
    for name, per_algo in (aircraft or {}).items():
        for algo, d in per_algo.items():
            if d.get("error") is None:
                replaced.add(f"larns/aircraft/{name}/estimate/{algo}")
                new += d.get("estimates", [])
    for name, d in (vehicles or {}).items():
        if d.get("estimates"):
            replaced.add(f"larns/vehicle/{name}/estimate")
            new += d["estimates"]
    new.sort(key=lambda m: m.log_time)
    # wire messages only; the Foxglove view is regenerated from the new estimates
    kept = [m for m in msgs if m.topic not in replaced and m.encoding == "msgpack"]
    wire = list(heapq.merge(kept, new, key=lambda m: m.log_time))
    with LogWriter(output, md, library="larns replay --offline") as w:
        for m in wire:
            w.write(m.topic, m.data, m.log_time, m.publish_time)
        if any(m.encoding == "json" for m in msgs):
            from ..viz.foxglove import iter_json, schema_for

            for lt, pt, topic, sname, data in iter_json(wire):
                w.write(topic, data, lt, pt, "json", schema_for(sname))


# --------------------------------------------------------------------------- aircraft

@dataclass
class AircraftJournal:
    """What a recording holds of one aircraft: its navigator's init record and journal inputs by seq
    (``ac_init``, ``ac_input``: aircraft/journal.py), its estimates per algorithm and its truth."""

    name: str
    init: dict | None = None
    inputs: dict[int, tuple[int, list]] = field(default_factory=dict)  # seq -> (log_time, entries)
    estimates: dict[str, list[tuple[int, dict]]] = field(default_factory=dict)  # algo -> [(log_time, msg)]
    truth: list[tuple[float, list, list]] = field(default_factory=list)  # (t_s, pos_m, vel_m_s)

    def half_time(self) -> float:
        """The middle of the flight (of its truth samples, else of its estimates)."""
        if self.truth:
            return half_time([{"t_s": r[0]} for r in self.truth])
        return half_time(*[[m for _lt, m in v] for v in self.estimates.values()])

    def contiguous(self) -> tuple[list[list], int | None, int]:
        """The journal's entries from input 1 up to the first hole, that hole's seq (None: none) and
        the number of inputs used."""
        out: list[list] = []
        k = 1
        while k in self.inputs:
            out += self.inputs[k][1]
            k += 1
        return out, (k if self.inputs and k <= max(self.inputs) else None), k - 1


def collect_aircraft(msgs: Sequence[Msg]) -> dict[str, AircraftJournal]:
    """Every aircraft of a recording (validated payloads, attributed by key)."""
    out: dict[str, AircraftJournal] = {}
    mine = (m for m in msgs if m.encoding == "msgpack" and m.topic.startswith("larns/aircraft/"))
    for m, msg, _phy in decoded(mine):
        a = out.setdefault(msg["src"], AircraftJournal(msg["src"]))
        k = msg["kind"]
        if k == "ac_init" and a.init is None:
            a.init = msg["record"]
        elif k == "ac_input":
            a.inputs.setdefault(int(msg["seq"]), (m.log_time, msg["entries"]))
        elif k == "ac_estimate":
            a.estimates.setdefault(msg["algo"], []).append((m.log_time, msg))
        elif k == "ac_truth":
            a.truth.append((float(msg["t_s"]), msg["pos_m"], msg.get("vel_m_s") or [0.0, 0.0, 0.0]))
    for a in out.values():
        a.truth.sort(key=lambda r: r[0])
    return out


def accuracy(ests: Sequence[dict], truth_at, t_from_s: float) -> dict[str, float]:
    """RMS position error against the recording's truth and mean sigma ``sqrt(trace P)`` of the
    estimates from ``t_from_s`` on (the second half of the run: past the start-up; the same window for
    a re-run and the recorded estimates), and how many estimates that is."""
    import numpy as np

    rows = [(truth_at(e["t_s"]), e) for e in ests if e["t_s"] >= t_from_s]
    rows = [(p, e) for p, e in rows if p is not None]
    if not rows:
        return {"rms_err_m": math.nan, "mean_sigma_m": math.nan, "samples": 0}
    err = np.array([np.linalg.norm(np.subtract(e["pos_m"], p)) for p, e in rows])
    sig = np.array([math.sqrt(max(float(np.trace(np.asarray(e["cov_m2"], float))), 0.0)) for _p, e in rows])
    return {"rms_err_m": float(np.sqrt(np.mean(err**2))), "mean_sigma_m": float(sig.mean()), "samples": len(rows)}


def half_time(*lists: Sequence[dict]) -> float:
    """The middle of the time span of the estimates in ``lists`` (``t_s``)."""
    ts = [e["t_s"] for x in lists for e in x]
    return 0.5 * (min(ts) + max(ts)) if ts else math.inf


def _truth_at(truth: Sequence[tuple[float, list, list]]):
    """The aircraft's true position at ``t`` from its ``ac_truth`` samples: the nearest one moved on by
    its velocity (within 1 s; None beyond)."""
    import bisect

    import numpy as np

    ts = [r[0] for r in truth]

    def at(t: float):
        i = bisect.bisect_left(ts, t)
        cand = [j for j in (i - 1, i) if 0 <= j < len(ts)]
        if not cand:
            return None
        j = min(cand, key=lambda j: abs(ts[j] - t))
        if abs(ts[j] - t) > 1.0:
            return None
        return np.asarray(truth[j][1], float) + np.asarray(truth[j][2], float) * (t - ts[j])
    return at


def _valid(outs: Sequence[dict]) -> tuple[list[dict], int]:
    """The replayed ``ac_estimate`` messages as the live process published them (validated and
    normalized; the ones it refused to send are counted, not kept)."""
    from net import messages as M

    ok, bad = [], 0
    for o in outs:
        if o["kind"] != "ac_estimate":
            continue
        try:
            ok.append(M.validate_msg(M.to_plain(o)))
        except M.MessageError:
            bad += 1
    return ok, bad


def reestimate_aircraft(msgs: Sequence[Msg], algos: Sequence[str] | None = None, epoch_unix_s: float | None = None,
                        speed: float = 1.0) -> dict[str, dict]:
    """Re-fly every recorded aircraft's navigator from its journal (aircraft/journal.py), no scenario,
    no world: the recorded algorithm(s) and, with ``algos``, others on the same inputs (radio filters
    on any aircraft's measurements; ``ins-ekf`` / ``triad`` on their own kind's journal).

    A recorded algorithm's re-flown ``ac_estimate`` messages are compared, every field, with the
    recorded ones of the same seq (``equal == compared``: bit for bit); a hole in the journal stops
    the re-flight there (``missing_from``, ``stopped_at_s``). Each algorithm's accuracy (RMS error
    against the recorded truth, mean sigma) is given for what was re-run and for what was recorded.
    Returns ``{name: {algo: {...}}}`` (``estimates``: the re-flown messages as :class:`Msg`)."""
    return {name: reestimate_one_aircraft(a, algos, epoch_unix_s, speed)
            for name, a in sorted(collect_aircraft(msgs).items())}


def reestimate_one_aircraft(a: AircraftJournal, algos: Sequence[str] | None, epoch_unix_s: float | None,
                            speed: float) -> dict[str, dict]:
    """One aircraft of :func:`reestimate_aircraft`: the recorded algorithms re-flown together (their
    estimates carry the live process's seq numbers), each other algorithm on its own."""
    from aircraft.journal import algos_of, can_run

    truth_at = _truth_at(a.truth)
    t_from = a.half_time()  # one window for every algorithm, re-run or recorded
    recorded_algos = list(algos_of(a.init)) if a.init is not None else sorted(a.estimates)
    wanted = list(dict.fromkeys(recorded_algos + list(algos or ())))
    res = {x: _aircraft_result([msg for _lt, msg in a.estimates.get(x, [])], truth_at, t_from) for x in wanted}
    entries, hole, n_inputs = a.contiguous()
    why = ("no ac_init record: no aircraft journal in this recording" if a.init is None else
           "no ac_input records" if not a.inputs else
           f"journal starts at input {min(a.inputs)} (inputs from 1 not recorded)" if not entries else None)
    if why:
        for d in res.values():
            d["error"] = why
        return res
    extra = [x for x in wanted if x not in recorded_algos]
    for x in extra:
        if not can_run(a.init, x):
            res[x]["error"] = f"the journal of a {a.init['kind']} aircraft holds no inputs for {x}"
    runs = [tuple(x for x in wanted if x in recorded_algos)] + [(x,) for x in extra if can_run(a.init, x)]
    for run in filter(None, runs):
        _refly(a, entries, run, res, recorded_algos, truth_at, t_from, epoch_unix_s, speed)
        for x in run:
            res[x].update(inputs=n_inputs, missing_from=hole)
            if not (hole or res[x]["stopped"]):
                res[x]["stopped_at_s"] = None
    return res


def _aircraft_result(recorded: list[dict], truth_at, t_from_s: float) -> dict:
    return {"n": 0, "recorded": len(recorded), "compared": 0, "equal": 0, "bit_exact": False, "equal_prefix": 0,
            "first_mismatch": None, "missing_from": None, "stopped": None, "stopped_at_s": None, "error": None,
            "invalid": 0, "inputs": 0, "rerun": {}, "recorded_accuracy": accuracy(recorded, truth_at, t_from_s), "estimates": [],
            "t_from_s": t_from_s}


def _refly(a: AircraftJournal, entries: list[list], run: tuple[str, ...], res: dict[str, dict],
           recorded_algos: Sequence[str], truth_at, t_from_s: float, epoch_unix_s: float | None,
           speed: float) -> None:
    """Re-fly the algorithms ``run`` together over ``entries``; fills their results in ``res``."""
    from aircraft.journal import replay

    try:
        outs, stopped, t_last = replay(a.init, a.name, entries, run)
    except Exception as e:  # a bad journal must not kill the whole run
        for x in run:
            res[x]["error"] = f"replay failed: {type(e).__name__}: {e}"
        return
    new, bad = _valid(outs)
    for x in run:
        d = res[x]
        mine = [o for o in new if o["algo"] == x]
        d.update(n=len(mine), invalid=bad, stopped=stopped, rerun=accuracy(mine, truth_at, t_from_s),
                 stopped_at_s=t_last)
        if x in recorded_algos:
            _compare_recorded(d, mine, a.estimates.get(x, []), epoch_unix_s, speed)
        else:
            d["estimates"] = [_as_msg(o, None, epoch_unix_s, speed) for o in mine]


def _as_msg(o: dict, log_time: int | None, epoch_unix_s: float | None, speed: float) -> Msg:
    from net import messages as M

    pub = int(round((epoch_unix_s + o["stamp_s"] / speed) * 1e9)) if epoch_unix_s is not None else 0
    return Msg(M.key_for(o), log_time if log_time is not None else pub, pub, o["seq"], M.encode(o))


def _compare_recorded(d: dict, mine: list[dict], recorded: list[tuple[int, dict]], epoch_unix_s: float | None,
                      speed: float) -> None:
    """Replayed against recorded estimates of the same seq, every field (floats exactly)."""
    by_seq = {msg["seq"]: (lt, msg) for lt, msg in recorded}
    same = []
    for o in mine:
        r = by_seq.get(o["seq"])
        if r is not None:
            same.append(o == r[1])
            if not same[-1] and d["first_mismatch"] is None:
                d["first_mismatch"] = {"seq": o["seq"], "recorded": r[1], "replayed": o}
        d["estimates"].append(_as_msg(o, r[0] if r else None, epoch_unix_s, speed))
    d.update(compared=len(same), equal=int(sum(same)), equal_prefix=same.index(False) if False in same else len(same),
             bit_exact=bool(same) and all(same))


def _aircraft_lines(res: "OfflineResult") -> list[str]:
    lines = []
    for name, per in res.aircraft.items():
        for a, d in per.items():
            if d.get("error"):
                lines.append(f"aircraft {name} {a}: not re-flown: {d['error']}")
                continue
            cmp = ""
            if d["recorded"] and d["compared"]:
                cmp = f"; vs the {d['recorded']} recorded: {d['equal']}/{d['compared']} identical" + (
                    "" if d["equal"] == d["compared"] else f" (first mismatch at seq {d['first_mismatch']['seq']})")
            hole = ""
            if d["missing_from"] is not None or d["stopped"]:
                where = f"journal hole at input {d['missing_from']}" if d["missing_from"] is not None else d["stopped"]
                hole = f"; {where}: stopped there (t = {d['stopped_at_s']:.2f} s)"
            lines.append(f"aircraft {name} {a}: {d['n']} estimates re-flown from {d['inputs']} journal inputs{cmp}{hole}; "
                         f"accuracy (second half) re-run {_acc(d['rerun'])}, recorded {_acc(d['recorded_accuracy'])} (RMS/sigma m)")
    return lines


def reestimate_vehicles(msgs: Sequence[Msg], epoch_unix_s: float | None = None, speed: float = 1.0) -> dict[str, dict]:
    """Re-run every recorded vehicle's navigator on its journal (``vehicle.navigator.live.replay``).

    Needs the ``veh_init`` record and the ``veh_input`` journal from seq 1 (a hole stops the replay
    there, reported as ``missing_from``). The re-estimated ``veh_estimate`` messages are compared
    with the recorded ones of the same seq, every field exactly (``equal == compared``: bit for bit);
    their errors against the recorded truth of the same time. Returns ``{name: {"n", "compared",
    "equal", "bit_exact", "missing_from", "error", "rms_err_m", "max_err_m", "final_err_m",
    "estimates": [Msg]}}``."""
    from ..log.series import Recording, VehicleSeries

    vehicles: dict[str, VehicleSeries] = {}
    rec_log: dict[tuple[str, int], int] = {}
    mine = (m for m in msgs if m.encoding == "msgpack" and m.topic.startswith("larns/vehicle/"))
    for m, msg, _phy in decoded(mine):
        if msg["kind"].startswith("veh_"):
            Recording._add_vehicle(vehicles.setdefault(msg["src"], VehicleSeries(msg["src"])), msg)
            if msg["kind"] == "veh_estimate":
                rec_log[(msg["src"], msg["seq"])] = m.log_time
    return {name: rerun_vehicle(v, rec_log, epoch_unix_s, speed) for name, v in sorted(vehicles.items())}


def rerun_vehicle(v, rec_log: dict[tuple[str, int], int], epoch_unix_s: float | None, speed: float) -> dict:
    """One vehicle of :func:`reestimate_vehicles` (``v`` a :class:`larns.log.series.VehicleSeries`;
    ``rec_log`` the log time of each recorded estimate)."""
    from collections import Counter

    import numpy as np

    from net import messages as M
    from vehicle.core import estimate_msg
    from vehicle.navigator.live import replay

    name = v.name
    d: dict[str, Any] = {"n": 0, "compared": 0, "equal": 0, "bit_exact": False, "missing_from": None,
                         "error": None, "invalid": 0, "recorded": len(v.estimates), "estimates": []}
    entries, d["missing_from"] = v.journal()
    if v.init is None or not entries:
        d["error"] = "no veh_init record" if v.init is None else "no veh_input journal from seq 1"
        return d
    try:
        ests = replay(v.init, entries)
    except Exception as e:  # a bad journal must not kill the whole run
        d["error"] = f"replay failed: {type(e).__name__}: {e}"
        return d
    recorded = {e["seq"]: e for e in v.estimates}
    seq: Counter[str] = Counter()
    errs = []
    for e in ests:
        try:
            o = M.validate_msg(M.to_plain(estimate_msg(name, seq, e)))
        except M.MessageError:  # the live process refused to send it too (counted, not compared)
            d["invalid"] += 1
            continue
        r = recorded.get(o["seq"])
        if r is not None:
            d["compared"] += 1
            d["equal"] += all(o.get(k) == r.get(k) for k in VEHICLE_FIELDS)
        t = v.truths.get(o["t_s"])
        if t is not None:
            errs.append(float(np.linalg.norm(np.subtract(o["pos_m"], t["pos_m"]))))
        lt = rec_log.get((name, o["seq"]))
        pub = int(round((epoch_unix_s + o["stamp_s"] / speed) * 1e9)) if epoch_unix_s is not None else lt
        d["estimates"].append(Msg(M.key_for(o), lt if lt is not None else (pub or 0), pub or 0, o["seq"], M.encode(o)))
    e_arr = np.asarray(errs)
    truth_at = lambda t: (v.truths[t]["pos_m"] if t in v.truths else None)  # noqa: E731
    new = [M.decode(x.data)[0] for x in d["estimates"]]
    t_from = half_time(new, v.estimates)
    d["rerun"], d["recorded_accuracy"] = accuracy(new, truth_at, t_from), accuracy(v.estimates, truth_at, t_from)
    d.update(n=len(ests), bit_exact=d["compared"] > 0 and d["equal"] == d["compared"],
             rms_err_m=float(np.sqrt(np.mean(e_arr**2))) if e_arr.size else math.nan,
             max_err_m=float(e_arr.max()) if e_arr.size else math.nan,
             final_err_m=float(e_arr[-1]) if e_arr.size else math.nan)
    return d


def _acc(x: dict) -> str:
    return "-" if not x or not x.get("samples") else f"{x['rms_err_m']:.3f}/{x['mean_sigma_m']:.3f}"


def format_result(res: OfflineResult, compare: bool = True) -> str:
    """The table of ``larns reestimate``: per station whether the re-run reproduces the recorded
    estimates and the accuracy of both (RMS error against the recorded truth / mean sigma, m, over
    the second half of the run: :func:`accuracy`); then each aircraft algorithm and vehicle."""
    lines = [f"{'station':>7} {'estimator':>9} {'inputs':>6} {'entries':>7} {'estimates':>9} "
             f"{'compared':>8} {'bit-exact':>9} {'re-run rms/sigma m':>18} {'recorded rms/sigma m':>20}  notes"]
    for sid, r in sorted(res.stations.items()):
        notes = []
        if r.error:
            notes.append(r.error)
        if r.missing_from is not None:
            notes.append(f"journal hole at input {r.missing_from}: stopped there")
        same = compare and r.same_estimator
        if r.first_mismatch is not None and same:
            notes.append(f"first mismatch at estimate seq {r.first_mismatch['seq']}")
        if not r.same_estimator:
            notes.append(f"recorded: {r.recorded_estimator}")
        exact = "-" if r.compared == 0 or not same else ("yes" if r.bit_exact else f"{r.equal}/{r.compared}")
        lines.append(f"{sid:>7} {r.estimator:>9} {r.n_inputs:>6} {r.n_entries:>7} {len(r.estimates):>9} "
                     f"{r.compared if same else '-':>8} {exact:>9} {_acc(r.rerun):>18} {_acc(r.recorded_accuracy):>20}"
                     f"  {'; '.join(notes)}")
    lines.append(f"{res.messages_in} messages, {res.fleet_span_s:.1f} s of fleet time re-estimated in "
                 f"{res.wall_s:.2f} s wall ({res.speedup:.0f}x real time; CPU {res.cpu_s:.2f} s, "
                 f"{res.speedup_cpu:.0f}x)")
    lines += _aircraft_lines(res)
    for name, d in res.vehicles.items():
        if d.get("error"):
            lines.append(f"vehicle {name}: not re-estimated: {d['error']}")
            continue
        hole = "" if d["missing_from"] is None else f"; journal hole at input {d['missing_from']}: stopped there"
        lines.append(f"vehicle {name} cdekf-map: {d['n']} estimates re-run from its journal; vs the {d['recorded']} "
                     f"recorded: {d['equal']}/{d['compared']} identical{hole}; error RMS {d['rms_err_m']:.2f} m, "
                     f"max {d['max_err_m']:.2f} m, final {d['final_err_m']:.2f} m; accuracy (second half) re-run "
                     f"{_acc(d.get('rerun'))}, recorded {_acc(d.get('recorded_accuracy'))} (RMS/sigma m)")
    return "\n".join(lines)
