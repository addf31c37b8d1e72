"""Reading LARNS MCAP logs, complete or not.

Every tool that opens a log (``info``, ``replay``, ``report``, ``export``, ``recover``) reads it
through :func:`read_log`, which **stream-reads** the file record by record instead of trusting the
summary section. A recording killed with SIGKILL has no summary, footer or trailing magic and may
end in the middle of a chunk; we keep every complete record before the damage and say so
(``LogFile.complete`` False, ``LogFile.error`` the reason). The recorder finishes a chunk every
few seconds (``larns record --flush``), so a killed recording loses at most that much.

Several files merge by ``log_time`` (:func:`merge`); ties keep file order, then record order.

Channel selection (``topics`` / ``exclude``) uses the Zenoh-style globs of
:mod:`larns.log.keyexpr`. Decoding the recorded wire messages is :mod:`larns.log.series`'s job.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

from .keyexpr import topic_selected


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
