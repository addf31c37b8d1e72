"""Live Foxglove view of a running fleet (``larns view``) and of a replayed recording (``larns replay --view``).

A pure core, :class:`LiveView`, turns LARNS wire samples into Foxglove messages; the shell,
:class:`FoxgloveServer`, serves them on a Foxglove WebSocket (the official Foxglove SDK,
``foxglove-sdk``) with the SDK's typed messages (protobuf) for the 3D scene, the transforms and the
logs, and JSON channels for the plottable numbers. :func:`serve_live` joins a Zenoh subscription
on ``larns/**`` to both.

| topic | schema | what |
|---|---|---|
| ``larns/foxglove/tf`` | ``foxglove.FrameTransform`` | as in recordings (``larns/viz/foxglove.py``) |
| ``larns/foxglove/scene`` | ``foxglove.SceneUpdate`` | 3-sigma ellipsoids, truth cubes, labels; also the aircraft / vehicle tracks (line strips of estimate and truth) and each range exchange as a line between the two stations (lifetime one second) |
| ``larns/foxglove/station/<id>`` | ``larns.StationEstimate`` | position, sigmas, 3-sigma bound, error vs truth |
| ``larns/foxglove/station/<id>/sync`` | ``larns.StationSync`` | the station's clock estimate against network time, its sigma, the true clock error and the sync error |
| ``larns/foxglove/aircraft/<name>/<algo>``, ``larns/foxglove/vehicle/<name>/<algo>`` | ``larns.AircraftEstimate`` | as in recordings |
| ``larns/foxglove/fix/...`` | ``foxglove.LocationFix`` | with a site (scenario ``[site]``): estimates and truth on WGS84 for the Map panel, as in recordings |
| ``larns/foxglove/tdma`` | ``larns.Exchange`` | one record per range request: fleet time, cycle, slot, initiator, addressee (TDMA timeline) |
| ``larns/foxglove/log`` | ``foxglove.Log`` | integrity decisions, processes appearing / leaving (liveliness), aircraft navigator states (``ac_status`` changes), malformed messages dropped (here, and the stations' own ``dropped`` counts) |

Message times (``log_time``) and the server's time (the ``time`` capability) are **fleet time**:
nanoseconds since the fleet epoch (``t_s`` of a message, else its ``stamp_s``), so Foxglove's
timeline reads fleet seconds. Malformed samples are counted by reason (:attr:`LiveView.dropped`)
and dropped; the view never raises on a sample.
"""

from __future__ import annotations

import json
import logging
import math
import queue
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass
from typing import Any, Callable

from .foxglove import COLORS, FRAME, IDENTITY, SCENE_TOPIC, SCHEMA_BYTES, FoxgloveView, _color, _empty_entity, _f, stamp

log = logging.getLogger("larns.view")

LOG_TOPIC = "larns/foxglove/log"
TDMA_TOPIC = "larns/foxglove/tdma"
TRACK_POINTS = 300        # last positions kept per track
TRACK_PERIOD_NS = 500_000_000  # a track (up to 300 points) is sent at most every 0.5 fleet s
EXCHANGE_LIFETIME_S = 1.0  # an exchange line stays one (default) TDMA cycle
DEFAULT_PORT = 8765
BACKLOG_MESSAGES = 16384   # per client before the SDK drops its oldest (a slow link; default 1024)
TRUTH_EVERY = 10           # a station's truth cube is sent again every 10 of its truths

