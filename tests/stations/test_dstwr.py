"""stations/dstwr.py: one poll answered by N responders, ranged by asymmetric DS-TWR (protocol v2,
issue 31), checked against an exact exchange simulator that stamps with each station's clock."""

from __future__ import annotations

import numpy as np
import pytest

from nav.geometry import SPEED_OF_LIGHT_M_S as C
from stations.dstwr import (ds_twr_range_m, ds_twr_tof_s, in_reply_window, reply_offset_s, ss_twr_tof_s,
                            time_transfer_s)

PPM = 1e-6


def exchange(rng, n, turnaround_s, spacing_s=300e-6, max_ppm=20.0, max_range_m=3000.0, max_offset_s=0.5):
    """One noiseless poll -> n staggered replies -> final, in true time, stamped on each clock
    ``t_local = (1 + f) t_true + offset``. Returns (stamps, truth) as dicts of arrays."""
    fa, fb = rng.uniform(-max_ppm, max_ppm) * PPM, rng.uniform(-max_ppm, max_ppm, n) * PPM
    oa, ob = rng.uniform(-max_offset_s, max_offset_s), rng.uniform(-max_offset_s, max_offset_s, n)
    range_m = rng.uniform(10.0, max_range_m, n)
    tau = range_m / C
    local_a = lambda t: (1 + fa) * t + oa  # noqa: E731
    local_b = lambda t: (1 + fb) * t + ob  # noqa: E731
    true_a = lambda t: (t - oa) / (1 + fa)  # noqa: E731
    true_b = lambda t: (t - ob) / (1 + fb)  # noqa: E731
    t1_true = rng.uniform(0.0, 1.0)
    T1 = local_a(t1_true)
    T2 = local_b(t1_true + tau)
    T3 = T2 + reply_offset_s(np.arange(n), turnaround_s, spacing_s)  # (V1), on the responder's clock
    T4 = local_a(true_b(T3) + tau)
    T5 = T1 + float(reply_offset_s(n, turnaround_s, spacing_s))  # the final: sub-slot N, poller's clock
    T6 = local_b(true_a(T5) + tau)
    stamps = dict(t_poll_tx_s=T1, t_poll_rx_s=T2, t_reply_tx_s=T3, t_reply_rx_s=T4, t_final_tx_s=T5, t_final_rx_s=T6)
    t_mid_true = 0.5 * (t1_true + true_b(T3) + tau)  # true midpoint of poll sent and reply received
    truth = dict(range_m=range_m, tau_s=tau, fa=fa, fb=fb, oa=oa, ob=ob, t1_true=t1_true, t_mid_true=t_mid_true,
                 reply_delay_s=true_b(T3) - true_b(T2))
    return stamps, truth


TURNAROUNDS_S = (100e-6, 1e-3, 3e-3)


@pytest.mark.parametrize("turnaround_s", TURNAROUNDS_S)
def test_ds_twr_is_exact_for_any_offsets_and_drifts_with_the_clocks_own_frequencies(turnaround_s):
    rng = np.random.default_rng(31)
    worst = 0.0
    for _ in range(200):
        s, tr = exchange(rng, 9, turnaround_s)
        r = ds_twr_range_m(**s, freq_poller=tr["fa"], freq_responder=tr["fb"])
        assert r.shape == (9,)
        worst = max(worst, float(np.max(np.abs(r - tr["range_m"]))))
    assert worst < 1e-6, worst


@pytest.mark.parametrize("turnaround_s", TURNAROUNDS_S)
def test_raw_ds_twr_keeps_only_the_harmonic_mean_rate_on_the_time_of_flight(turnaround_s):
    """Frequencies unknown: ToF_raw = ToF 2 ka kb / (ka + kb), eq. (V5), whatever the reply delays."""
    rng = np.random.default_rng(310)
    for _ in range(200):
        s, tr = exchange(rng, 9, turnaround_s)
        ka, kb = 1 + tr["fa"], 1 + tr["fb"]
        tof = ds_twr_tof_s(**s)
        assert np.allclose(tof, tr["tau_s"] * 2 * ka * kb / (ka + kb), rtol=0, atol=1e-6 / C)
        bound = tr["range_m"] * np.maximum(abs(tr["fa"]), np.abs(tr["fb"])) + 1e-6
        assert np.all(np.abs(C * tof - tr["range_m"]) <= bound)


