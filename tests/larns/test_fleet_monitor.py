"""Fleet launcher's live table: built from real wire messages (no Zenoh needed)."""

from __future__ import annotations

import math

import numpy as np

from larns.fleet.monitor import Monitor, format_table
from net import messages as M


def est(sid, pos, var, n, state="surveying", slot=None):
    m = {"kind": "estimate", "src": sid, "seq": n, "stamp_s": 1.0, "t_s": 1.0, "pos_m": pos,
         "cov_m2": np.diag(var), "n_updates": n, "estimator": "dmap", "state": state}
    if slot is not None:
        m["slot"] = slot
    return M.encode(m)


def truth(sid, pos):
    return M.encode({"kind": "truth", "src": sid, "seq": 1, "stamp_s": 1.0, "t_s": 1.0, "pos_m": pos})


def test_table_errors_sigma_and_junk():
    mon = Monitor()
    mon.on_sample("larns/station/1/estimate", est(1, [0, 0, 0], [0, 0, 0], 0, "frame", 0))
    mon.on_sample("larns/station/1/truth", truth(1, [0, 0, 0]))
    mon.on_sample("larns/station/2/estimate", est(2, [3.0, 4.0, 0.0], [1.0, 2.0, 6.0], 7, slot=1))
    mon.on_sample("larns/station/2/truth", truth(2, [0.0, 0.0, 0.0]))
    mon.on_sample("larns/station/3/estimate", b"junk")  # ignored
    views = mon.snapshot()
    assert [v.id for v in views] == [1, 2]
    v2 = views[1]
    assert v2.err_m == 5.0 and v2.sigma_m == 3.0 and v2.slot == 1 and v2.n_updates == 7
    txt = format_table(views, 12.0, 3)
    assert "fleet time    12.0 s" in txt and "processes alive: 3" in txt
    assert "RMS error of surveying stations: 5.00 m" in txt


def test_aircraft_error_uses_truth_nearest_in_time():
    mon = Monitor()
    for t in (1.0, 2.0, 3.0):
        mon.on_sample("larns/aircraft/ac1/truth", M.encode(
            {"kind": "ac_truth", "src": "ac1", "seq": int(t), "stamp_s": t, "t_s": t, "pos_m": [100 * t, 0, 0]}))
    mon.on_sample("larns/aircraft/ac1/estimate/ekf", M.encode(
        {"kind": "ac_estimate", "src": "ac1", "seq": 1, "stamp_s": 2.0, "t_s": 2.0, "pos_m": [203.0, 4.0, 0.0],
         "cov_m2": np.eye(3), "algo": "ekf"}))
    (line,) = mon.aircraft_lines()
    assert "ekf" in line and "error    5.00 m" in line and f"sigma {math.sqrt(3):7.2f} m" in line
