"""aircraft/navigator/radio/tracker.py (CvTracker) and the nav.kalman / nav.ut steps it runs on: the
EKF and UKF equal the linear KF on linear models (and the one-run fast paths the batched steps), the
prediction is the CV model, NEES/NIS inside their chi-square bands (own-model Monte Carlo and the
envelope's overhead / near-plane points), the EKF's second-order terms against finite-difference
Hessians, the height floor's truncation counted once, a TDMA far-field start from a wide prior, and no
drift along the unobservable height / symmetry-plane directions (the lagged Jacobian). Seeded."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from aircraft.config import from_scenario
from aircraft.navigator.radio import models as mdl
from aircraft.navigator.radio.tracker import CvTracker
from aircraft.navigator.radio.tuning import Prior, Tuning
from nav.kalman import ekf_update, kf_predict, kf_update, ukf_predict, ukf_update
from nav.ut import SigmaParams
from net.scenario import load
from radio_support import S001


def _linear_problem(rng, n=7, m=3):
    F = mdl.cv_transition(n, 0.1)
    Q = mdl.cv_noise(n, 0.1, 2.0, 0.01, 0.01)
    H = rng.normal(size=(m, n))
    R = np.diag(rng.uniform(0.1, 1.0, m))
    A = rng.normal(size=(n, n))
    P = A @ A.T + np.eye(n)
    x = rng.normal(size=(4, n))
    z = rng.normal(size=(4, m))
    return F, Q, H, R, P, x, z


def test_ekf_and_ukf_equal_linear_kf_on_linear_models():
    rng = np.random.default_rng(5)
    F, Q, H, R, P, x, z = _linear_problem(rng)
    Pb = np.broadcast_to(P, (4,) + P.shape)
    xk, Pk = kf_predict(x, Pb, F, Q)
    xu, Pu = ukf_predict(x, Pb, lambda X: X @ F.T, Q, SigmaParams.scaled(alpha=0.1))
    np.testing.assert_allclose(xu, xk, atol=1e-9)
    np.testing.assert_allclose(Pu, Pk, atol=1e-9)
    xa, Pa, nua, Sa = kf_update(xk, Pk, z, H, R)
    xe, Pe, nue, Se = ekf_update(xk, Pk, z, lambda X: X @ H.T, H, R)
    xs, Ps, nus, Ss = ukf_update(xk, Pk, z, lambda X: X @ H.T, R, SigmaParams.scaled(alpha=0.1))
    for xx, PP in ((xe, Pe), (xs, Ps)):
        np.testing.assert_allclose(xx, xa, atol=1e-9)
        np.testing.assert_allclose(PP, Pa, atol=1e-9)


def test_tracker_prediction_is_the_cv_model_and_ekf_matches_ukf_when_nearly_linear():
    tun = Tuning(p0=Prior(1e-3, 1e-3, 1e-3, 1e-3), floor_z_m=None)
    x0 = np.array([[800.0, 300.0, 60.0, 10.0, -5.0, 0.0, 3.0, 0.6]])
    e = CvTracker("ekf", "pr", x0, tun)
    u = CvTracker("ukf", "pr", x0, tun)
    e.predict_to(0.25)
    np.testing.assert_allclose(e.x[0], mdl.cv_transition(8, 0.25) @ x0[0])
    u.predict_to(0.25)
    z = mdl.h_pr(e.x, S001) + np.array([[0.3, -0.2, 0.1, 0.0]])
    e.update(S001, z)
    u.update(S001, z)
    np.testing.assert_allclose(u.x, e.x, atol=1e-5)
    np.testing.assert_allclose(u.P, e.P, rtol=1e-4, atol=1e-12)


def _simulate_own_model(rng, model, M, T, dt, kind):
    """Truth drawn from the filter's own model (CV + clock random walks), pseudoranges from it."""
    tun = Tuning(q_acc=1.0, q_clock=0.01, q_drift=0.01, p0=Prior(pos_m=5.0, vel_m_s=1.0, clock_m=5.0, drift_m_s=0.5),
                 floor_z_m=None)
    lay = mdl.StateLayout(model, drift=model == "pr")
    F, Q = mdl.cv_transition(lay.n, dt), mdl.cv_noise(lay.n, dt, tun.q_acc, tun.q_clock, tun.q_drift)
    LQ = np.linalg.cholesky(Q + 1e-15 * np.eye(lay.n))
    xt = np.zeros((M, lay.n))
    xt[:, :3] = [300.0, 200.0, 150.0]
    if model == "pr":
        xt[:, 7] = 0.6
    x0 = xt + rng.standard_normal((M, lay.n)) @ np.linalg.cholesky(tun.prior_cov(lay)).T
    trk = CvTracker(kind, model, x0, tun)
    for k in range(T):
        if k:
            xt = xt @ F.T + rng.standard_normal((M, lay.n)) @ LQ.T
            trk.predict_to(k * dt)
        rho = np.linalg.norm(xt[:, None, :3] - S001, axis=-1) + rng.standard_normal((M, 4)) * tun.sigma_m
        if model == "pr":
            rho = rho + xt[:, 6:7]
        nu, S = trk.update(S001, rho)
    return xt, trk, nu, S


