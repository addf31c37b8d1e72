"""Rewriting a damaged or unfinished recording as a clean, indexed MCAP file (``larns recover``)."""

from __future__ import annotations

from pathlib import Path


def recover(src: str | Path, dst: str | Path) -> dict:
    from .reader import read_log
    from .writer import LogWriter

    src, dst = Path(src), Path(dst)
    if src.resolve() == dst.resolve():
        raise ValueError("output must differ from the input")
    lg = read_log(src)
    md = dict(lg.metadata)
    md["larns_recover"] = {"source": str(src), "source_complete": str(lg.complete),
                           "source_error": lg.error or "", "messages": str(len(lg.messages))}
    schema_by_name = {name: (name, data) for name, _enc, data in lg.schemas.values()}
    with LogWriter(dst, md, library=f"larns recover ({lg.library or 'unknown'})") as w:
        for m in lg.messages:
            w.write(m.topic, m.data, m.log_time, m.publish_time, m.encoding,
                    schema_by_name.get(m.schema) if m.schema else None, sequence=m.sequence)
    return {"source": str(src), "output": str(dst), "source_complete": lg.complete, "source_error": lg.error,
            "messages": len(lg.messages), "channels": len(lg.channels), "bytes_read": lg.bytes_read,
            "source_bytes": src.stat().st_size}
