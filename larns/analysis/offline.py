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
from ..log.series import Journal, collect_journals, decode, decoded

JOURNAL_TOPICS = ["larns/station/*/init", "larns/station/*/input", "larns/station/*/estimate",
                  "larns/vehicle/*/init", "larns/vehicle/*/input", "larns/vehicle/*/estimate", "larns/vehicle/*/truth"]
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

    @property
    def bit_exact(self) -> bool:
        return self.compared > 0 and self.equal == self.compared


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
                                   "bit_exact": r.bit_exact, "missing_from": r.missing_from, "error": r.error}
                             for sid, r in self.stations.items()},
                "aircraft": {k: {a: {kk: vv for kk, vv in v.items() if kk not in ("estimates", "truth")}
                                 for a, v in d.items()} for k, d in self.aircraft.items()},
                "vehicles": {k: {kk: vv for kk, vv in v.items() if kk != "estimates"} for k, v in self.vehicles.items()}}


def fleet_span_s(logs: Sequence[LogFile], msgs: Sequence[Msg]) -> float:
    if not msgs:
        return 0.0
    speed = logs[0].speed if logs else 1.0
    return (msgs[-1].log_time - msgs[0].log_time) * 1e-9 * speed


def run_offline(paths: Sequence[str | Path], output: str | Path | None = None, estimator: str | None = None,
                stations: Sequence[int] | None = None, strict: bool = True, logs: Sequence[LogFile] | None = None,
                progress: bool = False, algos: Sequence[str] | None = None,
                scenario: str | None = None) -> OfflineResult:
    """Re-estimate every station with a journal; optionally write ``output`` (all recorded messages
    with the station estimates replaced by the re-estimated ones)."""
    import time

    t0 = time.perf_counter()
    c0 = time.process_time()
    if logs is None:
        # without an output file or the aircraft, only the journal and estimate channels are needed
        sel = None if (output is not None or algos) else JOURNAL_TOPICS
        logs = read_logs(paths, topics=sel)
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
    res = OfflineResult(results, len(msgs), fleet_span_s(logs, msgs))
    if algos:
        res.aircraft = reestimate_aircraft(logs, msgs, algos, scenario)
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
            key = f"larns/aircraft/{name}/estimate/{algo}"
            replaced.add(key)
            new += d.get("estimates", [])
        replaced.add(f"larns/aircraft/{name}/truth")
        first = next(iter(per_algo.values()), {})
        new += first.get("truth", [])
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


def aircraft_nav_sequence(msgs: Sequence[Msg], name: str) -> tuple[list[tuple[Msg, dict, dict]], str]:
    """The nav broadcasts the aircraft measured, in its order, and how that order was obtained.

    The aircraft publishes an ``ac_truth`` (``t_s`` = true reception time) for every broadcast it
    measured, so its truth topic identifies them: the broadcast whose true transmit time lies within
    a millisecond (the time of flight) before each reception. If that topic is complete (seq 1..n,
    every reception matched), its sequence is used ("aircraft"); otherwise every recorded usable nav
    in recorded order ("recorder")."""
    import bisect


    navs: list[tuple[float, Msg, dict, dict]] = []
    rx: dict[int, float] = {}
    truth_key = f"larns/aircraft/{name}/truth"
    mine = (m for m in msgs if m.encoding == "msgpack" and (m.topic.endswith("/nav") or m.topic == truth_key))
    for m, msg, phy in decoded(mine):
        if m.topic == truth_key:
            rx.setdefault(msg["seq"], msg["t_s"])
        elif msg["kind"] == "nav" and phy is not None:
            navs.append((phy["t_true_s"], m, msg, phy))
    recorder = [(m, msg, phy) for _t, m, msg, phy in navs]
    if not rx or 1 not in rx:
        return recorder, "recorder"
    by_t = sorted(navs, key=lambda x: x[0])
    ts = [x[0] for x in by_t]
    seq: list[tuple[Msg, dict, dict]] = []
    k = 1
    while k in rx:
        t = rx[k]
        i = bisect.bisect_right(ts, t) - 1
        if i < 0 or t - ts[i] > 1e-3:
            break
        seq.append(by_t[i][1:])
        k += 1
    if k > max(rx):
        return seq, "aircraft"
    # a truth sample is missing: the aircraft's sequence up to there, then the recorder's
    t_last = rx[k - 1] if k > 1 else -math.inf
    rest = [x[1:] for x in navs if x[0] > t_last]
    return seq + rest, f"aircraft up to measurement {k - 1}, then recorder"


