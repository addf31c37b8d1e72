"""The radio aircraft's bounds: nav/pcrb.py (the per-cycle Fisher information against a
finite-difference Fisher, its CRLB, the covariance form of the linear-Gaussian posterior CRLB against
Tichavsky's information recursion) and aircraft/montecarlo/radio.py's ``pcrb_track``, which the
pseudorange EKF/UKF reach on a short seeded hover."""

from __future__ import annotations

import numpy as np
import pytest

from aircraft.config import from_scenario
from aircraft.montecarlo import radio as sim
from aircraft.world import trajectory
from nav.pcrb import crlb_cycle, fisher_cycle, pcrb_linear_gaussian
from net.scenario import load
from radio_support import S003
from radio_support import fd_jac as _fd_jac


def test_cycle_fisher_matches_finite_difference_fisher():
    r0 = np.array([-20000.0, 8000.0, 1000.0])
    v = np.array([50.0, -10.0, 2.0])
    t = np.arange(8) * 0.1
    sig = np.linspace(0.8, 1.2, 8)
    for clock in (False, True):
        J = fisher_cycle(r0, v, S003, t, sig, clock=clock)
        theta = np.r_[r0, v, 4.0] if clock else np.r_[r0, v]

        def h(th):
            pos = th[..., None, :3] + th[..., None, 3:6] * t[:, None]
            r = np.linalg.norm(pos - S003, axis=-1)
            return r + th[..., 6:7] if clock else r

        G = _fd_jac(h, theta, eps=1e-3)  # (8, k)
        np.testing.assert_allclose(J, G.T @ np.diag(1 / sig**2) @ G, rtol=1e-6, atol=1e-10)
    b = crlb_cycle(J[None])
    C = np.linalg.inv(J)
    assert b["horiz_m"][0] == pytest.approx(np.sqrt(C[0, 0] + C[1, 1]), rel=1e-6)
    assert b["vert_m"][0] == pytest.approx(np.sqrt(C[2, 2]), rel=1e-6)


def test_pcrb_covariance_form_equals_tichavsky_information_recursion():
    rng = np.random.default_rng(6)
    n, m, T = 4, 2, 30
    F = np.eye(n) + 0.1 * rng.normal(size=(n, n))
    A = rng.normal(size=(n, n))
    Q = A @ A.T * 0.01 + 0.01 * np.eye(n)
    H = rng.normal(size=(T, m, n))
    R = np.diag([0.5, 2.0])
    P0 = np.eye(n) * 3.0
    P = pcrb_linear_gaussian(P0, F, Q, H, R)
    Qi = np.linalg.inv(Q)
    D11, D12, D22 = F.T @ Qi @ F, -F.T @ Qi, Qi
    J = np.linalg.inv(P0)
    for k in range(T):
        J = D22 + H[k].T @ np.linalg.inv(R) @ H[k] - D12.T @ np.linalg.inv(J + D11) @ D12
        np.testing.assert_allclose(np.linalg.inv(J), P[k], rtol=1e-8, atol=1e-12)


def test_filters_reach_the_pcrb_on_a_short_hover():
    """Seeded Monte Carlo at 1000 m: pseudorange EKF/UKF RMSE near the posterior CRLB (honest band:
    16 runs x 10 s of correlated epochs leave about +-20 % of sampling spread)."""
    ac = from_scenario(load("seed001"))
    t = np.arange(0.0, 20.0, 0.01)
    tr = trajectory.from_config({"kind": "hover", "distance_m": 1000.0}, t, ac.world.centre_m)
    rng = np.random.default_rng(9)
    rho = sim.pseudoranges(tr, ac.world.stations_m, ac.world.clock, ac.world.sigma_m, 16, rng)
    P = sim.pcrb_track("pr", tr, ac.world.stations_m, ac.nav.tuning, ac.world.clock)
    w = t >= 10.0
    pc = np.sqrt(np.mean(np.trace(P[w], axis1=1, axis2=2)))
    for algo in ("ekf-pr", "ukf-pr"):
        res = sim.run_algo(algo, tr, ac.world.stations_m, rho, ac.nav.tuning, ac.world.clock, rng)
        rmse = sim.rms_total(res.err_m[:, w])
        assert 0.6 * pc < rmse < 1.25 * pc, (algo, rmse, pc)
