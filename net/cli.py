"""Command-line plumbing shared by the LARNS processes (``python -m stations``, ``python -m aircraft``,
``larns station``, ``larns aircraft``): common flags, the bus with its ``--secure`` credentials, and
the run of a node until it stops or is signalled (clean exit: liveliness withdrawn, session closed).

Each process module keeps only what is its own: ``add_args`` (its flags, on top of
:func:`add_process_args`), the node and its options; ``main`` and ``build_parser`` come from here.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import threading
from typing import Any, Callable


def add_process_args(p: argparse.ArgumentParser, *, scenario: str, what: str, net_faults: bool = True) -> None:
    """The flags every process takes: scenario (default ``scenario``) and world, fleet time, network
    faults (``net_faults`` False: accepted for launcher compatibility but hidden), status and report.
    ``what`` names the process in the help texts ("station", "aircraft")."""
    p.add_argument("--scenario", default=scenario, help=f"scenario name or TOML path (default {scenario})")
    p.add_argument("--speed", type=float, default=1.0, help="run K times faster than real time (default 1)")
    p.add_argument("--epoch", type=float, default=None,
                   help="fleet epoch, Unix seconds (all processes must agree; default: start of the UTC day)")
    add_epoch_from_arg(p)
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="run for S fleet seconds from power-on (--until T: stop at fleet time T); default: "
                        "until the attached fleet ends, else until signalled")
    from .attach import add_attach_args

    add_attach_args(p)  # --fleet FILE, --until T (net/attach.py)
    p.add_argument("--seed", type=int, default=None, help="override the scenario's world seed")
    p.add_argument("--n-stations", type=int, default=None,
                   help="override the number of stations of a random-layout scenario")
    if net_faults:
        g = p.add_argument_group("network faults (override the scenario's [net] section)")
        g.add_argument("--net-delay", type=float, default=None, metavar="S", help="extra delivery delay, s")
        g.add_argument("--net-jitter", type=float, default=None, metavar="S", help="delay jitter (1 sigma), s")
        g.add_argument("--net-loss", type=float, default=None, metavar="P", help="loss probability")
        g.add_argument("--net-dup", type=float, default=None, metavar="P", help="duplication probability")
    else:
        g = p.add_argument_group(f"network faults (accepted for launcher compatibility; the {what}'s own "
                                 "subscription is not faulted - the stations' links are)")
        for flag in ("--net-delay", "--net-jitter", "--net-loss", "--net-dup"):
            g.add_argument(flag, type=float, default=None, help=argparse.SUPPRESS)


def add_epoch_from_arg(p: argparse.ArgumentParser) -> None:
    """``--epoch-from FILE``: the start barrier of ``larns fleet`` (:func:`await_epoch`); not for users."""
    p.add_argument("--epoch-from", default=None, metavar="FILE", help=argparse.SUPPRESS)


#: how long a process started with ``--epoch-from`` waits for its launcher to fix the epoch (the
#: launcher waits at most ``larns.fleet.spawn.BARRIER_TIMEOUT_S`` for every process to be up)
AWAIT_EPOCH_TIMEOUT_S = 300.0


def await_epoch(args: argparse.Namespace, who: str, stop: threading.Event | None = None) -> float | None:
    """The start barrier of ``larns fleet`` (``--epoch-from FILE``, docs/operations.md): once this
    process is up (imports done, Zenoh session open) it says so by creating ``FILE.ready.<pid>`` and
    waits for the launcher to write the epoch (Unix s) to ``FILE``, which the launcher does when every
    process it started is up. ``args.epoch`` is then the fleet's epoch. A fleet on a slow or loaded
    machine thus starts its field time when its processes can take part, instead of some of them
    powering on seconds late. Returns ``args.epoch`` (without ``--epoch-from``: unchanged). No epoch
    within :data:`AWAIT_EPOCH_TIMEOUT_S`, or ``stop`` set: exit 2 / return with ``args.epoch`` unchanged."""
    import time
    from pathlib import Path

    path = getattr(args, "epoch_from", None)
    if not path:
        return args.epoch
    f = Path(path)
    Path(f"{path}.ready.{os.getpid()}").touch()
    t_end = time.monotonic() + AWAIT_EPOCH_TIMEOUT_S
    while True:
        try:
            args.epoch = float(f.read_text())  # (the launcher writes it atomically; a partial write retries)
            return args.epoch
        except (OSError, ValueError):
            pass
        if stop is not None and stop.is_set():
            return args.epoch
        if time.monotonic() > t_end:
            print(f"{who}: --epoch-from {path}: no epoch from the launcher in {AWAIT_EPOCH_TIMEOUT_S:g} s",
                  file=sys.stderr)
            raise SystemExit(2)
        time.sleep(0.01)


def add_output_args(p: argparse.ArgumentParser) -> None:
    """Status lines, the JSON report at exit, quiet; then the Zenoh flags (``net.bus.add_bus_args``)."""
    from .bus import add_bus_args

    p.add_argument("--status-every", type=float, default=5.0, help="fleet seconds between status lines")
    p.add_argument("--report-json", action="store_true", help="print a JSON report on stdout at exit")
    p.add_argument("-q", "--quiet", action="store_true", help="no start, status and stop lines")
    add_bus_args(p)


def build_parser(prog: str, doc: str | None, add_args: Callable[[argparse.ArgumentParser], None]
                 ) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_args(p)
    return p


def main(argv: list[str] | None, prog: str, doc: str | None, add_args: Callable[[argparse.ArgumentParser], None],
         main_args: Callable[[argparse.Namespace], int]) -> int:
    """``python -m <package>``: parse ``argv`` with the process's flags and run it."""
    import time

    from .attach import FleetFileError, resolve

    parser = build_parser(prog, doc, add_args)
    args = parser.parse_args(argv)
    if args.epoch_from and args.epoch is None:
        # the launcher fixes the epoch once every process is up (await_epoch); until then a
        # provisional one (never the default fleet file: this process belongs to its launcher)
        args.epoch = time.time()
    try:  # --fleet / the default fleet file; --duration as a run length -> the end's fleet time
        resolve(args, time.time(), prog, parser)
    except FleetFileError as e:
        print(f"{prog}: {e}", file=sys.stderr)
        return 2
    return main_args(args)


