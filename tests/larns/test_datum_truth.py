"""The truth in the field's own datum (issue 30; ``larns/analysis/datum.py``): an S-transformation of
the founders'-frame truth, fixed when the carriers' references freeze."""

import numpy as np
import pytest

from larns.analysis.datum import FieldDatumTruth, datum_transform, rotation_exp, sim_datum_truth, truth_series

N = 6
COV = np.diag([0.01, 0.01, 0.25])  # every broadcast: converged (horizontal sigma 0.14 m <= 0.25 m)


def _field(seed=0):
    rng = np.random.default_rng(seed)
    truth = {sid: rng.uniform([-1000, -1000, -40], [1000, 1000, 40]) for sid in range(1, N + 1)}
    R0, s0 = rotation_exp(np.array([2e-4, -1e-4, 3e-4])), np.array([0.2, -0.1, 0.8])
    return truth, R0, s0


def _feed(dt, truth, R0, s0, until_s, drift_m=np.zeros(3), drift_from_s=np.inf):
    """Navs once a second per station: the founders (1-3) hold the frame (a zero variance) until 10 s;
    every estimate is the truth moved by (R0, s0), plus ``drift_m`` from ``drift_from_s`` on."""
    for t in np.arange(0.0, until_s, 1.0):
        for sid, x in truth.items():
            cov = COV.copy()
            if sid <= 3 and t < 10.0:
                cov[2, 2] = 0.0
            pos = R0 @ x + s0 + (drift_m if t >= drift_from_s else 0.0)
            dt.observe(t + 0.01 * sid, sid, pos, cov)


def test_a_rigidly_moved_noise_free_field_is_its_own_datum_truth():
    truth, R0, s0 = _field()
    dt = FieldDatumTruth(truth, converged_m=0.25)
    _feed(dt, truth, R0, s0, 30.0)
    assert dt.frozen_s == pytest.approx(10.03)  # the last founder (3) broadcasts free in x, y, z
    for sid, x in truth.items():
        np.testing.assert_allclose(dt.truth(sid), R0 @ x + s0, atol=1e-9)
        np.testing.assert_allclose(dt.truth_at(5.0, sid), x)  # before the release: the founders' frame


def test_a_rigid_drift_after_the_freeze_shows_as_error():
    """The transform is fixed at the freeze: re-fitted to the estimates at each evaluation it would
    absorb the drift and this error would be zero."""
    truth, R0, s0 = _field(1)
    drift = np.array([0.3, -0.2, 0.0])
    dt = FieldDatumTruth(truth, converged_m=0.25)
    _feed(dt, truth, R0, s0, 60.0, drift, drift_from_s=30.0)
    for sid, x in truth.items():
        est_at_59 = R0 @ x + s0 + drift
        np.testing.assert_allclose(est_at_59 - dt.truth_at(59.0, sid), drift, atol=1e-9)


def test_datum_transform_is_the_exact_rigid_motion():
    truth, R0, s0 = _field(2)
    X = np.stack(list(truth.values()))
    R, s = datum_transform(X, X @ R0.T + s0, np.broadcast_to(COV, (N, 3, 3)))
    np.testing.assert_allclose(R, R0, atol=1e-12)
    np.testing.assert_allclose(s, s0, atol=1e-9)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)


@pytest.fixture(scope="module")
def noise_free():
    from net.scenario import load
    from stations.sim import Simulator

    scn = load("seed000", channel={"sigma_d_m": 1e-3}, clock={"model": "perfect"}, survey={"datum": "field"})
    sim = Simulator(scn)
    dt = sim_datum_truth(scn, sim)
    r = sim.run(80.0, [80.0])
    return scn, sim, dt, r


def test_the_references_are_the_stations_own(noise_free):
    """The release read off the navs gives each station that froze then its own references exactly."""
    _, sim, dt, _ = noise_free
    assert dt.frozen_s is not None and 40.0 < dt.frozen_s < 60.0
    assert len(dt.ref_sets) >= 8  # (a station converging later freezes later)
    for sid, refs in dt.ref_sets.items():
        core = sim.cores[sid - 1]
        assert core.field_datum
        for p, q in refs.items():
            np.testing.assert_array_equal(q, core.datum_ref[p])


def test_noise_free_estimates_equal_the_datum_truth(noise_free):
    scn, _, dt, r = noise_free
    T = truth_series(dt, scn.ids, r.times_s)
    e = r.pos_m[0] - T[0]
    assert np.hypot(e[:, 0], e[:, 1]).max() < 1e-3  # sigma_d (0.3 mm)
    # the heights, which 1 mm ranges in an 80 m high field see weakly, within their 3 sigma (3-6 mm)
    assert np.all(np.abs(e[:, 2]) < 3.0 * np.sqrt(r.cov_m2[0, :, 2, 2]))


def test_the_recordings_station_table_uses_the_datum_truth(noise_free, tmp_path):
    from larns.analysis.summary import station_table
    from larns.bench.replay import synth_log
    from larns.log.series import load

    scn, _, dt, r = noise_free
    path = tmp_path / "field.mcap"
    synth_log(path, "seed000", 80.0, channel={"sigma_d_m": 1e-3}, clock={"model": "perfect"},
              survey={"datum": "field"})
    st = station_table(load([path]))
    for k, sid in enumerate(scn.ids):
        row = st[sid]
        assert row["datum"] == "field"
        np.testing.assert_allclose(row["truth_founders_m"], scn.true_pos(sid))
        # the journal's thresholds and the navs' stamps give the simulator's datum truth
        np.testing.assert_allclose(row["truth_m"], dt.truth(sid), atol=1e-6)
        assert row["err_m"] < 0.02
