"""Issue 14: integrity of the aircraft filters (aircraft/navigator/radio/fde.py): the innovation tests, exclusion of the
right station by the filter (4 stations: no snapshot redundancy), the clean false-alarm rate, the
protection levels, and the ``ac_estimate`` integrity fields."""

from __future__ import annotations

import numpy as np
import pytest

from aircraft.montecarlo import radio as sim
from aircraft.navigator.radio.estimator import AircraftEstimator, EstimatorConfig
from aircraft.navigator.radio.fde import FdeConfig, fault_vectors, protection_levels, snooping
from aircraft.navigator.radio.tuning import Prior, Tuning
from aircraft.radio_core import integrity_fields
from aircraft.world.clock import ReceiverClock
from aircraft.world.trajectory import Track
from net import messages as M

STATIONS = np.array([[0.0, 0.0, 0.0], [3000.0, 0.0, 20.0], [1500.0, 2500.0, 40.0], [1500.0, -2500.0, 10.0]])
TUNING = Tuning(sigma_m=0.5, p0=Prior(pos_m=20.0, vel_m_s=5.0), q_acc=1.0)


def _track(T: int, rate_hz: float = 10.0) -> Track:
    t = np.arange(T) / rate_hz
    pos = np.array([1500.0, -800.0, 1200.0]) + np.outer(t, [40.0, 10.0, 0.0])
    vel = np.broadcast_to([40.0, 10.0, 0.0], pos.shape).copy()
    return Track(t, pos, vel)


def _run(algo, T, runs, bias_from=None, bad=2, fde=FdeConfig(), seed=0, stations=STATIONS):
    track = _track(T)
    clock = ReceiverClock()
    rng = np.random.default_rng(seed)
    rho = sim.pseudoranges(track, stations, clock, TUNING.sigma_m, runs, rng)
    B = None
    if bias_from is not None:
        B = np.zeros((T, stations.shape[0]))
        B[bias_from:, bad] = 30.0
    return sim.run_algo(algo, track, stations, rho, TUNING, clock, rng, fde=fde, bias_m=B)


def test_snooping_statistics_have_their_chi_square_moments_and_point_at_the_bias():
    rng = np.random.default_rng(1)
    d = 5
    A = rng.standard_normal((d, d))
    S = A @ A.T + 0.5 * np.eye(d)
    nu = rng.standard_normal((40000, d)) @ np.linalg.cholesky(S).T
    q, w = snooping(nu, np.broadcast_to(S, (40000, d, d)), fault_vectors("pr", d))
    assert abs(q.mean() - d) < 0.06 and np.allclose(w.mean(0), 1.0, atol=0.04)
    assert np.all(q[:, None] >= w - 1e-9)  # q - w_i is the leave-one-out NIS (>= 0)
    nu_b = nu[:100] + 8.0 * np.sqrt(S[3, 3]) * np.eye(d)[3]
    _, wb = snooping(nu_b, np.broadcast_to(S, (100, d, d)), fault_vectors("pr", d))
    assert np.mean(np.argmax(wb, -1) == 3) > 0.95
    # differences against a base: the base station's fault direction is -1 on every difference
    _, wt = snooping(nu[:10, :4], np.broadcast_to(S[:4, :4], (10, 4, 4)), fault_vectors("tdoa", 5, 0))
    assert wt.shape == (10, 5) and np.all(wt >= 0)


@pytest.mark.parametrize("algo", ["ekf-pr", "ukf-tdoa"])
def test_filter_excludes_the_biased_station_with_four_stations(algo):
    T, onset = 120, 60
    r = _run(algo, T, runs=6, bias_from=onset, bad=2)
    ev = r.fde.events
    first = {}
    for t_s, run, sid, stat, thr in ev:
        first.setdefault(run, (t_s, sid, stat, thr))
    assert sorted(first) == list(range(6))  # every run excluded something ...
    for t_s, sid, stat, thr in first.values():
        assert sid == 2 and 6.0 <= t_s <= 6.5 and stat > thr  # ... the biased station, within 5 epochs
    assert all(r.fde.excluded(k) == [2] for k in range(6))
    err_after = np.linalg.norm(r.err_m[:, onset + 20 :], axis=-1)
    assert np.sqrt(np.mean(err_after**2)) < 20.0  # the filter goes on with 3 stations, unbiased


def test_clean_false_alarm_rate_within_its_nominal_value():
    """Loose p_fa (0.1 and 0.01 per epoch) so that a seeded 180-epoch x 6-run clean flight counts alarms:
    the observed rate stays at or below the nominal one (x 1.5 for the count's spread; the filter's
    process noise is larger than the straight flight's, so its NIS sits below chi-square and the rate
    below nominal), and the test does fire (it is not vacuous). The default p_fa: no alarm."""
    for p_fa in (0.1, 0.01):
        fde = FdeConfig(p_fa=p_fa, p_gate=1e-3)
        r = _run("ekf-pr", 200, runs=6, fde=fde, seed=4)
        rate = r.fde.alarms.sum() / (6 * (200 - fde.arm_after))
        assert rate < 1.5 * p_fa, (p_fa, rate)
        if p_fa == 0.1:
            assert rate > 0.01 * p_fa
    r0 = _run("ekf-pr", 200, runs=6, fde=FdeConfig(), seed=4)
    assert r0.fde.alarms.sum() == 0 and not r0.fde.out
    assert r0.nis[:, 20:].mean() < 4.2  # 4 pseudoranges: chi-square(4) or below (conservative)


