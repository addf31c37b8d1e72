"""`larns fleet`: launch a whole LARNS deployment on this machine, one OS process per station.

    larns fleet --scenario seed000 --duration 60 --speed 1 --record run.mcap

Spawns one ``python -m stations`` process per station of the scenario (each its own Zenoh peer,
listening on its own loopback port, seeded with the endpoints of stations 1 and 2 - gossip links
everyone to everyone; or, with ``--topology router``, one ``larns router`` process and every other
process a Zenoh client of it), the recorder (``larns record``) when ``--record`` is given, and optional
hot-joining stations (``--join ID@T``). ``--kill ID@T`` SIGKILLs a station's process at fleet time
T, ``--restart ID@T`` starts a fresh process with the same id at T (it joins the running field);
the scenario's ``[[faults]]`` leave (SIGTERM) and kill events are acted on the same way. All processes share one epoch chosen a few seconds in the
future, so they compute the same TDMA slot boundaries without a clock master.

While the fleet runs, a live table shows every station's slot, number of updates, estimated
position, sigma (root of the covariance trace) and error against the truth topic. At the end (or
on Ctrl-C / SIGTERM) every child is stopped with SIGINT (SIGKILL after a grace period), the
recorder finishes its MCAP file, and a final table is printed.
"""

from __future__ import annotations

import argparse
import sys


def register(sub) -> None:
    from net.bus import add_bus_args

    from .helptext import Formatter, examples

    p = sub.add_parser("fleet", help="launch a local fleet: one process per station + recorder, live table",
                       description=__doc__, formatter_class=Formatter,
                       epilog=examples(
                           "larns fleet --scenario seed000 --duration 60 --record runs/demo.mcap   # fleet file: runs/fleet.json",
                           "larns fleet --scenario seed000 --duration 60 --join 11@20 --speed 2        # station 11 hot-joins at 20 s",
                           "larns fleet --duration 0 --topology router --aircraft                   # until Ctrl-C",
                           "larns fleet --duration 400 --kill 1@60 --kill 2@120 --restart 1@300 --record runs/f.mcap  # founders fail",
                       ))
    p.add_argument("--scenario", default="seed000", help="scenario name or TOML path (default seed000)")
    p.add_argument("--duration", type=float, default=60.0,
                   help="fleet seconds to run (0 = until Ctrl-C; default 60)")
    p.add_argument("--speed", type=float, default=1.0, help="run K times faster than real time (default 1)")
    p.add_argument("--record", default=None, metavar="FILE.mcap", help="record everything to this MCAP file")
    p.add_argument("--join", action="append", metavar="ID@T",
                   help="hot-join station ID at fleet time T seconds (repeatable), e.g. --join 11@20")
    p.add_argument("--kill", action="append", metavar="ID@T",
                   help="SIGKILL station ID's process at fleet time T seconds (repeatable), e.g. --kill 1@60; "
                        "the scenario's [[faults]] leave (SIGTERM) / kill events are acted on too")
    p.add_argument("--restart", action="append", metavar="ID@T",
                   help="start a fresh process for station ID at fleet time T (after its --kill or leave; "
                        "repeatable): it joins the running field as an ordinary station, e.g. --restart 1@300")
    p.add_argument("--join-time", type=float, default=20.0,
                   help="fleet time at which the scenario's join stations join (default 20)")
    p.add_argument("--n-stations", type=int, default=None, help="override the station count of a random layout")
    p.add_argument("--aircraft", action="store_true", help="also run the aircraft process (if available)")
    p.add_argument("--vehicle", action="store_true",
                   help="also run the ground vehicle process (larns vehicle, docs/vehicle.md)")
    p.add_argument("--vehicle-route", default=None, metavar="FILE",
                   help="the vehicle's route file (straight legs in the network frame; implies --vehicle)")
    p.add_argument("--vehicle-outage", default=None, metavar="START,END",
                   help="the vehicle's station outage, vehicle seconds (implies --vehicle)")
    p.add_argument("--net-delay", type=float, default=None, metavar="S", help="wire delay, s (all stations)")
    p.add_argument("--net-jitter", type=float, default=None, metavar="S", help="wire jitter, s")
    p.add_argument("--net-loss", type=float, default=None, metavar="P", help="wire loss probability")
    p.add_argument("--net-dup", type=float, default=None, metavar="P", help="wire duplication probability")
    p.add_argument("--startup", type=float, default=None, metavar="S",
                   help="seconds a joining station is spawned ahead of its join time (default 3 + 0.25 per "
                        "station); the epoch itself waits until every process started at launch is up")
    p.add_argument("--nice", type=int, default=0, metavar="N",
                   help="niceness change for the station processes (negative = higher priority; needs privileges)")
    p.add_argument("--topology", choices=("peer", "router"), default="peer",
                   help="peer: full mesh by gossip (default); router: also start a `larns router` and run "
                        "every process as a Zenoh client of it (N links instead of N(N-1)/2)")
    p.add_argument("--refresh", type=float, default=1.0,
                   help="table refresh period, wall seconds (at least 10 s when stdout is not a terminal)")
    p.add_argument("--no-table", action="store_true", help="no live table (final table only)")
    p.add_argument("--logs", default=None, help="folder for per-process logs (default FILE.mcap.logs/)")
    p.add_argument("--json", default=None, help="write the final table as JSON")
    p.add_argument("--view", type=int, nargs="?", const=8765, default=None, metavar="PORT",
                   help="also serve a live Foxglove view (larns view) on this port (default 8765; docs/view.md)")
    p.add_argument("--fleet-file", default=None, metavar="FILE",
                   help="where to write the fleet file (epoch, speed, scenario, endpoints, secure or not) that "
                        "`larns station/aircraft/vehicle/record/monitor --fleet FILE` attach with; default: "
                        "fleet.json beside the --record file, else in the log folder")
    add_bus_args(p)
    p.set_defaults(func=lambda a: _run_checked(_fix(a)))


def _run_checked(args: argparse.Namespace) -> int:
    from larns.fleet.run import run_fleet
    from net.security import KeystoreError

    try:
        return run_fleet(args)
    except KeystoreError as e:
        print(f"[fleet] --secure: {e}", file=sys.stderr)
        return 2


def _fix(a: argparse.Namespace) -> argparse.Namespace:
    if a.duration is not None and a.duration <= 0:
        a.duration = None
    return a
