"""Issue 14: aircraft RAIM/FDE (snapshot chi-square test, leave-one-out exclusion, protection levels)."""

from __future__ import annotations

import numpy as np

from aircraft.navigator.radio.raim import raim_fde

STATIONS = np.array([[0, 0, 0], [2000, 0, 10], [300, 1900, 40], [1800, 1700, 80], [900, 900, 20],
                     [100, 1000, 60], [1500, 500, 30], [600, 300, 50.0]])
AC = np.array([1100.0, 800.0, 1500.0])
CLOCK_M = 123.0


def _rho(rng, sigma=1.0):
    return np.linalg.norm(AC - STATIONS, axis=1) + CLOCK_M + rng.normal(0, sigma, len(STATIONS))


def test_raim_excludes_the_biased_station():
    rng = np.random.default_rng(3)
    ids = list(range(1, 9))
    for bad in (3, 6):
        rho = _rho(rng)
        rho[bad - 1] += 30.0
        r = raim_fde(ids, STATIONS, rho, 1.0, np.r_[AC + 50.0, 0.0])
        assert r.fault and r.excluded == [bad]
        assert np.linalg.norm(r.pos_m - AC) < 10.0 and np.isfinite(r.hpl_m) and r.hpl_m > 0


def test_raim_false_alarm_rate_and_protection_level_on_clean_data():
    """Seeded: without a fault the alarm rate is about p_fa and the error stays inside the HPL."""
    rng = np.random.default_rng(4)
    ids = list(range(1, 9))
    n, alarms, exceed = 2000, 0, 0
    for _ in range(n):
        r = raim_fde(ids, STATIONS, _rho(rng), 1.0, np.r_[AC + 20.0, 0.0], p_fa=0.01, p_md=1e-3)
        alarms += r.fault
        exceed += np.hypot(*(r.pos_m - AC)[:2]) > r.hpl_m
    assert alarms / n < 0.02  # nominal 0.01; binomial sd 0.0022
    assert exceed / n <= 0.001
