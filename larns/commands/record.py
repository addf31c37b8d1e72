"""`larns record -o run.mcap`: the recorder (:mod:`larns.log.record`) as a command."""

from __future__ import annotations

import argparse
import json
import logging
import sys

DESCRIPTION = """\
Passive observer: subscribes to larns/** and writes the exact wire bytes to MCAP (one channel per
key, message_encoding msgpack), plus Foxglove JSON channels. log_time = receive time, publish_time
= sender stamp. SIGINT/SIGTERM finish the file.

Beside a running `larns fleet`, --fleet FILE (default: runs/fleet.json when it describes a running
fleet and no --epoch is given) takes the fleet's endpoints, epoch, speed and scenario; the
recording then stops when the fleet ends unless --duration says otherwise."""


def _attach(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """``--fleet`` (or the default fleet file): the fleet's endpoints, epoch, speed, scenario; without
    ``--duration``, record until the fleet's end."""
    import time

    from net.attach import apply_fleet, find_fleet

    now = time.time()
    if args.epoch_from:  # started by larns fleet (its start barrier): never the default fleet file
        return
    found = find_fleet(args, now, "larns record")
    if found is None:
        return
    path, rec = found
    apply_fleet(args, rec, path, parser)
    end = rec.get("end_unix_s")
    if args.duration is None and isinstance(end, (int, float)):
        args.duration = max(1.0, end - now + 1.0)  # wall seconds: a second past the fleet's end
    print(f"larns record: attaching to the fleet of {path}: scenario {args.scenario}, epoch {args.epoch:.3f}, "
          f"speed {args.speed:g}, connect {' '.join(args.connect or [])}", file=sys.stderr, flush=True)


def cmd_record(args: argparse.Namespace) -> int:
    from net.attach import FleetFileError
    from net.bus import bus_kwargs
    from net.cli import await_epoch

    try:
        _attach(args, args.parser)
    except FleetFileError as e:
        print(f"larns record: {e}", file=sys.stderr)
        return 2

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
                             foxglove=not args.no_foxglove,
                             await_epoch=(lambda: await_epoch(args, "larns record")) if args.epoch_from else None)
    except KeystoreError as e:
        print(f"larns record: --secure: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # full disk / file-size limit: the file was finished (larns/log/writer.py)
        print(f"larns record: {e}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(stats))
    return 0


def register(sub) -> None:
    from net.bus import add_bus_args

    from .helptext import add_parser

    p = add_parser(sub, "record", help="record all LARNS traffic on Zenoh to an MCAP file", description=DESCRIPTION,
                   example=["larns record -o runs/extra.mcap --fleet runs/fleet.json   # record a running fleet",
                            "larns record -o run.mcap --connect tcp/127.0.0.1:7447 --epoch 1767225600 --duration 60"])
    p.add_argument("-o", "--output", required=True, help="output .mcap file")
    p.add_argument("--keyexpr", default="larns/**", help="key expression to record (default larns/**)")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="stop after S wall seconds (default: when the attached fleet ends, else at SIGINT)")
    p.add_argument("--fleet", default=None, metavar="FILE",
                   help="attach to the running `larns fleet` of this fleet file (default: runs/fleet.json if it "
                        "describes a running fleet and no --epoch is given)")
    p.add_argument("--flush", type=float, default=2.0, help="finish a chunk every N seconds (default 2)")
    p.add_argument("--scenario", default=None, help="scenario name stored as metadata")
    p.add_argument("--epoch", type=float, default=None,
                   help="fleet epoch (Unix s): converts message stamps to publish_time")
    p.add_argument("--speed", type=float, default=1.0, help="fleet speed factor (for publish_time)")
    from net.cli import add_epoch_from_arg

    add_epoch_from_arg(p)
    p.add_argument("--meta", action="append", metavar="KEY=VALUE", help="extra metadata (repeatable)")
    p.add_argument("--no-foxglove", action="store_true",
                   help="do not write the Foxglove JSON channels (larns/foxglove/**: 3D scene, "
                        "transforms, plottable estimates and errors; see larns export)")
    p.add_argument("--json", action="store_true", help="print statistics as JSON at the end")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    add_bus_args(p)
    p.set_defaults(func=cmd_record, parser=p)
