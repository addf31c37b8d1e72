"""The world's signal models (aircraft/world/radio.py, aircraft/world/sky.py) and the one pseudorange
geometry of the navigators (nav/geometry.py ``line_of_sight``): each checked against its defining
equation, not against itself."""

from __future__ import annotations

import numpy as np
import pytest

from nav.geometry import SPEED_OF_LIGHT_M_S, line_of_sight


def test_line_of_sight_is_the_range_and_its_gradient():
    rng = np.random.default_rng(4)
    a = rng.normal(0.0, 3e3, (5, 4, 3))
    b = rng.normal(0.0, 3e3, (4, 3))
    r, u = line_of_sight(a, b)
    assert r.shape == (5, 4) and u.shape == (5, 4, 3)
    np.testing.assert_allclose(r, np.linalg.norm(a - b, axis=-1), rtol=1e-15)
    h = 1e-3  # central differences of |a - b| in a: the gradient to O(h^2 / r)
    fd = np.stack([(np.linalg.norm(a + h * e - b, axis=-1) - np.linalg.norm(a - h * e - b, axis=-1)) / (2 * h)
                   for e in np.eye(3)], axis=-1)
    np.testing.assert_allclose(u, fd, atol=1e-9)


def test_a_broadcast_is_heard_at_the_light_time_of_a_moving_receiver():
    from aircraft.world import radio

    v = np.array([250.0, -80.0, 30.0])  # a fast aircraft
    p0 = np.array([12e3, -4e3, 3e3])
    position_at = lambda t: p0 + v * t  # noqa: E731
    p_tx, t_tx = np.array([-30e3, 20e3, 10.0]), 5.0
    t_rx, p_rx = radio.heard(position_at, p_tx, t_tx)
    # the defining equation c (t_rx - t_tx) = |p(t_rx) - p_tx|, to well under a millimetre of range
    assert abs(SPEED_OF_LIGHT_M_S * (t_rx - t_tx) - np.linalg.norm(p_rx - p_tx)) < 1e-6
    np.testing.assert_array_equal(p_rx, position_at(t_rx))


def test_the_pseudorange_adds_the_receiver_clock_and_the_broadcast_clock_residual():
    from aircraft.world import radio

    class Clock:
        def bias_m(self, t):
            return 12.5 + 0.1 * t

    p_rx, p_tx = np.array([3e3, 4e3, 0.0]), np.zeros(3)
    # no message: the true transmit time, no residual (net.nettime.pseudorange_time_error_s)
    rho = radio.pseudorange_m(p_rx, p_tx, 1.0, 1.0 + 5e3 / SPEED_OF_LIGHT_M_S, None, Clock(), None)
    assert rho == pytest.approx(5e3 + 12.5 + 0.1 * (1.0 + 5e3 / SPEED_OF_LIGHT_M_S), abs=1e-9)


def test_the_sky_satisfies_the_light_time_of_each_satellite():
    from aircraft.world import sky
    from nav.constellation import EnuFrame, gps_like

    alm, frame = gps_like(), EnuFrame(55.75, 37.62, 0.0)
    t = np.array([100.0, 160.0])
    p = np.array([[0.0, 0.0, 10e3], [12e3, 0.0, 10e3]])
    ids = np.arange(alm.n)
    s, r, el, t_tx = sky.satellites_seen(alm, frame, p, t, ids)
    assert s.shape == (2, ids.size, 3) and r.shape == el.shape == t_tx.shape == (2, ids.size)
    # each satellite where the almanac puts it at its own transmission time, at the light time's range
    s_tx = frame.from_ecef(alm.ecef(t_tx)[0][:, np.arange(ids.size), ids])
    light = SPEED_OF_LIGHT_M_S * (t[:, None] - t_tx)
    np.testing.assert_allclose(np.linalg.norm(p[:, None, :] - s_tx, axis=-1), light, atol=1e-3)
    np.testing.assert_allclose(r, light, atol=1e-3)
    assert np.all(el <= 90.0) and np.any(el > 10.0) and np.any(el < 0.0)  # part of the sky is below
    clean = sky.clean_pseudorange_m(alm, ids, r, el, t_tx)
    # range + troposphere (2.4 m at zenith, more lower) - the satellite clock
    sat_clock_m = SPEED_OF_LIGHT_M_S * (alm.af0_s[ids] + alm.af1[ids] * t_tx)
    assert np.all(clean - r + sat_clock_m >= 2.39)
