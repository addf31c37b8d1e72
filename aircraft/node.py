"""Aircraft process: flies its true trajectory, listens to the stations' nav broadcasts over Zenoh,
measures pseudoranges in its own channel layer and runs the estimators (one per ``--algo``).

* **time**: fleet time ``t = (wall - epoch) * speed`` like the stations (same ``--epoch``).
* **receive**: ``larns/station/*/nav`` -> strict decode (malformed: counted and dropped) -> key/src
  check -> channel layer: reception at ``t_rx = t_true_tx + |r(t_rx) - p_tx| / c`` (the named sender's
  true position and transmit time from the scenario's truth, never the sender's ``phy`` claims:
  ``net.channel.UserIntake``) read on the aircraft's receiver clock, which runs on network
  time (station 1's oscillator) plus ``c dtau(t) = df lambda t + c tau0`` (seed 001) and timing noise
  ``sigma_m``; pseudorange ``rho = c (t_rx_local - (t_tx - theta_hat(t_tx)))`` from the *station-stamped*
  transmit time ``t_tx`` corrected by the broadcast clock correction ``theta_hat`` (``msg.clock``). Each
  station's residual sync error reaches the aircraft as in reality; the filters carry it as one
  Gauss-Markov bias state per station whose stationary variance is the broadcast clock variance
  ``c^2 P_theta`` (``tuning.clock_bias``; snapshot LSQ and the filter start add it to the range
  variance; docs/sync.md). The estimator sees the broadcast's *estimated* station position
  and covariance (``msg.pos_m``, ``msg.cov_m2``), never ``phy``.
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
from collections import Counter
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from nav.geometry import SPEED_OF_LIGHT_M_S

from net.channel import UserIntake
from net.clock import broadcast_clock_var_m2
from net.nettime import network_time, pseudorange_time_error_s

from net.queues import DropOldestQueue
from net.radio import link_var_m2, reception_sigma_m

from .journal import AcJournal
from .navigator import receiver as rx


log = logging.getLogger("larns.aircraft")

USABLE_STATES = ("frame", "surveying")
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


class AircraftCore:
    """Sans-I/O aircraft: channel layer + estimators. ``on_nav(msg, phy)`` returns messages to publish.

    Pure apart from its own seeded generator; the node and tests drive it with decoded messages.
    """

    def __init__(self, ac, algos, name: str, rng: np.random.Generator,
                 height_m: float | None = None, horizon_s: float = 7200.0, net_clock=None):
        from .world import trajectory

        self.ac = ac
        self.rng = rng
        dt = 1.0 / max(ac.rate_hz, 10.0)
        t = np.arange(0.0, horizon_s + dt, dt)
        h = height_m if height_m is not None else ac.height_m
        self.track = trajectory.from_config(dict(ac.trajectories.get(ac.trajectory.get("kind"), {}), **ac.trajectory),
                                            t, ac.centre_m, h)
        self.net_clock = net_clock  # station 1's oscillator: network time (None: perfect clocks)
        self._navigator(radio_record(ac, algos), name, tuple(algos))
        # the navigator's journal (aircraft/journal.py); none when another core navigates (--imu, triad)
        self.journal = AcJournal(name, radio_record(ac, algos)) if algos else None

    def _navigator(self, record: dict, name: str, algos: tuple[str, ...]) -> None:
        """The navigator side: the estimators of ``algos`` configured by the init record."""
        from .navigator.radio.estimator import AircraftEstimator

        self.name = name
        self.estimators = {a: AircraftEstimator(a, estimator_config(record)) for a in algos}
        self.seq: Counter[str] = Counter()
        self.stats: Counter[str] = Counter()
        self._pacer = rx.StatusPacer()

    @classmethod
    def from_record(cls, record: dict, name: str, algos: tuple[str, ...]) -> "AircraftCore":
        """The navigator alone (no world, no journal) for a replay of ``ac_input`` entries
        (:func:`aircraft.journal.replay`; :meth:`measurement`)."""
        core = cls.__new__(cls)
        core.journal = None
        core._navigator(record, name, algos)
        return core

    def measure(self, phy: dict, msg: dict | None = None) -> tuple[float, float, np.ndarray, float] | None:
        """Channel layer: (t_rx true, pseudorange, true aircraft position at reception, one-way
        timing sigma in m), or ``None`` where the scenario's ``[radio]`` has no link.

        ``rho = c (t_rx_ac - T_tx)``: ``t_rx_ac`` the receiver clock (network time at the true reception
        plus the seed-001 receiver clock), ``T_tx`` the station's stamped transmit time ``msg.t_tx_s``
        minus its broadcast offset ``msg.clock`` (without ``msg``: the true transmit time); timing
        noise of sigma ``sigma_m`` in quadrature with the link's TOA CRLB (:func:`net.radio.reception_sigma_m`)."""
        p_tx = np.asarray(phy["pos_m"], float)
        t_tx = float(phy["t_true_s"])
        p, _ = self.track.at(t_tx)
        t_rx = t_tx + np.linalg.norm(p - p_tx) / SPEED_OF_LIGHT_M_S
        p, _ = self.track.at(t_rx)  # one fixed-point step is exact to micrometres at aircraft speeds
        sigma = reception_sigma_m(p_tx, p, self.ac.radio, self.ac.sigma_m)
        if sigma is None:
            return None
        r = float(np.linalg.norm(p - p_tx))
        dt_s = pseudorange_time_error_s(msg, t_tx, t_rx, self.net_clock)
        rho = r + SPEED_OF_LIGHT_M_S * dt_s + float(self.ac.clock.bias_m(t_rx)) \
            + sigma * float(self.rng.standard_normal())
        return t_rx, rho, p, sigma

    @staticmethod
    def clock_var_m2(msg: dict) -> float:
        """Broadcast clock variance at the transmit time as a range variance, m^2."""
        return broadcast_clock_var_m2(msg)

    def on_nav(self, msg: dict, phy: dict) -> list[dict]:
        """One station nav broadcast -> ``ac_truth`` + one ``ac_estimate`` per algorithm that has one."""
        if msg.get("state") not in USABLE_STATES:
            self.stats["nav_unusable_state"] += 1
            return []
        from .navigator import plausible  # issue 32: an implausible nav never reaches the channel or a filter

        if plausible.refuse(msg, float(phy["t_true_s"]), self.ac, self.stats):
            return []
        got = self.measure(phy, msg)
        if got is None:
            self.stats["no_link"] += 1  # [radio]: beyond the horizon or the link budget
            return []
        t_rx, rho, p_true, sigma = got
        # the link's timing variance above the nominal sigma_m, known to the receiver from its SNR,
        # as an isotropic part of the transmitter's covariance: the radio filters weight a range by
        # sigma_m^2 + u^T C u, and u^T (C + s^2 I) u = u^T C u + s^2 (their clock variance feeds the
        # stations' clock-bias states, which are not white)
        st_cov = np.asarray(msg["cov_m2"], float) + link_var_m2(sigma, self.ac.sigma_m) * np.eye(3)
        cvar = self.clock_var_m2(msg)
        if not (np.all(np.isfinite(msg["pos_m"])) and math.isfinite(t_rx)):
            self.stats["nav_bad"] += 1
            return []
        self.stats["measurements"] += 1
        out = [self._msg("ac_truth", t_s=t_rx, pos_m=p_true.tolist(), vel_m_s=self.track.at(t_rx)[1].tolist())]
        if self.journal is not None:
            self.journal.m(t_rx, int(msg["src"]), msg["pos_m"], st_cov, cvar, rho)
        return out + self.measurement(t_rx, int(msg["src"]), msg["pos_m"], st_cov, cvar, rho)

    def measurement(self, t_rx: float, src: int, pos_m, st_cov, cvar: float, rho: float) -> list[dict]:
        """Navigator side: one measured broadcast (a journal ``m`` entry) -> ``ac_estimate`` /
        ``ac_status`` messages."""
        out: list[dict] = []
        st_cov = np.asarray(st_cov, float)
        for algo, est in self.estimators.items():
            n = est.n_updates
            est.on_measurement(t_rx, src, pos_m, st_cov, rho, clock_var_m2=cvar)
            e = est.estimate() if est.n_updates != n and est.tracker_or_fix() else None
            state = est.status
            if e is not None and not rx.publishable(e["pos_m"], e["cov_m2"], est.cfg.receiver or rx.ReceiverConfig()):
                e, state = None, rx.NO_FIX
            out.extend(self._status_msgs(algo, t_rx, state, est))
            if e is None:
                continue
            m = self._msg("ac_estimate", t_s=float(e["t_s"]), pos_m=e["pos_m"], cov_m2=np.asarray(e["cov_m2"]).tolist(),
                          algo=algo, n_updates=int(e["n_updates"]))
            if e["vel_m_s"] is not None:
                m["vel_m_s"] = e["vel_m_s"]
            m.update(integrity_fields(e))
            out.append(m)
        return out

    def _status_msgs(self, algo: str, t_s: float, state: str, est) -> list[dict]:
        """An ``ac_status`` when an algorithm's state changes, and once per second of fleet time: what
        the navigator is doing when it publishes no estimate (docs/aircraft.md "Cold start")."""
        if not self._pacer.due(algo, state, t_s):
            return []
        return [rx.status_msg(self.name, self.seq, algo, t_s, state, {**self.stats, **est.stats})]

    def _msg(self, kind: str, **fields: Any) -> dict:
        self.seq[kind] += 1
        return {"kind": kind, "src": self.name, "seq": self.seq[kind], "stamp_s": float(fields["t_s"]), **fields}


