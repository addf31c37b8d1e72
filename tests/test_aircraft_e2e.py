"""End-to-end: station processes + the aircraft process over real Zenoh on loopback, recorded to MCAP.

The aircraft's estimates and truth are read back from the MCAP file; the final errors must be
consistent with the estimators' own covariances. A malformed payload on a nav key is counted and
dropped, never a crash (the aircraft exits 0 and still reports).
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.e2e

PY = sys.executable


def scenario(tmp_path: Path) -> Path:
    p = tmp_path / "ac_e2e.toml"
    p.write_text(textwrap.dedent("""
        name = "ac_e2e"
        seed = 2
        [frame]
        z_ref = 4
        [[stations]]
        id = 1
        pos_m = [0.0, 0.0, 0.0]
        [[stations]]
        id = 2
        pos_m = [1800.0, 0.0, 5.0]
        [[stations]]
        id = 3
        pos_m = [900.0, 1500.0, 0.0]
        [[stations]]
        id = 4
        pos_m = [800.0, 500.0, 60.0]
        [[stations]]
        id = 5
        pos_m = [300.0, 1200.0, 20.0]
        [tdma]
        cycle_s = 0.25
        slot_s = 0.05
        [channel]
        sigma_d_m = 0.5
        [init]
        sigma0_m = 5.0
        [survey]
        estimator = "dmap"
        [aircraft]
        name = "ac1"
        algos = ["ukf-pr", "ekf-tdoa", "lsq-pr"]
        sigma_m = 0.5
        init_sigma_m = 30.0
        [aircraft.trajectory]
        kind = "hover"
        distance_m = 1500.0
        height_m = 300.0
        [aircraft.tuning]
        q_acc = 1.0
        p0_pos_m = 30.0
    """))
    return p


def test_aircraft_process_in_a_fleet_from_mcap(tmp_path):
    from mcap.reader import make_reader

    from net import messages as M

    scn = scenario(tmp_path)
    out = tmp_path / "ac.mcap"
    js = tmp_path / "fleet.json"
    r = subprocess.run([PY, "-m", "larns", "fleet", "--scenario", str(scn), "--duration", "45", "--speed", "3",
                        "--aircraft", "--record", str(out), "--no-table", "--json", str(js)],
                       capture_output=True, text=True, timeout=180)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    rep = json.loads(js.read_text())
    assert all(v == 0 for v in rep["exit_codes"].values()), rep["exit_codes"]
    est: dict[str, list[dict]] = {}
    truth = []
    with open(out, "rb") as f:
        for _s, ch, m in make_reader(f).iter_messages():
            if not ch.topic.startswith("larns/aircraft/"):
                continue
            msg, phy = M.decode(m.data)
            assert phy is None  # nothing physical leaves the aircraft
            if msg["kind"] == "ac_truth":
                truth.append(msg)
            else:
                assert ch.topic == f"larns/aircraft/ac1/estimate/{msg['algo']}"
                est.setdefault(msg["algo"], []).append(msg)
    assert len(truth) > 100
    assert set(est) == {"ukf-pr", "ekf-tdoa", "lsq-pr"}
    truth.sort(key=lambda m: m["t_s"])
    tt = np.array([m["t_s"] for m in truth])
    tp = np.array([m["pos_m"] for m in truth])
    assert tt[-1] - tt[0] > 30.0  # the aircraft measured for most of the 45 s run
    for algo, ms in est.items():
        assert len(ms) > 20, algo
        last = ms[-1]
        p = tp[np.argmin(np.abs(tt - last["t_s"]))]
        err = np.asarray(last["pos_m"]) - p
        C = np.asarray(last["cov_m2"])
        sig = np.sqrt(np.trace(C))
        # consistent with its own covariance (3D, generous 4 sigma) and far better than the 30 m start
        assert np.linalg.norm(err) <= 4.0 * sig + 1.0, (algo, err, sig)
        if algo != "lsq-pr":
            assert np.linalg.norm(err) < 15.0, (algo, err)