@pytest.mark.parametrize("algo", ["ekf-pr", "ukf-tdoa"])
def test_falsely_excluded_stations_are_readmitted_and_a_later_fault_still_excluded(algo):
    """A loose window test (p_fa 0.05 per epoch) excludes healthy stations now and then; with 4
    stations that would leave 3 and no way to exclude a real fault later (a seed-001 TDOA run diverged
    to 10^6 m so). Each healthy station comes back; the station biased from epoch 120 is excluded in
    every run at the end, and the error after the fault stays small (26 m RMS for ukf-tdoa without
    re-admission on this seed: one run kept the biased station)."""
    fde = FdeConfig(p_fa=0.05, p_gate=1e-3)
    r = _run(algo, 240, runs=6, bias_from=120, bad=2, fde=fde, seed=3)
    before = [(t_s, run, sid) for t_s, run, sid, _, _ in r.fde.events if t_s < 11.0]
    assert before, "no false exclusion before the fault: the test would not test re-admission"
    for t_s, run, sid in before:
        assert any(rt > t_s and rr == run and rs == sid for rt, rr, rs, _, _ in r.fde.readmitted), (t_s, run, sid)
    assert all(r.fde.excluded(k) == [2] for k in range(6))
    assert np.sqrt(np.mean(np.linalg.norm(r.err_m[:, 140:], axis=-1) ** 2)) < 15.0


def test_clean_filter_unchanged_by_the_wide_gate():
    a = _run("ukf-pr", 150, runs=6, fde=None, seed=2)
    b = _run("ukf-pr", 150, runs=6, fde=FdeConfig(), seed=2)
    if b.fde.gated.sum() == 0:
        np.testing.assert_allclose(a.err_m, b.err_m, atol=1e-9)
    assert abs(sim.rms_total(a.err_m[:, 30:]) / sim.rms_total(b.err_m[:, 30:]) - 1.0) < 0.02


def test_protection_levels_k_sigma():
    P = np.diag([4.0, 1.0, 9.0])
    hpl, vpl = protection_levels(P, 1e-3)
    assert hpl == pytest.approx(np.sqrt(-2 * np.log(1e-3)) * 2.0)
    assert vpl == pytest.approx(3.2905 * 3.0, rel=1e-4)
    # circular horizontal Gaussian: P(|e_h| > HPL) equals the integrity risk
    e = np.random.default_rng(0).standard_normal((400000, 2))
    h1, _ = protection_levels(np.eye(3), 1e-2)
    assert np.mean(np.hypot(*e.T) > h1) == pytest.approx(1e-2, rel=0.06)


def test_estimator_publishes_integrity_fields_and_they_round_trip():
    rng = np.random.default_rng(3)
    track = _track(120)
    clock = ReceiverClock()
    rho = sim.pseudoranges(track, STATIONS, clock, 0.5, 1, rng)[:, 0]
    rho[60:, 1] += 30.0
    est = AircraftEstimator("ekf-pr", EstimatorConfig(tuning=TUNING), x0_guess_m=track.pos_m[0] + 30.0)
    ids = [11, 12, 13, 14]
    for k in range(120):
        est.on_epoch(float(track.t_s[k]), STATIONS, None, rho[k], ids)
    e = est.estimate()
    assert e["excluded"] == [12] and e["hpl_m"] > 0 and e["vpl_m"] > 0
    assert np.linalg.norm(np.asarray(e["pos_m"]) - track.pos_m[-1]) < 30.0
    msg = {"kind": "ac_estimate", "src": "ac1", "seq": 3, "stamp_s": 1.0, "t_s": 1.0, "pos_m": e["pos_m"],
           "cov_m2": e["cov_m2"], "algo": "ekf-pr", **integrity_fields(e)}
    back, _ = M.decode(M.encode(msg))
    assert back["excluded"] == [12] and back["hpl_m"] == pytest.approx(e["hpl_m"])
    old = {k: v for k, v in msg.items() if k not in ("hpl_m", "vpl_m", "excluded")}
    assert "hpl_m" not in M.decode(M.encode(old))[0]  # older recordings: the fields are optional
    with pytest.raises(M.MessageError, match="hpl_m"):
        M.validate_msg({**msg, "hpl_m": -1.0})
    with pytest.raises(M.MessageError, match="excluded"):
        M.validate_msg({**msg, "excluded": ["x"]})