@pytest.mark.parametrize("turnaround_s", TURNAROUNDS_S)
def test_single_sided_drift_error_is_far_larger_than_double_sided(turnaround_s):
    """Raw durations on both (APS011's comparison): SS-TWR's error is (ka - kb) Db / 2 + (ka - 1) ToF,
    DS-TWR's about ToF (fa + fb) / 2 - the reply delay drops out."""
    rng = np.random.default_rng(311)
    err_ss, err_ds = [], []
    for _ in range(200):
        s, tr = exchange(rng, 9, turnaround_s)
        ss = ss_twr_tof_s(s["t_poll_tx_s"], s["t_poll_rx_s"], s["t_reply_tx_s"], s["t_reply_rx_s"])
        ka, kb = 1 + tr["fa"], 1 + tr["fb"]
        predicted = (ka - kb) * tr["reply_delay_s"] / 2 + (ka - 1) * tr["tau_s"]
        assert np.allclose(ss - tr["tau_s"], predicted, rtol=0, atol=1e-6 / C)
        err_ss.append(C * (ss - tr["tau_s"]))
        err_ds.append(C * (ds_twr_tof_s(**s) - tr["tau_s"]))
    rms_ss, rms_ds = (float(np.sqrt(np.mean(np.square(e)))) for e in (err_ss, err_ds))
    # reply delays 0.1-5.4 ms against times of flight up to 10 us: the ratio is about Db / ToF
    assert rms_ss > 50 * rms_ds, (rms_ss, rms_ds)
    assert rms_ds < 0.05  # m: 20 ppm of at most 3 km


def test_with_the_frequencies_single_sided_is_exact_too():
    """The advantage of DS-TWR is robustness to unknown or mis-estimated rates, not the exact case."""
    rng = np.random.default_rng(312)
    s, tr = exchange(rng, 5, 1e-3)
    ss = ss_twr_tof_s(s["t_poll_tx_s"], s["t_poll_rx_s"], s["t_reply_tx_s"], s["t_reply_rx_s"],
                      freq_poller=tr["fa"], freq_responder=tr["fb"])
    assert np.max(np.abs(C * ss - tr["range_m"])) < 1e-6


def test_time_transfer_is_exact_without_drift():
    rng = np.random.default_rng(313)
    for turnaround_s in TURNAROUNDS_S:
        for _ in range(100):
            s, tr = exchange(rng, 9, turnaround_s, max_ppm=0.0)
            dtheta, t_mid = time_transfer_s(s["t_poll_tx_s"], s["t_poll_rx_s"], s["t_reply_tx_s"], s["t_reply_rx_s"])
            assert dtheta.shape == t_mid.shape == (9,)
            assert np.max(np.abs(dtheta - (tr["oa"] - tr["ob"]))) < 1e-14  # s


def test_time_transfer_with_drift_is_exact_at_the_midpoint_and_first_order_at_the_poll():
    rng = np.random.default_rng(314)
    for turnaround_s in TURNAROUNDS_S:
        for _ in range(100):
            s, tr = exchange(rng, 9, turnaround_s)
            dtheta, t_mid = time_transfer_s(s["t_poll_tx_s"], s["t_poll_rx_s"], s["t_reply_tx_s"], s["t_reply_rx_s"])
            theta = lambda f, o, t: f * t + o  # noqa: E731  (local minus true time)
            tm = tr["t_mid_true"]
            at_mid = theta(tr["fa"], tr["oa"], tm) - theta(tr["fb"], tr["ob"], tm)
            assert np.max(np.abs(dtheta - at_mid)) < 1e-14
            assert np.allclose(t_mid, (1 + tr["fa"]) * tm + tr["oa"], rtol=0, atol=1e-14)  # the poller's clock there
            t1 = tr["t1_true"]
            at_poll = theta(tr["fa"], tr["oa"], t1) - theta(tr["fb"], tr["ob"], t1)
            # first order: T4 - T1 on the poller's clock is (1 + fa) times the true duration
            bound = np.abs(tr["fa"] - tr["fb"]) * (s["t_reply_rx_s"] - s["t_poll_tx_s"]) / 2
            assert np.all(np.abs(dtheta - at_poll) <= bound * (1 + 1e-4) + 1e-15)
            assert np.max(np.abs(dtheta - at_poll)) > 1e-10  # (the drift does show at the poll instant)


