"""Vehicle process (``larns vehicle``, ``python -m vehicle``): seed 004's ground vehicle on a mapped
route through the LARNS field, navigating by the stations' nav broadcasts, its IMU and its odometer.

* **world** (inside the process, :mod:`vehicle.core`): the vehicle drives the route (``--route FILE``:
  straight legs in the network frame, docs/routes/field-straight.toml; default: a level W -> E leg
  through the middle of the field at 5 m/s) from its start (the first whole fleet second after it
  comes up); IMU and odometer at ``--imu-rate``; receiver clock on network time.
* **receive**: ``larns/station/*/nav/**`` -> strict decode (malformed: counted and dropped) -> key/src
  check -> the channel's truth of the named sender (its true position and transmit time, never the
  sender's ``phy`` claims: ``net.channel.UserIntake``) -> a reorder buffer (half the integration lag: broadcasts reach the process by different
  links) -> pseudorange and carrier pseudorange rate formed like the aircraft's (docs/vehicle.md).
  The navigator integrates ``lag_s`` (1 s) x ``--speed`` behind fleet time; a broadcast older than its
  filter time is late (counted, not used).
* **navigator**: the 13-state map-constrained continuous-discrete EKF (seed 004, receiver clock
  states), fed only the IMU, the odometer and the broadcasts (station position and covariance as
  broadcast, never ``phy``).
* **publish**: ``larns/vehicle/<name>/estimate`` (``veh_estimate``, after every measurement and every
  whole second), ``larns/vehicle/<name>/truth`` (``veh_truth``, the truth at each estimate's time),
  the navigator's journal ``larns/vehicle/<name>/init`` + ``.../input`` (``veh_init``,
  ``veh_input``: everything it consumed; ``larns reestimate`` re-runs it bit for bit); liveliness
  ``larns/alive/vehicle/<name>``.

SIGINT / SIGTERM: clean exit (the last journal entries are published first).
"""

from __future__ import annotations

import argparse
import heapq
import logging
import math
import queue
import sys
import threading
import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from net.queues import DropOldestQueue

log = logging.getLogger("larns.vehicle")
INBOX_MAX = 4096  # samples waiting for the loop
HELD_MAX = 4096   # broadcasts in the reorder buffer


@dataclass
class VehicleOptions:
    name: str = "veh1"
    route: str | None = None
    speed: float = 1.0
    epoch_unix_s: float | None = None
    duration_s: float | None = None
    seed: int | None = None
    imu_rate_hz: float = 20.0
    speed_m_s: float | None = None
    outage_s: tuple[float, float] | None = None
    status_every_s: float = 5.0
    quiet: bool = False


