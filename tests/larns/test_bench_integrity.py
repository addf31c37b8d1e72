"""larns/bench/integrity.py: the recovery measurement (``--recovery``) on synthetic trials."""

import numpy as np
import pytest

from larns.bench.integrity import RECOVER_RATIO, recovery_summary


def _trial(detect_s, excess, grid=np.arange(1.0, 61.0), onset_s=20.0, n=7, seed=0):
    """A trial whose honest stations' squared errors are the twin's times ``excess(lag)^2``."""
    rng = np.random.default_rng(seed)
    twin = rng.uniform(0.01, 0.05, (grid.size, n))
    lag = grid - (onset_s + (detect_s if detect_s is not None else np.inf))
    g = np.where(lag >= 0, excess(np.maximum(lag, 0.0)), 3.0)
    return {"grid_s": grid, "onset_s": onset_s, "detect_time_s": detect_s, "twin_h2": twin,
            "grid_h2": twin * g[:, None] ** 2, "grid_nees": np.full((grid.size, n), 3.0)}


def test_recovery_is_the_first_lag_from_which_the_ratio_stays_below_the_bar():
    def excess(lag):
        return 1.0 + 0.5 * np.exp(-lag / 3.0)  # <= 1.15 from lag 3 ln(10/3) = 3.6 s on

    res = [_trial(1.0, excess, seed=1), _trial(3.0, excess, seed=2), _trial(None, excess, seed=3)]
    out = recovery_summary(res, np.arange(0.0, 31.0))
    assert out["trials_excluded"] == 2  # the undetected trial is not counted
    np.testing.assert_allclose(out["ratio"], excess(np.asarray(out["lags_s"])), rtol=1e-12)
    assert out["recover_s"] == 4.0 and out["ratio"][3] > RECOVER_RATIO >= out["ratio"][4]
    assert out["nees_mean"][0] == pytest.approx(3.0) and out["nees_band_95"][0][0] < 3.0 < out["nees_band_95"][0][1]
    # lags only as far as every trial reaches: 60 - (20 + 3) = 37 s of the 0..30 asked for
    assert out["lags_s"][-1] == 30.0
    # a ratio that comes back above the bar: recovery only from after its last excursion
    res2 = [_trial(1.0, lambda lag: np.where(lag == 12.0, 1.3, excess(lag)), seed=4)]
    assert recovery_summary(res2, np.arange(0.0, 31.0))["recover_s"] == 13.0
    # never below: None
    assert recovery_summary([_trial(1.0, lambda lag: 1.2 + 0 * lag)], np.arange(0.0, 31.0))["recover_s"] is None