def test_batch_axes_broadcast_like_single_exchanges():
    rng = np.random.default_rng(315)
    runs = [exchange(rng, 4, 1e-3) for _ in range(3)]
    batch = {k: np.stack([np.asarray(s[k]) for s, _ in runs]) for k in runs[0][0]}
    fa = np.array([tr["fa"] for _, tr in runs])
    fb = np.stack([tr["fb"] for _, tr in runs])
    r = ds_twr_range_m(**batch, freq_poller=fa, freq_responder=fb)
    assert r.shape == (3, 4)
    for i, (s, tr) in enumerate(runs):
        assert np.array_equal(r[i], ds_twr_range_m(**s, freq_poller=tr["fa"], freq_responder=tr["fb"]))
    dtheta, t_mid = time_transfer_s(batch["t_poll_tx_s"], batch["t_poll_rx_s"], batch["t_reply_tx_s"],
                                    batch["t_reply_rx_s"])
    assert dtheta.shape == t_mid.shape == (3, 4)


def test_a_missing_reply_spoils_only_its_own_range():
    rng = np.random.default_rng(316)
    s, tr = exchange(rng, 5, 1e-3)
    s["t_reply_rx_s"] = s["t_reply_rx_s"].copy()
    s["t_reply_rx_s"][2] = np.nan
    r = ds_twr_range_m(**s, freq_poller=tr["fa"], freq_responder=tr["fb"])
    assert np.isnan(r[2]) and np.all(np.abs(np.delete(r - tr["range_m"], 2)) < 1e-6)


def test_reply_schedule():
    assert np.allclose(reply_offset_s(np.arange(4), 1e-3, 3e-4), [1e-3, 1.3e-3, 1.6e-3, 1.9e-3])
    assert reply_offset_s(0, 5e-4, 1e-4) == 5e-4


def test_every_reply_of_a_noiseless_exchange_lies_in_its_window_at_the_poller():
    rng = np.random.default_rng(317)
    for _ in range(100):
        s, tr = exchange(rng, 9, 1e-3)
        # clock-rate error of the reply delays seen on the poller's clock: |fa - fb| o_k <= 40 ppm x 3.4 ms
        ok = in_reply_window(s["t_poll_tx_s"], s["t_reply_rx_s"], np.arange(9), 1e-3, 300e-6, 3000.0, guard_s=200e-9)
        assert ok.all()


def test_a_reply_outside_its_sub_slot_is_rejected_never_reassigned():
    turn, spacing, max_range = 1e-3, 300e-6, 3000.0
    t_ref = 0.25
    rtt = 2 * 1500.0 / C
    on_time = t_ref + reply_offset_s(3, turn, spacing) + rtt
    assert in_reply_window(t_ref, on_time, 3, turn, spacing, max_range)
    # member 3's reply one sub-slot late lies in member 4's window: it is still member 3's, so dropped
    late = on_time + spacing
    assert not in_reply_window(t_ref, late, 3, turn, spacing, max_range)
    assert in_reply_window(t_ref, late, 4, turn, spacing, max_range)  # (where it landed)
    # early (before its sub-slot) and just beyond the round trip at the maximum range: dropped
    assert not in_reply_window(t_ref, t_ref + reply_offset_s(3, turn, spacing) - 1e-9, 3, turn, spacing, max_range)
    beyond = t_ref + reply_offset_s(3, turn, spacing) + 2 * max_range / C + 1e-9
    assert not in_reply_window(t_ref, beyond, 3, turn, spacing, max_range)
    assert in_reply_window(t_ref, beyond, 3, turn, spacing, max_range, guard_s=2e-9)
    # vectorized: a mask, one entry per reply; the count of drops is the caller's
    rx = np.array([on_time, late, on_time + 2 * spacing])
    ok = in_reply_window(t_ref, rx, np.array([3, 3, 5]), turn, spacing, max_range)
    assert ok.tolist() == [True, False, True] and int((~ok).sum()) == 1


def test_a_listener_times_replies_from_its_own_reception_of_the_poll():
    """Any receiver, not only the poller: reply k arrives o_k + tau(A,Rk) + tau(Rk,L) - tau(A,L) after
    the poll, in [o_k, o_k + 2 tau_max] by the triangle inequality (V2)."""
    rng = np.random.default_rng(318)
    turn, spacing, max_range = 1e-3, 300e-6, 3000.0
    for _ in range(200):
        a, listener = rng.uniform(0, 2000.0, 2), rng.uniform(0, 2000.0, 2)
        resp = rng.uniform(0, 2000.0, (6, 2))
        d = lambda p, q: np.linalg.norm(np.asarray(p) - np.asarray(q), axis=-1) / C  # noqa: E731
        t_poll_rx = d(a, listener)
        t_rx = d(a, resp) + reply_offset_s(np.arange(6), turn, spacing) + d(resp, listener)
        assert in_reply_window(t_poll_rx, t_rx, np.arange(6), turn, spacing, max_range).all()
