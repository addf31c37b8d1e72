"""Issue 14: exclusions in the recording model (larns.log.series), `larns report` and the live table,
on a constructed recording (station integrity messages; ac_estimate with and without the optional
hpl_m / vpl_m / excluded fields)."""

from __future__ import annotations

import numpy as np

from larns.analysis.summary import summarize
from larns.fleet.monitor import Monitor, format_table
from larns.log import LogWriter
from larns.log.series import load
from larns.viz.report import _integrity_md, extract, integrity_numbers
from net import messages as M

T0 = 1_800_000_000 * 10**9


def _msgs():
    out = [(5.0, {"kind": "estimate", "src": 6, "seq": 1, "stamp_s": 5.0, "t_s": 5.0, "pos_m": [1.0, 2.0, 3.0],
                  "cov_m2": np.eye(3).tolist(), "n_updates": 3, "estimator": "dmap", "state": "surveying"})]
    for sid in (3, 4):
        out.append((21.0, {"kind": "integrity", "src": sid, "seq": 1, "stamp_s": 21.0, "t_s": 21.0, "suspect": 6,
                           "statistic": 99.0, "threshold": 15.1, "dof": 1, "p_fa": 1e-4, "decision": "exclude",
                           "excluded": [6]}))
    for k, t in enumerate([1.0, 2.0, 3.0, 4.0]):
        out.append((t, {"kind": "ac_truth", "src": "ac1", "seq": k + 1, "stamp_s": t, "t_s": t,
                        "pos_m": [100.0 * t, 0.0, 1000.0]}))
        est = {"kind": "ac_estimate", "src": "ac1", "seq": k + 1, "stamp_s": t, "t_s": t,
               "pos_m": [100.0 * t + (5.0 if t == 4.0 else 1.0), 0.0, 1000.0], "cov_m2": np.eye(3).tolist(),
               "algo": "ekf-pr"}
        if k > 0:  # the first estimate is an older one: no integrity fields
            est.update(hpl_m=3.7, vpl_m=3.3, excluded=[2] if t >= 3.0 else [])
        out.append((t, est))
    return out


def _write(path):
    with LogWriter(path, {"larns": {"epoch_unix_s": repr(T0 * 1e-9), "speed": "1.0"}}) as w:
        for t, m in _msgs():
            ns = T0 + int(t * 1e9)
            w.write(M.key_for(m), M.encode(m), ns, ns - 1_000_000)
    return path


def test_series_and_report_show_the_exclusions(tmp_path):
    path = _write(tmp_path / "rec.mcap")
    rec = load([path])
    ig = rec.aircraft["ac1"].integrity("ekf-pr")
    assert ig["t_s"].tolist() == [1.0, 2.0, 3.0, 4.0]
    assert np.isnan(ig["hpl_m"][0]) and ig["hpl_m"][1:].tolist() == [3.7] * 3
    assert ig["excluded"] == [[], [], [2], [2]] and ig["exclusions"] == {2: 3.0}
    assert rec.stations[3].excludes == [6] and rec.stations[4].excludes == [6]
    num = integrity_numbers(extract(rec), summarize([path], rec=rec))
    assert num["stations"] == {6: [3, 4]}
    row = num["aircraft"]["ac1"]["ekf-pr"]
    assert row["exclusions"] == {"2": 3.0} and row["hpl_median_m"] == 3.7
    assert row["hpl_exceed"] == 1 and row["hpl_samples"] == 3  # the 5 m error at t = 4 s exceeds 3.7 m
    md = "\n".join(_integrity_md(num))
    assert "station 6 EXCLUDED by 3,4" in md and "| ac1 | ekf-pr | 2 (3.0) | 3.70 | 3.30 | 1/3 |" in md


def test_live_table_shows_the_exclusions():
    mon = Monitor()
    for t, m in _msgs():
        mon.on_sample(M.key_for(m), M.encode(m))
    txt = format_table(mon.snapshot(), 22.0)
    assert "station 6 EXCLUDED by 3,4" in txt
    (line,) = mon.aircraft_lines()
    assert "HPL    3.70 m" in line and "VPL    3.30 m" in line and "EXCLUDED 2" in line
