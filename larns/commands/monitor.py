"""`larns monitor [--fleet FILE]`: the live table of any running fleet, read from the bus.

A passive observer like the recorder: it subscribes to the stations' estimates, truths and
integrity messages, the aircraft and vehicles, and the liveliness tokens, and prints the same table
`larns fleet` prints (:mod:`larns.fleet.monitor`).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time

DESCRIPTION = """\
Show the live table of a running fleet (stations' state, slot, updates, estimated position, sigma,
error against the truth, clock sync; aircraft and vehicles) - the table `larns fleet` prints - from
any process that can reach its Zenoh bus. Passive: it publishes nothing.

It finds the fleet with --fleet FILE (default: runs/fleet.json when it describes a running fleet),
or with --connect ENDPOINT [--epoch T]. It stops when the attached fleet ends, after --duration
wall seconds, or on Ctrl-C."""


def cmd_monitor(args: argparse.Namespace) -> int:
    from larns.fleet.monitor import Monitor
    from larns.fleet.watch import subscribe
    from net.attach import FleetFileError, apply_fleet, find_fleet
    from net.bus import Bus, bus_kwargs
    from net.security import KeystoreError

    now = time.time()
    try:
        found = find_fleet(args, now, "larns monitor")
        if found is not None:
            apply_fleet(args, found[1], found[0], args.parser)
    except FleetFileError as e:
        print(f"larns monitor: {e}", file=sys.stderr)
        return 2
    if found is None and not args.connect and not args.zenoh_config:
        print("larns monitor: no fleet to watch: give --fleet FILE (written by `larns fleet`, runs/fleet.json "
              "by default) or --connect ENDPOINT", file=sys.stderr)
        return 2
    end = _end_wall(args, found[1] if found else None, now)
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    args.secure_cn = "monitor"
    try:
        bus = Bus(**bus_kwargs(args))
    except KeystoreError as e:
        print(f"larns monitor: --secure: {e}", file=sys.stderr)
        return 2
    monitor = Monitor()
    try:
        subscribe(bus, monitor)
        tty = sys.stdout.isatty() and not args.once
        while not stop.is_set():
            stop.wait(args.refresh)
            print_table(monitor, args, tty)
            if args.once or time.time() >= end:
                break
    finally:
        bus.close()
    return 0


def _end_wall(args: argparse.Namespace, rec: dict | None, now: float) -> float:
    """When to stop (wall clock): ``--duration``, else a second past the attached fleet's end, else never."""
    if args.duration is not None:
        return now + args.duration
    end = rec.get("end_unix_s") if rec else None
    return end + 1.0 if isinstance(end, (int, float)) else float("inf")


def fleet_time_s(args: argparse.Namespace, views: list) -> float:
    """Fleet time from the epoch when known, else the latest estimate's time."""
    if args.epoch is not None:
        return (time.time() - args.epoch) * args.speed
    ts = [v.t_s for v in views if v.t_s == v.t_s]
    return max(ts) if ts else float("nan")


def print_table(monitor, args: argparse.Namespace, tty: bool) -> None:
    from larns.fleet.monitor import format_table

    views = monitor.snapshot()
    with monitor.lock:
        n_alive = len(monitor.alive)
    txt = "\n".join([format_table(views, fleet_time_s(args, views), n_alive), *monitor.aircraft_lines(),
                     *monitor.vehicle_lines()])
    sys.stdout.write("\x1b[H\x1b[2J" + txt + "\n" if tty else txt + "\n\n")
    sys.stdout.flush()


def register(sub) -> None:
    from net.bus import add_bus_args

    from .helptext import add_parser

    p = add_parser(sub, "monitor", help="live table of a running fleet, from the bus (passive)",
                   description=DESCRIPTION,
                   example=["larns monitor                                    # the fleet of runs/fleet.json",
                            "larns monitor --fleet runs/fleet.json --refresh 2",
                            "larns monitor --connect tcp/127.0.0.1:7447 --epoch 1767225600 --once --refresh 5"])
    p.add_argument("--fleet", default=None, metavar="FILE",
                   help="the fleet file written by `larns fleet` (default: runs/fleet.json if it describes a "
                        "running fleet)")
    p.add_argument("--epoch", type=float, default=None,
                   help="fleet epoch, Unix seconds, for the fleet time shown (default: the fleet file's; else "
                        "the latest estimate's time)")
    p.add_argument("--speed", type=float, default=1.0, help="fleet speed factor (for the fleet time shown)")
    p.add_argument("--refresh", type=float, default=1.0, metavar="S", help="wall seconds between tables")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="stop after S wall seconds (default: when the attached fleet ends, else at Ctrl-C)")
    p.add_argument("--once", action="store_true",
                   help="print one table (after --refresh seconds of listening) and exit")
    add_bus_args(p)
    p.set_defaults(func=cmd_monitor, parser=p)
