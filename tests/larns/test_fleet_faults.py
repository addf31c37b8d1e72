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
    p.write_text(random_world("faults", 7) + leave)
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


@pytest.mark.e2e
@pytest.mark.slow
def test_fleet_kill_restart_and_leave_from_mcap(tmp_path):
    """Seven stations at speed 5 (0.5 s cycles, 50 ms slots), 60 fleet s: station 1 SIGKILLed at 15 s
    and restarted at 30 s, station 5 leaving (SIGTERM, scenario ``[[faults]]``) at 25 s."""
    scn = _scenario(tmp_path, "\n[[faults]]\nkind = \"leave\"\nstation = 5\nat_s = 25.0\n")
    out = tmp_path / "run.mcap"
    try:
        r = subprocess.run([PY, "-m", "larns", "fleet", "--scenario", scn, "--duration", "60", "--speed", str(SPEED),
                            "--record", str(out), "--no-table", "--kill", "1@15", "--restart", "1@30"],
                           capture_output=True, text=True, timeout=240)
    finally:
        for pid in _pids(scn):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
    log = r.stdout + r.stderr
    assert r.returncode == 0, log[-3000:]
    assert "station 1 killed (SIGKILL)" in log and "station 5 leaves (SIGTERM)" in log, log[-3000:]
    assert "station 1 restarted" in log, log[-3000:]

    summ = mcap_station_summary(out)
    t1 = summ[1]["t_s"]
    assert t1.min() < 10.0 and np.any((t1 > 12.0) & (t1 <= 15.5))  # first life
    assert not np.any((t1 > 16.0) & (t1 < 30.0)), t1[(t1 > 16.0) & (t1 < 30.0)]  # dead
    assert t1.max() > 55.0  # second life to the end
    assert 24.0 < summ[5]["t_s"].max() <= 26.0  # left at 25 s
    for sid in (2, 3, 4, 6, 7):  # the survivors kept estimating to the end
        assert summ[sid]["t_s"].max() > 55.0, sid
        assert summ[sid]["err_m"] < 4.0 * summ[sid]["sigma_m"] + 0.5, (sid, summ[sid]["err_m"], summ[sid]["sigma_m"])
    # the restarted station 1 is an ordinary station: free in x, y, z, back at its true position
    k = t1 > 30.0
    assert np.all(np.diag(summ[1]["cov_m2"][-1]) > 0.0) and summ[1]["state"] == "surveying"
    assert summ[1]["err_m"] < 4.0 * summ[1]["sigma_m"] + 0.5, (summ[1]["err_m"], summ[1]["sigma_m"])
    assert k.sum() >= 40
    # and it has network time from the others (station 1's clock is gone): its sync error against
    # the ensemble truth once it is back
    rec = load([out])
    clk = rec.stations[1].clock()
    late = clk[clk[:, 0] > 40.0]
    assert len(late) >= 20 and np.abs(late[:, 1]).max() < 5.0, late[:, 1]
    for sid in (2, 3, 4, 6, 7):
        c = rec.stations[sid].clock()
        c = c[c[:, 0] > 20.0]
        assert np.abs(c[:, 1]).max() < 5.0, (sid, np.abs(c[:, 1]).max())
