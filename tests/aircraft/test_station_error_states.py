"""The stations' broadcast position errors as consider (Schmidt) range-bias states
(``Tuning.survey_bias_tau_s``, aircraft/navigator/radio/biases.py).

A station's survey error persists: counted as white range noise at every update the filter averages it
away and ends over-confident; carried as a consider state it does not, and a station whose survey is
wrong (its covariance does not say so) is not absorbed by a state: its innovations keep its bias.
"""

from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from aircraft.navigator.radio.tracker import CvTracker
from aircraft.navigator.radio.tuning import Prior, Tuning

WHITE = Tuning(rules=(), floor_z_m=None, clock_bias_tau_s=6.0, p0=Prior(pos_m=5.0, vel_m_s=1.0, clock_m=5.0),
               survey_bias_tau_s=0.0)
CONSIDER = replace(WHITE, survey_bias_tau_s=3600.0)
STATIONS = np.array([[0.0, 0.0, 5.0], [1500.0, 0.0, 10.0], [0.0, 1500.0, 0.0], [1500.0, 1500.0, 20.0],
                     [750.0, -600.0, 15.0]])
COV = np.array([np.diag([0.5, 0.5, 4.0])] * len(STATIONS))  # metres off in height, as surveyed fields are
CLOCK_VAR = 1e-4  # the stations' broadcast clock variance (small: the position error is what is tested)


def _fly(tuning, M=400, T=240, bias_m=None, seed=5):
    """``M`` runs hovering over the field for ``T`` epochs of 0.25 s, each run's stations off by a draw
    of their covariance (fixed over the run; ``bias_m`` (m,) added along each line of sight); returns the
    position NEES (M,) at the end and the mean innovation (m,) over the second half of the first run."""
    rng = np.random.default_rng(seed)
    m = len(STATIONS)
    p_true = np.array([700.0, 800.0, 600.0])
    x_true = np.concatenate([p_true, np.zeros(3), [10.0, 0.0]])
    err = np.einsum("mij,Mmj->Mmi", np.linalg.cholesky(COV), rng.standard_normal((M, m, 3)))  # (M, m, 3)
    P0 = tuning.prior_cov(CvTracker("ekf", "pr", x_true, tuning).layout)
    x0 = x_true + rng.multivariate_normal(np.zeros(8), P0, M)
    trk = CvTracker("ekf", "pr", x0, tuning)
    rho0 = np.linalg.norm(p_true - (STATIONS + err), axis=-1) + x_true[6]  # (M, m)
    if bias_m is not None:
        rho0 = rho0 + bias_m
    nus = []
    for k in range(1, T + 1):
        trk.predict_to(0.25 * k)
        rho = rho0 + tuning.sigma_m * rng.standard_normal((M, m))
        nu, _ = trk.update(STATIONS, rho, COV, bias_ids=list(range(m)), bias_var_m2=np.full(m, CLOCK_VAR))
        if k > T // 2:
            nus.append(nu[0])
    e = trk.x[:, :3] - p_true
    nees = np.einsum("Mi,Mi->M", e, np.linalg.solve(trk.P[:, :3, :3], e[..., None])[..., 0])
    return nees, np.mean(nus, axis=0)


def test_persisting_station_errors_white_is_overconfident_consider_is_not():
    hi = stats.chi2.ppf(0.999, 3 * 400) / 400
    white, _ = _fly(WHITE)
    consider, _ = _fly(CONSIDER)
    assert white.mean() > 2.0 * hi, white.mean()  # the defect the states remove
    assert consider.mean() <= hi and consider.mean() >= stats.chi2.ppf(0.001, 3 * 400) / 400 * 0.5, consider.mean()


def test_a_wrong_survey_is_not_absorbed():
    """Station 0's ranges 5 m long (its broadcast covariance says 0.5-2 m): its innovation keeps as much
    of it as with the white noise model (what the integrity test sees; a bias *state* of the same prior
    took it in: docs/aircraft.md, Known limits)."""
    bias = np.array([5.0, 0.0, 0.0, 0.0, 0.0])
    _, nu_white = _fly(WHITE, M=2, bias_m=bias)
    _, nu = _fly(CONSIDER, M=2, bias_m=bias)
    assert nu[0] > 2.0 and nu[0] >= 0.95 * nu_white[0], (nu, nu_white)


def test_without_station_covariances_nothing_changes():
    rng = np.random.default_rng(1)
    x0 = np.array([700.0, 800.0, 600.0, 0, 0, 0, 10.0, 0.0])
    a, b = CvTracker("ukf", "pr", x0, WHITE), CvTracker("ukf", "pr", x0, CONSIDER)
    for k in range(1, 20):
        rho = np.linalg.norm(x0[:3] - STATIONS, axis=1) + 10.0 + rng.normal(0, 0.5, len(STATIONS))
        for t in (a, b):
            t.predict_to(0.25 * k)
            t.update(STATIONS, rho, None, bias_ids=list(range(5)), bias_var_m2=np.full(5, CLOCK_VAR))
    assert np.array_equal(a.x, b.x) and np.array_equal(a.P, b.P)
    assert b.P.shape == (13, 13)  # the clock biases only


@pytest.mark.parametrize("kind", ["ekf", "ukf"])
def test_consider_states_keep_their_prior(kind):
    x0 = np.array([700.0, 800.0, 600.0, 0, 0, 0, 10.0, 0.0])
    trk = CvTracker(kind, "pr", x0, CONSIDER)
    rho = np.linalg.norm(x0[:3] - STATIONS, axis=1) + 13.0
    trk.predict_to(0.25)
    trk.update(STATIONS, rho, COV, bias_ids=list(range(5)), bias_var_m2=np.full(5, CLOCK_VAR))
    c = trk.biases.consider()
    assert c.size == 5 and np.all(trk.x[c] == 0.0)
    d = x0[:3] - STATIONS
    u = d / np.linalg.norm(d, axis=1)[:, None]
    v = np.einsum("mi,mij,mj->m", u, COV, u)
    assert np.allclose(np.diag(trk.P)[c], v, rtol=0.05)  # u^T C u (on its 2^(1/8) grid)
    assert np.all(np.linalg.eigvalsh(trk.P) > -1e-9)