_NUM = {"type": "number"}
LIVE_SCHEMAS: dict[str, dict] = {
    "larns.StationSync": {
        "title": "larns.StationSync",
        "description": "A station's clock against network time (station 1's clock): its estimate "
                       "(offset, fractional frequency, standard deviations) from the estimate message, "
                       "the true offset from the truth message of the same stamp and their difference.",
        "type": "object", "additionalProperties": False,
        "properties": {"t_s": _NUM, "id": {"type": "integer"}, "clock_offset_s": _NUM, "clock_freq": _NUM,
                       "clock_offset_sd_s": _NUM, "clock_freq_sd": _NUM, "clock_error_s": _NUM,
                       "sync_err_s": _NUM},
        "required": ["t_s", "id", "clock_offset_s"]},
    "larns.Exchange": {
        "title": "larns.Exchange",
        "description": "A range request in the TDMA plan: initiator src asks dst in its slot of the cycle.",
        "type": "object", "additionalProperties": False,
        "properties": {"t_s": _NUM, "cycle": {"type": "integer"}, "slot": {"type": "integer"},
                       "src": {"type": "integer"}, "dst": {"type": "integer"}},
        "required": ["t_s", "cycle", "slot", "src", "dst"]},
}
LIVE_SCHEMA_BYTES = {**SCHEMA_BYTES, **{k: json.dumps(v, sort_keys=True).encode() for k, v in LIVE_SCHEMAS.items()}}

EAGER_CHANNELS = ((LOG_TOPIC, "foxglove.Log"), (SCENE_TOPIC, "foxglove.SceneUpdate"),
                  ("larns/foxglove/tf", "foxglove.FrameTransform"), (TDMA_TOPIC, "larns.Exchange"))

# foxglove.Log levels (the SDK's LogLevel values)
INFO, WARNING = 2, 3


@dataclass(frozen=True)
class Out:
    """One message for the viewer: topic, schema name, the message as a dict (the JSON layout of
    the Foxglove schema), its log time (fleet ns)."""

    topic: str
    schema: str
    data: dict
    log_ns: int


def fleet_ns(msg: dict) -> int:
    """A message's fleet time in ns: ``t_s`` when it has one, else ``stamp_s`` (never negative)."""
    t = msg.get("t_s", msg.get("stamp_s", 0.0))
    t = float(t) if isinstance(t, (int, float)) and math.isfinite(t) else 0.0
    return max(int(round(t * 1e9)), 0)


def log_record(ns: int, level: int, name: str, text: str) -> dict[str, Any]:
    """A ``foxglove.Log`` message as a dict."""
    return {"timestamp": stamp(ns), "level": level, "message": text, "name": name, "file": "", "line": 0}


def _point(p) -> dict[str, float]:
    return {"x": _f(p[0]), "y": _f(p[1]), "z": _f(p[2])}


def _line_entity(ns: int, eid: str, points, color, thickness: float, lifetime_s: float = 0.0) -> dict:
    ent = _empty_entity(ns, eid)
    if lifetime_s > 0:
        ent["lifetime"] = {"sec": int(lifetime_s), "nsec": int(round((lifetime_s % 1.0) * 1e9))}
    ent["lines"].append({"type": 0, "pose": {"position": _point([0, 0, 0]), "orientation": dict(IDENTITY)},
                         "thickness": thickness, "scale_invariant": True,
                         "points": [_point(p) for p in points], "color": _color(color), "colors": [],
                         "indices": []})
    return ent


