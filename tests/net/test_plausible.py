"""Each bound of a nav broadcast's plausibility for the navigating receivers (net/plausible.py, used by
aircraft/navigator/plausible.py and vehicle/navigator/plausible.py; issue 32 item 1)."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from net.plausible import NavBounds, bounds_for, cov_ok, nav_reason
from net.scenario import load

STATIONS = np.array([[0.0, 0.0, 0.0], [2000.0, 0.0, 0.0], [500.0, 1500.0, 10.0]])
B = NavBounds.of(STATIONS, clock_offset_sigma_s=1e-3, clock_freq_sigma=1e-6)
T = 100.0


def _nav(**over) -> dict:
    m = {"kind": "nav", "src": 2, "t_tx_s": T, "pos_m": [2000.0, 1.0, 0.0], "cov_m2": (np.eye(3) * 0.01).tolist(),
         "clock": [T - 0.5, 1e-4, 1e-7, 1e-16, 1e-22, 1e-26]}
    m.update(over)
    return m


def test_bounds_from_the_field_and_its_oscillator_class():
    assert B.pos_m == pytest.approx(2000.0 + 1000.0)  # the farthest station from station 1, + 1 km
    assert B.var_m2 == pytest.approx((10 * B.pos_m) ** 2)
    assert B.clock_offset_s == pytest.approx(10 * 1e-3 + 10 * 1e-6 * 86400.0)
    assert B.clock_freq == pytest.approx(2e-5) and B.time_window_s == 6.0
    loose = NavBounds.of(STATIONS)  # a receiver that does not know the class: 50 ppm
    assert loose.clock_freq == 1e-3 and loose.clock_offset_s == pytest.approx(43.2)
    scn = load("seed000")
    sb = NavBounds.of_scenario(scn)
    assert sb.pos_m == pytest.approx(float(np.max(np.linalg.norm(scn.pos_m, axis=1))) + 1000.0)
    assert bounds_for(STATIONS, 1e-3, 1e-6) == B and bounds_for(STATIONS, 1e-3, 1e-6) is bounds_for(STATIONS, 1e-3, 1e-6)


def test_a_plausible_nav_passes():
    assert nav_reason(_nav(), T + 0.02, B) is None
    assert nav_reason({"kind": "nav", "pos_m": [0.0, 0.0, 0.0]}, T, B) is None  # (fields absent: not checked)


@pytest.mark.parametrize("over, reason", [
    ({"t_tx_s": 1e12}, "time"),
    ({"t_tx_s": T - 80.0}, "time"),                                           # beyond 2 x 18.6 s + 6 s
    ({"pos_m": [3100.0, 0.0, 0.0]}, "pos"),                                   # beyond the field + 1 km
    ({"pos_m": [1e12, 1e12, 1e12]}, "pos"),
    ({"cov_m2": (np.eye(3) * 1e12).tolist()}, "cov"),                         # variance beyond (10 pos)^2
    ({"cov_m2": [[1.0, 5.0, 0.0], [5.0, 1.0, 0.0], [0.0, 0.0, 1.0]]}, "cov"),  # not positive semi-definite
    ({"cov_m2": [[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]}, "cov"),  # not symmetric
    ({"clock": [T, 20.0, 0.0, 1e-16, 0.0, 1e-26]}, "clock"),                  # offset beyond the class
    ({"clock": [T, 0.0, -1.0, 1e-16, 0.0, 1e-26]}, "clock"),                  # frequency -1
    ({"clock": [T, 0.0, 0.0, 1e6, 0.0, 1e-26]}, "clock"),                     # offset variance
    ({"clock": [T, 0.0, 0.0, 1e-16, 0.0, 1.0]}, "clock"),                     # frequency variance
    ({"clock": [T, 0.0, 0.0, 1e-16, 1e-3, 1e-26]}, "clock"),                  # not a covariance
    ({"clock": [T - 100.0, 0.0, 0.0, 1e-16, 0.0, 1e-26]}, "clock"),           # reference time
])
def test_a_nav_outside_a_bound_is_refused_with_its_reason(over, reason):
    assert nav_reason(_nav(**over), T, B) == reason


def test_cov_ok_on_its_own():
    assert cov_ok(np.zeros((3, 3)), 1.0) and cov_ok(np.eye(3), 1.0)
    assert not cov_ok(np.eye(3) * 2.0, 1.0) and not cov_ok(np.full((3, 3), np.nan), 1.0)
    assert not cov_ok([[0.0] * 3] * 2, 1.0)


def test_the_aircraft_and_vehicle_wrappers_count_by_reason():
    from aircraft.config import from_scenario
    from aircraft.navigator import plausible as ap
    from vehicle.core import vehicle_map
    from vehicle.navigator import plausible as vp

    scn = load("seed000")
    bounds = from_scenario(scn).nav.field_bounds  # the navigator's: the deployment plan
    assert bounds == bounds_for(scn.pos_m)
    stats: Counter = Counter()
    assert not ap.refuse(_nav(pos_m=scn.pos_m[1].tolist()), T, bounds, stats) and not stats
    assert ap.refuse(_nav(pos_m=[1e12, 0.0, 0.0]), T, bounds, stats) and stats == {"implausible_pos": 1}
    assert ap.refuse(_nav(), T + 1e6, NavBounds.of_scenario(scn), stats) and stats["implausible_time"] == 1
    assert ap.unusable(_nav(state="listening"), T, bounds, stats) and stats["nav_unusable_state"] == 1
    rec = vehicle_map(scn, None, None)
    vs: Counter = Counter()
    assert not vp.refuse(_nav(pos_m=scn.pos_m[1].tolist()), T, rec, vs)
    assert vp.refuse(_nav(pos_m=[1e7, 0.0, 0.0]), T, rec, vs) and vs == {"implausible_pos": 1}
    vb = vp.bounds_of(rec)
    assert vp.measurement_reason(scn.pos_m[1], np.eye(3), 1.0, 500.0, 0.0, vb) is None
    assert vp.measurement_reason(scn.pos_m[1], -np.eye(3), 1.0, 500.0, 0.0, vb) == "cov"
    assert vp.measurement_reason(scn.pos_m[1], np.eye(3), -1.0, 500.0, 0.0, vb) == "clock"
    assert vp.measurement_reason(scn.pos_m[1], np.eye(3), 1.0, float("nan"), 0.0, vb) == "range"
    assert vp.measurement_reason([1e9, 0.0, 0.0], np.eye(3), 1.0, 500.0, 0.0, vb) == "pos"


def test_the_cholesky_shortcut_never_contradicts_the_eigenvalue_test():
    """cov_ok / publishable accept a covariance whose 3x3 Cholesky succeeds without an eigendecomposition:
    over random, near-singular, rank-deficient and indefinite matrices a success always passes
    ``lambda_min >= -1e-9 lambda_max``, and a matrix with a clearly negative eigenvalue never succeeds."""
    from net.plausible import cholesky3_ok

    rng = np.random.default_rng(7)
    n_ok = n_neg = 0
    for k in range(4000):
        V = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        scale = 10.0 ** rng.uniform(-6, 6)
        lam = scale * np.array([rng.choice([1.0, 1e-8, 1e-14, 0.0, -1e-12, -1e-6, -0.1]), rng.uniform(0.1, 1), 1.0])
        a = (V * lam) @ V.T
        a = 0.5 * (a + a.T)
        w = np.linalg.eigvalsh(a)
        if cholesky3_ok(a):
            n_ok += 1
            assert w[0] >= -1e-9 * w[-1], (k, lam, w)
        if w[0] < -1e-9 * w[-1]:
            n_neg += 1
            assert not cholesky3_ok(a), (k, lam, w)
    assert n_ok > 1000 and n_neg > 1000  # both branches exercised
    assert cov_ok(np.diag([1.0, 1.0, 0.0]), 2.0)  # semi-definite: left to the eigenvalue test, passes
    assert not cov_ok(np.diag([1.0, 1.0, -0.5]), 2.0)
