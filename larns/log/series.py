"""A recording decoded once into typed series: the one place recorded wire messages are decoded.

:func:`load` (or :meth:`Recording.from_logs`) reads one or several MCAP files (complete or killed,
:mod:`larns.log.reader`), merges them by log time and decodes every ``msgpack`` message exactly
once. Everything that looks at a recording - ``larns info``, ``report``, ``export``, the fleet's
final table, the tests - reads these series, so their numbers cannot diverge:

* per station (:class:`StationSeries`): estimates, truth, clock estimate against clock truth of the
  same stamp, state, drops, nav broadcasts and completed exchanges, journal presence, integrity;
* per aircraft (:class:`AircraftSeries`): estimates per algorithm and the truth track;
* per ground vehicle (:class:`VehicleSeries`): estimates, the truth at each estimate's time, the
  navigator journal;
* the network (:class:`NetworkStats`): per-topic counts, loss from sequence gaps per sender and
  kind, duplicates, reordering, undecodable payloads and latency ``log_time - publish_time``;
* the TDMA exchanges (range requests and which were answered) and the broadcasts' physical truth;
* one :class:`~larns.log.timebase.Timebase` for fleet / wall / publish time.
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator, Sequence

import msgpack
import numpy as np

from .reader import LogFile, Msg, merge, read_logs
from .timebase import Timebase


def decode(data: bytes) -> tuple[dict, dict | None]:
    """One LARNS envelope (``net.messages.decode``): ``(msg, phy)``; raises ``MessageError``."""
    from net import messages as M

    return M.decode(data)


def decode_all(msgs: Iterable[Msg]) -> Iterator[tuple[Msg, dict | None]]:
    """(record, decoded msg or None if not a valid LARNS envelope) for the msgpack records."""
    from net import messages as M

    for m in msgs:
        if m.encoding != "msgpack":
            continue
        try:
            msg, _ = M.decode(m.data)
        except M.MessageError:
            msg = None
        if msg is not None and key_publisher(m.topic) != msg["src"]:  # attributed by key (issue 32)
            msg = None
        yield m, msg


def decoded(msgs: Iterable[Msg], invalid: Counter[str] | None = None) -> Iterator[tuple[Msg, dict, dict | None]]:
    """``(record, msg, phy)`` for the valid LARNS envelopes among ``msgs``; invalid ones are counted by
    reason in ``invalid`` and skipped (``net.messages.decode_valid`` on the records' payloads), and so
    is one whose ``src`` is not its key's publisher (``src_mismatch``: attributed by key, issue 32)."""
    from net import messages as M

    for m, msg, phy in M.decode_valid(msgs, lambda m: m.data, invalid):
        if key_publisher(m.topic) != msg["src"]:
            if isinstance(invalid, Counter):
                invalid["src_mismatch"] += 1
            continue
        yield m, msg, phy


# --- the station journals (offline re-estimation reads them) ------------------------------------

@dataclass
class Journal:
    """The recorded journal of one station."""

    id: int
    init: dict | None = None
    inputs: dict[int, tuple[Msg, list]] = field(default_factory=dict)  # seq -> (record, entries)
    estimates: dict[int, tuple[Msg, dict]] = field(default_factory=dict)  # seq -> (record, msg)

    def contiguous(self) -> tuple[list[tuple[Msg, list]], int | None]:
        """Inputs from seq 1 up to the first hole; returns (inputs, seq of the first missing one or None)."""
        out = []
        s = 1
        last = max(self.inputs, default=0)
        while s <= last:
            if s not in self.inputs:
                return out, s
            out.append(self.inputs[s])
            s += 1
        return out, None


def _unpack(data: bytes) -> dict | None:
    try:
        env = msgpack.unpackb(data, raw=False, strict_map_key=False)
        msg = env["msg"]
        return msg if isinstance(msg, dict) else None
    except Exception:
        return None


def _time(v: Any) -> float:
    from net import messages as M

    if type(v) is not float and type(v) is not int:
        raise M.MessageError("type", "journal time must be a number")
    f = float(v)
    if not -M.MAX_ABS <= f <= M.MAX_ABS:
        raise M.MessageError("value", "journal time not finite")
    return f


def decode_input(data: bytes, cache: dict[bytes, dict]) -> dict:
    """Strictly validate a ``core_input`` envelope (signed or not), as ``net.messages.decode`` does, but validate each
    distinct embedded air message once: a nav broadcast sits in the journal of every station that
    heard it (``cache`` maps its msgpack bytes to the validated message)."""
    from net import messages as M

    if len(data) > M.MAX_PAYLOAD_BYTES:
        raise M.MessageError("size", "too big")
    if data[:1] == M.SIGNED_MARK:  # a secure fleet's signed frame: the envelope inside, unverified (as decode)
        from net.security import strip_signature

        data = strip_signature(bytes(data))
    try:
        env = msgpack.unpackb(data, raw=False, strict_map_key=True, max_bin_len=0, max_ext_len=0,
                              max_array_len=M.MAX_LIST * 4, max_map_len=64)
    except Exception as e:
        raise M.MessageError("msgpack", type(e).__name__) from None
    if not isinstance(env, dict) or env.get("v") != M.VERSION or isinstance(env.get("v"), bool) \
            or set(env) - {"v", "msg"} or not isinstance(env.get("msg"), dict):
        raise M.MessageError("envelope", "not a core_input envelope")
    raw = env["msg"]
    entries = raw.get("entries")
    msg = M.validate_msg({**raw, "entries": []})
    if msg["kind"] != "core_input":
        raise M.MessageError("kind", "not core_input")
    if not isinstance(entries, list) or len(entries) > M.MAX_JOURNAL:
        raise M.MessageError("shape", "entries")
    out = []
    for e in entries:
        if isinstance(e, list) and len(e) == 2 and e[0] in ("t", "g"):  # a timer, a collision heard
            out.append([e[0], _time(e[1])])
        elif isinstance(e, list) and len(e) == 3 and e[0] == "m":
            key = msgpack.packb(e[2], use_bin_type=True)
            v = cache.get(key)
            if v is None:
                v = M.validate_msg(e[2])
                if v["kind"] not in M.AIR_MSG_KINDS:
                    raise M.MessageError("kind", "not an air message")
                cache[key] = v
            out.append(["m", _time(e[1]), v])
        else:
            raise M.MessageError("shape", "journal entry")
    msg["entries"] = out
    return msg


def collect_journals(msgs: Sequence[Msg], strict: bool = True) -> dict[int, Journal]:
    """Group init / input / estimate records by station. ``strict`` validates every payload like
    ``net.messages.decode`` (malformed ones are skipped); otherwise plain msgpack (for logs written
    by our own recorder the values are identical: validation normalized them before sending)."""
    from net import messages as M

    out: dict[int, Journal] = {}
    cache: dict[bytes, dict] = {}
    for m in msgs:
        if m.encoding != "msgpack" or not m.topic.startswith("larns/station/"):
            continue
        tail = m.topic.rsplit("/", 1)[-1]
        if tail not in ("init", "input", "estimate"):
            continue
        if strict:
            try:
                msg = decode_input(m.data, cache) if tail == "input" else M.decode(m.data)[0]
            except M.MessageError:
                continue
        else:
            msg = _unpack(m.data)
            if msg is None or msg.get("kind") not in ("core_init", "core_input", "estimate"):
                continue
        sid = key_publisher(m.topic)
        if sid is None or msg.get("src") != sid:  # attributed by key, not by src (issue 32)
            continue
        j = out.setdefault(sid, Journal(sid))
        k = msg["kind"]
        if k == "core_init":
            if j.init is None:
                j.init = msg["record"]
        elif k == "core_input":
            j.inputs.setdefault(int(msg["seq"]), (m, msg["entries"]))
        elif k == "estimate":
            j.estimates.setdefault(int(msg["seq"]), (m, msg))
    return out


def sigma_m(cov_m2) -> np.ndarray:
    """Position sigma ``sqrt(trace P)`` of (..., 3, 3) covariances (negative traces clip to 0)."""
    c = np.asarray(cov_m2, float)
    return np.sqrt(np.maximum(np.trace(c[..., :3, :3], axis1=-2, axis2=-1), 0.0))


# --------------------------------------------------------------------------- series

@dataclass
class StationSeries:
    """One station's recorded messages, in log-time order."""

    id: int
    messages: int = 0
    estimates: list[tuple[int, dict]] = field(default_factory=list)  # (log_time_ns, estimate msg)
    truths: list[dict] = field(default_factory=list)                  # truth msgs
    navs: int = 0
    ranges: int = 0
    polled: int = 0    # protocol v2: members named in its polls
    nav: list[tuple[int, dict]] = field(default_factory=list)       # (log_time_ns, nav broadcast)
    journal: bool = False
    init: dict | None = None          # the first recorded core_init record
    excludes: list | None = None      # the peers its latest integrity decision excludes

    @property
    def last(self) -> dict | None:
        """The last estimate in log order."""
        return self.estimates[-1][1] if self.estimates else None

    @property
    def truth_m(self) -> list[float] | None:
        """The last recorded true position."""
        return self.truths[-1]["pos_m"] if self.truths else None

    @property
    def slot(self) -> int | None:
        """The TDMA slot the station reported last (None if its estimates carry none)."""
        for _, e in reversed(self.estimates):
            if e.get("slot") is not None:
                return int(e["slot"])
        return None

    def drops(self) -> tuple[np.ndarray, np.ndarray]:
        """The station's drop counter (``dropped`` on its estimates) over time: ``(t_s, dropped)``."""
        rows = [(e["t_s"], e["dropped"]) for _, e in self.estimates if e.get("dropped") is not None]
        return np.array([r[0] for r in rows], float), np.array([r[1] for r in rows], int)

    def track(self, order: str = "t_s") -> dict[str, Any]:
        """Estimates as arrays sorted by ``order`` ("t_s" or "log_time_ns"): ``t_s`` (K,), ``pos_m``
        (K, 3), ``cov_m2`` (K, 3, 3), ``n_updates`` (K,), ``log_time_ns`` (K,), ``state`` (last)."""
        rows = sorted(self.estimates, key=(lambda r: r[1]["t_s"]) if order == "t_s" else (lambda r: r[0]))
        return {"t_s": np.array([e["t_s"] for _, e in rows]),
                "pos_m": np.array([e["pos_m"] for _, e in rows], float),
                "cov_m2": np.array([e["cov_m2"] for _, e in rows], float),
                "n_updates": np.array([e["n_updates"] for _, e in rows]),
                "log_time_ns": np.array([ns for ns, _ in rows]),
                "state": rows[-1][1]["state"]}

    def clock(self) -> np.ndarray:
        """Rows ``[t_s, error_ns, sigma_ns]`` sorted by time: the estimate's ``clock_offset_s`` minus
        the truth's ``clock_error_s`` of the same stamp (the last message of each stamp counts)."""
        est = {e["stamp_s"]: (e["t_s"], e["clock_offset_s"], e.get("clock_offset_sd_s", 0.0))
               for _, e in self.estimates if "clock_offset_s" in e}
        tru = {t["stamp_s"]: t["clock_error_s"] for t in self.truths if "clock_error_s" in t}
        rows = sorted((est[k][0], (est[k][1] - tru[k]) * 1e9, est[k][2] * 1e9) for k in est.keys() & tru.keys())
        return np.array(rows, float).reshape(-1, 3)


@dataclass
class AircraftSeries:
    """One aircraft's estimates per algorithm and its truth track, in log order."""

    name: str
    messages: int = 0
    estimates: dict[str, list[dict]] = field(default_factory=dict)  # algo -> ac_estimate msgs
    truths: list[dict] = field(default_factory=list)
    statuses: dict[str, list[dict]] = field(default_factory=dict)  # algo -> ac_status msgs

    @property
    def algos(self) -> list[str]:
        return sorted(self.estimates)

    def track(self, algo: str) -> dict[str, np.ndarray]:
        """One algorithm's estimates sorted by time: ``t_s`` (K,), ``pos_m`` (K, 3), ``cov_m2`` (K, 3, 3)."""
        rows = sorted(self.estimates[algo], key=lambda r: r["t_s"])
        return {"t_s": np.array([r["t_s"] for r in rows]), "pos_m": np.array([r["pos_m"] for r in rows], float),
                "cov_m2": np.array([r["cov_m2"] for r in rows], float)}

    def integrity(self, algo: str) -> dict:
        """One algorithm's integrity series (issue 14; optional ``ac_estimate`` fields) sorted by time:
        ``t_s`` (K,), ``hpl_m`` / ``vpl_m`` (K,; NaN where not published), ``excluded`` (list of K id
        lists), ``exclusions`` {station id: first time it was reported excluded}."""
        rows = sorted(self.estimates[algo], key=lambda r: r["t_s"])
        first: dict[int, float] = {}
        for r in rows:
            for i in r.get("excluded") or ():
                first.setdefault(int(i), float(r["t_s"]))
        return {"t_s": np.array([r["t_s"] for r in rows], float),
                "hpl_m": np.array([r.get("hpl_m", np.nan) for r in rows], float),
                "vpl_m": np.array([r.get("vpl_m", np.nan) for r in rows], float),
                "excluded": [list(r.get("excluded") or ()) for r in rows], "exclusions": first}

    def truth_track(self) -> dict[str, np.ndarray] | None:
        """True ``t_s`` (K,), ``pos_m`` (K, 3), ``vel_m_s`` (K, 3; zeros where not recorded)."""
        if not self.truths:
            return None
        rows = sorted(self.truths, key=lambda r: r["t_s"])
        return {"t_s": np.array([r["t_s"] for r in rows]), "pos_m": np.array([r["pos_m"] for r in rows], float),
                "vel_m_s": np.array([r.get("vel_m_s") if r.get("vel_m_s") is not None else [0.0, 0.0, 0.0]
                                     for r in rows], float)}


@dataclass
class VehicleSeries:
    """One ground vehicle (``larns vehicle``): its estimates, its truth at each estimate's time and its
    navigator journal (init record and inputs by seq), in log order."""

    name: str
    messages: int = 0
    estimates: list[dict] = field(default_factory=list)     # veh_estimate msgs
    truths: dict[float, dict] = field(default_factory=dict)  # t_s -> veh_truth
    init: dict | None = None                                  # the navigator's init record
    inputs: dict[int, list] = field(default_factory=dict)    # veh_input seq -> entries

    def errors(self) -> dict[str, np.ndarray]:
        """Estimates with a truth of the same time: ``t_s`` (K,), ``err_m`` (K,) 3-D position error,
        ``sigma_m`` (K,) root of the position covariance trace, ``updated`` (K,) bool (after a
        measurement, else a whole-second estimate)."""
        rows = sorted(((e["t_s"], float(np.linalg.norm(np.subtract(e["pos_m"], self.truths[e["t_s"]]["pos_m"]))),
                        float(sigma_m(e["cov_m2"])), bool(e.get("extra", {}).get("updated", 0.0)))
                       for e in self.estimates if e["t_s"] in self.truths), key=lambda r: r[0])
        a = np.array(rows, float).reshape(-1, 4)
        return {"t_s": a[:, 0], "err_m": a[:, 1], "sigma_m": a[:, 2], "updated": a[:, 3].astype(bool)}

    def journal(self) -> tuple[list[list], int | None]:
        """The journal's entries from input 1 on, in order, and the first missing input seq (None: none)."""
        out: list[list] = []
        k = 1
        while k in self.inputs:
            out += self.inputs[k]
            k += 1
        return out, (k if self.inputs and k <= max(self.inputs) else None)


@dataclass
class NetworkStats:
    """What the recorder saw of the network, per topic, sender and kind."""

    topics: dict[str, dict] = field(default_factory=dict)
    seqs: dict[tuple, list[int]] = field(default_factory=lambda: defaultdict(list))  # (src, kind) -> seqs
    latency_ms: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    invalid: Counter = field(default_factory=Counter)
    refused: Counter = field(default_factory=Counter)  # (topic, claimed src, reason): not attributed

    def count(self, m: Msg) -> dict:
        t = self.topics.get(m.topic)
        if t is None:
            t = self.topics[m.topic] = {"count": 0, "bytes": 0, "encoding": m.encoding, "kinds": Counter(),
                                        "first_ns": m.log_time, "last_ns": m.log_time}
        t["count"] += 1
        t["bytes"] += len(m.data)
        t["last_ns"] = m.log_time
        return t

    def loss(self) -> tuple[dict[str, dict], dict]:
        """Per kind and in total: received, missing (sequence gaps), duplicates, reordered, leading."""
        loss: dict[str, dict] = {}
        tot: Counter = Counter()
        for (_src, kind), ss in sorted(self.seqs.items(), key=lambda kv: (str(kv[0][0]), kv[0][1])):
            d = loss.setdefault(kind, {"senders": 0, "received": 0, "missing": 0, "duplicates": 0,
                                       "reordered": 0, "leading": 0})
            g = sequence_gaps(ss)
            d["senders"] += 1
            for k in ("received", "missing", "duplicates", "reordered", "leading"):
                d[k] += g[k]
            tot.update(received=g["received"], missing=g["missing"], duplicates=g["duplicates"])
        for d in loss.values():
            d["loss_pct"] = _pct_of(d["missing"], d["received"])
        return loss, {**dict(tot), "loss_pct": _pct_of(tot["missing"], tot["received"])}

    def latency_summary(self) -> dict[str, dict]:
        return {k: {"n": len(v), "p50": percentile(v, 50), "p99": percentile(v, 99), "max": max(v)}
                for k, v in sorted(self.latency_ms.items())}


def _pct_of(missing: int, received: int) -> float:
    n = received + missing
    return 100.0 * missing / n if n else 0.0


def sequence_gaps(seqs: Sequence[int]) -> dict[str, int]:
    """Loss statistics of one sender's sequence numbers in arrival order: ``received`` (distinct),
    ``missing`` (gaps between the first and last), ``duplicates``, ``reordered`` (steps back) and
    ``leading`` (numbers before the first one heard, if the sender starts at 1)."""
    uniq = sorted(set(seqs))
    return {"received": len(uniq), "missing": uniq[-1] - uniq[0] + 1 - len(uniq),
            "duplicates": len(seqs) - len(uniq), "reordered": sum(1 for a, b in zip(seqs, seqs[1:]) if b < a),
            "leading": max(0, uniq[0] - 1)}


def percentile(v: Sequence[float], q: float) -> float:
    """The nearest-rank ``q`` percentile (NaN for no values)."""
    if not v:
        return math.nan
    v = sorted(v)
    return v[min(len(v) - 1, max(0, int(round(q / 100.0 * (len(v) - 1)))))]


# --------------------------------------------------------------------------- the recording

@dataclass
class Recording:
    """A recording decoded once. ``records`` keeps every msgpack record with its decoded message
    (None if undecodable) for consumers that convert message by message (the Foxglove export)."""

    logs: list[LogFile]
    messages: list[Msg]
    timebase: Timebase
    stations: dict[int, StationSeries] = field(default_factory=dict)
    aircraft: dict[str, AircraftSeries] = field(default_factory=dict)
    vehicles: dict[str, VehicleSeries] = field(default_factory=dict)
    net: NetworkStats = field(default_factory=NetworkStats)
    records: list[tuple[Msg, dict | None]] = field(default_factory=list)
    # the exchanges: (stamp_s, initiator, responder, seq, cycle) per range request, or per member a poll
    # names (protocol v2); answered: (initiator, responder, seq) per reply recorded, or per member
    # whose reply the poller's final lists (the poller heard it in its sub-slot)
    range_requests: list[tuple] = field(default_factory=list)
    range_replies: set = field(default_factory=set)
    nav_truth: list[tuple[float, list[float]]] = field(default_factory=list)  # (t_true_s, sender pos_m)
    init_record: dict | None = None  # the first core_init journal record recorded (any station)

    @classmethod
    def from_logs(cls, logs: Sequence[LogFile], check=None) -> "Recording":
        """Decode ``logs``. Every message is attributed by its key, not by its ``src`` field: one
        whose ``src`` is not the key's publisher is refused (``src_mismatch``, counted in
        ``net.refused``). ``check(m, msg)`` (:func:`larns.analysis.verify.signer_check`, from a
        keystore) may refuse more by returning a reason (its signer)."""
        from net import messages as M

        msgs = merge(logs)
        rec = cls(list(logs), msgs, Timebase.of(logs, msgs[0].log_time if msgs else 0))
        for m in msgs:
            t = rec.net.count(m)
            if m.encoding != "msgpack" or m.topic.startswith("larns/trust/"):  # (certificates: DER)
                t["kinds"][m.schema or m.encoding] += 1
                continue
            try:
                msg, phy = M.decode(m.data)
            except M.MessageError as e:
                rec.net.invalid[e.reason] += 1
                t["kinds"]["invalid"] += 1
                rec.records.append((m, None))
                continue
            why = "src_mismatch" if key_publisher(m.topic) != msg["src"] else (check(m, msg) if check else None)
            if why:
                rec.net.refused[(m.topic, str(msg["src"]), why)] += 1
                t["kinds"]["refused"] += 1
                rec.records.append((m, None))
                continue
            rec.records.append((m, msg))
            t["kinds"][msg["kind"]] += 1
            rec._add(m, msg, phy)
        rec.nav_truth.sort()
        return rec

    def _add(self, m: Msg, msg: dict, phy: dict | None) -> None:
        kind, src = msg["kind"], msg["src"]
        self.net.seqs[(src, kind)].append(msg["seq"])
        if m.publish_time != m.log_time:
            self.net.latency_ms[kind].append(Timebase.latency_ms(m.log_time, m.publish_time))
        if kind == "range_req":
            self.range_requests.append((msg["stamp_s"], src, msg["dst"], msg["seq"], msg["cycle"]))
        elif kind == "range_rsp":
            self.range_replies.add((msg["dst"], src, msg["req_seq"]))
        elif kind == "poll":
            self.range_requests += [(msg["stamp_s"], src, p, msg["seq"], msg["cycle"]) for p in msg["members"]]
        elif kind == "nav" and "poll" in msg:
            self.range_replies.update((src, p, msg["poll"]["seq"]) for p, _ in msg["poll"]["rx"])
        if isinstance(src, int):
            self._add_station(self.stations.setdefault(src, StationSeries(src)), m, msg, phy)
        elif kind.startswith("veh_"):
            self._add_vehicle(self.vehicles.setdefault(src, VehicleSeries(src)), msg)
        else:
            self._add_aircraft(self.aircraft.setdefault(src, AircraftSeries(src)), msg)

    def _add_station(self, s: StationSeries, m: Msg, msg: dict, phy: dict | None) -> None:
        s.messages += 1
        kind = msg["kind"]
        if kind == "estimate":
            s.estimates.append((m.log_time, msg))
        elif kind == "truth":
            s.truths.append(msg)
        elif kind == "nav":
            s.nav.append((m.log_time, msg))
            s.navs += 1
            s.ranges += len(msg["ranges"])
            if phy is not None and msg["state"] in ("frame", "surveying"):
                self.nav_truth.append((phy["t_true_s"], phy["pos_m"]))
        elif kind == "poll":
            s.polled += len(msg["members"])
        elif kind in ("core_init", "core_input"):
            s.journal = True
            if kind == "core_init" and s.init is None:
                s.init = msg["record"]
                if self.init_record is None:
                    self.init_record = s.init
        elif kind == "integrity":
            s.excludes = sorted(msg.get("excluded", []))

    @staticmethod
    def _add_aircraft(a: AircraftSeries, msg: dict) -> None:
        a.messages += 1
        if msg["kind"] == "ac_estimate":
            a.estimates.setdefault(msg["algo"], []).append(msg)
        elif msg["kind"] == "ac_truth":
            a.truths.append(msg)
        elif msg["kind"] == "ac_status":
            a.statuses.setdefault(msg["algo"], []).append(msg)

    @staticmethod
    def _add_vehicle(v: VehicleSeries, msg: dict) -> None:
        v.messages += 1
        kind = msg["kind"]
        if kind == "veh_estimate":
            v.estimates.append(msg)
        elif kind == "veh_truth":
            v.truths[msg["t_s"]] = msg
        elif kind == "veh_init" and v.init is None:
            v.init = msg["record"]
        elif kind == "veh_input":
            v.inputs.setdefault(msg["seq"], msg["entries"])

    # ------------------------------------------------------------------ derived views

    @property
    def truth_positions(self) -> dict[int, list[float]]:
        """Last true position per station that published one."""
        return {sid: s.truth_m for sid, s in self.stations.items() if s.truth_m is not None}

    @property
    def meta(self) -> dict[str, str]:
        return self.logs[0].larns_meta if self.logs else {}


def load(paths: Sequence[str | Path], check=None) -> Recording:
    """Read and decode one or several recordings (merged by log time; ``check``: see
    :meth:`Recording.from_logs`)."""
    return Recording.from_logs(read_logs(paths), check)


def key_publisher(topic: str) -> int | str | None:
    """Who publishes on ``topic`` (access control lets only them): ``larns/station/7/nav`` -> 7,
    ``larns/aircraft/ac1/...`` and ``larns/vehicle/v1/...`` -> the name; None for other keys."""
    parts = str(topic).split("/")
    if len(parts) < 3 or parts[0] != "larns":
        return None
    if parts[1] == "station":
        return int(parts[2]) if parts[2].isdigit() else None
    return parts[2] if parts[1] in ("aircraft", "vehicle") else None
