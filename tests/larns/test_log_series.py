"""The recording model (larns.log.series) on constructed MCAP files, and the report's numbers
(larns.analysis.metrics) as pure functions of constructed series (no matplotlib, no Zenoh)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from larns.analysis import metrics as MT
from larns.analysis.summary import mcap_station_summary, summarize
from larns.log import LogWriter, Timebase
from larns.log.series import load, sequence_gaps, sigma_m
from net import messages as M

T0 = 1_800_000_000 * 10**9  # log time of fleet time 0 (epoch 1.8e9 s)


def _est(sid, seq, t, pos, var, clk=None, slot=None):
    m = {"kind": "estimate", "src": sid, "seq": seq, "stamp_s": t, "t_s": t, "pos_m": list(pos),
         "cov_m2": np.diag(var).tolist(), "n_updates": seq, "estimator": "dmap", "state": "surveying"}
    if clk is not None:
        m.update(clock_offset_s=clk, clock_offset_sd_s=1e-9)
    if slot is not None:
        m["slot"] = slot
    return m


def _write(path, msgs, junk_at=None, speed=2.0):
    """msgs: (fleet time s, msg dict); log time = epoch + t / speed, publish 1 ms earlier."""
    with LogWriter(path, {"larns": {"epoch_unix_s": repr(T0 * 1e-9), "speed": repr(speed)}}) as w:
        for i, (t, m) in enumerate(msgs):
            ns = T0 + int(t / speed * 1e9)
            w.write(M.key_for(m), M.encode(m), ns, ns - 1_000_000)
            if junk_at == i:
                w.write("larns/station/9/estimate", b"\x93junk", ns, ns)


def _recording(tmp_path):
    msgs = []
    for k, t in enumerate([1.0, 2.0, 4.0, 5.0]):  # seq 3 of station 2 is lost (sent at t = 3)
        seq = k + 1 if k < 2 else k + 2
        msgs.append((t, _est(2, seq, t, [10.0 + k, 0.0, 0.0], [1.0, 4.0, 4.0], clk=1e-8 * k, slot=5)))
        msgs.append((t, {"kind": "truth", "src": 2, "seq": seq, "stamp_s": t, "t_s": t, "pos_m": [10.0, 0.0, 0.0],
                         "clock_error_s": 0.0}))
    msgs.append((5.5, {"kind": "ac_estimate", "src": "ac1", "seq": 1, "stamp_s": 5.5, "t_s": 5.5,
                       "pos_m": [1.0, 2.0, 3.0], "cov_m2": np.eye(3).tolist(), "algo": "ekf-pr"}))
    path = tmp_path / "rec.mcap"
    _write(path, msgs, junk_at=0)
    return path


def test_series_decodes_stations_aircraft_network_and_time(tmp_path):
    rec = load([_recording(tmp_path)])
    s = rec.stations[2]
    assert len(s.estimates) == 4 and len(s.truths) == 4 and s.slot == 5 and s.truth_m == [10.0, 0.0, 0.0]
    tr = s.track()
    assert tr["t_s"].tolist() == [1.0, 2.0, 4.0, 5.0] and tr["pos_m"][:, 0].tolist() == [10, 11, 12, 13]
    assert np.allclose(s.clock()[:, 1], [0.0, 10.0, 20.0, 30.0]) and np.allclose(s.clock()[:, 2], 1.0)
    assert rec.aircraft["ac1"].algos == ["ekf-pr"]
    loss, tot = rec.net.loss()
    assert loss["estimate"]["missing"] == 1 and loss["truth"]["missing"] == 1 and tot["received"] == 9
    assert rec.net.invalid and sum(rec.net.invalid.values()) == 1
    assert np.allclose(rec.net.latency_ms["estimate"], 1.0)
    # fleet time: epoch + t / speed -> t
    assert rec.timebase.fleet_s(rec.messages[-1].log_time) == pytest.approx(5.5, abs=1e-6)
    info = summarize([], rec=rec)
    assert info["stations"][2]["err_m"] == pytest.approx(3.0) and info["stations"][2]["sigma_m"] == 3.0
    assert info["fleet_start_s"] == pytest.approx(1.0, abs=1e-6) and info["speed"] == 2.0
    fs = mcap_station_summary(rec.logs[0].path)
    assert fs[2]["err_m"] == pytest.approx(3.0) and fs[2]["sigma_m"] == 3.0


def test_killed_recording_reads_up_to_the_damage(tmp_path):
    full = _recording(tmp_path)
    data = full.read_bytes()
    cut = tmp_path / "killed.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    rec = load([cut])
    assert not rec.logs[0].complete
    assert mcap_station_summary(cut) == {} or set(mcap_station_summary(cut)) <= {2}
    # merged with the complete file: every message of both, ordered by log time
    both = load([full, cut])
    assert len(both.messages) == len(load([full]).messages) + len(rec.messages)
    assert all(a.log_time <= b.log_time for a, b in zip(both.messages, both.messages[1:]))


def test_timebase_without_epoch_counts_from_the_first_message():
    tb = Timebase(None, 1.0, t0_ns=5 * 10**9)
    assert tb.fleet_s(7 * 10**9) == 2.0 and Timebase(10.0, 4.0).fleet_s(12 * 10**9) == 8.0


def test_sequence_gaps_and_sigma():
    g = sequence_gaps([3, 4, 6, 6, 5, 9])
    assert g == {"received": 5, "missing": 2, "duplicates": 1, "reordered": 1, "leading": 2}
    assert sigma_m(np.diag([1.0, 4.0, 4.0])) == 3.0
    assert np.allclose(sigma_m(np.stack([np.eye(3), 4 * np.eye(3)])), [math.sqrt(3), math.sqrt(12)])


def test_station_numbers_three_sigma_fraction():
    track = {"t_s": np.arange(4.0), "pos_m": np.array([[1.0, 0, 0], [2.0, 0, 0], [0.5, 0, 0], [4.0, 0, 0]]),
             "cov_m2": np.repeat((np.eye(3) / 3.0)[None], 4, axis=0), "n_updates": np.array([1, 2, 3, 4])}
    n = MT.station_numbers(track, [0.0, 0.0, 0.0])  # bound 3 * sqrt(1) = 3: errors 1, 2, 0.5 in, 4 out
    assert n == {"final_err_m": 4.0, "final_bound3_m": 3.0, "inside_3sigma": 0.75, "n_estimates": 4,
                 "n_updates": 4}
    f = MT.station_numbers(track, [0.0, 0.0, 0.0], frame=True)
    assert f["final_bound3_m"] == 0.0 and math.isnan(f["inside_3sigma"])


def test_convergence_time_is_when_the_mean_stays_below():
    grid = np.arange(6.0)
    assert MT.first_time_staying_below(grid, np.array([5, 0.5, 2, 0.4, 0.3, np.nan]), 1.0) == 3.0
    assert MT.first_time_staying_below(grid, np.array([5, 4, 3, 2, 1.5, 1.2]), 1.0) is None
    tracks = {2: {"t_s": np.array([0.0, 10.0]), "pos_m": np.array([[3.0, 4.0, 9.0], [0.0, 0.0, 0.0]]),
                  "cov_m2": np.repeat(np.eye(3)[None], 2, axis=0)}}
    grid, mean_h, max_h, mean_s = MT.survey_convergence(tracks, {2: np.zeros(3)}, n_grid=3)
    assert grid.tolist() == [0.0, 5.0, 10.0] and mean_h.tolist() == [5.0, 5.0, 0.0]
    assert np.allclose(mean_s, math.sqrt(2.0))


def test_aircraft_pcrb_is_the_nav_pcrb_recursion():
    """With equal steps the report's bound is nav.pcrb's posterior CRLB of the same model."""
    from aircraft.navigator.radio import models as mdl
    from aircraft.navigator.radio.tuning import Tuning
    from nav.pcrb import pcrb_linear_gaussian

    tuning = Tuning()
    dt = 0.01
    t = np.arange(40) * dt
    truth = {"t_s": t, "pos_m": np.stack([100.0 * t, 0 * t, 1000.0 + 0 * t], -1), "vel_m_s": np.zeros((40, 3))}
    senders = np.array([[5000.0, 0, 0], [0, 5000.0, 0], [-5000.0, 0, 0], [0, -5000.0, 0], [0, 0, 100.0]])
    navs = [(float(tk), senders[k % 5]) for k, tk in enumerate(t)]
    ts, bound = MT.aircraft_pcrb(truth, navs, tuning)
    layout = mdl.StateLayout("pr", drift=True)
    n = layout.n
    H = np.stack([mdl.jac_pr(np.r_[truth["pos_m"][k], np.zeros(n - 3)], senders[k % 5][None]) for k in range(40)])
    F = mdl.cv_transition(n, dt)
    Q = mdl.cv_noise(n, dt, tuning.q_acc, tuning.q_clock, tuning.q_drift)
    # the report measures the first broadcast without a prediction: start nav.pcrb one step earlier
    P = pcrb_linear_gaussian(np.linalg.solve(F, np.linalg.solve(F, (tuning.prior_cov(layout) - Q).T).T), F, Q, H,
                             np.full((40, 1, 1), tuning.sigma_m**2))
    ref = np.sqrt(np.trace(P[:, :3, :3], axis1=-2, axis2=-1))
    assert ts.tolist() == t.tolist() and np.allclose(bound, ref, rtol=1e-6)


def test_aircraft_crlb_uses_the_recorded_slots():
    truth = {"t_s": np.linspace(0, 10, 20), "pos_m": np.c_[np.linspace(0, 1000, 20), np.zeros(20), 1000 + np.zeros(20)],
             "vel_m_s": np.tile([100.0, 0.0, 0.0], (20, 1))}
    st = {1: [0.0, 0, 0], 2: [5000.0, 0, 0], 3: [0, 5000.0, 0], 7: [-5000.0, 0, 0], 9: [0, -5000.0, 0]}
    a = MT.aircraft_crlb(truth, st, {1: 0, 2: 1, 3: 2, 7: 3, 9: 4}, (0.05, 0.01), 0.5, n_points=5)
    b = MT.aircraft_crlb(truth, st, {1: 0, 2: 1, 3: 2, 7: 6, 9: 8}, (0.1, 0.01), 0.5, n_points=5)
    assert a[1].shape == (5,) and np.all(np.isfinite(a[1])) and not np.allclose(a[1], b[1])
