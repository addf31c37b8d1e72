"""Watching a running fleet: spawn the hot-joiners on time, print the live table, notice the end."""

from __future__ import annotations

import argparse
import sys
import threading
import time

from .monitor import Monitor, format_table
from .plan import FleetPlan
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


def watch(args: argparse.Namespace, p: FleetPlan, monitor: Monitor, stop: threading.Event) -> None:
    """Until the end of the run or ``stop``: late spawns and the live table."""
    next_print = p.epoch
    tty = sys.stdout.isatty() and not args.no_table
    period = args.refresh if tty else max(args.refresh, 10.0)
    while not stop.is_set():
        now = time.time()
        for c in p.children:
            if c.proc is None and c.start_wall and now >= c.start_wall:
                spawn(c)
        if finished(args, p, now):
            break
        if now >= next_print and not args.no_table:
            print_table(args, p, monitor, now, tty)
            next_print = now + period
        time.sleep(0.05)


