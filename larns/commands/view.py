"""`larns view`: a live Foxglove view of a running fleet (:mod:`larns.viz.live`).

    larns view --connect tcp/127.0.0.1:7447          # then open ws://localhost:8765 in Foxglove

Subscribes to ``larns/**`` on Zenoh and serves a Foxglove WebSocket (official Foxglove SDK): the
stations' 3-sigma ellipsoids and truth, the aircraft and vehicle with their tracks and covariance,
range exchanges, plottable errors / sigmas / clock sync per station, integrity decisions and process
liveliness as logs; the server's time is the fleet time. docs/view.md.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading


def cmd_view(args: argparse.Namespace) -> int:
    from net.bus import bus_kwargs
    from net.security import KeystoreError

    from larns.viz.live import serve_live

    if not 0 <= args.port <= 65535:
        print(f"larns view: --port {args.port}: expected 0..65535", file=sys.stderr)
        return 2
    stop = threading.Event()
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, lambda *_: stop.set())
    args.secure_cn = "monitor"  # a passive observer: the keystore's observe-only identity

    def ready(port: int) -> None:
        if not args.quiet:
            print(f"[view] Foxglove WebSocket on ws://{args.host}:{port} (Foxglove: Open connection -> "
                  f"Foxglove WebSocket); Ctrl-C to stop", file=sys.stderr, flush=True)

    site = None
    if args.scenario:  # its [site]: estimates and truth also as LocationFix (Map panel)
        from net.scenario import ScenarioError, load

        try:
            site = load(args.scenario).site
        except ScenarioError as e:
            print(e, file=sys.stderr)
            return 2
    try:
        stats = serve_live(bus_kwargs(args), host=args.host, port=args.port, keyexpr=args.keyexpr,
                           duration_s=args.duration, stop=stop, on_ready=ready, site=site)
    except KeystoreError as e:
        print(f"larns view: --secure: {e}", file=sys.stderr)
        return 2
    except RuntimeError as e:  # the SDK's server could not start (port in use, bad host)
        print(f"larns view: cannot serve on {args.host}:{args.port}: {e}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(stats))
    elif not args.quiet:
        print(f"[view] {stats['samples']} samples, {stats['sent']} messages sent on {stats['channels']} "
              f"channels, dropped {stats['dropped'] or 'none'}", file=sys.stderr)
    return 0


VIEW_DESCRIPTION = """\
Watch a running fleet live in Foxglove (docs/view.md): the view joins the fleet's Zenoh network as
a passive peer (--connect to any process of the fleet; ./dev demo's endpoints are in
runs/fleet.json) and serves a Foxglove WebSocket; in Foxglove, Open connection -> Foxglove
WebSocket -> ws://HOST:PORT. It shows the stations' 3-sigma ellipsoids and truth, the aircraft
and vehicle with their tracks and covariance, range exchanges, plottable errors, sigmas and clock
sync per station, and integrity decisions and processes coming and going as logs. The view's
clock is the fleet time. With --secure DIR it connects with the keystore's observe-only identity.

