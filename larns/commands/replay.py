"""`larns replay run.mcap`: play a recording back onto Zenoh, or re-estimate it offline.

Live replay (default) republishes the **exact recorded wire bytes** (``msgpack`` channels; JSON
view channels are skipped) on their keys with the recorded timing (``log_time`` differences divided
by ``--rate``). The flags follow ``ros2 bag play``:

    --rate R            play R times faster (0.5 = half speed)
    --loop              start again at the end (until Ctrl-C)
    --start-offset S    skip the first S seconds (log time) of the recording
    --until S           stop S seconds (log time) after the start of the recording
    --topics GLOB ...   only these keys (Zenoh globs: * one chunk, ** any chunks)
    --exclude GLOB ...  not these keys
    --remap FROM=TO     publish FROM (a key, key prefix or glob) as TO (repeatable)
    --start-paused      wait for the space bar before the first message
    --delay S           wait S seconds after opening the session (peers link up)
    --wait-for KEYEXPR  ...and until a liveliness token matching KEYEXPR is present

On a terminal: SPACE pauses/resumes, ``s`` publishes the next message while paused, ``q`` quits.
Several input files are merged by log time. A live ``larns aircraft`` can fly against a replayed
log of station broadcasts: its channel layer takes the sender's true position and transmit time
from the recorded ``phy`` part.

Offline (``--offline``, no Zenoh, no sleeping): every station, aircraft and vehicle with a recorded
journal is rebuilt and re-run (``larns/analysis/offline.py``); re-running the recorded estimator or
algorithm reproduces the recorded estimates bit for bit (checked and reported; ``--check`` exits 3
otherwise), ``--estimator`` runs another survey estimator on the same inputs, ``--algo`` other
aircraft algorithms on the aircraft's journal; each prints its accuracy against the recorded truth
beside the recorded one's. ``-o out.mcap`` writes the recording with the estimates replaced.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from ..log import merge, parse_remaps, read_logs
from ..log.player import Controls, Keyboard, play, select_messages  # noqa: F401  (old import path)


# --------------------------------------------------------------------------- selection

def _warn_incomplete(logs, tag: str, verb: str) -> None:
    """Say which inputs were cut short (a killed recorder) and how much of them is used."""
    for lg in logs:
        if not lg.complete:
            print(f"[{tag}] {lg.path}: incomplete recording ({lg.error}); {verb} the "
                  f"{len(lg.messages)} messages before the damage", file=sys.stderr)


def _wait_for(bus, keyexpr: str, timeout_s: float) -> bool:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if bus.alive(keyexpr, 0.5):
            return True
        time.sleep(0.2)
    return False


def cmd_replay(args: argparse.Namespace) -> int:
    if getattr(args, "secure", None):  # check the recording's signatures (docs/security.md)
        from larns.commands.keys import cmd_verify_recordings

        return cmd_verify_recordings(args.secure, args.files, args.topics, args.exclude)
    if args.offline:
        return cmd_offline(args)
    if getattr(args, "view", None) is not None:  # into Foxglove instead of Zenoh (larns/commands/view.py)
        from .view import cmd_replay_view

        return cmd_replay_view(args)
    from net.bus import Bus, bus_kwargs

    try:
        logs = read_logs(args.files, encodings=["msgpack"])
        rules = parse_remaps(args.remap)
    except (OSError, ValueError) as e:
        print(f"larns replay: {e}", file=sys.stderr)
        return 1
    _warn_incomplete(logs, "replay", "playing")
    msgs = select_messages(merge(logs), args.topics, args.exclude, args.start_offset, args.until)
    if not msgs:
        print("[replay] nothing to play (check --topics / --exclude / --start-offset / --until)", file=sys.stderr)
        return 1
    span = (msgs[-1].log_time - msgs[0].log_time) * 1e-9
    print(f"[replay] {len(msgs)} messages on {len({m.topic for m in msgs})} keys, {span:.1f} s at rate "
          f"{args.rate:g} ({span / args.rate:.1f} s)", file=sys.stderr, flush=True)
    bus = Bus(**bus_kwargs(args))
    try:
        if args.wait_for:
            ok = _wait_for(bus, args.wait_for, args.wait_timeout)
            print(f"[replay] {'found' if ok else 'timed out waiting for'} {args.wait_for}", file=sys.stderr)
        if args.delay > 0:
            time.sleep(args.delay)
        controls = Controls(paused=args.start_paused)
        kb = Keyboard(controls)
        if args.start_paused:
            print("[replay] paused: SPACE to start/pause, 's' to step one message, 'q' to quit"
                  if kb.enabled else "[replay] --start-paused needs a terminal on stdin: starting now",
                  file=sys.stderr, flush=True)
            if not kb.enabled:
                controls.paused = False
        with kb:
            st = play(msgs, bus.publish, rate=args.rate, loop=args.loop, remaps=rules, controls=controls,
                      progress=not args.quiet)
        time.sleep(0.2)  # let the last samples leave
    except KeyboardInterrupt:
        return 130
    finally:
        bus.close()
    print(f"[replay] published {st.published} messages in {st.wall_s:.1f} s ({st.loops} pass"
          f"{'es' if st.loops != 1 else ''}; max lag {st.max_lag_ms:.1f} ms)", file=sys.stderr)
    if args.json:
        print(json.dumps(vars(st)))
    return 0


def cmd_offline(args: argparse.Namespace) -> int:
    from ..analysis.offline import JOURNAL_TOPICS, format_result, run_offline

    try:  # only the journal, estimate and truth channels unless the whole recording is rewritten
        logs = read_logs(args.files, topics=None if args.output else JOURNAL_TOPICS)
    except (OSError, ValueError) as e:
        print(f"larns replay --offline: {e}", file=sys.stderr)
        return 1
    _warn_incomplete(logs, "offline", "using")
    if args.estimator:
        from stations.estimators import ESTIMATORS

        if args.estimator not in ESTIMATORS:
            print(f"larns replay --offline: unknown estimator {args.estimator!r}; choose from "
                  f"{', '.join(ESTIMATORS)}", file=sys.stderr)
            return 2
    try:
        res = run_offline(args.files, output=args.output, estimator=args.estimator, logs=logs,
                          strict=not args.fast, progress=not args.quiet, algos=args.algo, stations=args.stations)
    except (OSError, ValueError) as e:  # unknown algorithm, unwritable output, ...
        print(f"larns replay --offline: {e}", file=sys.stderr)
        return 2
    if not args.quiet:
        print(format_result(res))
    if args.json:
        print(json.dumps(res.as_dict()))
    if args.check:
        bad = check_failures(res)
        if bad:
            print(f"[offline] --check failed: {'; '.join(bad)}", file=sys.stderr)
            return 3
    return 0


def check_failures(res) -> list[str]:
    """What ``--check`` fails on: a station re-run with its recorded estimator, a recorded aircraft
    algorithm or a vehicle whose re-run differs from a recorded estimate, or whose journal could not
    be replayed (an aircraft without any journal, from before it existed, and a journal hole are
    reported, not failed: what was re-run up to the hole is checked); and a recording with no
    station reproduced at all."""
    bad = [f"station {s}: {r.equal}/{r.compared} identical" for s, r in res.stations.items()
           if r.same_estimator and r.compared and not r.bit_exact]
    if res.stations and not any(r.bit_exact for r in res.stations.values() if r.same_estimator) \
            and any(r.same_estimator for r in res.stations.values()):
        bad.append("no station reproduced its recorded estimates")
    bad += [f"aircraft {name} {algo}: {why}" for name, per in res.aircraft.items() for algo, d in per.items()
            for why in [_aircraft_failure(d)] if why]
    for name, d in res.vehicles.items():
        if d.get("error") or not d.get("bit_exact"):
            bad.append(f"vehicle {name}: " + (d["error"] or f"{d['equal']}/{d['compared']} identical"))
    return bad


def _aircraft_failure(d: dict) -> str | None:
    """Why one aircraft algorithm's re-flight fails ``--check`` (None: it passes)."""
    if d["compared"] and d["equal"] != d["compared"]:
        return f"{d['equal']}/{d['compared']} identical"
    if d["recorded"] and not d["compared"] and d["missing_from"] is None and not d["stopped"] \
            and not (d.get("error") or "").startswith("no ac_init"):
        return f"none of its {d['recorded']} recorded estimates re-flown" + (f" ({d['error']})" if d.get("error") else "")
    return None


