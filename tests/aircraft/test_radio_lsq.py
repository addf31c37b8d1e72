"""aircraft/navigator/radio/lsq.py: the snapshot pseudorange and range-difference least squares recover
the truth from noiseless ranges (with and without station covariances, any base station), and the
(G R G^T)^-1-weighted difference LSQ equals the pseudorange LSQ with the clock profiled out."""

from __future__ import annotations

import numpy as np
import pytest

from aircraft.navigator.radio.lsq import lsq_pr, lsq_tdoa
from radio_support import S001, S003


@pytest.mark.parametrize("stations,point", [(S001, [600.0, 300.0, 80.0]), (S003, [-20000.0, 5000.0, 1000.0])])
def test_lsq_recovers_truth_without_noise(stations, point):
    p = np.array(point)
    rho = np.linalg.norm(p - stations, axis=1) + 37.0
    x0 = np.r_[p + [30.0, -20.0, 15.0], 0.0][None]
    cov = np.broadcast_to(np.eye(3) * 0.1, (len(stations), 3, 3))
    for c in (None, cov):
        x = lsq_pr(rho[None], stations, x0, 0.25, c, iters=30, tol_m=1e-10)
        np.testing.assert_allclose(x[0], np.r_[p, 37.0], atol=1e-6)
        for base in (0, 2):
            y = lsq_tdoa(rho[None], stations, x0[:, :3], 0.25, c, base=base, iters=30, tol_m=1e-10)
            np.testing.assert_allclose(y[0], p, atol=1e-6)


def test_tdoa_weighting_equals_pseudorange_lsq_with_clock_profiled_out():
    """With (G R G^T)^-1 weights, range-difference LSQ gives exactly the pseudorange LSQ position
    (the clock is a nuisance parameter entering every pseudorange alike), for any base station."""
    rng = np.random.default_rng(4)
    p = np.array([5000.0, -8000.0, 1000.0])
    var = rng.uniform(0.3, 2.0, len(S003))
    rho = np.linalg.norm(p - S003, axis=1) + 12.0 + rng.standard_normal((6, len(S003))) * np.sqrt(var)
    x0 = np.tile(np.r_[p + 50.0, 0.0], (6, 1))
    xp = lsq_pr(rho, S003, x0, var, iters=40, tol_m=1e-11)
    for base in (0, 5):
        xt = lsq_tdoa(rho, S003, x0[:, :3], var, base=base, iters=40, tol_m=1e-11)
        np.testing.assert_allclose(xt, xp[:, :3], atol=1e-6)
    # an unweighted (identity) difference LSQ would not: the weighting matters
    assert np.max(np.abs(xp[:, :3] - p)) > 1e-3


def test_one_run_is_the_batched_iteration():
    """One run (rho (m,), x0 (k,): the live LSQ's warm start) takes the same Gauss-Newton iterations as
    the batched path (M, ...) with fewer, smaller array operations: equal to rounding (relative 1e-7:
    10 unconverged steps 900 m out of a 71 m array amplify it), with and without station covariances,
    any base, trust region and floor."""
    rng = np.random.default_rng(5)
    for stations, p in ((S001, np.array([900.0, 400.0, 120.0])), (S003, np.array([-9000.0, 4000.0, 700.0]))):
        m = len(stations)
        cov = np.einsum("k,ij->kij", rng.uniform(0.01, 0.5, m), np.eye(3))
        rho = np.linalg.norm(p - stations, axis=1) + 37.0 + rng.standard_normal(m)
        x0 = np.r_[p + [300.0, -200.0, -250.0], 0.0]
        for c in (None, cov):
            kw = dict(iters=10, max_step_m=200.0, floor_z_m=0.0)
            np.testing.assert_allclose(lsq_pr(rho, stations, x0, 0.25, c, **kw),
                                       lsq_pr(rho[None], stations, x0[None], 0.25, c, **kw)[0], rtol=1e-7, atol=1e-6)
            for base in (0, 2):
                np.testing.assert_allclose(
                    lsq_tdoa(rho, stations, x0[:3], 0.25, c, base=base, **kw),
                    lsq_tdoa(rho[None], stations, x0[None, :3], 0.25, c, base=base, **kw)[0], rtol=1e-7, atol=1e-6)