def setup_logging() -> None:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")


def early_stop() -> threading.Event:
    """SIGINT / SIGTERM during start-up (Zenoh opening) set the returned event; :func:`serve` then
    stops the node as soon as it exists (a signal still means: exit cleanly)."""
    ev = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: ev.set())
    signal.signal(signal.SIGTERM, lambda *_: ev.set())
    return ev


def open_bus(who: str, make_bus: Callable[[], Any]) -> Any:
    """``make_bus()``, or exit 2 with the reason when the ``--secure`` credentials cannot be loaded."""
    from .security import KeystoreError

    try:
        return make_bus()
    except KeystoreError as e:
        print(f"{who}: --secure: {e}", file=sys.stderr)
        raise SystemExit(2) from None


def serve(args: argparse.Namespace, bus: Any, make_node: Callable[[], Any],
          run: Callable[[Any], dict] | None = None, stop: threading.Event | None = None) -> dict | None:
    """Build the node (a ``ValueError`` - bad options - prints ``error: ...`` and returns None), route
    SIGINT / SIGTERM to ``node.stop``, run it (``run(node)``, default ``node.run()``), close the bus,
    print the report as JSON with ``--report-json``; returns the report."""
    try:
        try:
            node = make_node()
        except ValueError as e:
            print(f"error: {e}", file=sys.stderr)
            return None
        signal.signal(signal.SIGINT, node.stop)
        signal.signal(signal.SIGTERM, node.stop)
        if stop is not None and stop.is_set():
            node.stop()
        rep = node.run() if run is None else run(node)
    finally:
        closed = bus.close()
    if args.report_json:
        print(json.dumps(rep), flush=True)
    # the node's work is done and its data out (journal flushed, session closed or given up, report
    # printed): the process entry point exits at once (exit_process), whether or not the close hung
    global EXIT_AT_ONCE
    EXIT_AT_ONCE = True
    return rep


# exit without the interpreter's finalization (exit_process): set where a Zenoh session did not close in
# time (net.bus.Bus.close; its thread would keep a stopped process alive), and by every process whose
# work is done once its session is closed (the nodes of serve, the recorder once its file is finished,
# short commands): a Zenoh thread that calls into Python while the interpreter finalizes aborts the
# process ("FATAL: exception not rethrown", exit 134), seen with `larns keys revoke --publish` after it
# had published and with recorders after their file was complete
EXIT_AT_ONCE = False


def exit_process(code: int) -> None:
    """``sys.exit(code)`` for a ``python -m`` entry point; with ``EXIT_AT_ONCE`` (a hung session close, or
    a short command whose work is done), ``os._exit`` with the streams flushed."""
    if EXIT_AT_ONCE:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)