def register(sub) -> None:
    from net.bus import add_bus_args

    from .helptext import Formatter, examples

    p = sub.add_parser(
        "replay", help="play an MCAP recording back on Zenoh, or re-estimate it offline",
        description=__doc__, formatter_class=Formatter,
        epilog=examples(
            "larns replay runs/demo.mcap --rate 2",
            "larns replay --offline runs/demo.mcap --estimator seed-ukf",
            "larns replay --offline runs/demo.mcap --algo ekf-pr --check",
        ))
    p.add_argument("files", nargs="+", help="MCAP file(s), merged by log time")
    p.add_argument("-r", "--rate", type=float, default=1.0, help="playback rate factor (default 1)")
    p.add_argument("-l", "--loop", action="store_true", help="loop playback")
    p.add_argument("--start-offset", type=float, default=0.0, metavar="S", help="skip the first S seconds")
    p.add_argument("--until", type=float, default=None, metavar="S", help="stop S seconds after the start")
    p.add_argument("--topics", nargs="+", default=None, metavar="GLOB", help="only keys matching these globs")
    p.add_argument("--exclude", nargs="+", default=None, metavar="GLOB", help="skip keys matching these globs")
    p.add_argument("--remap", action="append", default=None, metavar="FROM=TO", help="publish FROM as TO")
    p.add_argument("--start-paused", action="store_true", help="start paused (SPACE plays, 's' steps)")
    p.add_argument("--delay", type=float, default=1.0, metavar="S",
                   help="wait S seconds after opening the Zenoh session before playing (default 1)")
    p.add_argument("--wait-for", default=None, metavar="KEYEXPR",
                   help="wait for a liveliness token, e.g. larns/alive/aircraft/*")
    p.add_argument("--wait-timeout", type=float, default=30.0, help="seconds to wait for --wait-for")
    g = p.add_argument_group("offline re-estimation (no Zenoh, no sleeping; also `larns reestimate`)")
    g.add_argument("--offline", action="store_true", help="re-run the estimators on the recorded inputs")
    add_offline_args(g)
    p.add_argument("--json", action="store_true", help="print statistics as JSON")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    from .view import add_replay_view_args

    add_replay_view_args(p)
    add_bus_args(p)
    p.set_defaults(func=cmd_replay)


def add_offline_args(g) -> None:
    """The options of offline re-estimation (``replay --offline`` and ``reestimate``)."""
    g.add_argument("-o", "--output", default=None, help="write the re-estimated recording here (.mcap)")
    g.add_argument("--estimator", default=None, help="survey estimator for the stations (dmap, seed-ukf); "
                                                     "default: the recorded one")
    g.add_argument("--algo", action="append", default=None,
                   help="another aircraft algorithm to re-fly on the recorded aircraft journal (repeatable; "
                        "radio filters on any aircraft's measurements, ins-ekf / triad on their own kind's); "
                        "the recorded algorithms are always re-flown and compared")
    g.add_argument("--scenario", default=None,
                   help="not needed any more: the aircraft journal carries its navigator's settings (accepted "
                        "for older command lines, unused)")
    g.add_argument("--stations", type=int, nargs="+", default=None, help="only these station ids")
    g.add_argument("--fast", action="store_true", help="skip strict validation of the journal payloads")
    g.add_argument("--check", action="store_true",
                   help="exit 3 unless every re-run station (recorded estimator), aircraft (recorded algorithms) "
                        "and vehicle reproduces its recorded estimates bit for bit")
