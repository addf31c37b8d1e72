"""The frame datum carried by the field (issue 30 item 2; docs/architecture.md, "The frame datum").

A near noise-free world (sigma_d = 1 mm, perfect clocks) in the real simulator: once the survey
converged the founders hand the frame to the field, any station can leave without moving the
others, and a restarted founder is an ordinary station that re-surveys to its true position."""

import numpy as np
import pytest

from net.scenario import load
from stations.core import rigid_motion
from stations.sim import Simulator

SIGMA_D_M = 1e-3
MOVE_TOL_M = 5 * SIGMA_D_M  # survivors against the same world without the departure


@pytest.fixture(scope="module")
def world():
    scn = load("seed000", seed=5, channel={"sigma_d_m": SIGMA_D_M}, clock={"model": "perfect"},
               survey={"datum": "field"})
    sim = Simulator(scn)
    base = sim.run(100.0, [60.0, 100.0])
    return scn, sim, base


def test_founders_hand_the_frame_to_the_field(world):
    scn, sim, base = world
    for core in sim.cores:
        assert core.est.datum_sigma_m is not None, core.id  # every station in the datum mode
        assert core.est.free.all() and np.all(np.diag(core.est.cov_m2) > 0)  # founders free in x, y, z
        assert core.state == "surveying"
    assert np.abs(base.pos_m[0] - base.truth_m).max() < 10 * SIGMA_D_M  # converged at 60 s


@pytest.mark.parametrize("gone", [1, 2, 3, 7])
def test_removing_any_station_moves_no_one(world, gone):
    scn, _, base = world
    sim = Simulator(scn, stop_s={gone: 60.0})
    r = sim.run(100.0, [100.0])
    keep = np.array([i != gone for i in scn.ids])
    move = np.abs(r.pos_m[0, keep] - base.pos_m[1, keep]).max()
    assert move < MOVE_TOL_M, move
    assert np.isnan(r.pos_m[0, ~keep]).all()  # it did leave
    # it is static: every survivor keeps it in the datum's fit, at its last broadcast (where it was)
    for c in (c for c in sim.cores if c.id != gone):
        assert gone not in c.members(c.clk.local_time(100.0)) and gone in c.datum_ref, c.id
        assert np.abs(c.peers[gone][0] - base.pos_m[0, ~keep][0]).max() < MOVE_TOL_M, c.id


def test_a_departed_carrier_leaves_the_fit_when_it_speaks_again(world):
    scn, _, base = world
    sim = Simulator(scn, stop_s={7: 60.0}, restart_s={7: 75.0})
    sim.run(74.0, [74.0])
    assert all(7 in c.datum_ref for c in sim.cores if c.id != 7)  # silent, still a point of the datum
    sim.run(78.0, [78.0])
    # a restarted station is an ordinary joiner: no carrier (no reference) until it converges again
    assert not any(7 in c.datum_ref for c in sim.cores if c.id != 7)
    r = sim.run(100.0, [100.0])
    keep = np.array([i != 7 for i in scn.ids])
    assert np.abs(r.pos_m[0, keep] - base.pos_m[1, keep]).max() < MOVE_TOL_M  # and it moved no one


def test_restarted_founder_resurveys_to_its_true_position(world):
    scn, _, base = world
    r = Simulator(scn, stop_s={1: 60.0}, restart_s={1: 70.0}).run(100.0, [71.0, 100.0])
    err = np.linalg.norm(r.pos_m[:, 0] - r.truth_m[0], axis=1)
    assert err[0] > 1.0  # it starts from its coarse fix (10 m per coordinate), not the origin
    assert err[1] < MOVE_TOL_M, err
    assert np.abs(r.pos_m[1, 1:] - base.pos_m[1, 1:]).max() < MOVE_TOL_M  # and moved no one


def test_rigid_motion_recovers_a_small_rotation_and_translation():
    rng = np.random.default_rng(0)
    ref = rng.uniform(-1000, 1000, (8, 3))
    t, w = np.array([0.3, -0.2, 0.1]), np.array([1e-5, -2e-5, 3e-5])
    pos = ref + t + np.cross(w, ref)
    cov = np.broadcast_to(np.diag([0.01, 0.01, 1.0]), (8, 3, 3))
    t_est, w_est = rigid_motion(pos, cov, ref)
    assert np.allclose(t_est, t, atol=1e-9) and np.allclose(w_est, w, atol=1e-12)


def test_datum_mode_keeps_the_prior_information_not_a_damping_of_its_own_solve():
    """A station whose ranges do not see its height (every peer in its plane) reports the height
    sigma of its coarse fix in the datum mode (the only information it has on it), not the 1 m of a
    damping term centred on its own previous solve; a datum correction moves the prior with the
    estimate."""
    from stations.estimators import DistributedMap

    rng = np.random.default_rng(7)
    truth = np.array([400.0, 300.0, 0.0])
    peers = {2: np.array([0.0, 0.0, 0.0]), 3: np.array([1000.0, 0.0, 0.0]), 5: np.array([500.0, 900.0, 0.0]),
             6: np.array([-300.0, 600.0, 0.0])}
    sigma0, sd = 10.0, 0.5
    est = DistributedMap(4, truth + rng.normal(0.0, sigma0, 3), np.eye(3) * sigma0**2, sd, robust=None)
    pc = np.diag([0.01, 0.01, 1.0])
    for t in range(40):
        for pid, p in peers.items():
            est.on_peer(pid, p, pc)
            est.on_range(pid, np.linalg.norm(truth - p) + rng.normal(0.0, sd), float(t), True, p, pc)
        est.refresh()
    est.hold_datum(1.0)
    for _ in range(5):
        est._dirty = True
        est.refresh()
    sz = np.sqrt(est.cov_m2[2, 2])
    assert 0.9 * sigma0 < sz <= sigma0, sz  # the coarse fix's height sigma (the 1 m damping gave < 1 m)
    prior = est.prior_mean.copy()
    est.shift(np.array([0.2, -0.1, 0.05]))
    assert np.allclose(est.prior_mean - prior, [0.2, -0.1, 0.05])  # the prior is in the field's datum


def test_seven_station_world_survivors_within_4_sigma():
    """The 7-station world of tests/larns/test_fleet_faults.py in the simulator (world seed 1,
    sigma_d 0.5 m, 0.5 s cycles, the field carries the datum), station 1 silent from 15 s and back at
    30 s, station 5 leaving at 25 s: at 59 s every station's 3-D error is within 4 sigma + 0.5 m of its
    reported covariance (the fleet test's check). With the datum mode's damping term counted as
    information (before 2026-11-30) station 4 read 5.2 m / sigma 0.95 m and station 7 10.1 m / 0.98 m
    (docs/survey.md, "Heights in the datum mode")."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from scenario_text import random_world
    from net.scenario import from_dict
    import tomllib

    text = random_world("faults", 7).replace("ranges_per_update = 3\n", 'ranges_per_update = 3\ndatum = "field"\n')
    scn = from_dict(tomllib.loads(text))
    sim = Simulator(scn, stop_s={1: 15.0, 5: 25.0}, restart_s={1: 30.0})
    r = sim.run(59.0, [59.0])
    assert any(c.est.datum_sigma_m is not None for c in sim.cores if c is not None)  # the datum mode is entered
    for i, sid in enumerate(r.ids):
        if sid == 5:
            assert np.isnan(r.pos_m[0, i]).all()
            continue
        err = np.linalg.norm(r.pos_m[0, i] - r.truth_m[i])
        sigma = np.sqrt(np.trace(r.cov_m2[0, i]))
        assert err < 4.0 * sigma + 0.5, (sid, err, sigma)
