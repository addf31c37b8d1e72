"""Planning a fleet: which processes to start, with which arguments, when (no process is started here).

:func:`plan_fleet` turns the ``larns fleet`` arguments into a :class:`FleetPlan`: the scenario, the
joins, one shared epoch a few seconds in the future, the Zenoh endpoints and topology, the log
folder and one :class:`~larns.fleet.spawn.Child` per process (router, recorder, stations, aircraft).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .spawn import Child

VEHICLE_NAME = "veh1"  # the fleet's ground vehicle (--vehicle): its name, and its enclave vehicle-veh1 under --secure


@dataclass
class FleetPlan:
    scn: Any
    joins: list[tuple[int, float]]
    initial: list[int]
    epoch: float
    margin: float
    logdir: Path | None
    mode: str                      # "peer" or "client"
    seeds: list[str]
    monitor_ep: str
    secure: str | None = None
    epoch_file: Path | None = None  # the start barrier (larns/fleet/spawn.py): the epoch, once all are up
    children: list[Child] = field(default_factory=list)
    events: list["FleetEvent"] = field(default_factory=list)  # kills, leaves, restarts in fleet-time order
    endpoints: dict[str, str] = field(default_factory=dict)  # process name -> its listening endpoint


def parse_joins(args: argparse.Namespace, scn) -> list[tuple[int, float]]:
    """``--join ID@T`` plus the scenario's join stations (at ``--join-time``), before ``--duration``."""
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
    for sid, _ in joins:
        if not 1 <= sid <= 65535:
            print(f"larns fleet: --join {sid}: expected a station id in 1..65535", file=sys.stderr)
            raise SystemExit(2)
    return joins


@dataclass
class FleetEvent:
    """A station fault acted on by the launcher at fleet time ``t_s``: ``kill`` (SIGKILL), ``leave``
    (SIGTERM: the station stops cleanly) or ``restart`` (a fresh process with the same id that joins
    the running field, ``--join --start-at t_s``)."""

    kind: str
    sid: int
    t_s: float
    done: bool = False


def _id_at(flag: str, spec: str, ids: list[int]) -> tuple[int, float]:
    sid, at, t = spec.partition("@")
    try:
        out = int(sid), float(t)
    except ValueError:
        out = None
    if out is None or not at or out[1] < 0:
        print(f"larns fleet: {flag} {spec}: expected ID@T (station id @ fleet seconds), e.g. {flag} 1@60",
              file=sys.stderr)
        raise SystemExit(2)
    if out[0] not in ids:
        print(f"larns fleet: {flag} {spec}: station {out[0]} is not in the fleet ({', '.join(map(str, ids))})",
              file=sys.stderr)
        raise SystemExit(2)
    return out


def parse_events(args: argparse.Namespace, scn) -> list[FleetEvent]:
    """``--kill ID@T``, ``--restart ID@T`` and the scenario's ``[[faults]]`` of kind ``leave`` /
    ``kill`` (a ``--kill`` or ``--restart`` of the same station overrides nothing: all are acted on),
    in fleet-time order; a restart must follow a kill or leave of the same station."""
    from net.scenario import DEPARTURE_KINDS

    ev = [FleetEvent(f.kind, f.station, float(f.at_s)) for f in scn.faults if f.kind in DEPARTURE_KINDS]
    for flag, kind in (("--kill", "kill"), ("--restart", "restart")):
        for spec in getattr(args, kind, None) or []:
            ev.append(FleetEvent(kind, *_id_at(flag, spec, list(scn.ids))))
    ev.sort(key=lambda e: (e.t_s, e.kind != "restart"))
    down: dict[int, bool] = {}
    for e in ev:
        if e.kind == "restart" and not down.get(e.sid):
            print(f"larns fleet: --restart {e.sid}@{e.t_s:g}: station {e.sid} is not down then "
                  f"(give --kill {e.sid}@T with T < {e.t_s:g}, or a [[faults]] leave / kill)", file=sys.stderr)
            raise SystemExit(2)
        down[e.sid] = e.kind != "restart"
    return [e for e in ev if not args.duration or e.t_s < args.duration]


