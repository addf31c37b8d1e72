"""aircraft/navigator/radio/estimator.py: the message-level AircraftEstimator - its API on TDMA slots
and synchronous epochs (bad input dropped, unknown algorithm refused), the reset of a broken filter,
and its start: from the broadcasts alone (no position guess, none from the node's truth) and deferred
while a batch has no redundancy (InitConfig.defer_batches)."""

from __future__ import annotations

import numpy as np
import pytest

from aircraft.config import from_scenario
from aircraft.navigator import receiver as rx
from aircraft.navigator.radio.estimator import AircraftEstimator, EstimatorConfig
from aircraft.world import trajectory
from net.scenario import load


def test_estimator_api_tdma_slots_and_bad_input():
    ac = from_scenario(load("seed003"))
    slot = 0.1
    t = np.arange(0.0, 40.0, slot)
    tr = trajectory.from_config(ac.world.trajectory, t, ac.world.centre_m)
    rng = np.random.default_rng(12)
    ests = {a: AircraftEstimator(a, EstimatorConfig(tuning=ac.nav.tuning),
                                 x0_guess_m=ac.world.centre_m + [0, 0, 1000.0])
            for a in ("ukf-pr", "ekf-pr", "lsq-pr", "ekf-tdoa")}
    for k, tk in enumerate(t):
        j = k % len(ac.world.stations_m)
        rho = (np.linalg.norm(tr.pos_m[k] - ac.world.stations_m[j]) + ac.world.clock.bias_m(tk)
               + ac.world.sigma_m * rng.standard_normal())
        for e in ests.values():
            e.on_measurement(tk, j + 1, ac.world.stations_m[j], np.eye(3) * 0.01, rho)
    for a, e in ests.items():
        est = e.estimate()
        assert est is not None and est["n_updates"] > 10, a
        p, _ = tr.at(est["t_s"])
        tol = 200.0 if a.startswith("lsq") else 30.0  # LSQ ignores the motion within a cycle (50 m/s)
        assert np.linalg.norm(np.array(est["pos_m"]) - p) < tol, (a, est["pos_m"], p)
    e = ests["ukf-pr"]
    n = e.n_updates
    e.on_measurement(t[-1] + 0.1, 1, [np.nan, 0, 0], None, 1.0)
    e.on_epoch(t[-1] + 0.2, ac.world.stations_m[:2], None, [1.0, 2.0, 3.0])
    assert e.n_dropped == 2 and e.n_updates == n
    with pytest.raises(ValueError):
        AircraftEstimator("pf-pr")


def test_estimator_api_synchronous_epochs():
    ac = from_scenario(load("seed001"))
    p = ac.world.centre_m + np.array([1000.0, 0.0, 52.4])
    rng = np.random.default_rng(13)
    guess = p + rng.normal(0.0, 20.0, 3)
    e = AircraftEstimator("ukf-tdoa", EstimatorConfig(tuning=ac.nav.tuning, guess_sigma_m=20.0), x0_guess_m=guess)
    for k in range(300):
        rho = np.linalg.norm(p - ac.world.stations_m, axis=1) + 0.6 * k * 0.01 + 0.5 * rng.standard_normal(4)
        e.on_epoch(k * 0.01, ac.world.stations_m, None, rho)
    est = e.estimate()
    assert np.linalg.norm(np.array(est["pos_m"]) - p) < 3 * np.sqrt(np.trace(np.array(est["cov_m2"]))) + 1.0


def test_estimator_resets_a_broken_filter_instead_of_raising():
    ac = from_scenario(load("seed003"))
    t = np.arange(0.0, 24.0, 0.1)
    tr = trajectory.from_config(ac.world.trajectory, t, ac.world.centre_m)
    rng = np.random.default_rng(14)
    e = AircraftEstimator("ukf-pr", EstimatorConfig(tuning=ac.nav.tuning),
                          x0_guess_m=ac.world.centre_m + [0, 0, 1000.0])
    for k, tk in enumerate(t):
        j = k % len(ac.world.stations_m)
        if k == 80:
            e.tracker.P = -np.eye(e.tracker.layout.n)  # corrupt: not positive definite
        rho = (np.linalg.norm(tr.pos_m[k] - ac.world.stations_m[j]) + ac.world.clock.bias_m(tk)
               + 0.9 * rng.standard_normal())
        e.on_measurement(tk, j + 1, ac.world.stations_m[j], None, rho)
    assert e.n_resets == 1
    est = e.estimate()
    p, _ = tr.at(est["t_s"])
    assert np.linalg.norm(np.array(est["pos_m"]) - p) < 30.0


