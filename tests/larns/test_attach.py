"""Issue 34 item 5: attaching separately started processes to a running ``larns fleet``.

Units: the fleet file (``net/attach.py``), ``--duration`` as a run length and ``--until``, the
hot-joiner from outside the scenario (``stations.node.with_joiner``). Real processes (marked e2e):
``larns fleet`` writes ``runs/fleet.json`` beside its recording; the README's hot-join line, taken
from README.md, attaches a station to it that surveys itself and completes exchanges; ``larns
monitor`` shows the fleet's table; ``--duration 5`` is five seconds of run for the station, the
aircraft and the vehicle.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from net import attach as A

ROOT = Path(__file__).resolve().parents[2]
PY = sys.executable


def _rec(**kw) -> dict:
    base = A.fleet_record(scenario="seed000", scenario_name="seed000", n_stations=None, epoch_unix_s=1000.0,
                          speed=2.0, duration_s=60.0, mode="peer", connect=["tcp/127.0.0.1:7001"],
                          endpoints={"station 1": "tcp/127.0.0.1:7001"}, secure=None, recording=None,
                          net_faults={"loss": 0.1}, pid=os.getpid(), host="thishost")
    return {**base, **kw}


def _args(**kw) -> argparse.Namespace:
    base = dict(fleet=None, epoch=None, speed=1.0, scenario="seed000", duration=None, until=None, start_at=None,
                connect=None, zenoh_mode="peer", secure=None, n_stations=None, net_loss=None)
    return argparse.Namespace(**{**base, **kw})


def _parser() -> argparse.ArgumentParser:
    from stations.node import add_args

    p = argparse.ArgumentParser()
    add_args(p)
    return p


# --------------------------------------------------------------------------- the fleet file

def test_fleet_file_round_trip_and_apply(tmp_path):
    path = A.write_fleet_file(tmp_path / "runs" / "fleet.json", _rec())
    rec = A.read_fleet_file(path)
    assert rec["end_unix_s"] == 1000.0 + 60.0 / 2.0
    args = _args(fleet=str(path))
    A.apply_fleet(args, rec, path, _parser())
    assert (args.epoch, args.speed, args.scenario, args.connect, args.net_loss, args.fleet_end_s) == (
        1000.0, 2.0, "seed000", ["tcp/127.0.0.1:7001"], 0.1, 60.0)
    # explicit endpoints win; a contradicting scenario or speed is refused with the file named
    args = _args(connect=["tcp/10.0.0.1:7447"])
    A.apply_fleet(args, rec, path, _parser())
    assert args.connect == ["tcp/10.0.0.1:7447"]
    with pytest.raises(A.FleetFileError, match=r"--scenario seed004: the fleet of .*fleet.json runs scenario seed000"):
        A.apply_fleet(_args(scenario="seed004"), rec, path, _parser())
    with pytest.raises(A.FleetFileError, match="--speed 3: the fleet of .* runs at speed 2"):
        A.apply_fleet(_args(speed=3.0), rec, path, _parser())


@pytest.mark.parametrize("content, message", [
    (None, "no such fleet file"),
    ("{not json", "not a fleet file"),
    (json.dumps({"format": "other"}), 'expected "format": "larns-fleet/1"'),
    (json.dumps({**_rec(), "epoch_unix_s": "soon"}), 'key "epoch_unix_s": expected a number'),
    (json.dumps({**_rec(), "connect": "tcp/127.0.0.1:1"}), 'key "connect": expected a list of endpoints'),
    (json.dumps({**_rec(), "speed": 0}), 'key "speed": expected a number > 0'),
])
def test_bad_fleet_files_are_one_clear_error(tmp_path, content, message):
    path = tmp_path / "fleet.json"
    if content is not None:
        path.write_text(content)
    with pytest.raises(A.FleetFileError) as ei:
        A.read_fleet_file(path)
    assert str(path) in str(ei.value) and message in str(ei.value)


def test_a_finished_fleet_is_not_running():
    assert A.fleet_running(_rec(), now_unix_s=1010.0, host="thishost")
    assert not A.fleet_running(_rec(), now_unix_s=1031.0, host="thishost")  # past its end
    done = subprocess.run([PY, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead = _rec(pid=int(done.stdout), end_unix_s=None)
    assert not A.fleet_running(dead, now_unix_s=1010.0, host="thishost")
    assert A.fleet_running(dead, now_unix_s=1010.0, host="otherhost")  # another host's pid: unknown


def test_default_fleet_file_only_without_epoch_and_only_while_running(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    A.write_fleet_file(A.DEFAULT_FLEET_FILE, _rec(end_unix_s=None))
    found = A.find_fleet(_args(), 1010.0, "station")
    assert found is not None and found[1]["epoch_unix_s"] == 1000.0
    assert A.find_fleet(_args(epoch=5.0), 1010.0, "station") is None  # an explicit epoch: no attaching
    A.write_fleet_file(A.DEFAULT_FLEET_FILE, _rec())
    assert A.find_fleet(_args(), 5000.0, "station") is None  # that fleet has ended
    assert "that fleet has ended" in capsys.readouterr().err


# --------------------------------------------------------------------------- run length

def test_duration_is_a_run_length_and_until_an_absolute_time(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no runs/fleet.json here
    day = 86400.0 * 20000
    now = day + 3600.0  # an hour into the UTC day: fleet time 3600 s without --epoch
    args = A.resolve(_args(duration=5.0), now, "station")
    assert args.duration == pytest.approx(3605.0) and args.run_s == 5.0
    args = A.resolve(_args(until=42.0, duration=5.0), now, "station")
    assert args.duration == 42.0 and args.run_s is None
    assert A.resolve(_args(), now, "station").duration is None
    # before the epoch the run starts at the epoch; --start-at later: from there
    assert A.resolve(_args(epoch=now + 10.0, duration=5.0), now, "station").duration == 5.0
    assert A.resolve(_args(epoch=now + 10.0, duration=5.0, start_at=20.0), now, "station").duration == 25.0
    # attached without --duration / --until: the fleet's end; at speed 2, 4 wall s = 8 fleet s
    path = A.write_fleet_file(tmp_path / "f.json", _rec(epoch_unix_s=now - 4.0))
    args = A.resolve(_args(fleet=str(path)), now, "station", _parser())
    assert args.duration == 60.0 and args.speed == 2.0
    args = A.resolve(_args(fleet=str(path), duration=10.0), now, "station", _parser())
    assert args.duration == pytest.approx(18.0)
    assert A.resolve(args, now + 100.0, "station").duration == pytest.approx(18.0)  # idempotent


# --------------------------------------------------------------------------- a joiner from outside

def test_joiner_outside_the_scenario_sits_where_the_scenario_joiners_do():
    from net import scenario as S
    from stations.node import with_joiner

    base = S.load("seed000")
    ref = S.load("seed000-join")  # the same ten stations plus station 11 as a scenario joiner
    scn = with_joiner(base, 11)
    assert scn.ids == list(range(1, 12)) and scn.join_ids == [11]
    np.testing.assert_allclose(scn.pos_m, ref.pos_m, atol=1e-9)
    twelve = with_joiner(base, 12)
    assert 11 not in twelve.ids and np.linalg.norm(twelve.true_pos(12) - scn.true_pos(11)) > 100.0


def test_joiner_of_a_listed_scenario_is_drawn_inside_it_and_peers_agree():
    from net import scenario as S
    from net.scenario import WorldPositions, joiner_position
    from stations.node import with_joiner

    scn = S.from_dict({"name": "listed", "seed": 5, "stations": [
        {"id": 1, "pos_m": [0, 0, 0]}, {"id": 2, "pos_m": [900, 0, 10]}, {"id": 3, "pos_m": [0, 900, 20]}]})
    p7 = with_joiner(scn, 7).true_pos(7)
    lo, hi = scn.pos_m.min(axis=0), scn.pos_m.max(axis=0)
    assert np.all(p7 >= lo) and np.all(p7 <= hi)
    assert min(np.hypot(*(p7[:2] - q[:2])) for q in scn.pos_m) >= 100.0
    assert np.linalg.norm(joiner_position(scn, 8) - p7) > 1.0  # another id, another place
    # the receive side (a peer that only knows the scenario) looks the joiner up at the same place
    world = WorldPositions({i: scn.true_pos(i) for i in scn.ids}, scn)
    np.testing.assert_array_equal(world.get(7), p7)
    np.testing.assert_array_equal(world.get(2), scn.true_pos(2))
    assert world.get(70000) is None  # not a station id


def test_station_cli_errors_are_one_line_exit_2(tmp_path):
    def run(*argv):
        return subprocess.run([PY, "-m", "larns", "station", *argv, "--quiet"], capture_output=True, text=True,
                              cwd=tmp_path, timeout=60)

    r = run("--id", "70000", "--join", "--duration", "1")
    assert r.returncode == 2 and "--id 70000: expected a station id in 1..65535" in r.stderr
    assert "Traceback" not in r.stderr
    (tmp_path / "bad.json").write_text("{}")
    r = run("--id", "11", "--join", "--fleet", "bad.json")
    assert r.returncode == 2 and "bad.json: not a fleet file" in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


# --------------------------------------------------------------------------- help

def _commands() -> list[str]:
    from larns.cli import COMMANDS

    return [m.rsplit(".", 1)[1] for m in COMMANDS]


@pytest.mark.parametrize("command", _commands())
def test_every_command_help_has_an_example(command):
    from larns.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    text = sub.choices[command].format_help()
    assert re.search(r"^examples?:", text, re.M | re.I), f"larns {command} --help has no example section"
    assert f"larns {command}" in text.split("xample", 1)[1], f"larns {command} --help: no example command line"


# --------------------------------------------------------------------------- real processes

def readme_hot_join_line() -> str:
    """The README's hot-join command line, verbatim (without its comment)."""
    lines = [ln for ln in (ROOT / "README.md").read_text().splitlines()
             if ln.startswith("./dev larns station") and "--join" in ln]
    assert len(lines) == 1, lines
    return lines[0].split("#", 1)[0].strip()


