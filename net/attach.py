"""Attaching a separately started process to a running ``larns fleet``, and its run length.

``larns fleet`` writes a *fleet file* (``fleet.json``, beside its recording) saying what a newcomer
must agree on: the epoch, the speed, the scenario, the Zenoh endpoints to connect to and whether the
fleet is ``--secure``. A station, aircraft, vehicle or recorder started with ``--fleet FILE`` takes
these values from it; started without ``--epoch`` and without ``--fleet``, it looks for
:data:`DEFAULT_FLEET_FILE` and attaches to that fleet when the file describes one that is still
running. Values given explicitly on the command line win, except a ``--scenario`` or ``--speed``
contradicting the fleet's, which is refused (exit 2, one line).

Run length: ``--duration S`` is the length of the run in fleet seconds, counted from when the process
starts (``--start-at``, the epoch if it starts before it, else now; a station counts from its power-on,
after its start-up, with ``args.run_s``); ``--until T`` stops at fleet time T. Attached without
either, a process stops when the fleet ends.

Only file reading and argument arithmetic here: no sockets, no clocks of our own (``now_unix_s`` is
passed in).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import socket
import sys
from pathlib import Path
from typing import Any

FORMAT = "larns-fleet/1"
DEFAULT_FLEET_FILE = Path("runs") / "fleet.json"


class FleetFileError(ValueError):
    """A fleet file that cannot be used (missing, not JSON, a key missing or of the wrong type)."""


def add_attach_args(p: argparse.ArgumentParser) -> None:
    """``--fleet FILE`` and ``--until T`` (``--duration`` is each command's own: a run length)."""
    p.add_argument("--fleet", default=None, metavar="FILE",
                   help="attach to the running `larns fleet` described by FILE (its epoch, speed, scenario, "
                        f"endpoints); default: {DEFAULT_FLEET_FILE} if it describes a running fleet and no "
                        "--epoch is given")
    p.add_argument("--until", type=float, default=None, metavar="T",
                   help="stop at fleet time T (seconds since the epoch); default: --duration, else the "
                        "attached fleet's end, else run until signalled")


def fleet_record(*, scenario: str, scenario_name: str, n_stations: int | None, epoch_unix_s: float, speed: float,
                 duration_s: float | None, mode: str, connect: list[str], endpoints: dict[str, str],
                 secure: str | None, recording: str | None, net_faults: dict[str, float],
                 pid: int, host: str) -> dict[str, Any]:
    """The fleet file's content (``larns fleet`` writes it as JSON)."""
    end = None if not duration_s else epoch_unix_s + duration_s / speed
    return {"format": FORMAT, "scenario": scenario, "scenario_name": scenario_name, "n_stations": n_stations,
            "epoch_unix_s": epoch_unix_s, "speed": speed, "duration_s": duration_s, "end_unix_s": end,
            "zenoh_mode": mode, "connect": list(connect), "endpoints": dict(endpoints), "secure": secure,
            "secure_enabled": bool(secure), "recording": recording, "net_faults": dict(net_faults),
            "pid": pid, "host": host}


def write_fleet_file(path: str | Path, record: dict[str, Any]) -> Path:
    """Write atomically (a reader never sees half a file)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + f".{os.getpid()}.tmp")
    tmp.write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    os.replace(tmp, path)
    return path


_REQUIRED = {"epoch_unix_s": (int, float), "speed": (int, float), "scenario": str, "connect": list}


def read_fleet_file(path: str | Path) -> dict[str, Any]:
    """The fleet file at ``path``, checked; :class:`FleetFileError` names the file and the problem."""
    path = Path(path)
    try:
        rec = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise FleetFileError(f"{path}: no such fleet file (`larns fleet` writes one beside its recording "
                             "and prints where)") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise FleetFileError(f"{path}: not a fleet file ({e})") from None
    if not isinstance(rec, dict) or rec.get("format") != FORMAT:
        raise FleetFileError(f"{path}: not a fleet file (expected \"format\": \"{FORMAT}\")")
    for key, typ in _REQUIRED.items():
        if not isinstance(rec.get(key), typ) or isinstance(rec.get(key), bool):
            raise FleetFileError(f"{path}: key \"{key}\": expected {_type_name(typ)}, got {rec.get(key)!r}")
    if not rec["speed"] > 0:
        raise FleetFileError(f"{path}: key \"speed\": expected a number > 0, got {rec['speed']!r}")
    return rec


def _type_name(typ: Any) -> str:
    return {str: "a string", list: "a list of endpoints"}.get(typ, "a number")


def fleet_running(rec: dict[str, Any], now_unix_s: float, host: str | None = None) -> bool:
    """Whether the fleet of ``rec`` is still running: before its end and, on the host that wrote it,
    its launcher process still alive."""
    end = rec.get("end_unix_s")
    if isinstance(end, (int, float)) and now_unix_s > end:
        return False
    pid = rec.get("pid")
    if isinstance(pid, int) and rec.get("host") == (host or socket.gethostname()):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:
            return True
    return True


def _given(p: argparse.ArgumentParser | None, args: argparse.Namespace, dest: str) -> bool:
    """Whether ``dest`` differs from its parser default (i.e. was given on the command line)."""
    if p is None or not hasattr(args, dest):
        return False
    return getattr(args, dest) != p.get_default(dest)


def _scenario_matches(given: str, rec: dict[str, Any]) -> bool:
    names = {str(rec.get("scenario")), str(rec.get("scenario_name")), Path(str(rec.get("scenario"))).stem}
    return given in names or Path(given).stem in names


def find_fleet(args: argparse.Namespace, now_unix_s: float, who: str) -> tuple[Path, dict] | None:
    """The fleet to attach to: ``--fleet FILE`` (must be readable), else :data:`DEFAULT_FLEET_FILE` when
    no ``--epoch`` was given and it describes a running fleet, else None."""
    explicit = getattr(args, "fleet", None)
    if explicit:
        rec = read_fleet_file(explicit)
        if not fleet_running(rec, now_unix_s):
            print(f"{who}: warning: {explicit}: that fleet seems to have ended; attaching anyway",
                  file=sys.stderr)
        return Path(explicit), rec
    if getattr(args, "epoch", None) is not None or not DEFAULT_FLEET_FILE.is_file():
        return None
    try:
        rec = read_fleet_file(DEFAULT_FLEET_FILE)
    except FleetFileError as e:
        print(f"{who}: warning: {e}; not attaching", file=sys.stderr)
        return None
    if not fleet_running(rec, now_unix_s):
        print(f"{who}: {DEFAULT_FLEET_FILE}: that fleet has ended; not attaching (epoch: start of the UTC day)",
              file=sys.stderr)
        return None
    return DEFAULT_FLEET_FILE, rec


def apply_fleet(args: argparse.Namespace, rec: dict[str, Any], path: Path,
                parser: argparse.ArgumentParser | None = None) -> None:
    """Take the fleet's epoch, speed, scenario, endpoints, mode, network faults and keystore into
    ``args`` (explicit ``--connect`` / ``--secure`` / ``--net-*`` win). A ``--scenario`` or ``--speed``
    given explicitly and contradicting the fleet raises :class:`FleetFileError`."""
    if _given(parser, args, "scenario") and args.scenario and not _scenario_matches(args.scenario, rec):
        raise FleetFileError(f"--scenario {args.scenario}: the fleet of {path} runs scenario {rec['scenario']}")
    if _given(parser, args, "speed") and not math.isclose(float(args.speed), float(rec["speed"])):
        raise FleetFileError(f"--speed {args.speed:g}: the fleet of {path} runs at speed {rec['speed']:g}")
    args.scenario = rec["scenario"]
    args.speed = float(rec["speed"])
    args.epoch = float(rec["epoch_unix_s"])
    if hasattr(args, "n_stations") and not getattr(args, "n_stations", None):
        args.n_stations = rec.get("n_stations")
    if hasattr(args, "connect") and not args.connect:
        args.connect = list(rec["connect"])
    if hasattr(args, "zenoh_mode") and rec.get("zenoh_mode") in ("peer", "client"):
        args.zenoh_mode = rec["zenoh_mode"]
    if hasattr(args, "secure") and not args.secure and rec.get("secure"):
        args.secure = str(rec["secure"])
    for key, val in (rec.get("net_faults") or {}).items():
        dest = f"net_{key}"
        if hasattr(args, dest) and getattr(args, dest) is None and isinstance(val, (int, float)):
            setattr(args, dest, float(val))
    args.fleet_end_s = _fleet_end_s(rec)


def _fleet_end_s(rec: dict[str, Any]) -> float | None:
    d = rec.get("duration_s")
    return float(d) if isinstance(d, (int, float)) and d > 0 else None


def end_fleet_s(duration_s: float | None, until_s: float | None, start_s: float,
                fleet_end_s: float | None = None) -> float | None:
    """The fleet time at which a process stops: ``until_s`` if given, else ``start_s + duration_s``,
    else the attached fleet's end, else None (run until signalled). ``start_s`` is the fleet time at
    which the process powers on."""
    if until_s is not None:
        return float(until_s)
    if duration_s is not None and duration_s > 0:
        return float(start_s) + float(duration_s)
    return fleet_end_s


def day_start_s(now_unix_s: float) -> float:
    """Start of the UTC day of ``now_unix_s``: the epoch of a process started without ``--epoch``."""
    return math.floor(now_unix_s / 86400.0) * 86400.0


def resolve(args: argparse.Namespace, now_unix_s: float, who: str,
            parser: argparse.ArgumentParser | None = None) -> argparse.Namespace:
    """Attach (``--fleet``, or the default fleet file) and turn ``--duration`` / ``--until`` into the
    absolute end the nodes take (``args.duration`` = stop at this fleet time, None = never; ``args.run_s``
    = the run length when it came from ``--duration``).
    Without an epoch the process uses the start of the UTC day. Idempotent (``args.attach_resolved``)."""
    if getattr(args, "attach_resolved", False):
        return args
    args.fleet_end_s = None
    found = find_fleet(args, now_unix_s, who)
    if found is not None:
        path, rec = found
        apply_fleet(args, rec, path, parser)
        print(f"{who}: attaching to the fleet of {path}: scenario {rec['scenario']}, epoch {rec['epoch_unix_s']:.3f}, "
              f"speed {rec['speed']:g}, connect {' '.join(args.connect or [])}", file=sys.stderr, flush=True)
    epoch = day_start_s(now_unix_s) if getattr(args, "epoch", None) is None else float(args.epoch)
    speed = float(getattr(args, "speed", 1.0) or 1.0)
    now_fleet = (now_unix_s - epoch) * speed
    start_at = getattr(args, "start_at", None)
    start = max(0.0, now_fleet, start_at if start_at is not None else -math.inf)
    run_s = getattr(args, "duration", None)
    until = getattr(args, "until", None)
    args.duration = end_fleet_s(run_s, until, start, args.fleet_end_s)
    # the run length itself, for a node that counts it from its power-on (after its start-up)
    args.run_s = float(run_s) if until is None and run_s is not None and run_s > 0 else None
    args.attach_resolved = True
    return args
