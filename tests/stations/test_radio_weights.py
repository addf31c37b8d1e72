"""The stations under a scenario's ``[radio]`` (issue 33): every range weighted by its link's noise, the
SNR's timing CRLB (``net.radio.range_var_m2``) at the estimated geometry, in the survey, the integrity
tests and the clock filter; without ``[radio]`` the nominal ``sigma_d`` as before."""

from __future__ import annotations

import numpy as np
import pytest

from nav.geometry import SPEED_OF_LIGHT_M_S as C
from net.radio import RadioParams, range_var_m2
from net.scenario import load
from stations.clocksync import ClockEstimator, ClockModel
from stations.sim import Simulator

# seed000's 2 km field with a weak (-5 dBm) radio: its links at 12-20 dB SNR carry 0.5-1.5 m of
# noise per range, three times the nominal 0.5 m on the farthest
WEAK = {"tx_power_dbm": -5.0}


def test_range_variance_without_radio_is_sigma_d_squared():
    assert range_var_m2([0, 0, 0], [1e5, 0, 0], None, 0.5) == 0.25
    far = range_var_m2([0, 0, 0], [20_000.0, 0, 0], RadioParams(), 0.5)
    near = range_var_m2([0, 0, 0], [2_000.0, 0, 0], RadioParams(), 0.5)
    assert 0.25 < near < far


@pytest.fixture(scope="module")
def weak_run():
    scn = load("seed000", radio=WEAK)
    sim = Simulator(scn)
    r = sim.run(40.0, np.array([40.0]))
    return scn, sim, r


def test_the_channels_range_noise_is_the_model_the_stations_weight_with(weak_run):
    scn, sim, r = weak_run
    log = np.array(sim.range_log)
    i, j = log[:, 1].astype(int), log[:, 2].astype(int)
    T = r.truth_m
    e = log[:, 3] - np.linalg.norm(T[i] - T[j], axis=1)
    v = range_var_m2(T[i], T[j], scn.channel.radio, scn.channel.sigma_d_m)
    assert len(e) > 300 and np.sqrt(v).max() > 2.5 * scn.channel.sigma_d_m
    # normalized errors: unit variance (sample std of ~400 normal draws: 3.5 % standard error)
    assert np.std(e / np.sqrt(v)) == pytest.approx(1.0, abs=0.12)


def test_weighted_links_raise_no_false_exclusion_and_the_survey_stays_consistent(weak_run):
    scn, sim, r = weak_run
    # with the nominal sigma_d on every link the far links failed the consistency test: 28 exclusions
    # in a 60 s fleet of this world; weighted, none
    assert all(not c.integrity.excluded for c in sim.cores if c is not None)
    err = r.pos_m[-1, 3:] - r.truth_m[3:]
    P = r.cov_m2[-1, 3:]
    nees = np.einsum("ni,ni->n", err, np.linalg.solve(P, err[..., None])[..., 0])
    assert np.mean(nees) < 7.8, nees  # mean of 7 chi-square(3): 95 % above 7.8 only if overconfident


def test_the_clock_filter_takes_each_transfers_own_variance():
    """A transfer given its link's variance is the Kalman update with that R: the same events with
    ``z_var_s2 = 4 (sigma_d / c)^2`` on every one equal the explicit filter with that noise."""
    from test_sync import _explicit_kf

    rng = np.random.default_rng(12)
    q = (1e-20, 3e-22)
    model = ClockModel(q[0], q[1], 1e-6, 2e-8)
    est = ClockEstimator(2, model, 0.0, 0.5, step_nis=np.inf)
    for sid in (3, 4, 5):
        est._add(sid)
    events, t = [], 0.0
    for _ in range(60):
        t += rng.uniform(0.01, 0.7)
        a, b = rng.choice([1, 2, 3, 4, 5], 2, replace=False)
        events.append((t, int(a), int(b), float(rng.normal(0, 1e-7))))
    var = 4 * (0.5 / C) ** 2
    for te, a, b, z in events:
        est.on_exchange(a, b, te, z, 0.0, var)
    est.predict(t + 1.0)
    x, P = _explicit_kf(4, (1e-12, 4e-16), q, events, var, t + 1.0)
    assert np.allclose(est.x, x, rtol=1e-6, atol=1e-15)
    assert np.allclose(est.P, P, rtol=1e-6, atol=1e-26)