class VehicleNode:
    """Wall-clock shell around :class:`vehicle.core.VehicleCore` over a :class:`net.bus.Bus`."""

    def __init__(self, scn, opts: VehicleOptions, bus: Any):
        from net import messages as M
        from net.channel import UserIntake
        from net.nettime import network_time

        from .core import VehicleCore

        if opts.speed <= 0:
            raise ValueError("--speed must be > 0")
        self.M = M
        self.opts = opts
        self.bus = bus
        self.epoch = (math.floor(time.time() / 86400.0) * 86400.0 if opts.epoch_unix_s is None
                      else float(opts.epoch_unix_s))
        seed = scn.seed if opts.seed is None else opts.seed
        net_clock = network_time(scn, seed)  # the receiver runs on network time as the field realizes it
        self.core = VehicleCore(scn, opts.name, seed=int(seed), t0_s=max(0.0, math.ceil(self.fleet_now())),
                                net_clock=net_clock, route_file=opts.route, imu_rate_hz=opts.imu_rate_hz,
                                speed_m_s=opts.speed_m_s, outage_s=opts.outage_s)
        self.drops = M.DropCounter(f"vehicle {opts.name}")
        # bounded, drop-oldest (net/queues.py): a flood of samples costs old ones, never memory
        self._inbox = DropOldestQueue(INBOX_MAX)
        self._stop = threading.Event()
        self._last_status = -math.inf
        self._last_est: dict | None = None
        self._last_truth: dict | None = None
        self._held: list[tuple] = []  # (t_true_s, n, msg, phy): the reorder buffer
        self._n_in = 0
        sec = getattr(bus, "security", None)
        decode = (lambda key, data: M.decode(data)) if sec is None else \
            sec.aircraft_guard(scn.tdma.cycle_s, self.fleet_now, opts.speed).decode  # (limiter: monotonic clock)
        # the channel owns physics (issue 32): each sender's true position and clock, never its phy claims
        self.intake = UserIntake(scn, int(seed), net_clock, decode, self.drops)

    def fleet_now(self) -> float:
        return (time.time() - self.epoch) * self.opts.speed

    def stop(self, *_: Any) -> None:
        self._stop.set()

    def _on_bytes(self, key: str, data: bytes) -> None:
        self._inbox.put((key, data))

    def _publish(self, outs: list[dict]) -> None:
        M = self.M
        for m in outs:
            if m["kind"] == "veh_estimate":
                self._last_est = m
            elif m["kind"] == "veh_truth":
                self._last_truth = m
            try:
                # the journal waits for room (a hole would stop its offline re-run there); the rest drops
                self.bus.publish(M.key_for(m), M.encode(m), block=m["kind"] in ("veh_init", "veh_input"))
            except M.MessageError as e:
                log.error("vehicle %s: refusing to send invalid %s: %s", self.opts.name, m["kind"], e)

    def _ingest(self, key: str, data: bytes) -> None:
        got = self.intake.take(key, data, self.fleet_now())
        if got is None:
            return
        msg, phy = got
        if phy["t_true_s"] > self.fleet_now() + 10.0 * self.opts.speed:  # never drained: refuse it now
            self.drops.drop("future", f"nav from {msg['src']} at t = {phy['t_true_s']:.1f} s")
            return
        self._n_in += 1
        heapq.heappush(self._held, (phy["t_true_s"], self._n_in, msg, phy))
        if len(self._held) > HELD_MAX:  # bounded: the oldest broadcast goes
            heapq.heappop(self._held)
            self.drops.drop("held_full", f"reorder buffer over {HELD_MAX}")

    def _drain(self, t_s: float) -> None:
        """Feed the held broadcasts transmitted before ``t_s`` to the core in transmit order (the
        stations' samples reach this process by different links: a reorder buffer of ``hold``)."""
        while self._held and self._held[0][0] <= t_s:
            _, _, msg, phy = heapq.heappop(self._held)
            try:
                outs = self.core.on_nav(msg, phy)
            except Exception as e:  # a navigator failure must not kill the node (logged at a limited rate)
                log.debug("vehicle %s: navigator failed on nav from %s", self.opts.name, msg.get("src"), exc_info=True)
                self.drops.drop("estimator", f"nav from {msg.get('src')}: {type(e).__name__}: {e}")
                continue
            self._publish(outs)

    def error_m(self) -> float | None:
        e, t = self._last_est, self._last_truth
        if e is None or t is None or t["t_s"] != e["t_s"]:
            return None
        return float(np.linalg.norm(np.subtract(e["pos_m"], t["pos_m"])))

    def _status(self, t: float) -> None:
        if self.opts.quiet or self.opts.status_every_s <= 0 or t - self._last_status < self.opts.status_every_s:
            return
        self._last_status = t
        err = self.error_m()
        st = self.core.stats
        print(f"[vehicle {self.opts.name}] t={t:7.1f}s tau={self.core.nav.t:7.2f}s meas={st['measurements']} "
              f"late={st['nav_late']} outage={st['nav_outage']} gated={self.core.nav.stats['gated']} "
              f"err={'-' if err is None else f'{err:.2f}m'} drops={self.drops.total}", file=sys.stderr, flush=True)

    def run(self) -> dict:
        self.bus.subscribe("larns/station/*/nav/**", self._on_bytes)
        self.bus.declare_token(self.M.alive_key("vehicle", self.opts.name))
        end = math.inf if self.opts.duration_s is None else self.opts.duration_s
        if not self.opts.quiet:
            r = self.core.record
            print(f"[vehicle {self.opts.name}] route {self.opts.route or 'default field leg'} "
                  f"({len(r['route_enu_m']) - 1} leg(s), {r['speeds_m_s']} m/s), IMU {self.opts.imu_rate_hz:g} Hz, "
                  f"start t0={self.core.t0_s:.0f}s, speed={self.opts.speed}, epoch={self.epoch:.3f}",
                  file=sys.stderr, flush=True)
        lag = self.core.lag_s * self.opts.speed
        while not self._stop.is_set():
            t = self.fleet_now()
            if t >= end:
                break
            self._status(t)
            self._drain(t - 0.5 * lag)
            try:
                self._publish(self.core.advance_to(t - lag))
            except Exception as e:  # the loop survives any core failure (counted, logged at a limited rate)
                self.drops.drop("core", f"advance_to: {type(e).__name__}: {e}")
            try:
                item = self._inbox.get(timeout=0.05)
            except queue.Empty:
                continue
            try:
                self._ingest(*item)
            except Exception as e:  # noqa: BLE001 - a malformed-but-valid sample must not stop the node
                self.drops.drop("ingest", f"{type(e).__name__}: {e}")
        self._drain(math.inf)
        self._publish(self.core.close())
        return self.report()

    def report(self) -> dict:
        st = self.core.stats
        return {"name": self.opts.name, "measurements": int(st["measurements"]), "stats": {**st, **self.core.nav.stats},
                "drops": self.drops.as_dict(), "queue_dropped": self._inbox.dropped, "t_s": self.core.t0_s + self.core.nav.t,
                "n_updates": self.core.nav.n_updates, "err_m": self.error_m()}