class LiveView:
    """Pure converter of live wire samples to viewer messages (no I/O, no clock).

    ``on_sample(key, data)`` and ``on_alive(key, alive)`` return :class:`Out` lists; ``t_ns`` is the
    latest fleet time seen (the server's time); ``dropped`` counts malformed samples by reason."""

    def __init__(self, track_points: int = TRACK_POINTS, site=None) -> None:
        self.fox = FoxgloveView(site)  # site (nav.site.Site): LocationFix channels too
        self.track_points = track_points
        self.t_ns = 0
        self.samples = 0
        self.sources: Counter[str] = Counter()   # samples per sender (first three key chunks)
        self.dropped: Counter[str] = Counter()
        self.station_pos: dict[int, list[float]] = {}
        self.tracks: dict[str, deque] = {}
        self._track_sent: dict[str, int] = {}                     # track id -> fleet ns last sent
        self._clock_truth: dict[int, tuple[float, float]] = {}   # sid -> (stamp_s, clock_error_s)
        self._pending_sync: dict[int, tuple[float, dict]] = {}   # sid -> (stamp_s, sync record)
        self._truths: dict[int, int] = {}                         # sid -> truths seen
        self._dropped_at: dict[int, int] = {}                     # sid -> its last `dropped` count
        self._ac_state: dict[tuple[str, str], str] = {}           # (aircraft, algo) -> last ac_status state

    # ------------------------------------------------------------------ entry points
    def on_sample(self, key: str, data: bytes, log_ns: int | None = None) -> list[Out]:
        """One wire sample. Its outputs are stamped with ``log_ns`` when given (a replay's player
        time), else with the message's own fleet time (:func:`fleet_ns`)."""
        from net.messages import MessageError

        from ..log.series import decode

        self.samples += 1
        self.sources["/".join(key.split("/")[:3])] += 1
        if log_ns is not None:
            self.t_ns = max(self.t_ns, int(log_ns))
        try:
            msg, _ = decode(data)
        except MessageError as e:
            return self._drop(e.reason, key)
        except Exception as e:  # noqa: BLE001 - a viewer never dies on a sample
            return self._drop(type(e).__name__, key)
        ns = fleet_ns(msg) if log_ns is None else int(log_ns)
        self.t_ns = max(self.t_ns, ns)
        try:
            return self._convert(msg, ns)
        except Exception as e:  # noqa: BLE001 - a valid message the view cannot draw
            return self._drop("view:" + type(e).__name__, key)

    def on_alive(self, key: str, alive: bool) -> list[Out]:
        """A liveliness token appeared or went away: a process started or stopped."""
        who = key.removeprefix("larns/alive/")
        text = f"{who} {'is up' if alive else 'went away'}"
        return [Out(LOG_TOPIC, "foxglove.Log", log_record(self.t_ns, INFO if alive else WARNING, who, text),
                    self.t_ns)]

    # ------------------------------------------------------------------ conversion
    def _drop(self, reason: str, key: str) -> list[Out]:
        self.dropped[reason] += 1
        n = self.dropped[reason]
        if n == 1 or n % 100 == 0:
            text = f"dropped malformed message on {key} ({reason}; {n} so far)"
            return [Out(LOG_TOPIC, "foxglove.Log", log_record(self.t_ns, WARNING, "larns view", text), self.t_ns)]
        return []

    def _convert(self, msg: dict, ns: int) -> list[Out]:
        kind = msg["kind"]
        out = [Out(t, s, d, ns) for t, s, d in self.fox.convert(msg, ns)]
        if kind == "estimate":
            self.station_pos[msg["src"]] = msg["pos_m"]
            out += self._sync_from_estimate(msg, ns) + self._station_drops(msg, ns)
        elif kind == "truth":
            out += self._truth_again(msg, ns, bool(out)) + self._sync_from_truth(msg)
        elif kind == "range_req":
            out += self._exchange(msg, ns)
        elif kind == "poll":  # protocol v2: one exchange per member named
            for p in msg["members"]:
                out += self._exchange(dict(msg, dst=p), ns, f"exchange/{msg['src']}/{p}")
        elif kind == "integrity":
            out += self._integrity(msg, ns)
        elif kind in ("ac_estimate", "veh_estimate", "ac_truth", "veh_truth"):
            out += self._track(msg, ns)
        elif kind == "ac_status":
            out += self._status_change(msg, ns)
        return out

    def _station_drops(self, msg: dict, ns: int) -> list[Out]:
        """A station's count of malformed messages it dropped went up: a warning."""
        sid, n = msg["src"], int(msg.get("dropped", 0))
        before = self._dropped_at.get(sid, 0)
        self._dropped_at[sid] = n
        if n <= before:
            return []
        text = f"station {sid} dropped {n - before} malformed message(s) ({n} so far)"
        return [Out(LOG_TOPIC, "foxglove.Log", log_record(ns, WARNING, f"station/{sid}", text), ns)]

    def _status_change(self, msg: dict, ns: int) -> list[Out]:
        """An aircraft navigator's state (waiting, tracking, restarting, ...) when it changes."""
        who = (msg["src"], msg["algo"])
        if self._ac_state.get(who) == msg["state"]:
            return []
        self._ac_state[who] = msg["state"]
        detail = f" ({msg['detail']})" if msg.get("detail") else ""
        text = f"{msg['src']} {msg['algo']}: {msg['state']}{detail}"
        return [Out(LOG_TOPIC, "foxglove.Log", log_record(ns, INFO, f"aircraft/{msg['src']}", text), ns)]

    def _truth_again(self, msg: dict, ns: int, sent: bool) -> list[Out]:
        """A station's truth cube again every ``TRUTH_EVERY`` truths: the recording view draws it once,
        a viewer that connects later must still get it."""
        sid = msg["src"]
        n = self._truths[sid] = self._truths.get(sid, 0) + 1
        if sent or n % TRUTH_EVERY:
            return []
        fresh = FoxgloveView(self.fox.site)
        return [Out(t, s, d, ns) for t, s, d in fresh.convert(msg, ns) if s != "larns.StationEstimate"]

    def _sync_from_estimate(self, msg: dict, ns: int) -> list[Out]:
        if "clock_offset_s" not in msg:
            return []
        sid = msg["src"]
        rec = {"t_s": _f(msg["t_s"]), "id": int(sid)}
        for k in ("clock_offset_s", "clock_freq", "clock_offset_sd_s", "clock_freq_sd"):
            if k in msg:
                rec[k] = _f(msg[k])
        tr = self._clock_truth.get(sid)
        if tr is not None and tr[0] == msg["stamp_s"]:
            return [self._sync_out(rec, tr[1], ns)]
        self._pending_sync[sid] = (msg["stamp_s"], rec)
        return [Out(f"larns/foxglove/station/{sid}/sync", "larns.StationSync", rec, ns)]

    def _sync_from_truth(self, msg: dict) -> list[Out]:
        if "clock_error_s" not in msg:
            return []
        sid = msg["src"]
        self._clock_truth[sid] = (msg["stamp_s"], float(msg["clock_error_s"]))
        pend = self._pending_sync.pop(sid, None)
        if pend is None or pend[0] != msg["stamp_s"]:
            return []
        rec = pend[1]
        return [self._sync_out(dict(rec), float(msg["clock_error_s"]), int(round(rec["t_s"] * 1e9)))]

    @staticmethod
    def _sync_out(rec: dict, clock_error_s: float, ns: int) -> Out:
        rec["clock_error_s"] = _f(clock_error_s)
        rec["sync_err_s"] = _f(rec["clock_offset_s"] - clock_error_s)
        return Out(f"larns/foxglove/station/{rec['id']}/sync", "larns.StationSync", rec, max(ns, 0))

    def _exchange(self, msg: dict, ns: int, entity: str | None = None) -> list[Out]:
        """A range request (or a poll's member, ``entity`` its line's id): the TDMA record and a line
        initiator -> responder in the 3-D scene."""
        src, dst = msg["src"], msg["dst"]
        rec = {"t_s": ns * 1e-9, "cycle": int(msg["cycle"]), "slot": int(msg["slot"]), "src": int(src),
               "dst": int(dst)}
        out = [Out(TDMA_TOPIC, "larns.Exchange", rec, ns)]
        a, b = self.station_pos.get(src), self.station_pos.get(dst)
        if a is not None and b is not None:
            ent = _line_entity(ns, entity or f"exchange/{src}", [a, b], (1.0, 1.0, 1.0, 0.8), 2.0, EXCHANGE_LIFETIME_S)
            out.append(Out(SCENE_TOPIC, "foxglove.SceneUpdate", {"deletions": [], "entities": [ent]}, ns))
        return out

    def _integrity(self, msg: dict, ns: int) -> list[Out]:
        exclude = msg["decision"] == "exclude"
        verb = "excludes" if exclude else "re-admits"
        text = (f"station {msg['src']} {verb} station {msg['suspect']} (chi-square {msg['statistic']:.2f} "
                f"{'>' if exclude else '<='} {msg['threshold']:.2f}, p_fa {msg['p_fa']:g})")
        return [Out(LOG_TOPIC, "foxglove.Log",
                    log_record(ns, WARNING if exclude else INFO, f"station/{msg['src']}", text), ns)]

    def _track(self, msg: dict, ns: int) -> list[Out]:
        role = "aircraft" if msg["kind"].startswith("ac_") else "vehicle"
        truth = msg["kind"].endswith("truth")
        tid = f"{role}/{msg['src']}/{'truth' if truth else msg['algo']}/track"
        pts = self.tracks.setdefault(tid, deque(maxlen=self.track_points))
        pts.append(msg["pos_m"])
        if len(pts) < 2 or ns - self._track_sent.get(tid, -TRACK_PERIOD_NS) < TRACK_PERIOD_NS:
            return []
        self._track_sent[tid] = ns
        color = COLORS["ac_truth" if truth else "aircraft"][:3] + (0.9,)
        ent = _line_entity(ns, tid, list(pts), color, 1.5)
        return [Out(SCENE_TOPIC, "foxglove.SceneUpdate", {"deletions": [], "entities": [ent]}, ns)]


