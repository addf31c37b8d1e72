"""Rewriting a damaged or unfinished recording as a clean, indexed MCAP file (``larns recover``).

Streaming, in constant memory (issue 32): records are read one at a time (``mcap``'s stream reader)
and each message is written to the new file as it is read, so a recording larger than the memory
recovers too. Messages keep the source file's order (the recorder writes them nearly in receive
order; every reader here sorts by log time). The source's metadata records are copied as they come,
and a ``larns_recover`` record at the end says what was kept.
"""

from __future__ import annotations

from pathlib import Path


def recover(src: str | Path, dst: str | Path) -> dict:
    from mcap.exceptions import InvalidMagic
    from mcap.records import Channel, Footer, Header, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader

    from .writer import LogWriter

    src, dst = Path(src), Path(dst)
    if src.resolve() == dst.resolve():
        raise ValueError("output must differ from the input")
    schemas: dict[int, tuple[str, bytes]] = {}
    channels: dict[int, tuple[str, str, tuple[str, bytes] | None]] = {}
    n = 0
    complete, error, library = False, None, ""
    with open(src, "rb") as f:
        if f.read(8) != b"\x89MCAP0\r\n":
            raise ValueError(f"{src}: not an MCAP file")
        f.seek(0)
        w = None
        try:
            for rec in StreamReader(f, record_size_limit=1 << 30).records:
                if isinstance(rec, Header):
                    library = rec.library
                    w = LogWriter(dst, None, library=f"larns recover ({library or 'unknown'})")
                elif w is None:
                    continue
                elif isinstance(rec, Message):
                    ch = channels.get(rec.channel_id)
                    if ch is not None:
                        w.write(ch[0], bytes(rec.data), rec.log_time, rec.publish_time, ch[1], ch[2],
                                sequence=rec.sequence)
                        n += 1
                elif isinstance(rec, Channel):
                    channels[rec.id] = (rec.topic, rec.message_encoding, schemas.get(rec.schema_id))
                elif isinstance(rec, Schema):
                    schemas[rec.id] = (rec.name, bytes(rec.data))
                elif isinstance(rec, Metadata):
                    w.metadata(rec.name, dict(rec.metadata))
                elif isinstance(rec, Footer):
                    complete = True
        except InvalidMagic as e:
            error = None if complete else f"bad magic: {e}"
        except Exception as e:  # noqa: BLE001 - truncated record / chunk, bad compression: keep what we have
            error = f"{type(e).__name__}: {e}" if str(e) else type(e).__name__
            complete = False
        bytes_read = f.tell()
    if w is None:
        w = LogWriter(dst, None, library="larns recover (unknown)")
    w.metadata("larns_recover", {"source": str(src), "source_complete": str(complete), "source_error": error or "",
                                 "messages": str(n)})
    w.finish()
    return {"source": str(src), "output": str(dst), "source_complete": complete, "source_error": error,
            "messages": n, "channels": len(channels), "bytes_read": bytes_read, "source_bytes": src.stat().st_size}
