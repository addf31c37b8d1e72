"""`larns fleet`: plan, spawn, watch, stop - and the final table."""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
from pathlib import Path

from .monitor import Monitor, StationView, format_table
from .plan import FleetPlan, join_start_wall, plan_fleet
from .spawn import remove_barrier, spawn, start_barrier
from .stop import shutdown
from .watch import open_monitor, watch


def _announce(args: argparse.Namespace, p: FleetPlan) -> None:
    joins = p.joins
    print(f"[fleet] scenario {p.scn.name}: {len(p.initial)} stations"
          + (f" + {len(joins)} joining ({', '.join(f'{s}@{t:g}s' for s, t in joins)})" if joins else "")
          + (f", events {', '.join(f'{e.kind} {e.sid}@{e.t_s:g}s' for e in p.events)}" if p.events else "")
          + (f", recorder -> {args.record}" if args.record else "")
          + f", speed {args.speed:g}, epoch once every process is up"
          + (f", logs in {p.logdir}/" if p.logdir else ""), file=sys.stderr, flush=True)


def fleet_file_path(args: argparse.Namespace, p: FleetPlan) -> Path:
    """``--fleet-file``, else ``fleet.json`` beside the recording, else in the log folder."""
    if getattr(args, "fleet_file", None):
        return Path(args.fleet_file)
    if args.record:
        return Path(args.record).parent / "fleet.json"
    return Path(p.logdir or ".") / "fleet.json"


def write_fleet_file(args: argparse.Namespace, p: FleetPlan) -> Path:
    """What a separately started process needs to attach (``larns station --join --fleet FILE``;
    ``net/attach.py``): epoch, speed, scenario, endpoints, secure or not."""
    import os
    import socket

    from net.attach import fleet_record
    from net.attach import write_fleet_file as write

    scenario = str(args.scenario)
    if Path(scenario).is_file():  # a path: absolute, so a process started elsewhere finds it
        scenario = str(Path(scenario).resolve())
    faults = {k: getattr(args, f"net_{k}") for k in ("delay", "jitter", "loss", "dup")
              if getattr(args, f"net_{k}", None) is not None}
    rec = fleet_record(scenario=scenario, scenario_name=p.scn.name, n_stations=args.n_stations, epoch_unix_s=p.epoch,
                       speed=args.speed, duration_s=args.duration, mode=p.mode, connect=p.seeds,
                       endpoints=p.endpoints, secure=p.secure,
                       recording=str(Path(args.record).resolve()) if args.record else None,
                       net_faults=faults, pid=os.getpid(), host=socket.gethostname())
    return write(fleet_file_path(args, p), rec)


def _final(args: argparse.Namespace, p: FleetPlan, monitor: Monitor, final: list[StationView],
           interrupted: bool) -> int:
    """Final table, exit codes, ``--json``; the launcher's exit code."""
    t_f = (time.time() - p.epoch) * args.speed
    print("\n".join([format_table(final, t_f), *monitor.aircraft_lines(), *monitor.vehicle_lines()]))
    rc = {c.name: (c.proc.returncode if c.proc else None) for c in p.children}
    expected = {c.name for c in p.children if c.expected_exit}  # --kill, [[faults]] leave / kill
    bad = {k: v for k, v in rc.items() if v not in (0, None) and k not in expected}
    if bad:
        print(f"[fleet] non-zero exit codes: {bad}", file=sys.stderr)
    if args.record:
        print(f"[fleet] recording: {args.record}", file=sys.stderr)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps({
            "scenario": p.scn.name, "epoch_unix_s": p.epoch, "speed": args.speed, "duration_s": args.duration,
            "exit_codes": rc, "stations": [dict(vars(v), err_m=v.err_m) for v in final]}, indent=2,
            default=float))
    return 130 if interrupted else (1 if bad else 0)


def _start(args: argparse.Namespace, p: FleetPlan, stop: threading.Event, t0: float) -> None:
    """The start barrier (larns/fleet/spawn.py): the epoch once the processes are up; then the
    joiners' spawn times and the fleet file, which both follow from it."""
    p.epoch, late = start_barrier(p.children, p.epoch_file, stop)
    for c in p.children:
        if c.join_t_s is not None:
            c.start_wall = join_start_wall(args, p, c.join_t_s)
    up = sum(1 for c in p.children if c.proc is not None)
    print(f"[fleet] {up - len(late)} of {up} processes up in {time.time() - t0:.1f} s; epoch {p.epoch:.3f}"
          + (f" (not up: {', '.join(late)})" if late else ""), file=sys.stderr, flush=True)
    ffile = write_fleet_file(args, p)
    print(f"[fleet] fleet file {ffile} (epoch {p.epoch:.3f}, connect {' '.join(p.seeds)}"
          f"{', secure' if p.secure else ''}); attach with: larns station --id N --join --fleet {ffile}",
          file=sys.stderr, flush=True)


def run_fleet(args: argparse.Namespace) -> int:
    """Launch the fleet of ``args`` (``larns fleet``), watch it until the end or Ctrl-C, stop it."""
    p = plan_fleet(args)
    stop = threading.Event()

    def on_signal(signum, frame):  # noqa: ARG001
        stop.set()

    old_int = signal.signal(signal.SIGINT, on_signal)
    old_term = signal.signal(signal.SIGTERM, on_signal)
    _announce(args, p)
    monitor = Monitor()
    bus = None
    final: list[StationView] = []
    try:
        t0 = time.time()
        for c in p.children:
            if c.start_wall == 0.0:
                spawn(c)
        _start(args, p, stop, t0)
        bus = open_monitor(args, p, monitor)
        watch(args, p, monitor, stop)
        final = monitor.snapshot()
    finally:
        # stations first (they exit at --duration on their own), then the recorder, the router last
        shutdown(p.children, wait_for_stations=not stop.is_set() and bool(args.duration))
        if bus is not None:
            bus.close()
        remove_barrier(p.epoch_file)
        signal.signal(signal.SIGINT, old_int)
        signal.signal(signal.SIGTERM, old_term)
    return _final(args, p, monitor, final, stop.is_set())
