"""aircraft/navigator/radio: the rules as parts - the repeat count of the linearization error
(repeats.py), the stations' clock-bias states (biases.py) and the lagged Jacobian's low-pass (lag.py)."""

import numpy as np
import pytest

from aircraft.navigator.radio.biases import ClockBiases
from aircraft.navigator.radio.lag import LaggedJacobian, complement
from aircraft.navigator.radio.repeats import RepeatCount, scaled


def test_repeats_count_each_station_once_per_its_own_interval():
    rc = RepeatCount(corr_s=10.0, t_start_s=0.0)
    keys = rc.keys(np.zeros((3, 3)), [1, 2, 3])
    assert keys == [("id", 1), ("id", 2), ("id", 3)]
    # never heard: each error counts once
    np.testing.assert_array_equal(rc.count(keys, 0.1, 0.1, None), [1.0, 1.0, 1.0])
    P0, P1 = np.eye(3)[None] * 4.0, np.eye(3)[None] * 3.0
    rc.record(keys[:2], 1.0, P0, P1)
    assert rc.memory[0] == pytest.approx(4.0)  # prior variance over what one update removes
    # TDMA: station 1 and 2 heard 0.5 s ago (their own interval), station 3 never; 1.5 s since start
    k = rc.count(keys, 1.5, 0.1, None)
    np.testing.assert_allclose(k, [[1.5 / 0.5, 1.5 / 0.5, 1.0]])
    # the window caps it: at most corr_s worth of that station's measurements
    rc.t_start_s = -100.0
    np.testing.assert_allclose(rc.count(keys, 1.5, 0.1, None), [[10.0 / 0.5, 10.0 / 0.5, 1.0]])
    assert rc.count(keys, 1.5, 0.1, 0).shape == (1, 2)  # TDOA rows: the base's own key dropped
    assert RepeatCount(0.0, 0.0).count(keys, 1.5, 0.1, None).shape == ()  # off: once (white term)
    assert RepeatCount(0.0, 0.0).keys(np.zeros((3, 3)), [1, 2, 3]) == []
    S2 = np.array([[4.0, 1.0], [1.0, 9.0]])
    np.testing.assert_allclose(scaled(S2, np.array([4.0, 1.0])), [[16.0, 2.0], [2.0, 9.0]])


def test_clock_biases_added_kept_and_dropped():
    cb = ClockBiases(n_base=7, tau_s=6.0, drop_s=60.0)
    x, P = np.ones((2, 7)), np.broadcast_to(np.eye(7), (2, 7, 7)).copy()
    x, P, D, changed = cb.use(x, P, [10, None, 12], [0.04, 0.05, 0.0], t_s=0.0)
    assert changed and cb.ids == [10] and x.shape == (2, 8) and P[0, 7, 7] == 0.04 and x[0, 7] == 0.0
    np.testing.assert_array_equal(D, [[1.0], [0.0], [0.0]])  # no id / no broadcast variance: no bias
    x, P, D, changed = cb.use(x, P, [11, 10], [0.09, 0.04], t_s=1.0)
    assert changed and cb.ids == [10, 11]
    np.testing.assert_array_equal(D, [[0.0, 1.0], [1.0, 0.0]])
    x, P, D, changed = cb.use(x, P, [10, 11], [0.04, 0.09], t_s=2.0)
    assert not changed
    F, Q = cb.process(np.eye(7), np.zeros((7, 7)), 0.5)
    a = np.exp(-0.5 / 6.0)
    np.testing.assert_allclose(np.diag(F)[7:], [a, a])
    np.testing.assert_allclose(np.diag(Q)[7:], (1 - a * a) * np.array([0.04, 0.09]))
    x, P, D, changed = cb.use(x, P, [11], [0.09], t_s=70.0)  # station 10 unheard for 68 s: dropped
    assert changed and cb.ids == [11] and x.shape == (2, 8)
    np.testing.assert_array_equal(D, [[1.0]])


def test_lag_low_passes_and_restarts_beyond_four_sigma():
    n = np.array([[0.0, 0.0, 1.0], [0.6, 0.8, 0.0]])
    E = complement(n)
    np.testing.assert_allclose(np.swapaxes(E, -1, -2) @ E, np.broadcast_to(np.eye(2), (2, 2, 2)), atol=1e-12)
    np.testing.assert_allclose(np.einsum("kij,ki->kj", E, n), 0.0, atol=1e-12)
    lag = LaggedJacobian(2.0, "height")
    P = np.broadcast_to(np.eye(6), (2, 6, 6)).copy()
    x = np.zeros((2, 6))

    def ident(X):
        return X

    lag.advance(x, P, ident, lambda X: None, 0.1)
    np.testing.assert_array_equal(lag.pos, np.zeros((2, 2)))
    x1 = x.copy()
    x1[0, 0], x1[1, 0] = 1.0, 10.0  # 1 sigma: low-passed (a = 0.05); 10 sigma: restarted at the estimate
    lag.advance(x1, P, ident, lambda X: None, 0.1)
    np.testing.assert_allclose(lag.pos, [[0.05, 0.0], [10.0, 0.0]])
    assert not lag.active(np.array([True, True])) and lag.active(np.array([True, False]))