def test_estimator_start_does_not_depend_on_a_guess_and_node_ignores_the_truth():
    """The message-level estimator starts from the broadcasts: a different (even absurd) position
    guess gives bit-identical estimates; the node's estimators carry no guess from the truth."""
    ac = from_scenario(load("seed001"))
    p = ac.world.centre_m + np.array([70.0, -40.0, 120.0])
    rng = np.random.default_rng(5)
    rho = [np.linalg.norm(p - ac.world.stations_m, axis=1) + 0.6 * k * 0.01 + 0.5 * rng.standard_normal(4)
           for k in range(50)]
    outs = []
    for guess in (p, p + [5000.0, -3000.0, 900.0]):
        e = AircraftEstimator("ukf-pr", EstimatorConfig(tuning=ac.nav.tuning), x0_guess_m=guess)
        for k in range(50):
            e.on_epoch(k * 0.01, ac.world.stations_m, None, rho[k])
        outs.append(e.estimate()["pos_m"])
        assert e.init is not None and e.init.snapshot
    assert outs[0] == outs[1]
    assert np.linalg.norm(np.array(outs[0]) - p) < 5.0
    from aircraft.radio_core import RadioAircraftCore

    core = RadioAircraftCore(ac, ["ukf-pr", "lsq-pr"], "ac1", np.random.default_rng(1))
    for est in core.estimators.values():
        assert est.cfg.guess_sigma_m is None  # no external fix (it was the truth plus noise)


def test_start_waits_for_a_batch_with_redundancy():
    """An aircraft that starts while the stations come up hears 4 of 5 stations in its first cycle:
    4 pseudoranges for x y z b have no redundancy and the fix is no snapshot; a filter started from a
    wide prior about it diverged to 83 km in a fleet (tests/aircraft/test_aircraft_e2e.py on a loaded
    machine; the batch below is that run's first, as recorded: stations 5, 1, 2, 3 mid-survey, the
    aircraft hovering at (2260, 640, 316) m). The start sets such batches aside
    (InitConfig.defer_batches) until the fifth station is heard; a world of only 4 stations still
    starts after that many batches. (The receiver's rule 5, which holds the start while a station is
    known to worse than 3 m, is off here: ``test_start_waits_for_a_surveyed_field`` tests it.)"""
    from aircraft.navigator.radio.initializer import InitConfig

    ids0 = [5, 1, 2, 3]
    pos0 = np.array([[297.8, 1200.781, 18.469], [0.0, 0.0, 0.0], [1800.077, 0.0, 0.0], [896.059, 1495.421, 0.0]])
    cov0 = np.zeros((4, 3, 3))
    cov0[0] = [[14.482, -3.538, -0.054], [-3.538, 1.002, -0.369], [-0.054, -0.369, 24.994]]
    cov0[2, 0, 0] = 0.124
    cov0[3, :2, :2] = [[18.117, -3.39], [-3.39, 23.331]]
    rho0 = np.array([2061.439, 2371.666, 850.929, 1642.971])
    st = np.array([[0.0, 0.0, 0.0], [1800.0, 0.0, 5.0], [900.0, 1500.0, 0.0], [800.0, 500.0, 60.0],
                   [300.0, 1200.0, 20.0]])         # tests/scenario_text.py five_stations
    p_ac = np.array([2260.04, 639.97, 315.96])
    b_m = float(np.mean(rho0 - np.linalg.norm(p_ac - st[[4, 0, 1, 2]], axis=1)))
    rng = np.random.default_rng(3)
    err = rng.normal(0.0, 0.3, st.shape)             # later: surveyed to decimetres

    def cycle(est, t0, ids):
        for k, i in enumerate(ids):
            rho = np.linalg.norm(p_ac - st[i - 1]) + b_m + 0.5 * rng.standard_normal()
            est.on_measurement(t0 + 0.05 * k, i, st[i - 1] + err[i - 1], np.eye(3) * 0.09, rho)

    # (the one-cycle start: which cycle it takes; the batch start takes the cycles it passes)
    no_hold = EstimatorConfig(fde=None, receiver=rx.ReceiverConfig(start_station_sigma_m=np.inf), batch_start=None)
    for algo in ("ukf-pr", "ekf-tdoa", "lsq-pr"):
        e = AircraftEstimator(algo, no_hold)
        for k, i in enumerate(ids0):
            e.on_measurement(3.105 + 0.05 * k, i, pos0[k], cov0[k], rho0[k])
        cycle(e, 3.255, [1, 2, 3, 4, 5])              # 1 repeats: the batch of 4 flushes; then 4 comes up
        assert e.fix is None and e.tracker is None and e.n_deferred == 1, algo
        for c in range(1, 40):
            cycle(e, 3.255 + 0.25 * c, [1, 2, 3, 4, 5])
        assert e.init.snapshot, algo                  # started from a 5-station snapshot
        est = e.estimate()
        d = np.linalg.norm(np.array(est["pos_m"]) - p_ac)
        # the snapshot (lsq) weights each slot with the aircraft's unknown motion since (receiver rules):
        # a covariance it can defend on a moving aircraft, a little less accuracy on this hovering one
        bound = 50.0 if algo.startswith("lsq") else 25.0
        assert d < bound and d <= 4.0 * np.sqrt(np.trace(est["cov_m2"])) + 1.0, (algo, d, est["cov_m2"])
    n_def = InitConfig().defer_batches
    only4 = AircraftEstimator("ukf-pr", no_hold)
    for c in range(n_def + 2):
        for k, i in enumerate(ids0):
            only4.on_measurement(0.25 * c + 0.05 * k, i, pos0[k], cov0[k], rho0[k])
    assert only4.tracker is not None and only4.n_deferred == 0 and not only4.init.snapshot