def radio_record(ac, algos) -> dict:
    """The radio navigator's init record (``ac_init``): the algorithms, the scenario's filter tuning
    and the start's wide prior. Every aircraft journal carries the tuning, so the radio filters can
    re-run on any aircraft's measurements."""
    from dataclasses import asdict

    return {"kind": "radio", "algos": list(algos), "tuning": asdict(ac.tuning),
            "init_sigma_m": None if not ac.init_sigma_m else float(ac.init_sigma_m)}


def estimator_config(record: dict):
    """The :class:`aircraft.navigator.radio.estimator.EstimatorConfig` of an init record. The filters start from the
    broadcasts alone (aircraft/navigator/radio/initializer.py), never from the truth or the scenario's station
    positions; ``init_sigma_m`` only widens the wide prior."""
    from .navigator.radio.estimator import EstimatorConfig, Tuning
    from .navigator.radio.initializer import InitConfig

    s = record.get("init_sigma_m")
    init = InitConfig() if not s else InitConfig(wide_sigma_m=max(InitConfig.wide_sigma_m, float(s)))
    return EstimatorConfig(tuning=Tuning(**record["tuning"]), init=init)


def integrity_fields(e: dict) -> dict:
    """The optional ``ac_estimate`` integrity fields of an estimate: ``hpl_m``, ``vpl_m`` (finite only),
    ``excluded`` (station ids)."""
    out = {k: float(e[k]) for k in ("hpl_m", "vpl_m") if e.get(k) is not None and math.isfinite(e[k])}
    if e.get("excluded") is not None:
        out["excluded"] = [int(i) for i in e["excluded"]]
    return out


