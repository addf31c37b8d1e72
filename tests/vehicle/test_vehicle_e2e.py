"""The vehicle process in a real fleet: 5 station processes + ``larns vehicle`` + the recorder over
real Zenoh on loopback (``larns fleet --vehicle``; the session's shared fleet run, ``fleet_run`` in
tests/conftest.py), the MCAP read back through :mod:`larns.log.series`,
the vehicle's navigator re-run offline from its recorded journal (``larns reestimate``)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

pytestmark = pytest.mark.e2e

PY = sys.executable


@pytest.fixture(scope="module")
def recording(fleet_run):
    """The shared recorded fleet (tests/conftest.py ``fleet_run``: 5 stations, the aircraft, the
    vehicle on its default route through the field; 30 fleet s at speed 2)."""
    assert fleet_run.rc == 0, fleet_run.log[-3000:]
    assert "vehicle    veh1  cdekf-map" in fleet_run.log, fleet_run.log[-2000:]
    return fleet_run.rec


def test_vehicle_recorded_error_bounded_and_offline_bit_exact(recording):
    from larns.analysis.offline import JOURNAL_TOPICS, reestimate_vehicles
    from larns.analysis.summary import vehicle_row
    from larns.log import merge, read_logs
    from larns.log.series import load

    rec = load([recording])
    v = rec.vehicles["veh1"]
    e = v.errors()
    # the stations broadcast 20 navs per fleet second once surveying; on a loaded machine
    # they start late (a run under load 10 gave 157 navs in 24 s): ask for a fraction
    assert e["err_m"].size > 60 and e["updated"].sum() > 50, vehicle_row(v)
    assert v.init is not None and 1 in v.inputs
    # the route passes 0.5 - 3 km from the stations; the stations survey themselves from 5 m during
    # the run and the vehicle sees their broadcast (estimated) positions: metres, not kilometres
    half = e["err_m"][e["err_m"].size // 2:]
    assert np.sqrt(np.mean(half**2)) < 8.0, vehicle_row(v)
    # the truth moves along the route at 5 m/s
    tt = sorted(v.truths)
    d = np.linalg.norm(np.subtract(v.truths[tt[-1]]["pos_m"], v.truths[tt[0]]["pos_m"])) / (tt[-1] - tt[0])
    assert d == pytest.approx(5.0, rel=0.02)
    # offline: the navigator re-run from the journal reproduces every recorded estimate exactly
    # (what `larns reestimate` runs for the vehicles; only the vehicle's channels are read)
    logs = read_logs([recording], topics=[t for t in JOURNAL_TOPICS if t.startswith("larns/vehicle/")])
    r = reestimate_vehicles(merge(logs), logs[0].epoch_unix_s, logs[0].speed)["veh1"]
    assert r["error"] is None and r["missing_from"] is None, r
    # (the recorder may drop estimates under load; the last ones depend on the journal message sent at exit)
    assert r["compared"] >= 0.8 * len(v.estimates) and r["equal"] == r["compared"] > 50, r
    assert r["rms_err_m"] == pytest.approx(vehicle_row(v)["rms_err_m"], rel=0.05)


def test_info_shows_the_vehicle(recording):
    r = subprocess.run([PY, "-m", "larns", "info", str(recording)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "Vehicle veh1:" in r.stdout and "position error RMS" in r.stdout
    assert "larns/vehicle/veh1/input" in r.stdout
