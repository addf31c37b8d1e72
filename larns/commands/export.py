"""`larns export run.mcap -o out.mcap`: the recording plus the Foxglove JSON channels
(:mod:`larns.viz.foxglove`)."""

from __future__ import annotations

import argparse
import json
import sys


def cmd_export(args: argparse.Namespace) -> int:
    from larns.viz.foxglove import export

    try:
        r = export(args.files, args.output)
    except (OSError, ValueError) as e:
        print(f"larns export: {e}", file=sys.stderr)
        return 1
    print(f"[export] {r['messages']} wire messages + {r['json_messages']} Foxglove JSON messages -> {r['output']}",
          file=sys.stderr)
    if args.json:
        print(json.dumps(r))
    return 0


def register(sub) -> None:
    from .helptext import Formatter, examples

    from . import doc_of

    p = sub.add_parser(
        "export", help="add Foxglove JSON channels (3D scene, transforms, plottable errors) to a recording",
        description=doc_of("larns.viz.foxglove"), formatter_class=Formatter,
        epilog=examples(
            "larns export runs/demo.mcap -o runs/demo-foxglove.mcap",
        ))
    p.add_argument("files", nargs="+", help="MCAP recording(s), merged by log time")
    p.add_argument("-o", "--output", required=True, help="output .mcap (wire channels + JSON channels)")
    p.add_argument("--json", action="store_true", help="print statistics as JSON")
    p.set_defaults(func=cmd_export)
