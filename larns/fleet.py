"""`larns fleet`: launch a whole LARNS deployment on this machine, one OS process per station.

    larns fleet --scenario seed000 --duration 60 --speed 1 --record run.mcap

Spawns one ``python -m stations`` process per station of the scenario (each its own Zenoh peer,
listening on its own loopback port, seeded with the endpoints of stations 1 and 2 - gossip links
everyone to everyone; or, with ``--topology router``, one ``larns router`` process and every other
process a Zenoh client of it), the recorder (``larns record``) when ``--record`` is given, and optional
hot-joining stations (``--join ID@T``). All processes share one epoch chosen a few seconds in the
future, so they compute the same TDMA slot boundaries without a clock master.

While the fleet runs, a live table shows every station's slot, number of updates, estimated
position, sigma (root of the covariance trace) and error against the truth topic. At the end (or
on Ctrl-C / SIGTERM) every child is stopped with SIGINT (SIGKILL after a grace period), the
recorder finishes its MCAP file, and a final table is printed.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


@dataclass
class Child:
    name: str
    cmd: list[str]
    log_path: Path | None
    proc: subprocess.Popen | None = None
    start_wall: float = 0.0  # when to spawn (wall clock)
    log_file: Any = None


@dataclass
class StationView:
    id: int
    slot: int | None = None
    state: str = "-"
    n_updates: int = 0
    pos_m: list[float] | None = None
    sigma_m: float = math.nan
    truth_m: list[float] | None = None
    t_s: float = math.nan
    dropped: int = 0
    n_estimates: int = 0
    clock_est: dict = field(default_factory=dict)   # estimate stamp -> estimated clock offset, s
    sync_ns: float = math.nan                       # estimated minus true offset vs network time, ns

    @property
    def err_m(self) -> float:
        if self.pos_m is None or self.truth_m is None:
            return math.nan
        return math.dist(self.pos_m, self.truth_m)


@dataclass
class Monitor:
    """Collects estimate and truth messages from the bus (thread-safe snapshot)."""

    views: dict[int, StationView] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)
    alive: set = field(default_factory=set)
    aircraft: dict[tuple[str, str], dict] = field(default_factory=dict)  # (name, algo) -> last estimate
    ac_truth: dict[str, deque] = field(default_factory=dict)              # name -> recent truths

    def on_sample(self, key: str, data: bytes) -> None:
        from net import messages as M

        try:
            msg, _ = M.decode(data)
        except M.MessageError:
            return
        if msg["kind"] in ("ac_estimate", "ac_truth"):
            with self.lock:
                if msg["kind"] == "ac_truth":
                    self.ac_truth.setdefault(msg["src"], deque(maxlen=256)).append(msg)
                else:
                    self.aircraft[(msg["src"], msg["algo"])] = msg
            return
        if msg["kind"] not in ("estimate", "truth"):
            return
        with self.lock:
            v = self.views.setdefault(msg["src"], StationView(msg["src"]))
            if msg["kind"] == "truth":
                v.truth_m = msg["pos_m"]
                est = v.clock_est.pop(msg["stamp_s"], None)
                if est is not None and "clock_error_s" in msg:
                    v.sync_ns = (est - msg["clock_error_s"]) * 1e9
            else:
                if "clock_offset_s" in msg:  # matched with the truth of the same stamp
                    v.clock_est[msg["stamp_s"]] = msg["clock_offset_s"]
                    while len(v.clock_est) > 8:
                        v.clock_est.pop(next(iter(v.clock_est)))
                v.pos_m = msg["pos_m"]
                v.n_updates = msg["n_updates"]
                v.state = msg["state"]
                v.slot = msg.get("slot", v.slot)
                v.dropped = msg.get("dropped", v.dropped)
                v.t_s = msg["t_s"]
                v.n_estimates += 1
                tr = sum(msg["cov_m2"][i][i] for i in range(3))
                v.sigma_m = math.sqrt(max(tr, 0.0))

    def on_alive(self, key: str, alive: bool) -> None:
        with self.lock:
            (self.alive.add if alive else self.alive.discard)(key)

    def snapshot(self) -> list[StationView]:
        with self.lock:
            return [StationView(**{**vars(v), "clock_est": {}}) for _, v in sorted(self.views.items())]

    def aircraft_lines(self) -> list[str]:
        """One line per (aircraft, algorithm): estimate error against the truth sample nearest in time."""
        out = []
        with self.lock:
            for (name, algo), m in sorted(self.aircraft.items()):
                hist = self.ac_truth.get(name)
                # truth sample nearest in time to the estimate (the aircraft moves fast)
                tr = min(hist, key=lambda h: abs(h["t_s"] - m["t_s"])) if hist else None
                err = math.dist(m["pos_m"], tr["pos_m"]) if tr else math.nan
                sig = math.sqrt(max(sum(m["cov_m2"][i][i] for i in range(3)), 0.0))
                out.append(f"aircraft {name:>6} {algo:>10}: t={m['t_s']:7.1f} s  sigma {sig:7.2f} m  "
                           f"error {err:7.2f} m")
        return out


def format_table(views: list[StationView], t_s: float, n_alive: int | None = None) -> str:
    head = f"fleet time {t_s:7.1f} s" + (f"   processes alive: {n_alive}" if n_alive is not None else "")
    lines = [head, f"{'station':>7} {'state':>9} {'slot':>4} {'updates':>7} {'x m':>9} {'y m':>9} "
                   f"{'z m':>8} {'sigma m':>8} {'error m':>8} {'drops':>5} {'sync ns':>8}"]
    for v in views:
        p = v.pos_m or [math.nan] * 3
        lines.append(f"{v.id:>7} {v.state:>9} {'-' if v.slot is None else v.slot:>4} {v.n_updates:>7} "
                     f"{p[0]:>9.2f} {p[1]:>9.2f} {p[2]:>8.2f} {v.sigma_m:>8.2f} {v.err_m:>8.2f} {v.dropped:>5} "
                     f"{v.sync_ns:>8.2f}")
    errs = [v.err_m for v in views if v.state != "frame" and not math.isnan(v.err_m)]
    if errs:
        rms = math.sqrt(sum(e * e for e in errs) / len(errs))
        lines.append(f"{'':>7} RMS error of surveying stations: {rms:.2f} m")
    return "\n".join(lines)


# --------------------------------------------------------------------------- MCAP summary

def mcap_station_summary(path: str | Path) -> dict[int, dict]:
    """Per station from an MCAP file alone (estimate + truth topics): truth, the estimate time
    series and the final error. ``{id: {"truth_m", "t_s" (K,), "pos_m" (K,3), "cov_m2" (K,3,3),
    "n_updates" (K,), "state", "err_m" (final), "sigma_m" (final)}}``."""
    import numpy as np
    from mcap.reader import make_reader

    from net import messages as M

    est: dict[int, list] = {}
    truth: dict[int, list] = {}
    with open(path, "rb") as f:
        for _schema, ch, m in make_reader(f).iter_messages():
            if not (ch.topic.endswith("/estimate") or ch.topic.endswith("/truth")):
                continue
            try:
                msg, _ = M.decode(m.data)
            except M.MessageError:
                continue
            if msg["kind"] == "truth":
                truth[msg["src"]] = msg["pos_m"]
            elif msg["kind"] == "estimate":
                est.setdefault(msg["src"], []).append(
                    (msg["t_s"], msg["pos_m"], msg["cov_m2"], msg["n_updates"], msg["state"], m.log_time))
    out: dict[int, dict] = {}
    for sid, rows in sorted(est.items()):
        rows.sort(key=lambda r: r[5])
        t = np.array([r[0] for r in rows])
        pos = np.array([r[1] for r in rows])
        cov = np.array([r[2] for r in rows])
        tr = np.asarray(truth.get(sid, [np.nan] * 3), float)
        out[sid] = {"truth_m": tr, "t_s": t, "pos_m": pos, "cov_m2": cov,
                    "n_updates": np.array([r[3] for r in rows]), "state": rows[-1][4],
                    "log_time_ns": np.array([r[5] for r in rows]),
                    "err_m": float(np.linalg.norm(pos[-1] - tr)),
                    "sigma_m": float(np.sqrt(max(np.trace(cov[-1]), 0.0)))}
    return out


# --------------------------------------------------------------------------- launcher

def _spawn(c: Child) -> None:
    if c.log_path is not None:
        c.log_file = open(c.log_path, "w")
        c.proc = subprocess.Popen(c.cmd, stdout=c.log_file, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                  start_new_session=True)
    else:
        c.proc = subprocess.Popen(c.cmd, stdin=subprocess.DEVNULL, start_new_session=True)


def _stop_children(children: list[Child], grace_s: float = 8.0) -> None:
    live = [c for c in children if c.proc is not None and c.proc.poll() is None]
    for c in live:
        try:
            c.proc.send_signal(signal.SIGINT)
        except ProcessLookupError:
            pass
    deadline = time.time() + grace_s
    for c in live:
        try:
            c.proc.wait(max(0.1, deadline - time.time()))
        except subprocess.TimeoutExpired:
            c.proc.kill()
            c.proc.wait()


def aircraft_available() -> bool:
    import importlib.util

    return importlib.util.find_spec("aircraft.__main__") is not None


def run_fleet(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from net import scenario as S
    from net.bus import Bus, bus_argv, free_tcp_ports

    over: dict[str, Any] = {}
    if args.n_stations:
        over["layout"] = {"n": int(args.n_stations)}
    scn = S.load(args.scenario, **over)
    joins: list[tuple[int, float]] = []
    for spec in args.join or []:
        sid, _, t = spec.partition("@")
        joins.append((int(sid), float(t or 20.0)))
    # stations marked join in the scenario join at --join-time unless given explicitly
    for sid in scn.join_ids:
        if sid not in [j for j, _ in joins]:
            joins.append((sid, args.join_time))
    if args.duration:
        joins = [(s, t) for s, t in joins if t < args.duration]
    join_ids = {j for j, _ in joins}
    for sid, _ in joins:
        if sid not in scn.ids:
            raise SystemExit(f"--join {sid}: no such station in scenario {scn.name} (ids {scn.ids})")
    initial = [i for i in scn.ids if i not in join_ids]
    secure = _fleet_keystore(args, scn) if getattr(args, "secure", None) else None
    n_proc = len(scn.ids) + (1 if args.record else 0) + 2
    ports = free_tcp_ports(n_proc)
    eps = [f"tcp/127.0.0.1:{p}" for p in ports]
    wall_slot_ms = scn.tdma.slot_s / args.speed * 1e3
    if wall_slot_ms < 5.0:
        print(f"[fleet] warning: at --speed {args.speed:g} a {scn.tdma.slot_s*1e3:g} ms slot lasts "
              f"{wall_slot_ms:.1f} ms of wall time; Zenoh round trips on a loaded machine may not fit "
              f"(late replies are lost measurements)", file=sys.stderr)
    margin = args.startup if args.startup is not None else 3.0 + 0.25 * len(scn.ids)
    epoch = time.time() + margin
    logdir: Path | None = None
    if args.logs:
        logdir = Path(args.logs)
    elif args.record:
        logdir = Path(str(args.record) + ".logs")
    else:  # keep the children's output out of the live table
        import tempfile

        logdir = Path(tempfile.mkdtemp(prefix="larns-fleet-logs-"))
    if logdir:
        logdir.mkdir(parents=True, exist_ok=True)
    py = sys.executable
    common = ["--scenario", args.scenario, "--speed", repr(args.speed), "--epoch", repr(epoch)]
    if args.n_stations:
        common += ["--n-stations", str(args.n_stations)]
    for flag, val in (("--net-delay", args.net_delay), ("--net-jitter", args.net_jitter),
                      ("--net-loss", args.net_loss), ("--net-dup", args.net_dup)):
        if val is not None:
            common += [flag, repr(val)]
    children: list[Child] = []
    station_ep = {sid: eps[i] for i, sid in enumerate(scn.ids)}
    monitor_ep = eps[len(scn.ids)]
    # peer: seeds = the first two stations (gossip links everyone else); --connect overrides.
    # router: every process is a client of our own router (or of the routers given with --connect)
    mode = "client" if args.topology == "router" or getattr(args, "zenoh_mode", "peer") == "client" else "peer"
    router_ep = eps[-1]
    if mode == "client":
        seeds = list(args.connect) if args.connect else [router_ep]
        if not args.connect:
            rcmd = [py, "-m", "larns", "router", "--listen", router_ep, "-q"]
            if secure:
                rcmd += ["--secure", secure, "--scenario", args.scenario, "--speed", repr(args.speed)]
            children.append(Child("router", rcmd, logdir / "router.log" if logdir else None))
    else:
        seeds = list(args.connect) if args.connect else [station_ep[scn.ids[0]], station_ep[scn.ids[1]]]
    if args.record:
        rec_ep = eps[len(scn.ids) + 1]
        cmd = [py, "-m", "larns", "record", "-o", str(args.record), "-q", "--scenario", scn.name,
               "--epoch", repr(epoch), "--speed", repr(args.speed),
               "--meta", f"stations={','.join(map(str, scn.ids))}", "--meta", f"seed={scn.seed}",
               "--meta", f"duration_s={args.duration}"]
        cmd += bus_argv([rec_ep], seeds, args.zenoh_config, mode, secure)
        children.append(Child("recorder", cmd, logdir / "recorder.log" if logdir else None))
    for sid in scn.ids:
        cmd = [py, "-m", "stations", "--id", str(sid), *common, "--status-every", "10"]
        if args.nice:
            cmd += ["--nice", str(args.nice)]
        if args.duration:
            cmd += ["--duration", repr(args.duration)]
        start_wall = 0.0
        if sid in join_ids:
            t_join = dict(joins)[sid]
            cmd += ["--join", "--start-at", repr(t_join)]
            # spawn early enough to be up at t_join (it sleeps until then)
            start_wall = max(0.0, epoch + t_join / args.speed - margin)
        cmd += bus_argv([station_ep[sid]], [s for s in seeds if s != station_ep[sid]], args.zenoh_config, mode,
                        secure)
        children.append(Child(f"station {sid}", cmd, logdir / f"station_{sid}.log" if logdir else None,
                              start_wall=start_wall))
    children.sort(key=lambda c: (c.name != "router", c.name != "recorder"))
    if args.aircraft:
        if not aircraft_available():
            print("[fleet] --aircraft: no aircraft process in this build (python -m aircraft); skipped",
                  file=sys.stderr)
        else:
            cmd = [py, "-m", "aircraft", *common]
            if args.duration:
                cmd += ["--duration", repr(args.duration)]
            cmd += bus_argv(["tcp/127.0.0.1:0"], seeds, args.zenoh_config, mode, secure)
            children.append(Child("aircraft", cmd, logdir / "aircraft.log" if logdir else None))

    stop = threading.Event()

    def on_signal(signum, frame):  # noqa: ARG001
        stop.set()

    old_int = signal.signal(signal.SIGINT, on_signal)
    old_term = signal.signal(signal.SIGTERM, on_signal)
    print(f"[fleet] scenario {scn.name}: {len(initial)} stations"
          + (f" + {len(joins)} joining ({', '.join(f'{s}@{t:g}s' for s, t in joins)})" if joins else "")
          + (f", recorder -> {args.record}" if args.record else "")
          + f", speed {args.speed:g}, epoch in {margin:.1f} s"
          + (f", logs in {logdir}/" if logdir else ""), file=sys.stderr, flush=True)
    monitor = Monitor()
    bus = None
    final: list[StationView] = []
    try:
        for c in children:
            if c.start_wall == 0.0:
                _spawn(c)
        # the launcher observes like any peer (spawned children first: no fork of a live runtime)
        bus = Bus(listen=[] if mode == "client" else [monitor_ep], connect=seeds, config_file=args.zenoh_config,
                  mode=mode, secure=(secure, "monitor") if secure else None)
        bus.subscribe("larns/station/*/estimate", monitor.on_sample)
        bus.subscribe("larns/station/*/truth", monitor.on_sample)
        if args.aircraft:
            bus.subscribe("larns/aircraft/**", monitor.on_sample)
        bus.subscribe_liveliness("larns/alive/**", monitor.on_alive)
        t_end_wall = epoch + args.duration / args.speed if args.duration else math.inf
        next_print = epoch
        tty = sys.stdout.isatty() and not args.no_table
        while not stop.is_set():
            now = time.time()
            for c in children:
                if c.proc is None and c.start_wall and now >= c.start_wall:
                    _spawn(c)
            if now >= t_end_wall + 1.0:
                break
            stations = [c for c in children if c.name.startswith("station")]
            if args.duration and all(c.proc is not None and c.proc.poll() is not None for c in stations):
                break
            if now >= next_print and not args.no_table:
                t_f = (now - epoch) * args.speed
                n_alive = sum(1 for c in children if c.proc is not None and c.proc.poll() is None)
                txt = "\n".join([format_table(monitor.snapshot(), t_f, n_alive), *monitor.aircraft_lines()])
                if tty:
                    sys.stdout.write("\x1b[H\x1b[2J" + txt + "\n")
                else:
                    sys.stdout.write(txt + "\n\n")
                sys.stdout.flush()
                next_print = now + (args.refresh if tty else max(args.refresh, 10.0))
            time.sleep(0.05)
        final = monitor.snapshot()
    finally:
        # stations first (they exit at --duration on their own), then the recorder
        stations = [c for c in children if c.name not in ("recorder", "router")]
        if not stop.is_set() and args.duration:
            for c in stations:
                if c.proc is not None:
                    try:
                        c.proc.wait(5.0)
                    except subprocess.TimeoutExpired:
                        pass
        _stop_children(stations)
        time.sleep(0.3)  # let the recorder receive the last samples
        _stop_children([c for c in children if c.name == "recorder"], grace_s=20.0)
        _stop_children([c for c in children if c.name == "router"])  # last: it carries everyone's traffic
        if bus is not None:
            bus.close()
        for c in children:
            if c.log_file:
                c.log_file.close()
        signal.signal(signal.SIGINT, old_int)
        signal.signal(signal.SIGTERM, old_term)
    t_f = (time.time() - epoch) * args.speed
    print("\n".join([format_table(final, t_f), *monitor.aircraft_lines()]))
    rc = {c.name: (c.proc.returncode if c.proc else None) for c in children}
    bad = {k: v for k, v in rc.items() if v not in (0, None)}
    if bad:
        print(f"[fleet] non-zero exit codes: {bad}", file=sys.stderr)
    if args.record:
        print(f"[fleet] recording: {args.record}", file=sys.stderr)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps({
            "scenario": scn.name, "epoch_unix_s": epoch, "speed": args.speed, "duration_s": args.duration,
            "exit_codes": rc, "stations": [dict(vars(v), err_m=v.err_m) for v in final]}, indent=2,
            default=float))
    return 130 if stop.is_set() else (1 if bad else 0)


def register(sub) -> None:
    from net.bus import add_bus_args

    p = sub.add_parser("fleet", help="launch a local fleet: one process per station + recorder, live table",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenario", default="seed000", help="scenario name or TOML path (default seed000)")
    p.add_argument("--duration", type=float, default=60.0,
                   help="fleet seconds to run (0 = until Ctrl-C; default 60)")
    p.add_argument("--speed", type=float, default=1.0, help="run K times faster than real time (default 1)")
    p.add_argument("--record", default=None, metavar="FILE.mcap", help="record everything to this MCAP file")
    p.add_argument("--join", action="append", metavar="ID@T",
                   help="hot-join station ID at fleet time T seconds (repeatable), e.g. --join 11@20")
    p.add_argument("--join-time", type=float, default=20.0,
                   help="fleet time at which the scenario's join stations join (default 20)")
    p.add_argument("--n-stations", type=int, default=None, help="override the station count of a random layout")
    p.add_argument("--aircraft", action="store_true", help="also run the aircraft process (if available)")
    p.add_argument("--net-delay", type=float, default=None, metavar="S", help="wire delay, s (all stations)")
    p.add_argument("--net-jitter", type=float, default=None, metavar="S", help="wire jitter, s")
    p.add_argument("--net-loss", type=float, default=None, metavar="P", help="wire loss probability")
    p.add_argument("--net-dup", type=float, default=None, metavar="P", help="wire duplication probability")
    p.add_argument("--startup", type=float, default=None, metavar="S",
                   help="seconds between launch and the epoch (default 3 + 0.25 per station)")
    p.add_argument("--nice", type=int, default=0, metavar="N",
                   help="niceness change for the station processes (negative = higher priority; needs privileges)")
    p.add_argument("--topology", choices=("peer", "router"), default="peer",
                   help="peer: full mesh by gossip (default); router: also start a `larns router` and run "
                        "every process as a Zenoh client of it (N links instead of N(N-1)/2)")
    p.add_argument("--refresh", type=float, default=1.0,
                   help="table refresh period, wall seconds (at least 10 s when stdout is not a terminal)")
    p.add_argument("--no-table", action="store_true", help="no live table (final table only)")
    p.add_argument("--logs", default=None, help="folder for per-process logs (default FILE.mcap.logs/)")
    p.add_argument("--json", default=None, help="write the final table as JSON")
    add_bus_args(p)
    p.set_defaults(func=lambda a: _run_checked(_fix(a)))


def _run_checked(args: argparse.Namespace) -> int:
    from net.security import KeystoreError

    try:
        return run_fleet(args)
    except KeystoreError as e:
        print(f"[fleet] --secure: {e}", file=sys.stderr)
        return 2


def _fleet_keystore(args: argparse.Namespace, scn) -> str:
    """``--secure DIR`` (checked: every process's credentials must be there) or, with a bare
    ``--secure``, a fresh temporary keystore for this scenario's stations, its aircraft, the
    recorder, the router and the monitor."""
    from net.security import Keystore, KeystoreError, aircraft_cn, station_cn

    if args.secure != "auto":
        ks = Keystore(args.secure)
        need = [station_cn(i) for i in scn.ids] + ["monitor"]
        need += ["recorder"] if args.record else []
        need += ["router"] if args.topology == "router" and not args.connect else []
        for cn in need:
            ks.check_enclave(cn)
        return str(args.secure)
    import tempfile

    from larns.keys import init_keystore

    root = Path(tempfile.mkdtemp(prefix="larns-keys-")) / "keys"
    name = str(scn.aircraft.get("name", "ac1")) if isinstance(getattr(scn, "aircraft", None), dict) else "ac1"
    init_keystore(root, list(scn.ids), [name], recorder=True)
    print(f"[fleet] --secure: temporary keystore {root}", file=sys.stderr)
    if not root.is_dir():
        raise KeystoreError(f"cannot create {root}")
    return str(root)


def _fix(a: argparse.Namespace) -> argparse.Namespace:
    if a.duration is not None and a.duration <= 0:
        a.duration = None
    return a
