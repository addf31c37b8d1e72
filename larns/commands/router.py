"""`larns router`: a Zenoh router for the client/router topology.

One router process, every station / recorder / monitor a Zenoh **client** connected to it
(``--zenoh-mode client --connect <router endpoint>``): N TCP links instead of the peer mesh's
N(N-1)/2, and the fan-out of every broadcast happens in Zenoh's Rust core inside the router.
It is also the natural multi-host setup (one router per host, routers connected to each other).

    larns router --listen tcp/127.0.0.1:7447
    larns station --id 5 --scenario seed000 --zenoh-mode client --connect tcp/127.0.0.1:7447

Secure (docs/security.md): ``larns router --secure DIR --listen tls/127.0.0.1:7447`` and the clients
with ``--secure DIR --connect tls/127.0.0.1:7447``. A revocation list that revokes a client (the
keystore's ``crl.pem``, or ``larns keys revoke --publish``) takes it out of the router's access rules:
the router reopens its session (~0.03 s; the clients are back within ~0.1 s: net/bus.py ``Bus.reopen``)
and Zenoh refuses everything that client sends from then on.

SIGINT / SIGTERM: clean exit. The router holds no LARNS state; its clients lose connectivity while
it is down and reconnect when it comes back.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time

from net.procsched import add_sched_args


def run_router(listen: list[str], connect: list[str], config_file: str | None = None,
               duration_s: float | None = None, quiet: bool = False, nice: int = 0,
               slice_us: float = 0.0, secure: tuple | None = None) -> int:
    import os

    from net.bus import Bus
    from net.procsched import set_slice_us

    if nice:
        try:
            os.nice(nice)
        except OSError as e:
            print(f"[router] cannot change niceness by {nice}: {e}", file=sys.stderr)

    if slice_us > 0 and set_slice_us(slice_us) is None and not quiet:  # before Zenoh's threads start
        print("[router] short CPU slice not available on this kernel; running with the default",
              file=sys.stderr)
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    from net.security import KeystoreError

    try:
        bus = Bus(listen=listen, connect=connect, config_file=config_file, mode="router", secure=secure)
    except KeystoreError as e:
        print(f"[router] --secure: {e}", file=sys.stderr)
        return 2
    if not quiet:
        print(f"[router] zid {bus.session.info.zid()} listening on {', '.join(listen)}",
              file=sys.stderr, flush=True)
    t_end = None if duration_s is None else time.time() + duration_s
    try:  # (--secure: the Bus takes revocations into its access rules by itself, net/bus.py)
        while not stop.is_set():
            if t_end is not None and time.time() >= t_end:
                break
            stop.wait(0.5)
    finally:
        bus.close()
    if not quiet:
        print("[router] stopped", file=sys.stderr, flush=True)
    return 0


def cmd_router(args: argparse.Namespace) -> int:
    secure = None
    if args.secure:
        from net import scenario as S
        from net.security import Keystore, KeystoreError, flood_guard
        from net.tiles import station_nav_keys

        if args.secure == "auto":
            print("[router] --secure needs a keystore DIR (larns keys init DIR)", file=sys.stderr)
            return 2
        scn = S.load(args.scenario)
        tdma = scn.tdma  # the flood guard's budget: the fleet's TDMA
        try:
            ks = Keystore(args.secure)
        except KeystoreError as e:
            print(f"[router] --secure: {e}", file=sys.stderr)
            return 2
        issued = sorted(e["id"] for e in ks.enclaves.values() if e.get("role") == "station")
        secure = (args.secure, "router", flood_guard(tdma.cycle_s, tdma.slot_s, args.speed, ks.reserved,
                                                     None, issued, nav_keys=station_nav_keys(scn, ks.reserved)))
    default = "tls/127.0.0.1:7447" if secure else "tcp/127.0.0.1:7447"
    return run_router(args.listen or [default], args.connect or [], args.zenoh_config,
                      args.duration, args.quiet, args.nice, args.slice_us, secure)


def register(sub) -> None:
    from .helptext import Formatter, examples

    p = sub.add_parser("router", help="Zenoh router for the client/router topology (--zenoh-mode client)",
                       description=__doc__, formatter_class=Formatter,
                       epilog=examples(
                           "larns router --listen tcp/127.0.0.1:7447",
                           "larns fleet --topology router --connect tcp/127.0.0.1:7447 --duration 60",
                       ))
    p.add_argument("--listen", action="append", default=None, metavar="ENDPOINT",
                   help="endpoint to listen on (repeatable; default tcp/127.0.0.1:7447)")
    p.add_argument("--connect", action="append", default=None, metavar="ENDPOINT",
                   help="other routers to connect to (multi-host; repeatable)")
    p.add_argument("--zenoh-config", default=None, metavar="FILE",
                   help="full Zenoh JSON5 config instead of the built-in router defaults")
    p.add_argument("--secure", default=None, nargs="?", const="auto", metavar="DIR",
                   help="keystore (larns keys init): TLS/mTLS only, certificate `router`, access control per "
                        "client and a per-client flood guard sized for --scenario's TDMA at --speed")
    p.add_argument("--scenario", default="seed000", help="scenario whose TDMA sizes the flood guard (--secure)")
    p.add_argument("--speed", type=float, default=1.0, help="fleet speed factor (--secure flood guard)")
    p.add_argument("--duration", type=float, default=None, help="exit after S seconds (default: run until signalled)")
    p.add_argument("--nice", type=int, default=0, metavar="N",
                   help="niceness change (negative = ahead of the stations on a busy machine; needs privileges)")
    add_sched_args(p)
    p.add_argument("-q", "--quiet", action="store_true", help="no start and statistics lines")
    p.set_defaults(func=cmd_router)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(prog="python -m larns.commands.router")
    register(ap.add_subparsers(dest="cmd", required=True))
    a = ap.parse_args(["router", *sys.argv[1:]])
    sys.exit(a.func(a))
