"""The live triad core (aircraft/triad_core.py): messages in, estimates out, no Zenoh; its offline
re-flight from its journal (larns/analysis/offline.py ``reestimate_aircraft``) reproduces them bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from aircraft.events import to_msgs


def _fly(n_sv: int, seconds: float, loop_step_s: float, seed: int = 5):
    """Drive a core with TDMA nav broadcasts of seed003-text (stations' estimates = truth + 5 cm) and
    a node-like loop integrating behind fleet time; returns (core, recorded Msgs, estimates)."""
    from aircraft.config import from_scenario
    from aircraft.triad_core import TriadAircraftCore
    from larns.log import Msg
    from net import messages as M
    from net.scenario import load

    sc = load("seed003-text")
    ac = from_scenario(sc)
    core = TriadAircraftCore(sc, ac, "ac1", n_sv=n_sv, seed=seed)
    rng = np.random.default_rng(2)
    msgs, est, seq = [], [], {}
    t_loop = 0.0
    for k in range(int(seconds / sc.tdma.slot_s)):
        t = k * sc.tdma.slot_s
        j = k % 8
        while t_loop + loop_step_s < t - core.lag_s:
            t_loop += loop_step_s
            core.advance_to(t_loop)
        seq[j] = seq.get(j, 0) + 1
        msg = {"kind": "nav", "src": j + 1, "seq": seq[j], "stamp_s": t, "cycle": seq[j], "slot": j, "t_tx_s": t,
               "pos_m": (sc.pos_m[j] + rng.normal(0, 0.05, 3)).tolist(), "cov_m2": (0.05**2 * np.eye(3)).tolist(),
               "n_updates": 1, "state": "frame", "ranges": [], "members": []}
        phy = {"pos_m": sc.pos_m[j].tolist(), "t_true_s": t}
        ns = int(t * 1e9)
        msgs.append(Msg(M.key_for(msg), ns, ns, k, M.encode(msg, phy)))
        for o in to_msgs(core.on_nav(msg, phy) + core.journal.take()):
            M.validate_msg(o)
            msgs.append(Msg(M.key_for(o), ns, ns, o["seq"], M.encode(o)))
            if o["kind"] == "ac_estimate":
                est.append(o)
    return core, msgs, est


def test_triad_core_flies_and_refly_is_bit_exact():
    from larns.log import Msg
    from net import messages as M
    from larns.analysis.offline import reestimate_aircraft

    core, msgs, est = _fly(4, 30.0, 0.37)
    assert core.stats["nav_before_start"] > 0  # the start window (full-sky fix) drops the first broadcasts
    assert core.stats["sat_used"] == 4 * 20  # epochs 11..30 s (the last broadcast at 29.9 s reaches 30 s)
    assert len(est) == core.stats["measurements"] > 150
    assert all(e["algo"] == "triad" and e["extra"]["n_sv"] == 4 for e in est)
    # the filter's own 3-sigma holds at the end (one seeded run; the 60 s live run is in docs/triad.md)
    e = est[-1]
    d = np.asarray(e["pos_m"]) - core.truth_n(e["t_s"])[0]
    assert d @ np.linalg.solve(np.asarray(e["cov_m2"]), d) < 3.0**2 * 3
    msgs += [Msg(M.key_for(o), msgs[-1].log_time, msgs[-1].log_time, o["seq"], M.encode(o)) for o in to_msgs(core.journal.close())]
    res = reestimate_aircraft(msgs)["ac1"]["triad"]
    assert res["missing_from"] is None and res["stopped"] is None
    assert res["n"] == res["recorded"] == res["compared"] == res["equal"] == len(est)
    assert res["rerun"]["rms_err_m"] < 5.0


def test_triad_fewer_satellites_and_bad_options():
    from aircraft.config import from_scenario
    from aircraft.triad_core import TriadAircraftCore
    from net.scenario import load

    core, _msgs, est = _fly(0, 15.0, 0.05)  # stations + baro only after the start
    assert core.stats["sat_used"] == 0 and est
    sc = load("seed003-text")
    with pytest.raises(ValueError, match="above the mask"):
        TriadAircraftCore(sc, from_scenario(sc), "ac1", n_sv=40)


@pytest.mark.slow
@pytest.mark.e2e
def test_triad_live_fleet_recorded_and_reflown(tmp_path):
    """A real fleet (seed003-text stations over Zenoh, the triad aircraft with 2 satellites, the
    recorder): the recorded triad estimates are re-flown offline bit for bit (~40 s)."""
    import re
    import subprocess
    import sys
    from pathlib import Path

    from larns.analysis.offline import reestimate_aircraft
    from larns.log import read_logs

    text = (Path(__file__).parents[2] / "net" / "scenarios" / "seed003-text.toml").read_text()
    text = re.sub(r'^algos = \["ins-ekf"\].*$', 'algos = ["triad"]\nsatellites = 2', text, flags=re.M)
    text = re.sub(r'^imu = .*\n', "", text, flags=re.M)
    scn = tmp_path / "triad_live.toml"
    scn.write_text(text)
    rec = tmp_path / "triad.mcap"
    r = subprocess.run([sys.executable, "-m", "larns", "fleet", "--scenario", str(scn), "--duration", "25",
                        "--aircraft", "--record", str(rec), "--no-table"], capture_output=True, text=True, timeout=180)
    assert r.returncode == 0, r.stderr[-3000:]
    logs = read_logs([rec])
    msgs = [m for lf in logs for m in lf.messages]
    res = reestimate_aircraft(msgs)["ac1"]["triad"]
    assert res["recorded"] > 50
    assert res["equal"] == res["compared"] == res["recorded"]
    assert res["rerun"]["rms_err_m"] < 10.0