def _larns(line: str) -> list[str]:
    """``./dev larns ARGS`` as run by this interpreter (``./dev`` is the venv's ``larns``)."""
    argv = shlex.split(line)
    assert argv[:2] == ["./dev", "larns"], argv
    return [PY, "-m", "larns", *argv[2:]]


@pytest.fixture
def procs():
    started: list[subprocess.Popen] = []
    yield started
    for p in started:  # SIGINT first: the fleet stops its children
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    for p in started:
        try:
            p.wait(20)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(10)


@pytest.mark.e2e
def test_readme_hot_join_attaches_to_a_running_fleet(tmp_path, procs):
    """``./dev demo`` (here 40 fleet s at speed 2) in one terminal, the README's line in another."""
    fleet = subprocess.Popen([PY, "-m", "larns", "fleet", "--scenario", "seed000", "--duration", "40", "--speed", "2",
                              "--record", "runs/demo.mcap", "--no-table"], cwd=tmp_path,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    procs.append(fleet)
    ffile = tmp_path / "runs" / "fleet.json"
    t0 = time.time()
    while not ffile.exists() and time.time() - t0 < 30:
        time.sleep(0.2)
    rec = A.read_fleet_file(ffile)
    assert rec["scenario"] == "seed000" and rec["speed"] == 2.0 and rec["duration_s"] == 40.0
    assert len(rec["endpoints"]) == 10 and rec["connect"] == [rec["endpoints"]["station 1"], rec["endpoints"]["station 2"]]
    assert rec["secure"] is None and Path(rec["recording"]) == (tmp_path / "runs" / "demo.mcap").resolve()
    station = subprocess.Popen(_larns(readme_hot_join_line()), cwd=tmp_path, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    procs.append(station)
    time.sleep(max(0.0, rec["epoch_unix_s"] + 20.0 / 2.0 - time.time()))  # fleet time 20 s
    mon = subprocess.run([PY, "-m", "larns", "monitor", "--once", "--refresh", "3"], cwd=tmp_path,
                         capture_output=True, text=True, timeout=60)
    _, s_err = station.communicate(timeout=rec["end_unix_s"] - time.time() + 30)  # stops with the fleet
    f_out, f_err = fleet.communicate(timeout=60)
    assert station.returncode == 0, s_err
    assert "attaching to the fleet of runs/fleet.json" in s_err, s_err
    assert re.search(r"state=surveying slot=\d+", s_err), s_err
    stopped = re.search(r"\[station 11\] stopped: updates=(\d+)", s_err)
    assert stopped and int(stopped.group(1)) >= 5, s_err
    assert "fleet file runs/fleet.json" in f_err and fleet.returncode == 0, f_err
    assert re.search(r"^\s+11 surveying", f_out, re.M), f_out  # the fleet's final table
    assert mon.returncode == 0 and re.search(r"^\s+11 +(joining|surveying)", mon.stdout, re.M), mon.stdout + mon.stderr
    assert "processes alive:" in mon.stdout
    # the recording: station 11 surveyed itself from completed exchanges, within a few metres
    from larns.analysis.summary import mcap_station_summary

    s11 = mcap_station_summary(tmp_path / "runs" / "demo.mcap")[11]
    assert s11["state"] == "surveying" and s11["n_updates"][-1] >= 5 and s11["err_m"] < 15.0, s11["err_m"]


@pytest.mark.e2e
@pytest.mark.parametrize("command, span_s", [(["station", "--id", "3"], 3.5), (["aircraft"], 1.0), (["vehicle"], 1.0)])
def test_duration_means_seconds_of_run(tmp_path, command, span_s):
    """Without --epoch (start of the UTC day) ``--duration 5`` used to be fleet time 5 s: an instant exit.
    The station counts the 5 s from its power-on (its status lines span them); the aircraft and the
    vehicle from the command's start (their start-up, 1-3 s on a loaded machine, included)."""
    t0 = time.time()
    r = subprocess.run([PY, "-m", "larns", *command, "--duration", "5", "--status-every", "1"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=60)
    wall = time.time() - t0
    assert r.returncode == 0, r.stderr
    assert 5.0 <= wall < 30.0, wall
    ts = [float(t) for t in re.findall(r"\] t=\s*([\d.]+)s", r.stderr)]
    assert len(ts) >= 2 and ts[-1] - ts[0] >= span_s, r.stderr  # status lines across the run


def test_fleet_plans_a_joiner_from_outside_the_scenario(tmp_path):
    from larns.cli import build_parser
    from larns.fleet.plan import plan_fleet

    args = build_parser().parse_args(["fleet", "--scenario", "seed000", "--duration", "60", "--join", "11@20",
                                      "--logs", str(tmp_path)])
    p = plan_fleet(args)
    assert p.scn.ids == list(range(1, 12)) and p.joins == [(11, 20.0)] and 11 not in p.initial
    child = next(c for c in p.children if c.name == "station 11")
    assert child.cmd[child.cmd.index("--start-at") + 1] == "20.0" and "--join" in child.cmd
    assert child.cmd[child.cmd.index("--until") + 1] == "60.0" and "--duration" not in child.cmd
    assert "station 11" in p.endpoints
    args = build_parser().parse_args(["fleet", "--duration", "60", "--join", "70000@20", "--logs", str(tmp_path)])
    with pytest.raises(SystemExit) as ei:
        plan_fleet(args)
    assert ei.value.code == 2


def test_monitor_and_record_refuse_a_missing_fleet_in_one_line(tmp_path):
    def run(*argv):
        return subprocess.run([PY, "-m", "larns", *argv], capture_output=True, text=True, cwd=tmp_path, timeout=60)

    r = run("monitor")
    assert r.returncode == 2 and r.stderr.startswith("larns monitor: no fleet to watch") and "Traceback" not in r.stderr
    r = run("monitor", "--fleet", "nowhere.json")
    assert r.returncode == 2 and "nowhere.json: no such fleet file" in r.stderr and "Traceback" not in r.stderr
    r = run("record", "-o", "x.mcap", "--fleet", "nowhere.json")
    assert r.returncode == 2 and "nowhere.json: no such fleet file" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "x.mcap").exists()