def _aircraft_world(logs, scenario, name, seed):
    """(recording metadata, scenario, [aircraft] config, aircraft name, world seed) for a re-flight."""
    from aircraft.config import from_scenario
    from net.scenario import load

    md = logs[0].larns_meta if logs else {}
    scn_name = scenario or md.get("scenario")
    if not scn_name:
        raise ValueError("aircraft re-estimation needs the scenario: pass --scenario")
    scn = load(scn_name)
    ac = from_scenario(scn)
    return md, scn, ac, name or ac.name, scn.seed if seed is None else seed


def _refly(core, navs, ep: float | None, speed: float) -> tuple[list[Msg], list[tuple[dict, Msg]]]:
    """Feed the nav broadcasts to an aircraft core: its ``ac_truth`` records and (estimate, record)
    pairs, stamped like the live process would have published them."""
    from net import messages as M

    truth: list[Msg] = []
    flown: list[tuple[dict, Msg]] = []
    for m, msg, phy in navs:
        for o in core.on_nav(msg, phy):
            pub = m.log_time if ep is None else int(round((ep + o["stamp_s"] / speed) * 1e9))
            rec = Msg(M.key_for(o), m.log_time, pub, o["seq"], M.encode(o))
            if o["kind"] == "ac_truth":
                truth.append(rec)
            else:
                flown.append((o, rec))
    return truth, flown


def _compare(new: list[dict], recorded: list[dict], keys: Sequence[str]) -> tuple[list[bool], int]:
    """Re-flown vs recorded estimates matched by the per-algorithm update count (robust to recorded
    estimates lost on the way): (equal flags, length of the equal prefix)."""
    rec_by_n = {y.get("n_updates"): y for y in recorded}
    same = [all(x.get(k) == rec_by_n[x.get("n_updates")].get(k) for k in keys)
            for x in new if x.get("n_updates") in rec_by_n]
    return same, (same.index(False) if False in same else len(same))