def test_tdma_slots_exclude_the_biased_station():
    """The node's path: one station per slot, scalar updates (w = nu^2 / S); the window's per-station
    sums identify the biased one."""
    rng = np.random.default_rng(5)
    slot_s = 0.025
    t = np.arange(480) * slot_s
    track = _track(480, rate_hz=1.0 / slot_s)
    clock = ReceiverClock()
    ids = [11, 12, 13, 14]
    est = AircraftEstimator("ukf-pr", EstimatorConfig(tuning=TUNING), x0_guess_m=track.pos_m[0] + 30.0)
    for k in range(t.size):
        j = k % 4
        r = np.linalg.norm(track.pos_m[k] - STATIONS[j]) + clock.bias_m(t[k]) + 0.5 * rng.standard_normal()
        r += 30.0 if (j == 2 and t[k] >= 6.0) else 0.0
        est.on_measurement(float(t[k]), ids[j], STATIONS[j], np.zeros((3, 3)), float(r))
    e = est.estimate()
    assert e["excluded"] == [13]
    (t_ex, _, sid, _, _), = est.fde.events
    assert sid == 13 and 6.0 <= t_ex <= 6.5
    assert np.linalg.norm(np.asarray(e["pos_m"]) - track.pos_m[-1]) < 30.0


@pytest.mark.parametrize("algo", ["ekf-pr", "ukf-pr"])
def test_a_gated_measurement_is_dropped_not_down_weighted(algo):
    """Issue 32: the live (unbatched) filter drops a gated measurement whatever its size. Before, it
    got sigma_out_m = 1e5 m, so an error of 1e12 m still moved the estimate by ~ nu P / sigma_out^2
    (hundreds of metres). Twin filters on the same clean TDMA broadcasts; one also receives station
    3's pseudorange off by 1e12 m (then 1e6 m, then 300 m) between two clean ones - gated or, once
    the window test has excluded station 3, masked: either way dropped -; after the next clean
    measurement both estimates agree to a micrometre."""
    import copy

    truth = np.array([1500.0, -800.0, 1200.0])
    rng = np.random.default_rng(4)
    clock = ReceiverClock()
    est = AircraftEstimator(algo, EstimatorConfig(tuning=TUNING))

    def rho(j, t):
        return float(np.linalg.norm(truth - STATIONS[j]) + clock.bias_m(t) + TUNING.sigma_m * rng.standard_normal())

    t = 0.0
    for k in range(4 * 40):  # 40 cycles of 4 slots: started, armed
        t = 0.1 * k
        est.on_measurement(t, k % 4 + 1, STATIONS[k % 4], np.eye(3) * 0.01, rho(k % 4, t))
    assert est.tracker is not None and est.fde.n_updates > est.fde.cfg.arm_after
    for err in (1e12, 1e6, 300.0):
        twin = copy.deepcopy(est)
        t += 0.05
        est.on_measurement(t, 3, STATIONS[2], np.eye(3) * 0.01, rho(2, t) + err)
        assert est.tracker is not None and est.status == "tracking"  # (not a restart: the filter went on)
        t += 0.05
        r = rho(0, t)
        for f in (est, twin):
            f.on_measurement(t, 1, STATIONS[0], np.eye(3) * 0.01, r)
        a, b = est.estimate(), twin.estimate()
        assert np.max(np.abs(np.subtract(a["pos_m"], b["pos_m"]))) < 1e-6, (err, a["pos_m"], b["pos_m"])


def test_an_excluded_stations_absurd_measurements_do_not_reach_the_window_test():
    """Issue 32: once station 3 is excluded, an insider keeps sending its pseudoranges 540 km off (a
    copy of its nav stamped 1.8 ms from its clock). Masked, each still added nu^2 / sigma_out^2 = 29 to
    the window's NIS, the test alarmed on the others and (4 stations: at min_stations) re-admitted 3;
    now the tests see only the measurements in use: 3 stays excluded alone, no alarm is raised by it."""
    truth = np.array([1500.0, -800.0, 1200.0])
    rng = np.random.default_rng(5)
    clock = ReceiverClock()
    est = AircraftEstimator("ukf-pr", EstimatorConfig(tuning=TUNING))

    def rho(j, t):
        return float(np.linalg.norm(truth - STATIONS[j]) + clock.bias_m(t) + TUNING.sigma_m * rng.standard_normal())

    for k in range(4 * 40):
        t = 0.1 * k
        est.on_measurement(t, k % 4 + 1, STATIONS[k % 4], np.eye(3) * 0.01, rho(k % 4, t))
    alarms = int(est.fde.alarms)
    for k in range(4 * 40, 4 * 100):
        t = 0.1 * k
        j = k % 4
        est.on_measurement(t, j + 1, STATIONS[j], np.eye(3) * 0.01, rho(j, t) + (5.4e5 if j == 2 else 0.0))
    assert est.fde.excluded() == [3] and not est.fde.readmitted
    assert int(est.fde.alarms) - alarms == 1  # the one that excluded it
    e = est.estimate()
    assert np.linalg.norm(np.subtract(e["pos_m"], truth)) < 10.0
