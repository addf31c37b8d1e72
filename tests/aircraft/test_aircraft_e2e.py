"""End-to-end: station processes + the aircraft process over real Zenoh on loopback, recorded to MCAP.

The aircraft's estimates and truth are read back from the MCAP file of the session's shared fleet run
(``fleet_run`` in tests/conftest.py); the final errors must be consistent with the estimators' own
covariances.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

pytestmark = pytest.mark.e2e



def test_aircraft_process_in_a_fleet_from_mcap(fleet_run):
    """The shared recorded fleet (tests/conftest.py ``fleet_run``: 5 stations, the aircraft hovering
    1.5 km out at 300 m with ukf-pr, ekf-tdoa and lsq-pr, the vehicle; 30 fleet s at speed 2)."""
    from mcap.reader import make_reader

    from net import messages as M

    out, js = fleet_run.rec, fleet_run.js
    assert fleet_run.rc == 0, fleet_run.log[-3000:]
    rep = json.loads(js.read_text())
    assert all(v == 0 for v in rep["exit_codes"].values()), rep["exit_codes"]
    est: dict[str, list[dict]] = {}
    truth = []
    statuses: dict[str, list[str]] = {}
    with open(out, "rb") as f:
        for _s, ch, m in make_reader(f).iter_messages():
            if not ch.topic.startswith("larns/aircraft/"):
                continue
            msg, phy = M.decode(m.data)
            assert phy is None  # nothing physical leaves the aircraft
            if msg["kind"] == "ac_truth":
                truth.append(msg)
            elif msg["kind"] in ("ac_init", "ac_input"):  # the navigator's journal (docs/replay.md)
                continue
            elif msg["kind"] == "ac_status":  # what a navigator does when it publishes no estimate
                assert ch.topic == f"larns/aircraft/ac1/status/{msg['algo']}"
                statuses.setdefault(msg["algo"], []).append(msg["state"])
            else:
                assert ch.topic == f"larns/aircraft/ac1/estimate/{msg['algo']}"
                est.setdefault(msg["algo"], []).append(msg)
    assert len(truth) > 100
    assert set(est) == {"ukf-pr", "ekf-tdoa", "lsq-pr"}
    assert all(s and s[-1] == "tracking" for s in statuses.values()) and set(statuses) == set(est), statuses
    truth.sort(key=lambda m: m["t_s"])
    tt = np.array([m["t_s"] for m in truth])
    tp = np.array([m["pos_m"] for m in truth])
    assert tt[-1] - tt[0] > 20.0  # the aircraft measured for most of the 30 s run
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
            # within 3 of its own sigma (ekf-tdoa's vertical is weak here: sigma ~ 3.7 / 0.5 / 6.3 m at
            # 30 s, so a fixed 15 m would be a 2-sigma test) and converged from its start over many
            # cycles (issue 29: started from one cycle's 80 m / 145 m snapshot, a filter stalled under
            # the repeat count, honest but 44 m / 99 m wide at 30 s; aircraft/navigator/radio/batch_start.py)
            assert np.linalg.norm(err) < 3.0 * sig + 1.0, (algo, err, sig)
            assert sig < 10.0, (algo, sig, np.linalg.norm(err))
            # integrity (issue 14, aircraft/navigator/radio/fde.py): protection levels on every filter estimate, and no
            # station excluded in a clean fleet
            assert all(m["hpl_m"] > 0 and m["vpl_m"] > 0 for m in ms), algo
            assert all(not m["excluded"] for m in ms), (algo, [m["excluded"] for m in ms if m["excluded"]][:3])
