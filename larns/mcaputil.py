"""Reading LARNS MCAP logs, complete or not.

Every tool that opens a log (``info``, ``replay``, ``report``, ``export``, ``recover``) reads it
through :func:`read_log`, which **stream-reads** the file record by record instead of trusting the
summary section. A recording killed with SIGKILL has no summary, footer or trailing magic and may
end in the middle of a chunk; we keep every complete record before the damage and say so
(``LogFile.complete`` False, ``LogFile.error`` the reason). The recorder finishes a chunk every
few seconds (``larns record --flush``), so a killed recording loses at most that much.

Several files merge by ``log_time`` (:func:`merge`); ties keep file order, then record order.

Key-expression globs (``--topics`` / ``--exclude``) follow Zenoh: ``*`` matches one chunk (no
``/``), ``**`` matches any number of chunks (:func:`keyexpr_match`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Iterable, Iterator, Sequence


@dataclass(frozen=True)
class Msg:
    """One recorded message. Times in ns since the Unix epoch."""

    topic: str
    log_time: int
    publish_time: int
    sequence: int
    data: bytes
    encoding: str = "msgpack"
    schema: str = ""  # schema name ("" for schemaless msgpack channels)
    file_index: int = 0


@dataclass
class LogFile:
    path: Path
    messages: list[Msg] = field(default_factory=list)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    channels: dict[int, tuple[str, str, str]] = field(default_factory=dict)  # id -> (topic, encoding, schema name)
    schemas: dict[int, tuple[str, str, bytes]] = field(default_factory=dict)  # id -> (name, encoding, data)
    complete: bool = False  # footer seen: the file was finished cleanly
    error: str | None = None  # why reading stopped early (truncated / corrupt tail)
    library: str = ""
    profile: str = ""
    bytes_read: int = 0

    @property
    def larns_meta(self) -> dict[str, str]:
        return self.metadata.get("larns", {})

    @property
    def epoch_unix_s(self) -> float | None:
        v = self.larns_meta.get("epoch_unix_s")
        try:
            return float(v) if v is not None else None
        except ValueError:
            return None

    @property
    def speed(self) -> float:
        try:
            return float(self.larns_meta.get("speed", "1.0"))
        except ValueError:
            return 1.0


def read_log(path: str | Path, *, topics: Sequence[str] | None = None, exclude: Sequence[str] | None = None,
             encodings: Sequence[str] | None = None, file_index: int = 0, sort: bool = True) -> LogFile:
    """Stream-read one MCAP file, tolerating a missing summary/footer or a truncated tail.

    Parameters
    ----------
    topics, exclude : key-expression globs selecting channels (None: all).
    encodings : keep only channels with these message encodings (e.g. ``["msgpack"]``).
    sort : sort messages by log_time (stable). Recorder chunks are nearly ordered already.

    Raises ``ValueError`` if the file is not an MCAP file at all.
    """
    from mcap.exceptions import InvalidMagic
    from mcap.records import Channel, Footer, Header, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader

    path = Path(path)
    out = LogFile(path=path)
    keep: dict[int, bool] = {}
    with open(path, "rb") as f:
        head = f.read(8)
        if head != b"\x89MCAP0\r\n":
            raise ValueError(f"{path}: not an MCAP file")
        f.seek(0)
        reader = StreamReader(f, record_size_limit=1 << 30)
        try:
            for rec in reader.records:
                if isinstance(rec, Message):
                    if keep.get(rec.channel_id):
                        topic, enc, sname = out.channels[rec.channel_id]
                        out.messages.append(Msg(topic, rec.log_time, rec.publish_time, rec.sequence,
                                                bytes(rec.data), enc, sname, file_index))
                elif isinstance(rec, Channel):
                    sname = out.schemas.get(rec.schema_id, ("", "", b""))[0]
                    out.channels[rec.id] = (rec.topic, rec.message_encoding, sname)
                    keep[rec.id] = (topic_selected(rec.topic, topics, exclude)
                                    and (encodings is None or rec.message_encoding in encodings))
                elif isinstance(rec, Schema):
                    out.schemas[rec.id] = (rec.name, rec.encoding, bytes(rec.data))
                elif isinstance(rec, Metadata):
                    out.metadata[rec.name] = dict(rec.metadata)
                elif isinstance(rec, Header):
                    out.library, out.profile = rec.library, rec.profile
                elif isinstance(rec, Footer):
                    out.complete = True
        except InvalidMagic as e:
            if not out.complete:
                out.error = f"bad magic: {e}"
            else:  # footer read but trailing magic missing/damaged: data are all there
                out.error = "trailing magic missing"
        except Exception as e:  # truncated record / chunk, bad compression, ...: keep what we have
            out.error = f"{type(e).__name__}: {e}" if str(e) else type(e).__name__
            out.complete = False
        out.bytes_read = f.tell()
    if sort:
        out.messages.sort(key=lambda m: m.log_time)
    return out


def read_logs(paths: Sequence[str | Path], **kw) -> list[LogFile]:
    return [read_log(p, file_index=i, **kw) for i, p in enumerate(paths)]


def merge(logs: Iterable[LogFile]) -> list[Msg]:
    """All messages of several logs merged by log_time (stable: file order, then record order)."""
    import heapq

    return list(heapq.merge(*[lg.messages for lg in logs], key=lambda m: m.log_time))


# --------------------------------------------------------------------------- key expressions

@lru_cache(maxsize=512)
def _chunk_re(chunk: str) -> re.Pattern:
    return re.compile("^" + "".join("[^/]*" if c == "*" else re.escape(c)
                                    for c in re.split(r"(\*)", chunk) if c) + "$")


def _match_chunks(pat: tuple[str, ...], key: tuple[str, ...]) -> bool:
    if not pat:
        return not key
    if pat[0] == "**":
        return any(_match_chunks(pat[1:], key[i:]) for i in range(len(key) + 1))
    return bool(key) and bool(_chunk_re(pat[0]).match(key[0])) and _match_chunks(pat[1:], key[1:])


def keyexpr_match(pattern: str, key: str) -> bool:
    """Zenoh-style glob: ``*`` = one chunk (or part of one), ``**`` = any number of chunks.

    >>> keyexpr_match("larns/station/*/nav", "larns/station/12/nav")
    True
    >>> keyexpr_match("larns/**", "larns/station/1/range/req/2")
    True
    >>> keyexpr_match("**/estimate", "larns/station/3/estimate")
    True
    """
    return _match_chunks(tuple(pattern.strip("/").split("/")), tuple(key.strip("/").split("/")))


def topic_selected(topic: str, include: Sequence[str] | None, exclude: Sequence[str] | None) -> bool:
    if include and not any(keyexpr_match(p, topic) for p in include):
        return False
    if exclude and any(keyexpr_match(p, topic) for p in exclude):
        return False
    return True


def parse_remaps(specs: Sequence[str] | None) -> list[tuple[str, str]]:
    """``["larns/station=sim/station", ...]`` -> [(from_prefix, to_prefix)]; prefix match on chunks."""
    out = []
    for s in specs or []:
        a, sep, b = s.partition("=")
        if not sep or not a or not b:
            raise ValueError(f"--remap {s!r}: expected FROM=TO")
        out.append((a.strip("/"), b.strip("/")))
    return out


def remap(topic: str, rules: Sequence[tuple[str, str]]) -> str:
    """First matching rule wins. ``FROM`` may be a whole key or a key prefix (whole chunks) or a glob
    (then the whole key is replaced by ``TO``)."""
    for a, b in rules:
        if topic == a:
            return b
        if topic.startswith(a + "/"):
            return b + topic[len(a):]
        if "*" in a and keyexpr_match(a, topic):
            return b
    return topic


# --------------------------------------------------------------------------- decoding helpers

def decode_all(msgs: Iterable[Msg]) -> Iterator[tuple[Msg, dict | None]]:
    """(record, decoded msg or None if not a valid LARNS envelope) for msgpack records."""
    from net import messages as M

    for m in msgs:
        if m.encoding != "msgpack":
            continue
        try:
            msg, _ = M.decode(m.data)
        except M.MessageError:
            msg = None
        yield m, msg


def fleet_time_s(log: LogFile, t_ns: int, t0_ns: int) -> float:
    """Convert a wall-clock ns stamp to fleet seconds (epoch and speed from metadata; else since t0)."""
    ep = log.epoch_unix_s
    if ep is None:
        return (t_ns - t0_ns) * 1e-9
    return (t_ns * 1e-9 - ep) * log.speed


# --------------------------------------------------------------------------- writing

class LogWriter:
    """An indexed, chunked (zstd) MCAP writer keyed by topic; registers channels and schemas lazily.

    ``write(topic, data, log_time, publish_time)`` for msgpack wire bytes (schemaless, like
    ``larns record``); ``write(topic, data, ..., encoding="json", schema=(name, json_schema_bytes))``
    for JSON channels.
    """

    def __init__(self, path: str | Path, metadata: dict[str, dict[str, str]] | None = None,
                 library: str = "larns", chunk_size: int = 1 << 20):
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "wb")
        self.writer = Writer(self._f, compression=CompressionType.ZSTD, chunk_size=chunk_size)
        self.writer.start(profile="", library=library)
        self.channels: dict[tuple[str, str], int] = {}
        self.schemas: dict[tuple[str, bytes], int] = {}
        self.seq: dict[int, int] = {}
        self.count = 0
        for name, md in (metadata or {}).items():
            self.writer.add_metadata(name, {str(k): str(v) for k, v in md.items()})
        self.finished = False

    def channel(self, topic: str, encoding: str = "msgpack", schema: tuple[str, bytes] | None = None) -> int:
        ch = self.channels.get((topic, encoding))
        if ch is None:
            sid = 0
            if schema is not None:
                sid = self.schemas.get(schema)
                if sid is None:
                    sid = self.writer.register_schema(name=schema[0], encoding="jsonschema", data=schema[1])
                    self.schemas[schema] = sid
            ch = self.writer.register_channel(topic=topic, message_encoding=encoding, schema_id=sid,
                                              metadata={"source": "larns"})
            self.channels[(topic, encoding)] = ch
            self.seq[ch] = 0
        return ch

    def write(self, topic: str, data: bytes, log_time: int, publish_time: int | None = None,
              encoding: str = "msgpack", schema: tuple[str, bytes] | None = None,
              sequence: int | None = None) -> None:
        ch = self.channel(topic, encoding, schema)
        seq = self.seq[ch] if sequence is None else sequence
        self.writer.add_message(channel_id=ch, log_time=int(log_time), data=data,
                                publish_time=int(log_time if publish_time is None else publish_time),
                                sequence=seq)
        self.seq[ch] += 1
        self.count += 1

    def finish(self) -> None:
        if not self.finished:
            self.finished = True
            self.writer.finish()
            self._f.close()

    def __enter__(self) -> "LogWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.finish()
