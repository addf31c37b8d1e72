"""`larns recover in.mcap -o out.mcap`: rewrite a damaged or unfinished recording as a clean file
(:func:`larns.log.recover.recover`).

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

from ..log.recover import recover  # noqa: F401  (old import path)


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
    from .helptext import Formatter, examples

    p = sub.add_parser(
        "recover", help="rewrite a killed/damaged MCAP recording as a clean indexed file",
        description=__doc__, formatter_class=Formatter,
        epilog=examples(
            "larns recover runs/killed.mcap -o runs/clean.mcap",
        ))
    p.add_argument("input", help="damaged or unfinished .mcap")
    p.add_argument("-o", "--output", required=True, help="clean output .mcap")
    p.add_argument("--json", action="store_true", help="print statistics as JSON")
    p.set_defaults(func=cmd_recover)
