"""Aircraft process: a thin Zenoh shell around one live core (:mod:`aircraft.core`): it listens to the
stations' nav broadcasts, hands each to the core and publishes what the core returns.

* **core**: :func:`aircraft.core.make_core` picks it by configuration - the radio aircraft
  (``aircraft/radio_core.py``, ``--algo ukf-pr ...``), the inertial one (``aircraft/ins_core.py``,
  ``--imu`` / ``ins-ekf``) or the triad (``aircraft/triad_core.py``, ``--satellites`` / ``triad``); each
  owns its world (truth, channel layer: pseudoranges on the receiver clock from the sender's true
  position and transmit time), its navigator and its journal.
* **time**: fleet time ``t = (wall - epoch) * speed`` like the stations (same ``--epoch``); the core
  is ticked ``lag_s`` (x speed) behind it between broadcasts (an inertial core integrates its IMU there).
* **receive**: ``larns/station/*/nav/**`` into a Zenoh ring buffer drained once per TDMA cycle (a
  nav's timing comes from its ``phy``, not from when it is read: batches keep the process from waking
  and switching threads for every broadcast; a bus without ring buffers: one callback per nav into
  a bounded inbox) -> strict decode (malformed: counted and dropped) -> key/src
  check -> the named sender's true position and transmit time from the scenario's truth, never the
  sender's ``phy`` claims (``net.channel.UserIntake``) -> ``core.on_nav``.
* **publish**: ``larns/aircraft/<name>/estimate/<algo>`` (``ac_estimate``) after every update and
  ``larns/aircraft/<name>/truth`` (``ac_truth``) with every measurement; the navigator's journal
  ``larns/aircraft/<name>/init`` + ``.../input`` (``ac_init``, ``ac_input``: everything it consumed,
  aircraft/journal.py; ``larns reestimate`` re-flies it bit for bit; congestion control BLOCK, the last
  entries at exit); liveliness token ``larns/alive/aircraft/<name>``.

SIGINT / SIGTERM: clean exit.
"""

from __future__ import annotations

import argparse
import logging
import math
import queue
import sys
import threading
import time
from dataclasses import dataclass, replace
from typing import Any

from net.channel import UserIntake
from net.nettime import network_time
from net.queues import DropOldestQueue

from .core import AircraftCore, make_core


log = logging.getLogger("larns.aircraft")

INBOX_MAX = 4096  # samples waiting for the loop (a few seconds of every station's navs)


@dataclass
class AircraftOptions:
    name: str = "ac1"
    algos: tuple[str, ...] = ("ukf-pr",)
    speed: float = 1.0
    epoch_unix_s: float | None = None
    duration_s: float | None = None
    seed: int | None = None
    height_m: float | None = None
    status_every_s: float = 5.0
    quiet: bool = False
    imu: str | None = None  # IMU preset: fly the 6-DOF world with an IMU and run ins-ekf (docs/ins.md)
    satellites: int | None = None  # run the triad (INS + N satellites + stations + baro, docs/triad.md)


