"""Watching a running fleet: spawn the hot-joiners on time, print the live table, notice the end."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time

from .monitor import Monitor, format_table
from .plan import FleetPlan, restart_child
from .spawn import spawn


def open_monitor(args: argparse.Namespace, p: FleetPlan, monitor: Monitor):
    """The launcher observes like any peer (spawn the children first: no fork of a live runtime)."""
    from net.bus import Bus

    from .plan import wants_vehicle

    bus = Bus(listen=[] if p.mode == "client" else [p.monitor_ep], connect=p.seeds, config_file=args.zenoh_config,
              mode=p.mode, secure=(p.secure, "monitor") if p.secure else None)
    subscribe(bus, monitor, aircraft=args.aircraft, vehicle=wants_vehicle(args))
    return bus


def subscribe(bus, monitor: Monitor, aircraft: bool = True, vehicle: bool = True) -> None:
    """What the live table needs from the bus (the fleet's own view and ``larns monitor``)."""
    bus.subscribe("larns/station/*/estimate", monitor.on_sample)
    bus.subscribe("larns/station/*/truth", monitor.on_sample)
    bus.subscribe("larns/station/*/integrity", monitor.on_sample)
    if aircraft:
        bus.subscribe("larns/aircraft/**", monitor.on_sample)
    if vehicle:
        bus.subscribe("larns/vehicle/*/estimate", monitor.on_sample)
        bus.subscribe("larns/vehicle/*/truth", monitor.on_sample)
    bus.subscribe_liveliness("larns/alive/**", monitor.on_alive)


def finished(args: argparse.Namespace, p: FleetPlan, now: float) -> bool:
    """Past the end (``--duration`` + 1 s), or every station process has exited."""
    if args.duration and now >= p.epoch + args.duration / args.speed + 1.0:
        return True
    stations = [c for c in p.children if c.name.startswith("station")]
    return bool(args.duration) and all(c.proc is not None and c.proc.poll() is not None for c in stations)


def print_table(args: argparse.Namespace, p: FleetPlan, monitor: Monitor, now: float, tty: bool) -> None:
    t_f = (now - p.epoch) * args.speed
    n_alive = sum(1 for c in p.children if c.proc is not None and c.proc.poll() is None)
    txt = "\n".join([format_table(monitor.snapshot(), t_f, n_alive), *monitor.aircraft_lines(), *monitor.vehicle_lines()])
    sys.stdout.write("\x1b[H\x1b[2J" + txt + "\n" if tty else txt + "\n\n")
    sys.stdout.flush()


RESTART_LEAD_S = 3.0  # wall seconds a restarted station is spawned ahead of its fleet time (imports, bus)


def station_events(args: argparse.Namespace, p: FleetPlan, now: float) -> None:
    """Act on the fleet's station events that are due (``--kill``, ``--restart``, scenario
    ``[[faults]]`` leave / kill): SIGKILL or SIGTERM to the station's live process; a restart spawns
    a fresh process with the same id ``RESTART_LEAD_S`` ahead (after the station is down), which
    sleeps until its fleet time and joins the running field."""
    for e in p.events:
        if e.done:
            continue
        due = p.epoch + e.t_s / args.speed
        live = [c for c in p.children if c.name.split("#")[0] == f"station {e.sid}" and c.proc is not None
                and c.proc.poll() is None]
        if e.kind == "restart":
            if now < due - RESTART_LEAD_S or live:
                continue
            n = 1 + sum(1 for c in p.children if c.name.split("#")[0] == f"station {e.sid}")
            c = restart_child(args, p, e.sid, e.t_s, n)
            p.children.append(c)
            spawn(c)
            print(f"[fleet] t={e.t_s:g} s: station {e.sid} restarted (a fresh process, joining)", file=sys.stderr,
                  flush=True)
        elif now >= due:
            for c in live:
                c.proc.send_signal(signal.SIGKILL if e.kind == "kill" else signal.SIGTERM)
                c.expected_exit = True
            print(f"[fleet] t={e.t_s:g} s: station {e.sid} {'killed (SIGKILL)' if e.kind == 'kill' else 'leaves (SIGTERM)'}",
                  file=sys.stderr, flush=True)
        else:
            continue
        e.done = True


def watch(args: argparse.Namespace, p: FleetPlan, monitor: Monitor, stop: threading.Event) -> None:
    """Until the end of the run or ``stop``: late spawns, station events and the live table."""
    next_print = p.epoch
    tty = sys.stdout.isatty() and not args.no_table
    period = args.refresh if tty else max(args.refresh, 10.0)
    while not stop.is_set():
        now = time.time()
        for c in p.children:
            if c.proc is None and c.start_wall and now >= c.start_wall:
                spawn(c)
        station_events(args, p, now)
        if finished(args, p, now):
            break
        if now >= next_print and not args.no_table:
            print_table(args, p, monitor, now, tty)
            next_print = now + period
        time.sleep(0.05)


