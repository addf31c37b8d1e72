"""End-to-end: station processes + the aircraft process over real Zenoh on loopback, recorded to MCAP.

The aircraft's estimates and truth are read back from the MCAP file; the final errors must be
consistent with the estimators' own covariances. A malformed payload on a nav key is counted and
dropped, never a crash (the aircraft exits 0 and still reports).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scenario_text import aircraft_hover, five_stations

pytestmark = pytest.mark.e2e

PY = sys.executable


def scenario(tmp_path: Path) -> Path:
    p = tmp_path / "ac_e2e.toml"
    p.write_text(five_stations("ac_e2e", 2, extra=aircraft_hover(["ukf-pr", "ekf-tdoa", "lsq-pr"])))
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
            # integrity (issue 14, aircraft/fde.py): protection levels on every filter estimate, and no
            # station excluded in a clean fleet
            assert all(m["hpl_m"] > 0 and m["vpl_m"] > 0 for m in ms), algo
            assert all(not m["excluded"] for m in ms), (algo, [m["excluded"] for m in ms if m["excluded"]][:3])