class AircraftNode:
    """Wall-clock shell around one :class:`aircraft.core.AircraftCore` over a :class:`net.bus.Bus`."""

    def __init__(self, scn, opts: AircraftOptions, bus: Any):
        from net import messages as M

        from .config import from_scenario

        self.M = M
        self.ac = from_scenario(scn)
        if opts.speed <= 0:
            raise ValueError("--speed must be > 0")
        self.opts = opts
        self.bus = bus
        self.epoch = (math.floor(time.time() / 86400.0) * 86400.0 if opts.epoch_unix_s is None
                      else float(opts.epoch_unix_s))
        seed = int(scn.seed if opts.seed is None else opts.seed)
        net_clock = network_time(scn, seed)  # the receivers run on network time as the field realizes it
        self.core: AircraftCore = make_core(scn, self.ac, opts, seed, t0_s=max(0.0, math.floor(self.fleet_now())),
                                            net_clock=net_clock)
        self.drops = M.DropCounter(f"aircraft {opts.name}")
        # bounded, drop-oldest (net/queues.py): a flood of samples costs old ones, never memory
        self._inbox = DropOldestQueue(INBOX_MAX)
        self._ring = None  # the navs' Zenoh ring buffer (run), when the bus has them
        # wall seconds between drains of the ring: one TDMA cycle, at most the core's own step
        self._drain_s = min(float(self.core.step_s), float(scn.tdma.cycle_s) / opts.speed)
        self._stop = threading.Event()
        self._last_status = -math.inf
        # (key, bytes) -> (msg, phy); --secure: rate limit, signature, replay first (net/security.py)
        sec = getattr(bus, "security", None)
        decode = (lambda key, data: M.decode(data)) if sec is None else \
            sec.aircraft_guard(scn.tdma.cycle_s, self.fleet_now, opts.speed).decode  # (limiter: monotonic clock)
        # the channel owns physics: each sender's true position and clock, never its phy claims
        self.intake = UserIntake(scn, seed, net_clock, decode, self.drops)

    def fleet_now(self) -> float:
        return (time.time() - self.epoch) * self.opts.speed

    def stop(self, *_: Any) -> None:
        self._stop.set()

    def _on_bytes(self, key: str, data: bytes) -> None:
        self._inbox.put((key, data))

    def _next_navs(self) -> list:
        """The navs received since the last call: the ring's batch after a wait of one drain period
        (the loop's pace), or the inbox's next sample (waits up to ``core.step_s``; none: empty)."""
        if self._ring is not None:
            self._stop.wait(self._drain_s)
            return self.bus.drain(self._ring)
        try:
            return [self._inbox.get(timeout=self.core.step_s)]
        except queue.Empty:
            return []

    def _ingest(self, key: str, data: bytes) -> None:
        got = self.intake.take(key, data, self.fleet_now())
        if got is None:
            return
        msg, phy = got
        try:
            outs = self.core.on_nav(msg, phy)
        except Exception as e:  # a navigator failure must not kill the node
            log.exception("aircraft %s: %s failed on nav from %s", self.opts.name, ",".join(self.core.algos),
                          msg.get("src"))
            self.drops.drop("estimator", type(e).__name__)
            return
        self._publish(outs + self._journal_msgs())

    def _journal_msgs(self, close: bool = False) -> list:
        """The navigator's journal events that are due (all of them at ``close``)."""
        j = self.core.journal
        if j is None:
            return []
        return j.close() if close else j.take()

    def _publish(self, events: list) -> None:
        """The core's events (aircraft/events.py) as the wire's messages."""
        M = self.M
        for ev in events:
            m = ev.to_msg()
            try:
                # the journal waits for room (a hole would stop its offline re-flight there); the rest drops
                self.bus.publish(M.key_for(m), M.encode(m), block=m["kind"] in ("ac_init", "ac_input"))
            except M.MessageError as e:
                log.error("aircraft %s: refusing to send invalid %s: %s", self.opts.name, m["kind"], e)

    def _status(self, t: float) -> None:
        if self.opts.quiet or self.opts.status_every_s <= 0 or t - self._last_status < self.opts.status_every_s:
            return
        self._last_status = t
        line = self.core.status_line(t)
        if line is not None:
            print(f"[aircraft {self.opts.name}] t={t:7.1f}s {line} drops={self.drops.total}", file=sys.stderr,
                  flush=True)

    def run(self) -> dict:
        if hasattr(self.bus, "subscribe_ring"):
            self._ring = self.bus.subscribe_ring("larns/station/*/nav/**", INBOX_MAX)
        else:  # a bus without ring buffers (tests' fakes): one callback per nav
            self.bus.subscribe("larns/station/*/nav/**", self._on_bytes)
        self.bus.declare_token(self.M.alive_key("aircraft", self.opts.name))
        end = math.inf if self.opts.duration_s is None else self.opts.duration_s
        if not self.opts.quiet:
            print(f"[aircraft {self.opts.name}] algos {','.join(self.core.algos)}, trajectory "
                  f"{self.ac.world.trajectory.get('kind')}, speed={self.opts.speed}, epoch={self.epoch:.3f}",
                  file=sys.stderr, flush=True)
        lag = self.core.lag_s * self.opts.speed  # ticked behind fleet time so delayed broadcasts still fit
        while not self._stop.is_set():
            t = self.fleet_now()
            if t >= end:
                break
            self._status(t)
            try:
                self._publish(self.core.tick(t - lag))
                items = self._next_navs()
            except Exception as e:  # the loop survives any core failure (counted, logged at a limited rate)
                self.drops.drop("core", type(e).__name__)
                continue
            for item in items:
                try:
                    self._ingest(*item)
                except Exception as e:
                    self.drops.drop("core", type(e).__name__)
        self._publish(self._journal_msgs(close=True))  # the last journal entries
        return self.report()

    def report(self) -> dict:
        s = self.core.summary()
        return {"name": self.opts.name, "measurements": s["measurements"], "drops": self.drops.as_dict(),
                "estimates": s["estimates"]}