# --------------------------------------------------------------------------- the SDK's typed messages

def _enum(cls, value: int):
    """The member of one of the SDK's enums with this value (they cannot be made from an int)."""
    for name in dir(cls):
        m = getattr(cls, name)
        if isinstance(m, cls) and m.value == value:
            return m
    raise ValueError(f"{cls.__name__}: no member of value {value}")


def _sdk_pose(d: dict):
    from foxglove.messages import Pose, Quaternion, Vector3

    return Pose(position=Vector3(**d["position"]), orientation=Quaternion(**d["orientation"]))


def _sdk_shape(cls, d: dict):
    from foxglove.messages import Color, Vector3

    return cls(pose=_sdk_pose(d["pose"]), size=Vector3(**d["size"]), color=Color(**d["color"]))


def _sdk_entity(e: dict):
    from foxglove.messages import (Color, CubePrimitive, Duration, KeyValuePair, LinePrimitive,
                                   LinePrimitiveLineType, Point3, SceneEntity, SpherePrimitive, TextPrimitive,
                                   Timestamp)

    texts = [TextPrimitive(pose=_sdk_pose(t["pose"]), billboard=t["billboard"], font_size=t["font_size"],
                           scale_invariant=t["scale_invariant"], color=Color(**t["color"]), text=t["text"])
             for t in e["texts"]]
    lines = [LinePrimitive(type=_enum(LinePrimitiveLineType, ln["type"]), pose=_sdk_pose(ln["pose"]),
                           thickness=ln["thickness"], scale_invariant=ln["scale_invariant"],
                           points=[Point3(**p) for p in ln["points"]], color=Color(**ln["color"]))
             for ln in e["lines"]]
    return SceneEntity(timestamp=Timestamp(**e["timestamp"]), frame_id=e["frame_id"], id=e["id"],
                       lifetime=Duration(**e["lifetime"]), frame_locked=e["frame_locked"],
                       metadata=[KeyValuePair(**kv) for kv in e["metadata"]],
                       cubes=[_sdk_shape(CubePrimitive, c) for c in e["cubes"]],
                       spheres=[_sdk_shape(SpherePrimitive, s) for s in e["spheres"]], lines=lines, texts=texts)


