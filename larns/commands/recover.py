"""`larns recover in.mcap -o out.mcap`: rewrite a damaged or unfinished recording as a clean file.

A recorder killed with SIGKILL (or a full disk, or a power cut) leaves an MCAP file without its
summary section, footer and trailing magic, possibly ending inside a chunk. ``recover`` stream-reads
every complete record before the damage (``larns.log.read_log``) and writes them to a new,
chunked, indexed file with a summary: schemas, channels (topics and encodings kept), metadata and
every message with its log time, publish time and sequence number. The indexed reader
(``mcap.reader.make_reader(...).get_summary()``) and every MCAP tool open the result.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def recover(src: str | Path, dst: str | Path) -> dict:
    from ..log import LogWriter, read_log

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


def cmd_recover(args: argparse.Namespace) -> int:
    try:
        r = recover(args.input, args.output)
    except (OSError, ValueError) as e:
        print(f"larns recover: {e}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(r))
    else:
        state = "was complete" if r["source_complete"] else f"was damaged ({r['source_error']})"
        print(f"[recover] {r['source']} {state}: kept {r['messages']} messages on {r['channels']} channels "
              f"-> {r['output']}", file=sys.stderr)
    return 0


def register(sub) -> None:
    p = sub.add_parser(
        "recover", help="rewrite a killed/damaged MCAP recording as a clean indexed file",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("input", help="damaged or unfinished .mcap")
    p.add_argument("-o", "--output", required=True, help="clean output .mcap")
    p.add_argument("--json", action="store_true", help="print statistics as JSON")
    p.set_defaults(func=cmd_recover)