class AircraftNode:
    """Wall-clock shell around :class:`AircraftCore` over a :class:`net.bus.Bus`."""

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
        seed = scn.seed if opts.seed is None else opts.seed
        rng = np.random.default_rng([int(seed), 0xA1C, sum(map(ord, opts.name))])
        horizon = (opts.duration_s or 7200.0) + 10.0
        net_clock = network_time(scn, seed)  # the receivers run on network time as the field realizes it
        triad = opts.satellites is not None or "triad" in opts.algos  # the triad: aircraft/triad_core.py
        if triad and set(opts.algos) - {"triad"}:
            raise ValueError(f"triad runs alone in its 6-DOF world; drop {sorted(set(opts.algos) - {'triad'})}")
        ins_algos, opts.algos = ((), ()) if triad else _split_ins(opts)
        self.all_algos = ("triad",) if triad else tuple(opts.algos) + tuple(ins_algos)  # for the start line
        self.core = AircraftCore(self.ac, opts.algos, opts.name, rng, opts.height_m, horizon_s=horizon,
                                 net_clock=net_clock)
        self.ins = None
        if ins_algos:  # the inertial aircraft: own world (6-DOF, IMU) and ins-ekf (aircraft/ins_core.py)
            from .ins_core import InsAircraftCore

            self.ins = InsAircraftCore(scn, self.ac, opts.name, np.random.default_rng([int(seed), 0x1A5,
                                       sum(map(ord, opts.name))]), imu=opts.imu, height_m=opts.height_m,
                                       seed=int(seed), t0_s=max(0.0, math.floor(self.fleet_now())),
                                       net_clock=net_clock)
            self.ins.seq = self.core.seq  # one sequence per (aircraft, kind)
        if triad:
            from .triad_core import TriadAircraftCore

            self.ins = TriadAircraftCore(scn, self.ac, opts.name, n_sv=4 if opts.satellites is None else opts.satellites,
                                         imu=opts.imu, height_m=opts.height_m, seed=int(seed),
                                         t0_s=max(0.0, math.floor(self.fleet_now())), net_clock=net_clock)
            self.ins.seq = self.core.seq
        self.drops = M.DropCounter(f"aircraft {opts.name}")
        # bounded, drop-oldest (net/queues.py): a flood of samples costs old ones, never memory
        self._inbox = DropOldestQueue(INBOX_MAX)
        self._stop = threading.Event()
        self._last_status = -math.inf
        # (key, bytes) -> (msg, phy); --secure: rate limit, signature, replay first (net/security.py)
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

    def _ingest(self, key: str, data: bytes) -> None:
        got = self.intake.take(key, data, self.fleet_now())
        if got is None:
            return
        msg, phy = got
        try:
            outs = self.core.on_nav(msg, phy) if self.ins is None else []
        except Exception as e:  # an estimator failure must not kill the node
            log.exception("aircraft %s: estimator failed on nav from %s", self.opts.name, msg.get("src"))
            self.drops.drop("estimator", type(e).__name__)
            return
        if self.ins is not None:
            try:
                outs = outs + self.ins.on_nav(msg, phy)
            except Exception as e:
                log.exception("aircraft %s: ins-ekf failed on nav from %s", self.opts.name, msg.get("src"))
                self.drops.drop("estimator", type(e).__name__)
        self._publish(outs + self._journal_msgs())

    def _journal_msgs(self, close: bool = False) -> list[dict]:
        """The navigator's journal messages that are due (all of them at ``close``)."""
        j = self.core.journal if self.ins is None else self.ins.journal
        if j is None:
            return []
        return j.close() if close else j.take()

    def _publish(self, outs: list[dict]) -> None:
        M = self.M
        for m in outs:
            try:
                # the journal waits for room (a hole would stop its offline re-flight there); the rest drops
                self.bus.publish(M.key_for(m), M.encode(m), block=m["kind"] in ("ac_init", "ac_input"))
            except M.MessageError as e:
                log.error("aircraft %s: refusing to send invalid %s: %s", self.opts.name, m["kind"], e)

    def _status(self, t: float) -> None:
        if self.opts.quiet or self.opts.status_every_s <= 0 or t - self._last_status < self.opts.status_every_s:
            return
        self._last_status = t
        if self.ins is not None:
            e = self.ins.ekf
            if e is None:  # still in its start window (aircraft/navigator/ins_start.py; the triad's window fix)
                buffered = getattr(self.ins, "stats", {}).get("start_buffered")
                if buffered is not None:
                    print(f"[aircraft {self.opts.name}] t={t:7.1f}s imu={self.ins.preset.name} steps={self.ins.imu_steps} "
                          f"starting: {buffered} broadcasts", file=sys.stderr, flush=True)
                return
            pt = self.ins.truth_n(e.t_s)[0]
            print(f"[aircraft {self.opts.name}] t={t:7.1f}s imu={self.ins.preset.name} steps={self.ins.imu_steps} "
                  f"t_ins={e.t_s:.2f}s pos=({pt[0]:.0f},{pt[1]:.0f},{pt[2]:.0f}) meas={self.ins.stats['measurements']} "
                  f"err {getattr(self.ins, 'algo', 'ins-ekf')}={np.linalg.norm(e.p[0] - pt):.1f}m late={self.ins.stats['nav_bad_or_late']} "
                  f"drops={self.drops.total}", file=sys.stderr, flush=True)
            return
        p, _ = self.core.track.at(max(t, 0.0))
        parts = []
        for a, est in self.core.estimators.items():
            e = est.estimate()
            if e is None:
                parts.append(f"{a}=init")
            else:
                pt, _ = self.core.track.at(e["t_s"])
                parts.append(f"{a}={np.linalg.norm(np.asarray(e['pos_m']) - pt):.1f}m")
        print(f"[aircraft {self.opts.name}] t={t:7.1f}s pos=({p[0]:.0f},{p[1]:.0f},{p[2]:.0f}) "
              f"meas={self.core.stats['measurements']} err {' '.join(parts)} drops={self.drops.total}",
              file=sys.stderr, flush=True)

    def run(self) -> dict:
        self.bus.subscribe("larns/station/*/nav", self._on_bytes)
        self.bus.declare_token(self.M.alive_key("aircraft", self.opts.name))
        end = math.inf if self.opts.duration_s is None else self.opts.duration_s
        if not self.opts.quiet:
            print(f"[aircraft {self.opts.name}] algos {','.join(self.all_algos)}, trajectory "
                  f"{self.ac.trajectory.get('kind')}, speed={self.opts.speed}, epoch={self.epoch:.3f}",
                  file=sys.stderr, flush=True)
        while not self._stop.is_set():
            t = self.fleet_now()
            if t >= end:
                break
            self._status(t)
            try:
                if self.ins is not None:  # integrate behind fleet time so delayed broadcasts still fit
                    self.ins.advance_to(t - self.ins.lag_s * self.opts.speed)
                    self._publish(self._journal_msgs())
                item = self._inbox.get(timeout=0.1 if self.ins is None else self.ins.tn.dt_s)
            except queue.Empty:
                continue
            except Exception as e:  # the loop survives any core failure (counted, logged at a limited rate)
                self.drops.drop("core", type(e).__name__)
                continue
            try:
                self._ingest(*item)
            except Exception as e:
                self.drops.drop("core", type(e).__name__)
        self._publish(self._journal_msgs(close=True))  # the last journal entries
        return self.report()

    def report(self) -> dict:
        out = {"name": self.opts.name, "measurements": int(self.core.stats["measurements"]),
               "drops": self.drops.as_dict(), "estimates": {}}
        for a, est in self.core.estimators.items():
            e = est.estimate()
            if e is not None:
                pt, _ = self.core.track.at(e["t_s"])
                out["estimates"][a] = {"t_s": e["t_s"], "err_m": float(np.linalg.norm(np.asarray(e["pos_m"]) - pt)),
                                       "n_updates": e["n_updates"], **({"excluded": e["excluded"]}
                                                                       if e.get("excluded") else {})}
        if self.ins is not None and self.ins.ekf is not None:
            e = self.ins.ekf
            pt = self.ins.truth_n(e.t_s)[0]
            out["measurements"] = int(self.ins.stats["measurements"])
            out["estimates"][getattr(self.ins, "algo", "ins-ekf")] = {"t_s": e.t_s, "err_m": float(np.linalg.norm(e.p[0] - pt)),
                                           "n_updates": e.n_updates, "imu_steps": self.ins.imu_steps,
                                           "imu_steps_expected": int(np.floor((e.t_s - self.ins.t0_s)
                                                                               * self.ins.preset.rate_hz + 1e-9))}
        return out


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
    algos = args.algo or (("triad",) if (args.satellites if args.satellites is not None else ac.satellites)
                          is not None else ("ins-ekf",) if args.imu else ac.algos)
    opts = AircraftOptions(name=args.name or ac.name, algos=tuple(algos), speed=args.speed,
                           epoch_unix_s=args.epoch, duration_s=args.duration, seed=args.seed,
                           height_m=args.height, status_every_s=args.status_every, quiet=args.quiet,
                           imu=args.imu or ac.imu,
                           satellites=args.satellites if args.satellites is not None else ac.satellites)
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


def _split_ins(opts: AircraftOptions) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(inertial algorithms, the others). ``--imu`` without ``ins-ekf`` adds it; ``ins-ekf`` without
    ``--imu`` uses the adis16480 preset."""
    ins = tuple(a for a in opts.algos if a == "ins-ekf")
    if opts.imu and not ins:
        ins = ("ins-ekf",)
    if ins and not opts.imu:
        opts.imu = "adis16480"
    rest = tuple(a for a in opts.algos if a != "ins-ekf")
    if ins and rest:  # one world per aircraft: the 6-DOF one of --imu (its own truth and channel)
        raise ValueError(f"ins-ekf runs alone in its 6-DOF world; drop {list(rest)} or run another aircraft")
    return ins, rest


def build_parser() -> argparse.ArgumentParser:
    from net import cli

    return cli.build_parser("python -m aircraft", __doc__, add_args)


def main(argv: list[str] | None = None) -> int:
    from net import cli

    return cli.main(argv, "python -m aircraft", __doc__, add_args, main_args)