@pytest.mark.parametrize("kind", ["ekf", "ukf"])
@pytest.mark.parametrize("model", ["pr", "tdoa"])
def test_nees_nis_inside_chi_square_bands(kind, model):
    rng = np.random.default_rng(11)
    M = 300
    xt, trk, nu, S = _simulate_own_model(rng, model, M, 150, 0.02, kind)
    e = trk.x - xt
    nees = np.einsum("...i,...i->...", e, np.linalg.solve(trk.P, e[..., None])[..., 0]).sum()
    nis = np.einsum("...i,...i->...", nu, np.linalg.solve(S, nu[..., None])[..., 0]).sum()
    n, m = trk.layout.n, nu.shape[-1]
    lo, hi = stats.chi2.ppf([0.0005, 0.9995], n * M)
    assert lo < nees < hi, (nees / M, n)
    lo, hi = stats.chi2.ppf([0.0005, 0.9995], m * M)
    assert lo < nis < hi, (nis / M, m)


def test_floor_truncation_moment_matching_counted_once():
    """x / P report the Gaussian truncated to above the station plane (a mean on the plane moves to
    the truncated-normal mean; far above: untouched); the filter's own Gaussian stays untruncated, so
    updates that carry no height information do not shrink the height variance again and again (the
    truncation fed back at every update did: 100 such updates took sigma_z from 6.0 m to ~1 m)."""
    tun = Tuning(floor_z_m=0.0)
    x0 = np.array([[100.0, 0.0, 0.0, 0, 0, 0, 0, 0], [100.0, 0.0, 500.0, 0, 0, 0, 0, 0]])
    trk = CvTracker("ukf", "pr", x0, tun)
    P = np.broadcast_to(np.diag([4.0, 4.0, 100.0, 1, 1, 1, 4.0, 1]), (2, 8, 8)).copy()
    P[:, 2, 6] = P[:, 6, 2] = 10.0  # z correlated with the clock
    trk.P = P
    s = 10.0
    assert trk.x[0, 2] == pytest.approx(s * np.sqrt(2 / np.pi), rel=1e-9)
    assert trk.P[0, 2, 2] == pytest.approx(s**2 * (1 - 2 / np.pi), rel=1e-9)
    assert trk.x[0, 6] == pytest.approx(10.0 / 100.0 * s * np.sqrt(2 / np.pi), rel=1e-9)  # via cov(z, b)
    assert np.all(np.linalg.eigvalsh(trk.P[0]) > 0)
    np.testing.assert_array_equal(trk.x[1], x0[1])
    np.testing.assert_array_equal(trk.P[1], P[1])
    np.testing.assert_array_equal(trk._x, x0)  # the filter's own Gaussian is not truncated
    np.testing.assert_array_equal(trk._P, P)
    st = np.array([[1e7, 0.0, 0.0]])  # a far station, huge noise: no information
    for k in range(100):
        trk.update(st, np.full((2, 1), 1e7), sigma_m=1e5)
    assert np.sqrt(trk.P[0, 2, 2]) == pytest.approx(s * np.sqrt(1 - 2 / np.pi), rel=1e-3)