def _sdk_fix(d: dict):
    from foxglove.messages import Color, KeyValuePair, LocationFix, LocationFixPositionCovarianceType, Timestamp, Vector3

    return LocationFix(timestamp=Timestamp(**d["timestamp"]), frame_id=d["frame_id"], latitude=d["latitude"],
                       longitude=d["longitude"], altitude=d["altitude"], position_covariance=d["position_covariance"],
                       position_covariance_type=_enum(LocationFixPositionCovarianceType, d["position_covariance_type"]),
                       heading=d["heading"], velocity=Vector3(**d["velocity"]), color=Color(**d["color"]),
                       metadata=[KeyValuePair(**kv) for kv in d["metadata"]])


def to_sdk(schema: str, d: dict):
    """The Foxglove SDK's typed message for a ``foxglove.*`` dict of :class:`LiveView` /
    :class:`~larns.viz.foxglove.FoxgloveView` (same field names as the Foxglove schemas)."""
    from foxglove.messages import (FrameTransform, Log, LogLevel, Quaternion, SceneEntityDeletion,
                                   SceneEntityDeletionType, SceneUpdate, Timestamp, Vector3)

    if schema == "foxglove.FrameTransform":
        return FrameTransform(timestamp=Timestamp(**d["timestamp"]), parent_frame_id=d["parent_frame_id"],
                              child_frame_id=d["child_frame_id"], translation=Vector3(**d["translation"]),
                              rotation=Quaternion(**d["rotation"]))
    if schema == "foxglove.SceneUpdate":
        dels = [SceneEntityDeletion(timestamp=Timestamp(**x["timestamp"]), type=_enum(SceneEntityDeletionType, x["type"]),
                                    id=x["id"]) for x in d["deletions"]]
        return SceneUpdate(deletions=dels, entities=[_sdk_entity(e) for e in d["entities"]])
    if schema == "foxglove.LocationFix":
        return _sdk_fix(d)
    if schema == "foxglove.Log":
        return Log(timestamp=Timestamp(**d["timestamp"]), level=_enum(LogLevel, d["level"]), message=d["message"],
                   name=d["name"], file=d["file"], line=d["line"])
    raise KeyError(schema)