`larns fleet --view` starts one with the fleet; `larns replay --view` serves a recording."""


def register(sub) -> None:
    from net.bus import add_bus_args

    from .helptext import add_parser

    p = add_parser(sub, "view", help="live Foxglove view of a running fleet (WebSocket, default :8765)",
                   description=VIEW_DESCRIPTION,
                   example=["larns view --connect tcp/127.0.0.1:7447        # then open ws://127.0.0.1:8765 in Foxglove",
                            "larns view --host 0.0.0.0 --port 8766 --connect tcp/10.0.0.5:7447   # other hosts may connect",
                            "larns view --connect tcp/127.0.0.1:7447 --duration 60 --json     # statistics at the end",
                            "larns fleet --scenario seed000 --aircraft --view                 # a fleet with its own view"])
    p.add_argument("--host", default="127.0.0.1",
                   help="address to serve on (default 127.0.0.1; 0.0.0.0 in a container)")
    p.add_argument("--port", type=int, default=8765, help="WebSocket port (default 8765; 0 = any free port)")
    p.add_argument("--keyexpr", default="larns/**", help="key expression to view (default larns/**)")
    p.add_argument("--duration", type=float, default=None,
                   help="stop after this many wall seconds (default: until Ctrl-C)")
    p.add_argument("--epoch", type=float, default=None,
                   help="fleet epoch, Unix s (accepted like every fleet process; not needed: fleet time "
                        "comes from the messages)")
    p.add_argument("--speed", type=float, default=None, help="fleet speed factor (accepted, not needed)")
    p.add_argument("--scenario", default=None, metavar="NAME|FILE",
                   help="the fleet's scenario: with a [site], estimates and truth are also sent as "
                        "foxglove.LocationFix for the Map panel (default: none)")
    p.add_argument("--json", action="store_true", help="print statistics as JSON at the end")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")
    add_bus_args(p)
    p.set_defaults(func=cmd_view)


def cmd_replay_view(args: argparse.Namespace) -> int:
    """`larns replay --view run.mcap`: the recording served through the live view on a Foxglove
    WebSocket; Foxglove's playback controls (play, pause, speed, seek) drive the player."""
    from larns.log import Timebase, merge, read_logs
    from larns.log.player import select_messages
    from larns.viz.live import serve_recording

    if not 0 <= args.view <= 65535:
        print(f"larns replay --view {args.view}: expected a port 0..65535", file=sys.stderr)
        return 2
    if not args.rate > 0:
        print(f"larns replay --view: --rate {args.rate:g}: expected > 0", file=sys.stderr)
        return 2
    try:
        logs = read_logs(args.files, encodings=["msgpack"])
    except (OSError, ValueError) as e:
        print(f"larns replay --view: {e}", file=sys.stderr)
        return 2
    msgs = select_messages(merge(logs), args.topics, args.exclude, args.start_offset, args.until)
    if not msgs:
        print("larns replay --view: nothing to play (check --topics / --exclude / --start-offset / --until)",
              file=sys.stderr)
        return 1
    stop = threading.Event()
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, lambda *_: stop.set())

    def ready(port: int) -> None:
        if not args.quiet:
            print(f"[replay] {len(msgs)} messages served on ws://{args.view_host}:{port} (Foxglove: Open "
                  f"connection -> Foxglove WebSocket; the playback bar plays, pauses, seeks); Ctrl-C to stop",
                  file=sys.stderr, flush=True)

    from larns.viz.foxglove import recording_site

    try:
        stats = serve_recording(msgs, Timebase.of(logs, msgs[0].log_time), host=args.view_host, port=args.view,
                                speed=args.rate, start_paused=args.start_paused, stop=stop, on_ready=ready,
                                duration_s=args.view_duration, site=recording_site(logs))
    except RuntimeError as e:
        print(f"larns replay --view: cannot serve on {args.view_host}:{args.view}: {e}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(stats))
    elif not args.quiet:
        print(f"[replay] delivered {stats['delivered']} of {stats['messages']} messages ({stats['seeks']} seeks)",
              file=sys.stderr)
    return 0


def add_replay_view_args(p) -> None:
    """``larns replay --view [PORT]`` and its options."""
    g = p.add_argument_group("replay into Foxglove (docs/view.md)")
    g.add_argument("--view", type=int, nargs="?", const=8765, default=None, metavar="PORT",
                   help="serve the recording on a Foxglove WebSocket (default port 8765) instead of Zenoh; "
                        "Foxglove's playback controls drive the player (--rate is the initial speed)")
    g.add_argument("--view-host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    g.add_argument("--view-duration", type=float, default=None, metavar="S",
                   help="stop serving after S wall seconds (default: until Ctrl-C)")


def view_child(args: argparse.Namespace, plan):
    """``larns fleet --view [PORT]``: the fleet's ``larns view`` process (a :class:`larns.fleet.spawn.Child`)."""
    from net.bus import bus_argv

    from larns.fleet.spawn import Child

    cmd = [sys.executable, "-m", "larns", "view", "--port", str(args.view), "-q", "--scenario", args.scenario]
    cmd += bus_argv(["tcp/127.0.0.1:0"], plan.seeds, args.zenoh_config, plan.mode, plan.secure)
    print(f"[fleet] live Foxglove view on ws://127.0.0.1:{args.view}", file=sys.stderr)
    return Child("viewer", cmd, plan.logdir / "viewer.log" if plan.logdir else None)
