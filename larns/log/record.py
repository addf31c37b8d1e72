"""The recorder behind `larns record -o run.mcap` (adapter: ``larns/commands/record.py``): passive Zenoh observer writing every `larns/**` sample to MCAP.

One MCAP channel per key expression, ``message_encoding`` "msgpack", the exact wire bytes
(lossless, replayable). ``log_time`` is the receive time (ns since the Unix epoch);
``publish_time`` is the sender's stamp (``msg.stamp_s`` converted with the fleet epoch and speed:
``epoch + stamp_s / speed``), or the receive time when the payload has no readable stamp.
The file's metadata record ``larns`` holds the scenario name, epoch and speed, and, when the scenario
has a ``[site]``, the site (``site``: origin, azimuth and the network frame's tie, JSON; ``nav/site.py``):
the Foxglove view then writes ``foxglove.LocationFix`` channels and ``larns export --geojson`` finds it.

The file is flushed (chunk finished) every ``--flush`` seconds, so a SIGKILLed recording loses at
most that much. SIGINT / SIGTERM finish the file cleanly (summary + index).

Bounded (issue 32): samples wait in a drop-oldest queue (``net/queues.py``, :data:`QUEUE_MAX`), and
a source (``larns/<role>/<name>``) may open at most :data:`MAX_CHANNELS_PER_SOURCE` channels
(:data:`MAX_CHANNELS` in all); samples on further keys are counted (``refused_keys``), not
written. On a full disk (or a file-size limit) the recorder finishes the file with what it has
(``larns/log/writer.py``) and stops with :class:`~larns.log.writer.LogWriteError`.
"""

from __future__ import annotations

import logging
import queue
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Callable

import net.cli

log = logging.getLogger("larns.record")

MESSAGE_ENCODING = "msgpack"
QUEUE_MAX = 65536              # samples between the Zenoh threads and the writer
MAX_CHANNELS_PER_SOURCE = 512  # a station: nav, estimate, ..., a request and a reply key per peer
MAX_CHANNELS = 32768


class McapSink:
    """Writes wire samples into an MCAP file (a :class:`larns.log.writer.LogWriter`): one channel per
    key, the Foxglove view's JSON channels next to them. Not thread-safe (one writer)."""

    def __init__(self, path: str | Path, metadata: dict[str, str] | None = None,
                 epoch_unix_s: float | None = None, speed: float = 1.0, foxglove: bool = True):
        from net.messages import peek_stamp

        from .writer import LogWriter

        self._peek = peek_stamp
        self.path = Path(path)
        self.channels: dict[str, int] = {}   # wire key -> channel id
        self._per_source: dict[str, int] = {}  # larns/<role>/<name> -> channels opened
        self.refused_keys = 0  # samples on a key beyond the channel caps
        self.count = 0
        self.bytes = 0
        self.epoch_unix_s = epoch_unix_s
        self.speed = float(speed)
        md = {"recorder": "larns record", "message_encoding": MESSAGE_ENCODING,
              "speed": repr(self.speed)}
        if epoch_unix_s is not None:
            md["epoch_unix_s"] = repr(float(epoch_unix_s))
        md.update({k: str(v) for k, v in (metadata or {}).items()})
        site = _site_of(md)
        if site is not None:
            md["site"] = site.to_json()
        self.log = LogWriter(self.path, {"larns": md}, library="larns-record", chunk_size=256 * 1024)
        # Foxglove view (larns/viz/foxglove.py): JSON channels next to the wire channels
        self.fox = None
        self.json_count = 0
        if foxglove:
            from ..viz.foxglove import FoxgloveView

            self.fox = FoxgloveView(site)

    @property
    def finished(self) -> bool:
        return self.log.finished

    def _admit_key(self, key: str) -> bool:
        """A new key opens a channel while its source and the file are below their caps."""
        src = "/".join(key.split("/", 3)[:3])
        n = self._per_source.get(src, 0)
        if n >= MAX_CHANNELS_PER_SOURCE or len(self.channels) >= MAX_CHANNELS:
            self.refused_keys += 1
            return False
        self._per_source[src] = n + 1
        return True

    def write(self, key: str, data: bytes, recv_ns: int) -> None:
        if key not in self.channels:
            if not self._admit_key(key):
                return
            self.channels[key] = self.log.channel(key, MESSAGE_ENCODING, metadata=_WIRE_CHANNEL)
        pub_ns = recv_ns
        if self.epoch_unix_s is not None:
            stamp = self._peek(data)
            if stamp is not None:
                t = self.epoch_unix_s + stamp / self.speed
                if 0.0 < t < 4e9:
                    pub_ns = int(round(t * 1e9))
        self.log.write(key, data, recv_ns, pub_ns, MESSAGE_ENCODING)
        self.count += 1
        self.bytes += len(data)
        if self.fox is not None:
            try:
                for topic, schema, js in self.fox.convert_bytes(key, data, recv_ns):
                    self._write_json(topic, schema, js, recv_ns)
            except Exception:  # the view must never cost a wire message
                log.exception("foxglove view failed on %s", key)

    def _write_json(self, topic: str, schema: str, data: bytes, recv_ns: int) -> None:
        from ..viz.foxglove import SCHEMA_BYTES

        self.log.write(topic, data, recv_ns, recv_ns, encoding="json", schema=(schema, SCHEMA_BYTES[schema]),
                       channel_metadata=_VIEW_CHANNEL)
        self.json_count += 1

    def flush(self) -> None:
        self.log.flush()

    def finish(self) -> None:
        self.log.finish()