# --------------------------------------------------------------------------- command line

def _outage(text: str) -> tuple[float, float]:
    a, sep, b = text.partition(",")
    try:
        lo, hi = float(a), float(b)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--outage wants START,END seconds, got {text!r}") from None
    if not sep or not 0 <= lo < hi:
        raise argparse.ArgumentTypeError(f"--outage wants 0 <= START < END, got {text!r}")
    return lo, hi


def add_args(p: argparse.ArgumentParser) -> None:
    from net import cli

    p.add_argument("--name", default="veh1", help="vehicle name (default veh1)")
    p.add_argument("--route", default=None, metavar="FILE",
                   help="route file: straight legs in the network frame (TOML [route], kind = \"straight\"; "
                        "docs/routes/field-straight.toml). Default: a level W -> E leg through the field")
    p.add_argument("--vehicle-speed", type=float, default=None, metavar="M_S",
                   help="cruise speed on every leg, m/s (default: the route's speeds_m_s, 5 m/s for the default leg)")
    p.add_argument("--imu-rate", type=float, default=20.0, metavar="HZ",
                   help="IMU / odometer rate and filter step (whole Hz dividing one second; default 20)")
    p.add_argument("--outage", type=_outage, default=None, metavar="START,END",
                   help="station outage: broadcasts received between these vehicle seconds are lost")
    cli.add_process_args(p, scenario="seed000", what="vehicle", net_faults=False)
    cli.add_output_args(p)


def main_args(args: argparse.Namespace) -> int:
    from net import cli
    from net.bus import Bus, bus_kwargs
    from net.scenario import load_cli

    from net.security import vehicle_cn

    cli.setup_logging()
    scn = load_cli(args.scenario, args.n_stations)
    opts = VehicleOptions(name=args.name, route=args.route, speed=args.speed, epoch_unix_s=args.epoch,
                          duration_s=args.duration, seed=args.seed, imu_rate_hz=args.imu_rate,
                          speed_m_s=args.vehicle_speed, outage_s=args.outage, status_every_s=args.status_every,
                          quiet=args.quiet)
    args.secure_cn = vehicle_cn(opts.name)  # --secure: the keystore's vehicle-<name> enclave
    bus = cli.open_bus(f"vehicle {opts.name}", lambda: Bus(**bus_kwargs(args)))
    # larns fleet's start barrier (--epoch-from): the epoch once every process is up
    opts = replace(opts, epoch_unix_s=cli.await_epoch(args, f"vehicle {opts.name}"))
    rep = cli.serve(args, bus, lambda: VehicleNode(scn, opts, bus))
    if rep is None:
        return 2
    if not args.quiet:
        err = rep["err_m"]
        print(f"[vehicle {opts.name}] stopped: measurements={rep['measurements']} updates={rep['n_updates']} "
              f"error {'-' if err is None else f'{err:.2f} m'}", file=sys.stderr, flush=True)
    return 0


def build_parser() -> argparse.ArgumentParser:
    from net import cli

    return cli.build_parser("python -m vehicle", __doc__, add_args)


def main(argv: list[str] | None = None) -> int:
    from net import cli

    return cli.main(argv, "python -m vehicle", __doc__, add_args, main_args)
