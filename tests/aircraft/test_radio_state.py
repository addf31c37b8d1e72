"""aircraft/navigator/radio: the state layout's named blocks, the saved state (snapshot) round trip,
the inverse-range chart and the height floor's truncated moments."""

import dataclasses

import numpy as np
import pytest
from scipy.stats import truncnorm

from aircraft.navigator.radio import models as mdl
from aircraft.navigator.radio.chart import InverseChart
from aircraft.navigator.radio.floor import HeightFloor, truncated_normal
from aircraft.navigator.radio.snapshot import TrackerSnapshot
from aircraft.navigator.radio.state import StateLayout
from aircraft.navigator.radio.tracker import CvTracker
from aircraft.navigator.radio.tuning import Tuning

ST = np.array([[50.0, 0.0, 0.0], [0.0, 50.0, 0.0], [-50.0, 0.0, 0.0], [0.0, -50.0, 0.0]])


def test_layout_blocks_are_the_models_columns():
    lay = StateLayout("pr", drift=True)
    X = np.arange(8.0)[None] + [100, 0, 300, 0, 0, 0, 0, 0]
    J = mdl.jac_pr(X, ST, np.array([-0.1, 0.0, 0.1, 0.2]))
    assert np.all(J[..., lay.clock] == 1.0)
    np.testing.assert_array_equal(J[..., lay.clock_rate], [[-0.1, 0.0, 0.1, 0.2]])
    np.testing.assert_allclose(np.linalg.norm(J[..., lay.pos], axis=-1), 1.0)
    F = mdl.cv_transition(lay.n, 0.5)
    assert F[lay.clock, lay.clock_rate] == 0.5 and np.all(F[lay.pos, lay.vel] == 0.5 * np.eye(3))
    assert lay.pos_clock == [0, 1, 2, 6] and lay.biases(2) == slice(8, 10)
    tdoa = StateLayout("tdoa")
    assert tdoa.n == 6 and tdoa.clock is None and tdoa.clock_rate is None and tdoa.pos_clock == [0, 1, 2]
    assert StateLayout("pr").clock_rate is None and StateLayout("pr").n == 7
    with pytest.raises(ValueError):
        StateLayout("tdoa", drift=True)


def _run(trk, rng_seed, detour_at=None):
    rng = np.random.default_rng(rng_seed)
    out = []
    for k in range(12):
        trk.predict_to(0.125 * (k + 1))  # steps exact in binary: restore() rebuilds the cached F, Q
        rho = np.linalg.norm(np.array([[30.0, 20.0, 80.0], [300.0, -200.0, 900.0]])[:, None] - ST, axis=-1) + 10.0
        rho = rho + rng.normal(0, 0.5, rho.shape)
        kw = {"bias_ids": [1, 2, 3, 4], "bias_var_m2": np.full(4, 0.04)}
        if k == detour_at:
            s = trk.save()
            trk.update(ST, rho + 7.0, **kw)
            trk.restore(s)
        out.append(trk.update(ST, rho, **kw) + (trk.x, trk.P))
    return out


@pytest.mark.parametrize("kind", ["ekf", "ukf"])
def test_snapshot_round_trip_is_exact(kind):
    x0 = np.array([[30.0, 20.0, 80.0, 0, 0, 0, 10.0, 0], [300.0, -200.0, 900.0, 0, 0, 0, 10.0, 0]])
    a = _run(CvTracker(kind, "pr", x0 + 3.0, Tuning()), 4)
    b = _run(CvTracker(kind, "pr", x0 + 3.0, Tuning()), 4, detour_at=6)
    for ra, rb in zip(a, b):
        for u, v in zip(ra, rb):
            np.testing.assert_array_equal(u, v)
    trk = CvTracker(kind, "pr", x0, Tuning())
    _run(trk, 5)
    s = trk.save()
    assert isinstance(s, TrackerSnapshot) and s.bias_ids == (1, 2, 3, 4)
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.t_s = 0.0


def test_chart_round_trip_and_jacobians():
    rng = np.random.default_rng(6)
    ch = InverseChart((5,), clock=True)
    ch.set_reference(np.array([0.0, 0.0, 0.0]), 50.0)
    ch.inv = np.array([True, False, True, True, False])
    x = np.concatenate([rng.normal(0, 500, (5, 3)), rng.normal(0, 5, (5, 3)), rng.normal(0, 10, (5, 2))], -1)
    s = ch.to_internal_x(x)
    np.testing.assert_array_equal(s[~ch.inv], x[~ch.inv])
    np.testing.assert_allclose(ch.cart(s), x, rtol=1e-12, atol=1e-9)
    T = ch.T(s)
    h = 1e-4 * np.abs(s[..., :1]) + 1e-6
    for i in range(8):
        e = np.zeros_like(s)
        e[:, i] = h[:, 0]
        num = (ch.cart(s + e) - ch.cart(s - e)) / (2 * h)
        np.testing.assert_allclose(T[..., i], num, rtol=1e-5, atol=1e-6)


def test_floor_moments_are_those_of_the_truncated_gaussian():
    a = np.array([-3.0, -0.5, 0.0, 1.0, 4.0, 30.0])
    mu, var = truncated_normal(a)
    np.testing.assert_allclose(mu, truncnorm.mean(a, np.inf), rtol=1e-9)
    np.testing.assert_allclose(var, truncnorm.var(a, np.inf), rtol=1e-6)
    fl = HeightFloor(0.0, 6.0)
    x = np.array([[0.0, 0.0, 1.0, 0.5], [0.0, 0.0, 500.0, 0.0]])
    P = np.stack([np.diag([4.0, 4.0, 9.0, 1.0])] * 2)
    P[:, 2, 3] = P[:, 3, 2] = 1.5
    xt, Pt = fl.moments(x, P, np.zeros(2, bool), None)
    a0 = (0.0 - 1.0) / 3.0
    assert xt[0, 2] == pytest.approx(1.0 + 3.0 * truncnorm.mean(a0, np.inf), rel=1e-9)
    assert Pt[0, 2, 2] == pytest.approx(9.0 * truncnorm.var(a0, np.inf), rel=1e-6)
    assert xt[0, 3] == pytest.approx(0.5 + 1.5 / 3.0 * truncnorm.mean(a0, np.inf), rel=1e-9)
    np.testing.assert_array_equal(xt[1], x[1])  # far above: untouched
    fl2 = HeightFloor(0.0, 6.0)
    xs, Ps = x[1:].copy(), P[1:].copy()
    out = fl2.moments(xs, Ps, np.zeros(1, bool), None)
    assert out[0] is xs and out[1] is Ps  # no mass below: the same objects
    assert fl.cached(x, P, np.zeros(2, bool), None)[0] is fl.cached(x, P, np.zeros(2, bool), None)[0]


def test_one_run_floor_moments_equal_the_batched_ones_bit_for_bit():
    """HeightFloor's one-run path (the live filters) is the batched arithmetic without the run masks."""
    rng = np.random.default_rng(3)
    fl = HeightFloor(0.0, 6.0)
    for k in range(200):
        A = rng.normal(size=(8, 8))
        P = A @ A.T * 10.0 ** rng.uniform(-2, 3)
        x = rng.normal(0, 30, 8)
        inv = np.array(k % 3 == 0)
        ref = np.array([5.0, -3.0, 0.0])
        one = fl.moments(x, P, inv, ref)
        many = fl.moments(x[None], P[None], inv.reshape(1), ref)
        np.testing.assert_array_equal(one[0], many[0][0])
        np.testing.assert_array_equal(one[1], many[1][0])