def _algo_result(err: Sequence[float], recorded: list[dict], new: list[dict], keys: Sequence[str], order: str,
                 est: list[Msg], truth: list[Msg]) -> dict:
    """One algorithm's re-flight: error statistics (RMS after the first 10 %: filter start-up) and the
    comparison with the recorded estimates."""
    import numpy as np

    e = np.asarray(err)
    tail = e[len(e) // 10:] if e.size else e
    same, prefix = _compare(new, recorded, keys)
    return {"n": int(e.size), "final_err_m": float(e[-1]) if e.size else math.nan,
            "rms_err_m": float(np.sqrt(np.mean(tail**2))) if tail.size else math.nan,
            "recorded": len(recorded), "compared": len(same), "equal": int(sum(same)),
            "equal_prefix": prefix, "sequence": order, "estimates": est, "truth": truth}


def _refly_inertial(core, logs: Sequence[LogFile], msgs: Sequence[Msg], name: str, algo: str,
                    recorded: list[dict]) -> dict[str, dict]:
    """Re-fly an inertial core (INS, triad) over the broadcasts it measured; bit for bit."""
    import numpy as np

    ep = logs[0].epoch_unix_s if logs else None
    speed = logs[0].speed if logs else 1.0
    navs, order = aircraft_nav_sequence(msgs, name)
    truth, flown = _refly(core, navs, ep, speed)
    flown = [(o, rec) for o, rec in flown if o["kind"] == "ac_estimate"]  # not ac_status
    est = [rec for _o, rec in flown]
    err = [float(np.linalg.norm(np.asarray(o["pos_m"]) - core.truth_n(o["t_s"])[0])) for o, _rec in flown]
    new = [decode(x.data)[0] for x in est]
    keys = ("t_s", "pos_m", "cov_m2", "vel_m_s", "n_updates", "extra")
    return {name: {algo: _algo_result(err, recorded, new, keys, order, est, truth)}}


def _recorded_estimates(msgs: Sequence[Msg], name: str, algo: str) -> list[dict]:
    key = f"larns/aircraft/{name}/estimate/{algo}"
    return [msg for _m, msg, _phy in decoded(m for m in msgs if m.encoding == "msgpack" and m.topic == key)]


def reestimate_aircraft(logs: Sequence[LogFile], msgs: Sequence[Msg], algos: Sequence[str],
                        scenario: str | None = None, name: str | None = None, seed: int | None = None,
                        height_m: float | None = None) -> dict[str, dict]:
    """Re-fly the aircraft over the recorded station nav broadcasts with other algorithms.

    The aircraft process does not record its measurement inputs (pseudoranges), so they are
    regenerated: the aircraft core (``aircraft.node.AircraftCore``: trajectory, receiver clock,
    channel noise from the world seed) is rebuilt from the scenario and fed the recorded nav
    messages (with their ``phy`` part) in recorded order. Deterministic for a given log, but not
    bit-identical to the live aircraft's estimates (its Zenoh link may have delivered the navs in
    another order or lost some). Returns ``{name: {algo: {"n", "final_err_m", "rms_err_m",
    "estimates": [Msg], "truth": [Msg]}}}``.
    """
    import numpy as np

    from aircraft.node import AircraftCore

    if "ins-ekf" in algos:
        return reestimate_ins(logs, msgs, scenario, name, seed, height_m)
    if "triad" in algos:
        return reestimate_triad(logs, msgs, scenario, name, seed, height_m)
    md, scn, ac, name, seed = _aircraft_world(logs, scenario, name, seed)
    horizon = float(md.get("duration_s", 7200.0)) + 10.0
    rng = np.random.default_rng([int(seed), 0xA1C, sum(map(ord, name))])  # as aircraft.node.AircraftNode
    from net.nettime import network_time

    net_clock = network_time(scn, seed)
    core = AircraftCore(ac, tuple(algos), name, rng, height_m, horizon_s=horizon, net_clock=net_clock)
    ep = logs[0].epoch_unix_s if logs else None
    speed = logs[0].speed if logs else 1.0
    out: dict[str, dict] = {a: {"estimates": [], "truth": [], "err": []} for a in algos}
    navs, order = aircraft_nav_sequence(msgs, name)
    truth, flown = _refly(core, navs, ep, speed)
    for o, rec in flown:
        if o["kind"] != "ac_estimate":  # ac_status (waiting / restarting / no fix) has no position
            continue
        d = out[o["algo"]]
        d["estimates"].append(rec)
        p_true, _ = core.track.at(o["t_s"])
        d["err"].append(float(np.linalg.norm(np.asarray(o["pos_m"]) - p_true)))
    # the recorded estimates of the same algorithms, in order (the aircraft core is deterministic given
    # the world seed and the sequence of broadcasts it measured)
    recorded: dict[str, list[dict]] = {a: [] for a in algos}
    mine = (m for m in msgs if m.encoding == "msgpack" and m.topic.startswith(f"larns/aircraft/{name}/estimate/"))
    for _m, msg, _phy in decoded(mine):
        if msg["kind"] == "ac_estimate" and msg["algo"] in recorded:
            recorded[msg["algo"]].append(msg)
    keys = ("t_s", "pos_m", "cov_m2", "n_updates")
    return {name: {a: _algo_result(d["err"], recorded[a], [decode(x.data)[0] for x in d["estimates"]] if recorded[a] else [],
                                   keys, order, d["estimates"], truth) for a, d in out.items()}}


def reestimate_ins(logs: Sequence[LogFile], msgs: Sequence[Msg], scenario: str | None = None,
                   name: str | None = None, seed: int | None = None, height_m: float | None = None,
                   imu: str | None = None) -> dict[str, dict]:
    """Re-fly the inertial aircraft (``ins-ekf``, aircraft/ins_core.py) over the recorded broadcasts.

    The core is rebuilt with the live node's seeds and fed the nav broadcasts it measured, in its
    order (:func:`aircraft_nav_sequence`); its IMU samples do not depend on the live loop's timing,
    so the estimates are reproduced bit for bit (``equal == compared``). Same result layout as
    :func:`reestimate_aircraft`.
    """
    import numpy as np

    from aircraft.ins_core import InsAircraftCore

    md, scn, ac, name, seed = _aircraft_world(logs, scenario, name, seed)
    rng = np.random.default_rng([int(seed), 0x1A5, sum(map(ord, name))])  # as aircraft.node.AircraftNode
    recorded = _recorded_estimates(msgs, name, "ins-ekf")
    t0 = float(recorded[0].get("extra", {}).get("t0_s", 0.0)) if recorded else 0.0  # the aircraft's start
    from net.nettime import network_time

    net_clock = network_time(scn, seed)
    core = InsAircraftCore(scn, ac, name, rng, imu=imu or ac.imu or "adis16480", height_m=height_m, seed=int(seed),
                           t0_s=t0, net_clock=net_clock)
    return _refly_inertial(core, logs, msgs, name, "ins-ekf", recorded)


def reestimate_triad(logs: Sequence[LogFile], msgs: Sequence[Msg], scenario: str | None = None,
                     name: str | None = None, seed: int | None = None, height_m: float | None = None) -> dict[str, dict]:
    """Re-fly the triad aircraft (``triad``, aircraft/triad_core.py) over the recorded broadcasts, as
    :func:`reestimate_ins` (bit for bit: ``equal == compared``). The number of satellites, the IMU
    preset and rate and the start time come from the recorded estimates' ``extra``."""

    from aircraft.triad_core import DEFAULT_IMU, TriadAircraftCore
    from aircraft.world.imu import PRESETS

    md, scn, ac, name, seed = _aircraft_world(logs, scenario, name, seed)
    recorded = _recorded_estimates(msgs, name, "triad")
    x = recorded[0].get("extra", {}) if recorded else {}
    from net.nettime import network_time

    net_clock = network_time(scn, seed)
    imu = list(PRESETS)[int(x["imu_preset"])] if "imu_preset" in x else DEFAULT_IMU
    core = TriadAircraftCore(scn, ac, name, n_sv=int(x.get("n_sv", 4)), imu=imu, imu_rate_hz=float(x.get("imu_rate_hz", 10.0)),
                             height_m=height_m, seed=int(seed), t0_s=float(x.get("t0_s", 0.0)), net_clock=net_clock)
    return _refly_inertial(core, logs, msgs, name, "triad", recorded)


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
    d.update(n=len(ests), bit_exact=d["compared"] > 0 and d["equal"] == d["compared"],
             rms_err_m=float(np.sqrt(np.mean(e_arr**2))) if e_arr.size else math.nan,
             max_err_m=float(e_arr.max()) if e_arr.size else math.nan,
             final_err_m=float(e_arr[-1]) if e_arr.size else math.nan)
    return d


def format_result(res: OfflineResult, compare: bool = True) -> str:
    lines = [f"{'station':>7} {'estimator':>9} {'inputs':>6} {'entries':>7} {'estimates':>9} "
             f"{'compared':>8} {'bit-exact':>9}  notes"]
    for sid, r in sorted(res.stations.items()):
        notes = []
        if r.error:
            notes.append(r.error)
        if r.missing_from is not None:
            notes.append(f"journal hole at input {r.missing_from}: stopped there")
        if r.first_mismatch is not None:
            notes.append(f"first mismatch at estimate seq {r.first_mismatch['seq']}")
        exact = "-" if r.compared == 0 else ("yes" if r.bit_exact else f"{r.equal}/{r.compared}")
        lines.append(f"{sid:>7} {r.estimator:>9} {r.n_inputs:>6} {r.n_entries:>7} {len(r.estimates):>9} "
                     f"{r.compared:>8} {exact:>9}  {'; '.join(notes)}")
    lines.append(f"{res.messages_in} messages, {res.fleet_span_s:.1f} s of fleet time re-estimated in "
                 f"{res.wall_s:.2f} s wall ({res.speedup:.0f}x real time; CPU {res.cpu_s:.2f} s, "
                 f"{res.speedup_cpu:.0f}x)")
    for name, per in res.aircraft.items():
        for a, d in per.items():
            cmp = ""
            if d.get("recorded"):
                cmp = (f"; vs the {d['recorded']} recorded: {d['equal']}/{d['compared']} identical"
                       + ("" if d["equal"] == d["compared"] else f" (first {d['equal_prefix']} in a row)"))
            lines.append(f"aircraft {name} {a}: {d['n']} estimates, final error {d['final_err_m']:.2f} m, "
                         f"RMS error (after the first 10 %) {d['rms_err_m']:.2f} m{cmp} "
                         f"[broadcast sequence: {d.get('sequence', '-')}'s]")
    for name, d in res.vehicles.items():
        if d.get("error"):
            lines.append(f"vehicle {name}: not re-estimated: {d['error']}")
            continue
        hole = "" if d["missing_from"] is None else f"; journal hole at input {d['missing_from']}: stopped there"
        lines.append(f"vehicle {name} cdekf-map: {d['n']} estimates re-run from its journal; vs the {d['recorded']} "
                     f"recorded: {d['equal']}/{d['compared']} identical{hole}; error RMS {d['rms_err_m']:.2f} m, "
                     f"max {d['max_err_m']:.2f} m, final {d['final_err_m']:.2f} m")
    return "\n".join(lines)