def with_outside_joiners(scn, joins: list[tuple[int, float]]):
    """The scenario plus the joiners it does not list (``--join 11@20`` on seed000's ten stations),
    each where its own process and its peers put it (``net.scenario.joiner_position``)."""
    from stations.node import with_joiner

    for sid, _ in joins:
        if sid not in scn.ids:
            scn = with_joiner(scn, sid)
    return scn


def log_folder(args: argparse.Namespace) -> Path:
    """``--logs``, else ``FILE.mcap.logs/`` next to the recording, else a temporary folder."""
    if args.logs:
        logdir = Path(args.logs)
    elif args.record:
        logdir = Path(str(args.record) + ".logs")
    else:  # keep the children's output out of the live table
        import tempfile

        logdir = Path(tempfile.mkdtemp(prefix="larns-fleet-logs-"))
    logdir.mkdir(parents=True, exist_ok=True)
    return logdir


def common_argv(args: argparse.Namespace, epoch: float, epoch_file: Path | None = None) -> list[str]:
    """Arguments every station and the aircraft get: scenario, speed, epoch (``epoch_file``: the
    start barrier's ``--epoch-from`` instead), network emulation."""
    common = ["--scenario", args.scenario, "--speed", repr(args.speed)]
    common += ["--epoch-from", str(epoch_file)] if epoch_file is not None else ["--epoch", repr(epoch)]
    if args.n_stations:
        common += ["--n-stations", str(args.n_stations)]
    for flag, val in (("--net-delay", args.net_delay), ("--net-jitter", args.net_jitter),
                      ("--net-loss", args.net_loss), ("--net-dup", args.net_dup)):
        if val is not None:
            common += [flag, repr(val)]
    return common


def _warn_short_slot(args: argparse.Namespace, scn) -> None:
    wall_slot_ms = scn.tdma.slot_s / args.speed * 1e3
    if wall_slot_ms < 5.0:
        print(f"[fleet] warning: at --speed {args.speed:g} a {scn.tdma.slot_s*1e3:g} ms slot lasts "
              f"{wall_slot_ms:.1f} ms of wall time; Zenoh round trips on a loaded machine may not fit "
              f"(late replies are lost measurements)", file=sys.stderr)


def plan_fleet(args: argparse.Namespace) -> FleetPlan:
    """Everything :func:`larns.fleet.run.run_fleet` starts, decided before anything starts."""
    from net import scenario as S
    from net.bus import free_tcp_ports

    scn = S.load_cli(args.scenario, args.n_stations)
    joins = parse_joins(args, scn)
    scn = with_outside_joiners(scn, joins)
    join_ids = {j for j, _ in joins}
    secure = _fleet_keystore(args, scn) if getattr(args, "secure", None) else None
    eps = [f"tcp/127.0.0.1:{p}" for p in free_tcp_ports(len(scn.ids) + (1 if args.record else 0) + 2)]
    _warn_short_slot(args, scn)
    margin = args.startup if args.startup is not None else 3.0 + 0.25 * len(scn.ids)
    epoch = time.time() + margin  # provisional: the start barrier fixes it (larns/fleet/spawn.py)
    station_ep = {sid: eps[i] for i, sid in enumerate(scn.ids)}
    # peer: seeds = the first two stations (gossip links everyone else); --connect overrides.
    # router: every process is a client of our own router (or of the routers given with --connect)
    mode = "client" if args.topology == "router" or getattr(args, "zenoh_mode", "peer") == "client" else "peer"
    if mode == "client":
        seeds = list(args.connect) if args.connect else [eps[-1]]
    else:
        seeds = list(args.connect) if args.connect else [station_ep[scn.ids[0]], station_ep[scn.ids[1]]]
    p = FleetPlan(scn, joins, [i for i in scn.ids if i not in join_ids], epoch, margin, log_folder(args), mode,
                  seeds, eps[len(scn.ids)], secure)
    p.epoch_file = Path(tempfile.mkdtemp(prefix="larns-fleet-")) / "epoch"
    p.endpoints = _endpoints(args, mode, station_ep, eps[-1])
    if mode == "client" and not args.connect:
        p.children.append(_router_child(args, p, eps[-1]))
    if args.record:
        p.children.append(_recorder_child(args, p, eps[len(scn.ids) + 1]))
    common = common_argv(args, epoch, p.epoch_file)
    for sid in scn.ids:
        p.children.append(_station_child(args, p, sid, station_ep[sid], common))
    p.children.sort(key=lambda c: (c.name != "router", c.name != "recorder"))
    p.events = parse_events(args, scn)
    if args.aircraft:
        if not aircraft_available():
            print("[fleet] --aircraft: no aircraft process in this build (python -m aircraft); skipped",
                  file=sys.stderr)
        else:
            p.children.append(_aircraft_child(args, p, common))
    if wants_vehicle(args):
        p.children.append(_vehicle_child(args, p, common))
    if getattr(args, "view", None) is not None:  # --view: live Foxglove view (larns/commands/view.py)
        from larns.commands.view import view_child

        p.children.append(view_child(args, p))
    return p