# --------------------------------------------------------------------------- the shell: Foxglove WebSocket

def _latch_listener(subscribed: queue.SimpleQueue):
    """The SDK server listener of the live view: the topic of every subscription into ``subscribed``."""
    from foxglove.websocket import ServerListener

    class Latch(ServerListener):
        def on_subscribe(self, client, channel) -> None:  # noqa: ARG002
            subscribed.put(channel.topic)

    return Latch()


class FoxgloveServer:
    """A Foxglove WebSocket server (SDK) with one channel per topic, made on first use.

    ``playback_range_ns`` (``(start_ns, end_ns)``, with a ``listener``) turns on the playback-control
    capability. Without a listener (live) a channel is latched: a client that subscribes gets its
    latest message again (:meth:`resend_latched`, called by the serving loop)."""

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT, name: str = "larns view",
                 playback_range_ns: tuple[int, int] | None = None, listener=None) -> None:
        import foxglove
        from foxglove.websocket import Capability

        self.ctx = foxglove.Context()
        caps = [Capability.Time]
        self.last: dict[str, Out] = {}                      # topic -> its latest message
        self._subscribed: queue.SimpleQueue = queue.SimpleQueue()  # topics a client just subscribed to
        if listener is None:  # live: a new subscriber gets the channel's latest message (latched)
            listener = _latch_listener(self._subscribed)
        self.server = foxglove.start_server(name=name, host=host, port=port, context=self.ctx, capabilities=caps,
                                            playback_time_range=playback_range_ns, server_listener=listener,
                                            supported_encodings=["json", "protobuf"],
                                            message_backlog_size=BACKLOG_MESSAGES)
        self.channels: dict[str, Any] = {}
        self.sent = 0
        self.failed: Counter[str] = Counter()
        self._time_ns = -1
        # advertised from the start: a client subscribes before the first scene update or log line
        for topic, schema in EAGER_CHANNELS:
            self.channel(topic, schema)

    @property
    def port(self) -> int:
        return self.server.port

    def channel(self, topic: str, schema: str):
        ch = self.channels.get(topic)
        if ch is None:
            import foxglove
            from foxglove.channels import FrameTransformChannel, LocationFixChannel, LogChannel, SceneUpdateChannel

            typed = {"foxglove.FrameTransform": FrameTransformChannel, "foxglove.SceneUpdate": SceneUpdateChannel,
                     "foxglove.Log": LogChannel, "foxglove.LocationFix": LocationFixChannel}
            if schema in typed:
                ch = typed[schema](topic, context=self.ctx)
            else:
                ch = foxglove.Channel(topic, schema=foxglove.Schema(name=schema, encoding="jsonschema",
                                                                    data=LIVE_SCHEMA_BYTES[schema]),
                                      message_encoding="json", context=self.ctx)
            self.channels[topic] = ch
        return ch

    def send(self, outs: list[Out]) -> None:
        for o in outs:
            if self._log(o):
                self.last[o.topic] = o
                self.sent += 1

    def _log(self, o: Out) -> bool:
        try:
            ch = self.channel(o.topic, o.schema)
            if o.schema.startswith("foxglove."):
                ch.log(to_sdk(o.schema, o.data), log_time=o.log_ns)
            else:
                ch.log(json.dumps(o.data, allow_nan=False, separators=(",", ":")).encode(), log_time=o.log_ns)
            return True
        except Exception as e:  # noqa: BLE001 - one message lost, never the server
            self.failed[f"{o.schema}:{type(e).__name__}"] += 1
            if self.failed[f"{o.schema}:{type(e).__name__}"] == 1:
                log.warning("cannot send %s on %s: %r", o.schema, o.topic, e)
            return False

    def resend_latched(self) -> int:
        """The latest message of each channel a client subscribed to since the last call, again (the
        first message of a new channel goes out before anyone could subscribe to it). Returns how many."""
        topics = set()
        while True:
            try:
                topics.add(self._subscribed.get_nowait())
            except queue.Empty:
                break
        n = sum(self._log(self.last[t]) for t in topics if t in self.last)
        self.sent += n
        return n

    def time(self, t_ns: int) -> None:
        """The server's time (Foxglove's current time), sent when it changes."""
        if t_ns != self._time_ns:
            self._time_ns = t_ns
            self.server.broadcast_time(int(t_ns))

    def stop(self) -> None:
        self.server.stop()


