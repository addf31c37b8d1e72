"""The aircraft's true motion and clock on the world side: aircraft/world/trajectory.py (the turn and
ellipse trajectories, velocity the derivative of position) and aircraft/world/clock.py (the receiver
clock model's seed001 drift and bias)."""

from __future__ import annotations

import numpy as np
import pytest

from aircraft.world import trajectory
from aircraft.world.clock import ReceiverClock


def test_clock_model_seed001():
    c = ReceiverClock()
    assert c.drift_m_s == pytest.approx(0.6)
    assert c.bias_m(10.0) == pytest.approx(6.0)


def test_trajectories():
    t = np.arange(0, 60, 0.01)
    tr = trajectory.from_config({"kind": "turn", "distance_m": 1000.0, "speed_m_s": 30.0}, t, np.zeros(3))
    assert tr.pos_m[0] == pytest.approx([1000.0, 0.0, 1000 * np.tan(np.radians(3))])
    np.testing.assert_allclose(np.linalg.norm(tr.vel_m_s, axis=1), 30.0)
    # velocity is the derivative of position (exact arcs, continuous at segment jumps)
    np.testing.assert_allclose(np.gradient(tr.pos_m[:, :2], t, axis=0)[1:-1], tr.vel_m_s[1:-1, :2], atol=0.02)
    el = trajectory.ellipse(t, [15000, 0], (18000, 12000), 1000.0, 50.0)
    assert el.pos_m[0, 0] == pytest.approx(-3000.0)
    np.testing.assert_allclose(np.gradient(el.pos_m, t, axis=0)[1:-1], el.vel_m_s[1:-1], atol=1e-3)


def test_track_at_is_numpy_interp_bit_for_bit():
    """Track.at's six-column interpolation is np.interp's arithmetic: equal to the last bit inside,
    at sample times and held at both ends."""
    rng = np.random.default_rng(4)
    t = np.cumsum(rng.uniform(0.005, 0.02, 400))
    tr = trajectory.Track(t, rng.normal(0, 1e3, (400, 3)), rng.normal(0, 30, (400, 3)))
    for q in np.concatenate([rng.uniform(t[0] - 1, t[-1] + 1, 500), t[:5], t[-3:], [t[0] - 5, t[-1] + 5]]):
        p, v = tr.at(float(q))
        np.testing.assert_array_equal(p, [np.interp(q, t, tr.pos_m[:, i]) for i in range(3)])
        np.testing.assert_array_equal(v, [np.interp(q, t, tr.vel_m_s[:, i]) for i in range(3)])
