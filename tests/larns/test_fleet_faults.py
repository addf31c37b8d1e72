"""Founders' faults with real processes (issue 30 item 3): ``larns fleet --kill ID@T`` (SIGKILL),
``--restart ID@T`` (a fresh process with the same id, joining the running field) and a scenario's
``[[faults]] leave`` (SIGTERM), checked from the MCAP recording alone."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from larns.analysis.summary import mcap_station_summary
from larns.log.series import load
from scenario_text import random_world

PY = sys.executable
SPEED = 5.0


def _scenario(tmp_path, leave: str = "") -> str:
    p = tmp_path / "faults.toml"
    text = random_world("faults", 7).replace("ranges_per_update = 3\n", 'ranges_per_update = 3\ndatum = "field"\n')
    p.write_text(text + leave)  # the field carries the datum: the founders may go
    return str(p)


def test_kill_and_restart_arguments_are_checked(tmp_path):
    """A bad ``ID@T`` or a restart of a station that is not down: one line, exit code 2, nothing run."""
    scn = _scenario(tmp_path)
    for bad, why in ((["--kill", "9@10"], "station 9 is not in the fleet"),
                     (["--kill", "1at10"], "expected ID@T"),
                     (["--restart", "2@20"], "station 2 is not down then")):
        r = subprocess.run([PY, "-m", "larns", "fleet", "--scenario", scn, "--duration", "30", "--no-table",
                            "--logs", str(tmp_path / "logs"), *bad], capture_output=True, text=True, timeout=60)
        assert r.returncode == 2, (bad, r.stderr)
        assert why in r.stderr and "Traceback" not in r.stderr, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1, r.stderr


def _pids(tag: str) -> list[int]:
    out = subprocess.run(["ps", "-ww", "-eo", "pid=,args="], capture_output=True, text=True).stdout
    return [int(line.split()[0]) for line in out.splitlines() if tag in line and "stations" in line]


@pytest.fixture(scope="module")
def faults_run(tmp_path_factory):
    """Seven stations at speed 5 (0.5 s cycles, 50 ms slots), 75 fleet s: station 1 SIGKILLed at 30 s
    and restarted at 45 s, station 5 leaving (SIGTERM, scenario ``[[faults]]``) at 40 s (not earlier: at
    speed 5 on a loaded machine the processes were seen to start publishing some 4 wall s late)."""
    tmp_path = tmp_path_factory.mktemp("faults")
    scn = _scenario(tmp_path, "\n[[faults]]\nkind = \"leave\"\nstation = 5\nat_s = 40.0\n")
    out = tmp_path / "run.mcap"
    try:
        r = subprocess.run([PY, "-m", "larns", "fleet", "--scenario", scn, "--duration", "75", "--speed", str(SPEED),
                            "--record", str(out), "--no-table", "--kill", "1@30", "--restart", "1@45"],
                           capture_output=True, text=True, timeout=240)
    finally:
        for pid in _pids(scn):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
    return r, out


@pytest.mark.e2e
@pytest.mark.slow
def test_fleet_kill_restart_and_leave_from_mcap(faults_run):
    r, out = faults_run
    log = r.stdout + r.stderr
    assert r.returncode == 0, log[-3000:]
    assert "station 1 killed (SIGKILL)" in log and "station 5 leaves (SIGTERM)" in log, log[-3000:]
    assert "station 1 restarted" in log, log[-3000:]

    summ = mcap_station_summary(out)
    t1 = summ[1]["t_s"]
    assert t1.min() < 25.0 and np.any((t1 > 27.0) & (t1 <= 30.5))  # first life
    assert not np.any((t1 > 31.0) & (t1 < 45.0)), t1[(t1 > 31.0) & (t1 < 45.0)]  # dead
    assert t1.max() > 70.0 and (t1 > 45.0).sum() >= 40  # second life to the end
    assert 39.0 < summ[5]["t_s"].max() <= 41.0  # left at 40 s
    for sid in (2, 3, 4, 6, 7):  # the survivors kept estimating to the end
        assert summ[sid]["t_s"].max() > 70.0, sid
    # the restarted station 1 is an ordinary station, free in x, y, z
    assert np.all(np.diag(summ[1]["cov_m2"][-1]) > 0.0) and summ[1]["state"] == "surveying"
    # and it has network time from the others (station 1's clock is gone): its sync error against
    # the ensemble truth once it is back
    rec = load([out])
    clk = rec.stations[1].clock()
    late = clk[clk[:, 0] > 55.0]
    assert len(late) >= 20 and np.abs(late[:, 1]).max() < 5.0, late[:, 1]
    for sid in (2, 3, 4, 6, 7):
        c = rec.stations[sid].clock()
        c = c[c[:, 0] > 20.0]
        assert np.abs(c[:, 1]).max() < 5.0, (sid, np.abs(c[:, 1]).max())


@pytest.mark.e2e
@pytest.mark.slow
def test_fleet_faults_survivors_and_restarted_station_within_4_sigma(faults_run):
    """(An xfail until 2026-11-30: in the datum mode a height could end metres off under a sigma
    capped near 1 m; the datum mode now keeps the prior instead, docs/survey.md "Heights in the datum
    mode"; passed 3 of 3 runs that day.)"""
    _, out = faults_run
    summ = mcap_station_summary(out)
    for sid in (1, 2, 3, 4, 6, 7):
        s = summ[sid]
        assert s["err_m"] < 4.0 * s["sigma_m"] + 0.5, (sid, s["err_m"], s["sigma_m"])