LIVE_QUEUE_MAX = 16384  # samples waiting for the view's loop (a 10-station fleet sends ~300 per second)


def serve_live(bus_kw: dict, host: str = "127.0.0.1", port: int = DEFAULT_PORT, keyexpr: str = "larns/**",
               duration_s: float | None = None, stop: threading.Event | None = None,
               on_ready: Callable[[int], None] | None = None, site=None) -> dict:
    """Subscribe to ``keyexpr`` on Zenoh and serve the live view until ``stop`` / ``duration_s``
    (``site``: the scenario's :class:`nav.site.Site`, for the LocationFix channels).
    Returns statistics (samples, messages sent, dropped by reason)."""
    from net.bus import Bus

    from net.queues import DropOldestQueue

    stop = stop or threading.Event()
    q = DropOldestQueue(LIVE_QUEUE_MAX)  # bounded (issue 32): a flood costs old samples, never memory
    bus = Bus(**bus_kw)
    view = LiveView(site=site)
    try:
        srv = FoxgloveServer(host, port)
    except Exception:
        bus.close()
        raise
    try:
        bus.subscribe(keyexpr, lambda k, d: q.put(("s", k, d)))
        bus.subscribe_liveliness("larns/alive/**", lambda k, a: q.put(("a", k, a)))
        if on_ready is not None:
            on_ready(srv.port)
        t_end = time.monotonic() + duration_s if duration_s else float("inf")
        while not stop.is_set() and time.monotonic() < t_end:
            srv.resend_latched()
            try:
                item = q.get(timeout=0.1)
            except queue.Empty:
                continue
            while item is not None:
                outs = view.on_sample(item[1], item[2]) if item[0] == "s" else view.on_alive(item[1], item[2])
                srv.send(outs)
                try:
                    item = q.get_nowait()
                except queue.Empty:
                    item = None
            srv.time(view.t_ns)
    finally:
        bus.close()
        srv.stop()
    return {"samples": view.samples, "sources": dict(sorted(view.sources.items())), "sent": srv.sent,
            "channels": len(srv.channels),
            "dropped": {**view.dropped, **({"queue_full": q.dropped} if q.dropped else {})},
            "failed": dict(srv.failed)}


# --------------------------------------------------------------------------- replay into Foxglove

def replay_times_ns(msgs, timebase) -> list[int]:
    """The player's time axis for recorded messages: fleet ns of each ``log_time`` (the recording's
    timebase), clamped at 0 and never decreasing."""
    out, last = [], 0
    for m in msgs:
        last = max(last, int(round(max(timebase.fleet_s(m.log_time), 0.0) * 1e9)))
        out.append(last)
    return out


