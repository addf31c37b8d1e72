"""`larns record -o run.mcap`: the recorder (:mod:`larns.log.record`) as a command."""

from __future__ import annotations

import argparse
import json
import logging
import sys


def cmd_record(args: argparse.Namespace) -> int:
    from net.bus import bus_kwargs

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    md = {}
    for kv in args.meta or []:
        k, _, v = kv.partition("=")
        md[k] = v
    if args.scenario:
        md["scenario"] = args.scenario
    from net.security import KeystoreError

    args.secure_cn = "recorder"
    from larns.log.record import run_recorder

    try:
        stats = run_recorder(args.output, bus_kwargs(args), keyexpr=args.keyexpr,
                             duration_s=args.duration, flush_s=args.flush, metadata=md,
                             epoch_unix_s=args.epoch, speed=args.speed, quiet=args.quiet,
                             foxglove=not args.no_foxglove)
    except KeystoreError as e:
        print(f"larns record: --secure: {e}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(stats))
    return 0


def register(sub) -> None:
    from net.bus import add_bus_args

    p = sub.add_parser(
        "record", help="record all LARNS traffic on Zenoh to an MCAP file",
        description="Passive observer: subscribes to larns/** and writes the exact wire bytes to "
                    "MCAP (one channel per key, message_encoding msgpack). log_time = receive "
                    "time, publish_time = sender stamp. SIGINT/SIGTERM finish the file.")
    p.add_argument("-o", "--output", required=True, help="output .mcap file")
    p.add_argument("--keyexpr", default="larns/**", help="key expression to record (default larns/**)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    p.add_argument("--flush", type=float, default=2.0, help="finish a chunk every N seconds (default 2)")
    p.add_argument("--scenario", default=None, help="scenario name stored as metadata")
    p.add_argument("--epoch", type=float, default=None,
                   help="fleet epoch (Unix s): converts message stamps to publish_time")
    p.add_argument("--speed", type=float, default=1.0, help="fleet speed factor (for publish_time)")
    p.add_argument("--meta", action="append", metavar="KEY=VALUE", help="extra metadata (repeatable)")
    p.add_argument("--no-foxglove", action="store_true",
                   help="do not write the Foxglove JSON channels (larns/foxglove/**: 3D scene, "
                        "transforms, plottable estimates and errors; see larns export)")
    p.add_argument("--json", action="store_true", help="print statistics as JSON at the end")
    p.add_argument("-q", "--quiet", action="store_true")
    add_bus_args(p)
    p.set_defaults(func=cmd_record)