# --------------------------------------------------------------------------- command line

def add_args(p: argparse.ArgumentParser) -> None:
    from net import cli

    from .navigator.radio.models import ALGOS

    p.add_argument("--algo", action="append", choices=ALGOS + ("ins-ekf", "triad"), default=None,
                   help="estimator to run (repeatable; default: the scenario's [aircraft] algos)")
    p.add_argument("--name", default=None, help="aircraft name (default: scenario's, ac1)")
    p.add_argument("--height", type=float, default=None, help="fixed flight height, m (overrides the scenario)")
    cli.add_process_args(p, scenario="seed003", what="aircraft", net_faults=False)
    p.add_argument("--imu", default=None, metavar="PRESET",
                   help="fly with an IMU (adis16480, tactical, navigation) and run ins-ekf (docs/ins.md)")
    p.add_argument("--satellites", type=int, default=None, metavar="N",
                   help="run the triad: INS (--imu, else [aircraft] imu, else navigation; 10 Hz) + N GPS-like satellites + the stations "
                        "+ baro in one filter, algorithm triad (docs/triad.md)")
    cli.add_output_args(p)


def main_args(args: argparse.Namespace) -> int:
    from net import cli
    from net.bus import Bus, bus_kwargs
    from net.scenario import load_cli

    from .config import from_scenario

    cli.setup_logging()
    scn = load_cli(args.scenario, args.n_stations)
    ac = from_scenario(scn)
    nav = ac.nav  # the navigator's defaults: algorithms, IMU, satellites
    algos = args.algo or (("triad",) if (args.satellites if args.satellites is not None else nav.satellites)
                          is not None else ("ins-ekf",) if args.imu else nav.algos)
    opts = AircraftOptions(name=args.name or ac.name, algos=tuple(algos), speed=args.speed,
                           epoch_unix_s=args.epoch, duration_s=args.duration, seed=args.seed,
                           height_m=args.height, status_every_s=args.status_every, quiet=args.quiet,
                           imu=args.imu or nav.imu,
                           satellites=args.satellites if args.satellites is not None else nav.satellites)
    args.secure_cn = f"aircraft-{opts.name}"
    bus = cli.open_bus(f"aircraft {opts.name}", lambda: Bus(**bus_kwargs(args)))
    # larns fleet's start barrier (--epoch-from): the epoch once every process is up
    opts = replace(opts, epoch_unix_s=cli.await_epoch(args, f"aircraft {opts.name}"))
    rep = cli.serve(args, bus, lambda: AircraftNode(scn, opts, bus))
    if rep is None:  # bad options (algorithm mix, IMU preset, trajectory kind): the error was printed
        return 2
    for a in ("ins-ekf", "triad"):
        if args.quiet or a not in rep["estimates"]:
            continue
        v = rep["estimates"][a]
        print(f"[aircraft {opts.name}] {a}: IMU steps {v['imu_steps']} of {v['imu_steps_expected']} "
              f"expected at t = {v['t_s']:.2f} s", file=sys.stderr, flush=True)
    if not args.quiet:
        print(f"[aircraft {opts.name}] stopped: measurements={rep['measurements']} "
              + " ".join(f"{a}: {v['err_m']:.1f} m" for a, v in rep["estimates"].items()),
              file=sys.stderr, flush=True)
    return 0


def build_parser() -> argparse.ArgumentParser:
    from net import cli

    return cli.build_parser("python -m aircraft", __doc__, add_args)


def main(argv: list[str] | None = None) -> int:
    from net import cli

    return cli.main(argv, "python -m aircraft", __doc__, add_args, main_args)