def _site_of(md: dict[str, str]):
    """The recording's site: the ``site`` metadata (JSON) if given, else the ``[site]`` of the scenario
    ``scenario`` names (a packaged name or a path) when it loads; None otherwise."""
    from nav.site import Site
    from net.scenario import ScenarioError, load

    try:
        if md.get("site"):
            return Site.from_json(md["site"])
        if md.get("scenario"):
            return load(md["scenario"]).site
    except (ScenarioError, ValueError, KeyError, TypeError) as e:
        log.warning("no site for the Foxglove view: %s", e)
    return None


_WIRE_CHANNEL = {"source": "zenoh"}
_VIEW_CHANNEL = {"source": "larns foxglove view"}


def run_recorder(out: str, bus_kw: dict, keyexpr: str = "larns/**", duration_s: float | None = None,
                 flush_s: float = 2.0, metadata: dict[str, str] | None = None,
                 epoch_unix_s: float | None = None, speed: float = 1.0,
                 quiet: bool = False, foxglove: bool = True,
                 await_epoch: Callable[[], float | None] | None = None) -> dict:
    """Record ``keyexpr`` to ``out`` until ``duration_s`` wall seconds or a signal. ``await_epoch``
    (``larns fleet``'s start barrier): called once the session is open, returns the fleet's epoch."""
    from net.bus import Bus
    from net.queues import DropOldestQueue

    from .writer import LogWriteError

    stop = threading.Event()

    def on_signal(signum, frame):  # noqa: ARG001
        stop.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    if hasattr(signal, "SIGXFSZ"):  # a file-size limit is a write error (the file gets finished), not a kill
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)

    q = DropOldestQueue(QUEUE_MAX)
    bus = Bus(**bus_kw)  # first: credentials that cannot be loaded fail before the file is created
    if await_epoch is not None:
        epoch_unix_s = await_epoch()
    sink = McapSink(out, metadata=metadata, epoch_unix_s=epoch_unix_s, speed=speed, foxglove=foxglove)
    on_sample = lambda k, d: q.put((time.time_ns(), k, d))  # noqa: E731
    limiter = None
    if bus.security is not None:  # --secure: a per-source budget (signed frames are kept as they are)
        from net.security import RECORDER_BUDGET, RateLimiter, source_of

        limiter = RateLimiter(*RECORDER_BUDGET)

        def on_sample(k, d):  # noqa: F811
            if limiter.allow(source_of(k), time.monotonic()):
                q.put((time.time_ns(), k, d))
    bus.subscribe(keyexpr, on_sample)
    bus.declare_token("larns/alive/recorder/" + str(int(time.time() * 1e3) % 10**9))
    if not quiet:
        print(f"[record] writing {keyexpr} to {out} (Ctrl-C to stop)", file=sys.stderr, flush=True)
    t_end = time.monotonic() + duration_s if duration_s else float("inf")
    next_flush = time.monotonic() + flush_s
    failed: LogWriteError | None = None
    try:
        while not stop.is_set() and time.monotonic() < t_end:
            try:
                item = q.get(timeout=0.1)
            except queue.Empty:
                item = None
            while item is not None:
                sink.write(item[1], item[2], item[0])
                try:
                    item = q.get_nowait()
                except queue.Empty:
                    item = None
            if time.monotonic() >= next_flush:
                sink.flush()
                next_flush = time.monotonic() + flush_s
    except LogWriteError as e:  # full disk: the writer finished the file with what it had
        failed = e
    finally:
        bus.close()  # (a hung close too: the entry point exits at once once the file is done, below)
        try:
            while failed is None:  # whatever arrived before the session closed
                try:
                    r, k, d = q.get_nowait()
                except queue.Empty:
                    break
                sink.write(k, d, r)
            sink.finish()
        except LogWriteError as e:
            failed = e
    net.cli.EXIT_AT_ONCE = True  # the file is finished: nothing is left for the interpreter's finalization
    stats = {"file": out, "messages": sink.count, "bytes": sink.bytes, "channels": len(sink.channels),
             "queue_dropped": q.dropped, "refused_keys": sink.refused_keys}
    if failed is not None:
        stats["error"] = str(failed)
        raise LogWriteError(f"{failed}; {out} is finished and holds every message up to its last complete "
                            "chunk")
    if limiter is not None:
        stats["throttled"] = dict(limiter.throttled)
    if not quiet:
        print(f"[record] finished {out}: {sink.count} messages on {len(sink.channels)} channels",
              file=sys.stderr, flush=True)
    return stats