class _PlaybackListener:
    """The SDK's server listener: Foxglove's playback controls drive the player."""

    def __init__(self, player, clock=time.monotonic, auto_start: bool = True):
        self.player = player
        self.clock = clock
        self.auto_start = auto_start  # play once the first client has subscribed
        self.subscribed_s: float | None = None

    def on_subscribe(self, client, channel) -> None:  # noqa: ARG002
        if self.subscribed_s is None:
            self.subscribed_s = self.clock()

    def start_if_subscribed(self, settle_s: float = 0.25) -> None:
        """Auto start ``settle_s`` after the first subscription (a client subscribes to its channels
        one after another: none misses the first messages)."""
        if self.auto_start and self.subscribed_s is not None and self.clock() - self.subscribed_s > settle_s:
            self.auto_start = False
            self.player.control(True, None, None, self.clock())

    def on_playback_control_request(self, req):
        from foxglove.websocket import PlaybackCommand, PlaybackState

        p = self.player
        p.control(req.playback_command == PlaybackCommand.Play, req.playback_speed, req.seek_time, self.clock())
        return PlaybackState(status=_status(p), current_time=p.cur_ns, playback_speed=p.speed,
                             did_seek=req.seek_time is not None, request_id=req.request_id)


def _status(p):
    from foxglove.websocket import PlaybackStatus

    if p.ended:
        return PlaybackStatus.Ended
    return PlaybackStatus.Playing if p.playing else PlaybackStatus.Paused


def serve_recording(msgs, timebase, host: str = "127.0.0.1", port: int = DEFAULT_PORT, speed: float = 1.0,
                    start_paused: bool = False, duration_s: float | None = None,
                    stop: threading.Event | None = None, on_ready: Callable[[int], None] | None = None,
                    tick_s: float = 0.02, site=None) -> dict:
    """Serve recorded wire messages (``msgpack``, sorted by log time) through the live view on a
    Foxglove WebSocket with playback controls (play, pause, speed, seek) driving the player.
    Playback starts when the first client subscribes (unless ``start_paused``: then on the client's
    play). Serves until ``stop`` / ``duration_s`` (also after the end: the client may seek back)."""
    from foxglove.websocket import PlaybackState

    from ..log.player import SeekablePlayer

    stop = stop or threading.Event()
    times = replay_times_ns(msgs, timebase)
    player = SeekablePlayer(times, speed=speed, playing=False, now_s=time.monotonic())
    from foxglove.websocket import ServerListener

    class Listener(_PlaybackListener, ServerListener):  # the SDK's no-op defaults for the other callbacks
        pass

    listener = Listener(player, auto_start=not start_paused)
    srv = FoxgloveServer(host, port, name="larns replay", playback_range_ns=(player.start_ns, player.end_ns),
                         listener=listener)
    view, seeks, delivered, status = LiveView(site=site), 0, 0, None
    try:
        dry = LiveView(site=site)  # every channel advertised before playing: a client gets each first message
        for m, t in zip(msgs, times):
            for o in dry.on_sample(m.topic, m.data, log_ns=t):
                srv.channel(o.topic, o.schema)
        if on_ready is not None:
            on_ready(srv.port)
        t_end = time.monotonic() + duration_s if duration_s else float("inf")
        while not stop.is_set() and time.monotonic() < t_end:
            if listener.subscribed_s is None:  # nobody to play to yet
                time.sleep(tick_s)
                continue
            listener.start_if_subscribed()
            due, cur_ns = player.step(time.monotonic())
            if player.seeks != seeks:  # a seek: tracks and pending records start afresh
                seeks, view = player.seeks, LiveView(site=site)
            for i in due:
                srv.send(view.on_sample(msgs[i].topic, msgs[i].data, log_ns=times[i]))
                delivered += 1
            srv.time(cur_ns)
            st = _status(player)
            if st != status:  # tell clients when playback ends (or its state changes by itself)
                status = st
                srv.server.broadcast_playback_state(PlaybackState(status=st, current_time=cur_ns,
                                                                  playback_speed=player.speed, did_seek=False,
                                                                  request_id=None))
            time.sleep(tick_s)
    finally:
        srv.stop()
    return {"messages": len(msgs), "delivered": delivered, "sent": srv.sent, "seeks": player.seeks,
            "dropped": dict(view.dropped), "failed": dict(srv.failed)}