def test_one_run_fast_paths_equal_the_batched_nav_steps():
    """The small-matrix (n,) path of nav.kalman / nav.ut gives the batched (1, n) result."""
    from nav.kalman import chol_solve
    from nav.ut import sigma_points, unscented_transform

    rng = np.random.default_rng(3)
    st = np.array([[50.0, 0, 0], [0, 50, 0], [-50, 0, 0], [0, -50, 0]])
    n = 8
    A = rng.standard_normal((n, n))
    P = A @ A.T + n * np.eye(n)
    x = np.array([400.0, -300, 40, 5, 1, 0, 3, 0.5])
    z = mdl.h_pr(x, st) + rng.standard_normal(4)
    R = np.diag(rng.uniform(0.2, 0.4, 4))
    p = SigmaParams.scaled(alpha=0.1)
    h = lambda X: mdl.h_pr(X, st)  # noqa: E731
    one = ukf_update(x, P, z, h, R, p)
    bat = ukf_update(x[None], P[None], z[None], h, R[None], p)
    for a, b in zip(one, bat):
        np.testing.assert_allclose(a, b[0], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(sigma_points(x, P, p), sigma_points(x[None], P[None], p)[0], rtol=1e-12)
    u1, ub = unscented_transform(h, x, P, p), unscented_transform(h, x[None], P[None], p)
    np.testing.assert_allclose(u1.cov, ub.cov[0], rtol=1e-9)
    np.testing.assert_allclose(u1.cross, ub.cross[0], rtol=1e-9)
    F = mdl.cv_transition(n, 0.01)
    Q = mdl.cv_noise(n, 0.01, 4.0, 1e-4, 1e-4)
    for a, b in zip(kf_predict(x, P, F, Q), kf_predict(x[None], P[None], F, Q)):
        np.testing.assert_allclose(a, b[0], rtol=1e-12)
    wm, _, _ = p.weights(n)
    assert not wm.flags.writeable and p.weights(n)[0] is wm  # cached, read-only
    with pytest.raises(np.linalg.LinAlgError):
        chol_solve(-np.eye(3), np.ones((3, 1)))


def test_ekf_second_order_terms_match_finite_difference_hessians():
    """c_j = 0.5 tr(Hess_j P), S2_ij = 0.5 tr(Hess_i P Hess_j P) with Hessians of h_pr by finite differences
    (synchronous and TDMA offsets)."""
    rng = np.random.default_rng(5)
    st = np.array([[50.0, 0, 0], [0, 50, 0], [-50, 0, 0], [0, -50, 0]])
    x = np.array([-30.0, -20, 3, 4, -2, 0.5, 1, 0.6])
    A = rng.standard_normal((8, 8))
    P = A @ A.T * 0.5 + np.eye(8)
    for dt in (None, np.array([-0.3, -0.2, -0.1, 0.0])):
        trk = CvTracker("ekf", "pr", x, Tuning())
        trk.P = P.copy()
        c2, S2 = trk._second_order(st, dt, trk._x, trk._P)
        e, m = 1e-4, 4
        Hs = np.zeros((m, 8, 8))
        for i in range(8):
            for k in range(8):
                di, dk = np.eye(8)[i] * e, np.eye(8)[k] * e
                Hs[:, i, k] = (mdl.h_pr(x + di + dk, st, dt) - mdl.h_pr(x + di - dk, st, dt)
                               - mdl.h_pr(x - di + dk, st, dt) + mdl.h_pr(x - di - dk, st, dt)) / (4 * e * e)
        np.testing.assert_allclose(c2, 0.5 * np.einsum("jik,ki->j", Hs, P), rtol=1e-4, atol=1e-7)
        S2_fd = 0.5 * np.einsum("iab,bc,jcd,da->ij", Hs, P, Hs, P)
        np.testing.assert_allclose(S2, S2_fd, rtol=1e-4, atol=1e-7)


@pytest.mark.parametrize("point", [("hover", 300.0, 0.0, 225.0), ("hover", 50.0, 1000.0, 225.0),
                                   ("turn", 50.0, 0.0, 225.0)],
                         ids=["overhead", "near-station-plane", "turn-50m-overhead"])
def test_pr_filters_nees_in_band_overhead_and_near_the_station_plane(point):
    """Seeded: mean NEES of the pseudorange EKF/UKF (8 states) at or below the upper end of its 95 %
    band, right above the stations (height and clock nearly collinear) and 50 m above the station
    plane 1 km out (mirror solution, range and clock nearly collinear)."""
    from larns.bench.envelope import Point, run_chunk

    ac = from_scenario(load("seed001"))
    out = run_chunk(ac, [Point(*point)], runs=24, duration_s=12.0, warmup_s=4.0,
                    rng=np.random.default_rng(21), algos=("ekf-pr", "ukf-pr"))
    for e in out:
        assert e["nees_mean"] <= e["nees_band"][1], e
        assert e["rmse_m"] < 3.0 * e["pcrb_m"], e


def test_tdma_far_field_start_from_a_wide_prior_converges():
    """Stations taking TDMA turns (one range per update, 5 stations over 1.8 x 1.5 km), the aircraft
    hovering 1.5 km out at 300 m, filters started 100 m wide: converged within 10 s. Counting the
    repeating linearization term per update instead of per station interval kept them ~50 m wide
    for 30 s (docs/aircraft.md, "Linearization error counted as repeating")."""
    from dataclasses import replace

    from aircraft.navigator.radio import models as mdl
    from aircraft.navigator.radio.tracker import CvTracker
    from aircraft.navigator.radio.tuning import Tuning

    S = np.array([[0, 0, 0], [1800, 0, 5], [900, 1500, 0], [800, 500, 60], [300, 1200, 20]], float)
    truth = S.mean(axis=0) + np.array([1500.0, 0.0, 0.0])
    truth[2] = 300.0
    rng = np.random.default_rng(3)
    tun = replace(Tuning(), p0=Prior(pos_m=100.0, clock_m=100.0))
    P0 = tun.prior_cov(mdl.StateLayout("pr", drift=True))
    xt = np.r_[truth, 0.0, 0.0, 0.0, 50.0, 0.0]
    x0 = xt + rng.standard_normal((12, 8)) @ np.linalg.cholesky(P0).T
    for kind in ("ekf", "ukf"):
        trk = CvTracker(kind, "pr", x0, tun, t0_s=0.0)
        for k in range(200):  # 10 s of 50 ms slots
            j = k % 5
            trk.predict_to(0.05 * (k + 1))
            rho = np.linalg.norm(truth - S[j]) + xt[6] + 0.5 * rng.standard_normal(12)
            trk.update(S[j : j + 1], rho[:, None])
        err = np.sqrt(np.mean(np.sum((trk.x[:, :3] - truth) ** 2, axis=1)))
        sig = np.sqrt(np.mean(np.trace(trk.P[:, :3, :3], axis1=1, axis2=2)))
        assert sig < 10.0 and err < 10.0, (kind, err, sig)


def _ekf_pr_over(ac, track, xt, t, tun, runs: int, seed: int):
    """An EKF-PR (8 states) over ``track`` from the prior around the truth, seeded; returns it."""
    from aircraft.montecarlo import radio as sim
    from aircraft.navigator.radio import models as mdl

    rng = np.random.default_rng(seed)
    rho = sim.pseudoranges(track, ac.world.stations_m, ac.world.clock, ac.world.sigma_m, runs, rng)
    x0 = xt[0] + rng.standard_normal((runs, 8)) @ np.linalg.cholesky(tun.prior_cov(mdl.StateLayout("pr", drift=True))).T
    trk = CvTracker("ekf", "pr", x0, tun)
    for k in range(t.size):
        trk.predict_to(float(t[k]))
        trk.update(ac.world.stations_m, rho[k])
    return trk


def test_hover_overhead_height_does_not_drift_with_the_lagged_height_column():
    """Right above the centre of the seed001 square the height is not observable; an EKF whose
    Jacobian's height column is taken at its own (noisy) horizontal estimate pushed the height up
    (+17 m mean after 10 s at 100 m, 24 runs; docs/aircraft.md). With the column at the low-passed
    horizontal position (``height_jacobian_lag_s``, default) the mean stays small (+4 m)."""
    from aircraft.montecarlo import radio as sim
    from aircraft.navigator.radio import models as mdl
    from larns.bench import envelope as env

    ac = from_scenario(load("seed001"))
    t = np.arange(0.0, 10.0, 1.0 / ac.world.rate_hz)
    track = env._tracks(ac, env.points((100.0,), (0.0,), (225.0,), ("hover",)), t)[0]
    lay = mdl.StateLayout("pr", drift=True)
    xt = sim.true_state(track, ac.world.clock, lay)
    out = {}
    for lag in (2.0, 0.0):
        trk = _ekf_pr_over(ac, track, xt, t, ac.nav.tuning if lag else ac.nav.tuning.without("lag"), 24, 2)
        out[lag] = float(np.mean(trk.x[:, 2] - xt[-1, 2]))
    assert abs(out[2.0]) < 8.0 and out[0.0] > 15.0, out


def test_symmetry_plane_no_drift_along_the_unobservable_direction():
    """Hover 50 m high, 100 m out on the mirror plane of the seed001 square (bearing 180): symmetric
    stations give equal ranges, so one combination of (x, z, clock) is unobservable at the truth, along
    a curved ridge. Lagging only the height column left the estimate drifting along it (mean +15 m
    after 10 s, 96 runs); lagging the filter's own least observable direction
    (``lag_direction = "weakest"``, default) keeps it small. Seeded, 48 runs."""
    from aircraft.montecarlo import radio as sim
    from aircraft.navigator.radio import models as mdl
    from larns.bench import envelope as env

    ac = from_scenario(load("seed001"))
    t = np.arange(0.0, 10.0, 1.0 / ac.world.rate_hz)
    track = env._tracks(ac, env.points((50.0,), (100.0,), (180.0,), ("hover",)), t)[0]
    lay = mdl.StateLayout("pr", drift=True)
    xt = sim.true_state(track, ac.world.clock, lay)
    Hpb = mdl.jac_pr(xt[-1][None], ac.world.stations_m)[0][:, [0, 1, 2, 6]]
    null = np.linalg.svd(Hpb)[2][-1]  # the truth's unobservable (x, y, z, b) direction (test side only)
    assert np.linalg.norm(Hpb @ null) < 1e-9
    out = {}
    for mode in ("weakest", "height"):
        tu = ac.nav.tuning if mode == "weakest" else ac.nav.tuning.without("weakest")
        trk = _ekf_pr_over(ac, track, xt, t, tu, 48, 5)
        e = (trk.x - xt[-1])[:, [0, 1, 2, 6]] @ null
        out[mode] = abs(float(np.mean(e)))
    assert out["weakest"] < 0.5 * out["height"] and out["height"] > 10.0, out