def _endpoints(args: argparse.Namespace, mode: str, station_ep: dict[int, str], router_ep: str) -> dict[str, str]:
    """Who listens where (for the fleet file): the stations of a peer fleet, or our own router."""
    if mode == "peer":
        return {f"station {sid}": ep for sid, ep in station_ep.items()}
    return {} if args.connect else {"router": router_ep}


def wants_vehicle(args: argparse.Namespace) -> bool:
    """``--vehicle`` (or a vehicle route / outage, which imply it)."""
    return bool(getattr(args, "vehicle", False) or getattr(args, "vehicle_route", None)
                or getattr(args, "vehicle_outage", None))


def _vehicle_child(args: argparse.Namespace, p: FleetPlan, common: list[str]) -> Child:
    from net.bus import bus_argv

    cmd = [sys.executable, "-m", "vehicle", *common, "--name", VEHICLE_NAME]  # (net-fault flags: not applied)
    if args.duration:
        cmd += ["--until", repr(args.duration)]
    if getattr(args, "vehicle_route", None):
        cmd += ["--route", str(args.vehicle_route)]
    if getattr(args, "vehicle_outage", None):
        cmd += ["--outage", str(args.vehicle_outage)]
    cmd += bus_argv(["tcp/127.0.0.1:0"], p.seeds, args.zenoh_config, p.mode, p.secure)
    return Child("vehicle", cmd, _log(p, "vehicle.log"))


def _log(p: FleetPlan, name: str) -> Path | None:
    return p.logdir / name if p.logdir else None


def _router_child(args: argparse.Namespace, p: FleetPlan, router_ep: str) -> Child:
    rcmd = [sys.executable, "-m", "larns", "router", "--listen", router_ep, "-q"]
    if p.secure:
        rcmd += ["--secure", p.secure, "--scenario", args.scenario, "--speed", repr(args.speed)]
    return Child("router", rcmd, _log(p, "router.log"))


def _recorder_child(args: argparse.Namespace, p: FleetPlan, rec_ep: str) -> Child:
    from net.bus import bus_argv

    scn = p.scn
    cmd = [sys.executable, "-m", "larns", "record", "-o", str(args.record), "-q", "--scenario", scn.name,
           "--epoch-from", str(p.epoch_file), "--speed", repr(args.speed),
           "--meta", f"stations={','.join(map(str, scn.ids))}", "--meta", f"seed={scn.seed}",
           "--meta", f"duration_s={args.duration}"]
    cmd += ["--meta", f"site={scn.site.to_json()}"] if scn.site is not None else []  # [site]: LocationFix, export
    cmd += bus_argv([rec_ep], p.seeds, args.zenoh_config, p.mode, p.secure)
    return Child("recorder", cmd, _log(p, "recorder.log"))


