"""aircraft/navigator/radio/models.py: the pseudorange and range-difference functions' Jacobians
against finite differences, the TDOA covariance G R G^T (also as the covariance of differenced noise,
seeded) and a station's position covariance entering the range variance."""

from __future__ import annotations

import numpy as np
import pytest

from aircraft.navigator.radio import models as mdl
from radio_support import S001, S003
from radio_support import fd_jac as _fd_jac


@pytest.mark.parametrize("n", [7, 8])
def test_pr_jacobian_matches_finite_differences(n):
    rng = np.random.default_rng(1)
    X = rng.normal(0, 300, (5, n)) + np.r_[[500, 200, 100], np.zeros(n - 3)]
    dt = np.array([-0.3, -0.2, -0.1, 0.0])
    for d in (None, dt):
        H = mdl.jac_pr(X, S001, d)
        Hn = _fd_jac(lambda x: mdl.h_pr(x, S001, d), X)
        np.testing.assert_allclose(H, Hn, atol=1e-7)


def test_tdoa_jacobian_matches_finite_differences():
    rng = np.random.default_rng(2)
    X = rng.normal(0, 2000, (5, 6)) + np.r_[15000, 0, 1000, 0, 0, 0]
    dt = np.linspace(-0.7, 0.0, 8)
    for base in (0, 3):
        for d in (None, dt):
            H = mdl.jac_tdoa(X, S003, base, d)
            Hn = _fd_jac(lambda x: mdl.h_tdoa(x, S003, base, d), X)
            np.testing.assert_allclose(H, Hn, atol=1e-6)


def test_tdoa_covariance_is_g_r_gt():
    var = np.array([0.25, 0.5, 1.0, 2.0])
    G = mdl.g_matrix(4, 2)
    assert G.shape == (3, 4) and np.all(G[:, 2] == -1) and np.allclose(np.delete(G, 2, axis=1), np.eye(3))
    R = mdl.r_tdoa(var, 2)
    np.testing.assert_allclose(R, G @ np.diag(var) @ G.T)
    # and it is the covariance of the differenced noise (Monte Carlo, seeded)
    xi = np.random.default_rng(3).standard_normal((200_000, 4)) * np.sqrt(var)
    d = np.delete(xi, 2, axis=1) - xi[:, 2:3]
    np.testing.assert_allclose(np.cov(d.T), R, atol=0.03)


def test_station_covariance_enters_the_range_variance():
    X = np.array([[1000.0, 0, 50, 0, 0, 0, 0]])
    P = np.zeros((4, 3, 3))
    P[1] = np.diag([4.0, 1.0, 9.0])
    var = mdl.range_var(X, S001, P, 0.5)
    u = (X[0, :3] - S001[1]) / np.linalg.norm(X[0, :3] - S001[1])
    assert var[0, 0] == pytest.approx(0.25)
    assert var[0, 1] == pytest.approx(0.25 + u @ P[1] @ u)
