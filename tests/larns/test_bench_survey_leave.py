"""``larns bench survey --founders-leave`` (docs/survey.md, "The founders leave"): one short trial."""

import numpy as np

from larns.bench.survey import _leave_trial, leave_summary


def test_founders_leave_trial_with_the_scenarios_station_count():
    """Without ``--stations`` (None: the scenario's 10) the trial runs (it used to hand the loader
    ``[layout] n = None``); 61 s: station 1 leaves at 60 s, the survivors are scored against the twin."""
    res = _leave_trial(("seed000", 0.5, None, 1, 61.0, None, None))
    assert res["times"] == [59.0, 61.0]
    assert res["dev_m"].shape == (2, 10)
    assert np.all(res["dev_m"][0] == 0.0)  # before the departure the two runs are one
    assert np.isnan(res["dev_m"][1, 0]) and np.all(np.isfinite(res["dev_m"][1, 1:]))  # station 1 gone
    s = leave_summary([res], 0.5)
    assert s["rows"][-1]["survivors"] == 9
    assert 0.0 <= s["end_within_if_info_loss_frac"] <= 1.0 and s["end_survivors"] == 9


def test_info_loss_against_its_definition():
    """``_info_loss``: deviations drawn from N(0, D) have NEES 2 against D on average, the chance of
    |d| <= r is 1 - exp(-r^2 / (2 s^2)) for D = s^2 I, and a D that is not positive definite gives NaN."""
    from larns.bench.survey import _info_loss

    rng = np.random.default_rng(7)
    n, s = 4000, 0.02
    A = rng.normal(size=(n, 2, 2)) * s
    D = A @ A.transpose(0, 2, 1) + 1e-6 * np.eye(2)
    twin = np.tile(1e-4 * np.eye(2), (n, 1, 1))
    d = np.einsum("kij,kj->ki", np.linalg.cholesky(D), rng.standard_normal((n, 2)))
    nees, _ = _info_loss(d, D + twin, twin, np.full(n, 0.01), np.random.default_rng(1), draws=10)
    assert abs(nees.mean() - 2.0) < 0.15  # 4000 chi-square(2) samples: sd of the mean 0.03
    iso = np.tile(s**2 * np.eye(2), (3, 1, 1))
    r = np.array([0.01, 0.02, 0.04])
    _, p = _info_loss(np.zeros((3, 2)), iso + 1e-4 * np.eye(2), np.tile(1e-4 * np.eye(2), (3, 1, 1)), r,
                      np.random.default_rng(2), draws=40000)
    np.testing.assert_allclose(p, 1.0 - np.exp(-r**2 / (2 * s**2)), atol=0.01)
    nees, p = _info_loss(np.zeros((1, 2)), np.eye(2)[None] * 1e-4, np.eye(2)[None] * 2e-4, np.ones(1),
                         np.random.default_rng(3))
    assert np.isnan(nees[0]) and np.isnan(p[0])