def _station_child(args: argparse.Namespace, p: FleetPlan, sid: int, ep: str, common: list[str]) -> Child:
    from net.bus import bus_argv

    cmd = [sys.executable, "-m", "stations", "--id", str(sid), *common, "--status-every", "10"]
    if args.nice:
        cmd += ["--nice", str(args.nice)]
    if args.duration:
        cmd += ["--until", repr(args.duration)]
    start_wall = 0.0
    joins = dict(p.joins)
    if sid in joins:
        cmd += ["--join", "--start-at", repr(joins[sid])]
        # spawned early enough to be up at t_join (it sleeps until then); set again once the
        # start barrier has fixed the epoch (join_start_wall)
        start_wall = join_start_wall(args, p, joins[sid])
    cmd += bus_argv([ep], [s for s in p.seeds if s != ep], args.zenoh_config, p.mode, p.secure)
    return Child(f"station {sid}", cmd, _log(p, f"station_{sid}.log"), start_wall=start_wall, join_t_s=joins.get(sid))


def join_start_wall(args: argparse.Namespace, p: FleetPlan, t_join_s: float) -> float:
    """When to spawn a station that joins at fleet time ``t_join_s``: ``margin`` ahead of it."""
    return max(1e-6, p.epoch + t_join_s / args.speed - p.margin)  # (0.0 means: spawn at once)


def restart_child(args: argparse.Namespace, p: FleetPlan, sid: int, t_s: float, n: int) -> Child:
    """A fresh process for station ``sid`` at fleet time ``t_s`` (its ``n``-th life): the station's
    own command, joining at ``t_s``, connecting to every other station (the seeds may be gone)."""
    from net.bus import bus_argv

    first = next(c for c in p.children if c.name == f"station {sid}")
    i = first.cmd.index("--id")
    cmd = first.cmd[:i + 2] + common_argv(args, p.epoch) + ["--status-every", "10"]
    if args.nice:
        cmd += ["--nice", str(args.nice)]
    if args.duration:
        cmd += ["--until", repr(args.duration)]
    cmd += ["--join", "--start-at", repr(t_s)]
    ep = p.endpoints.get(f"station {sid}")
    others = [e for k, e in p.endpoints.items() if k.startswith("station ") and e != ep] if p.mode == "peer" else p.seeds
    # a fresh port: the old one may linger; it connects to everyone, nobody needs to connect to it
    cmd += bus_argv(["tcp/127.0.0.1:0"], others, args.zenoh_config, p.mode, p.secure)
    return Child(f"station {sid}#{n}", cmd, _log(p, f"station_{sid}.{n}.log"))


def _aircraft_child(args: argparse.Namespace, p: FleetPlan, common: list[str]) -> Child:
    from net.bus import bus_argv

    cmd = [sys.executable, "-m", "aircraft", *common]
    if args.duration:
        cmd += ["--until", repr(args.duration)]
    cmd += bus_argv(["tcp/127.0.0.1:0"], p.seeds, args.zenoh_config, p.mode, p.secure)
    return Child("aircraft", cmd, _log(p, "aircraft.log"))


def aircraft_available() -> bool:
    import importlib.util

    return importlib.util.find_spec("aircraft.__main__") is not None


def _fleet_keystore(args: argparse.Namespace, scn) -> str:
    """``--secure DIR`` (checked: every process's credentials must be there) or, with a bare
    ``--secure``, a fresh temporary keystore for this scenario's stations, its aircraft, the
    recorder, the router and the monitor."""
    from net.security import Keystore, KeystoreError, station_cn, vehicle_cn

    if args.secure != "auto":
        ks = Keystore(args.secure)
        need = [station_cn(i) for i in scn.ids] + ["monitor"]
        need += ["recorder"] if args.record else []
        need += [vehicle_cn(VEHICLE_NAME)] if wants_vehicle(args) else []
        need += ["router"] if args.topology == "router" and not args.connect else []
        for cn in need:
            ks.check_enclave(cn)
        return str(args.secure)
    import tempfile

    from net.keystore import init_keystore

    root = Path(tempfile.mkdtemp(prefix="larns-keys-")) / "keys"
    name = str(scn.aircraft.get("name", "ac1")) if isinstance(getattr(scn, "aircraft", None), dict) else "ac1"
    init_keystore(root, list(scn.ids), [name], recorder=True, vehicles=[VEHICLE_NAME])
    print(f"[fleet] --secure: temporary keystore {root}", file=sys.stderr)
    if not root.is_dir():
        raise KeystoreError(f"cannot create {root}")
    return str(root)
