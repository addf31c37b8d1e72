"""nav/: unscented transform, Kalman steps, geometry, frame, survey CRLB."""

import numpy as np
import pytest

from nav.crlb import batch_map, survey_crlb, survey_fim
from nav.geometry import frame_free_mask, range_jacobian, ranges, to_network_frame
from nav.kalman import ekf_update, kf_predict, kf_update, nees, ukf_predict, ukf_update
from nav.ut import SigmaParams, sigma_points, unscented_transform

PARAMS = [SigmaParams.julier(), SigmaParams.julier(kappa=1.0), SigmaParams.scaled(1e-3, 2.0, 0.0),
          SigmaParams.scaled(0.5, 2.0, 1.0)]


def _spd(rng, n, batch=()):
    A = rng.normal(size=batch + (n, n))
    return A @ np.swapaxes(A, -1, -2) + n * np.eye(n)


@pytest.mark.parametrize("params", PARAMS)
def test_ut_exact_for_linear_maps_and_batched(params):
    rng = np.random.default_rng(0)
    n, m, B = 4, 3, (5, 2)
    x = rng.normal(size=B + (n,))
    P = _spd(rng, n, B)
    A = rng.normal(size=(m, n))
    c = rng.normal(size=m)
    ut = unscented_transform(lambda X: X @ A.T + c, x, P, params)
    np.testing.assert_allclose(ut.mean, x @ A.T + c, atol=1e-9)
    np.testing.assert_allclose(ut.cov, A @ P @ A.T, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(ut.cross, P @ A.T, rtol=1e-9, atol=1e-9)
    assert ut.sigma_x.shape == B + (2 * n + 1, n)


def test_sigma_points_reproduce_mean_and_covariance():
    rng = np.random.default_rng(1)
    x, P = rng.normal(size=3), _spd(rng, 3)
    p = SigmaParams.scaled(0.3, 2.0, 0.0)
    X = sigma_points(x, P, p)
    wm, wc, _ = p.weights(3)
    np.testing.assert_allclose(wm @ X, x, atol=1e-12)
    d = X - x
    np.testing.assert_allclose((wc[:, None, None] * d[:, :, None] * d[:, None, :]).sum(0) - (wc[0] - wm[0]) * 0, P,
                               rtol=1e-9)


def test_ut_matches_analytic_moments_of_quadratic():
    # y = x^T x for x ~ N(mu, P): E[y] = mu^T mu + tr P (exact for sigma points with any kappa)
    rng = np.random.default_rng(2)
    mu, P = rng.normal(size=3), _spd(rng, 3) * 0.1
    ut = unscented_transform(lambda X: np.sum(X**2, axis=-1, keepdims=True), mu, P, SigmaParams.julier())
    assert ut.mean[0] == pytest.approx(mu @ mu + np.trace(P), rel=1e-12)
    # scalar case: Var[x^2] = 2 s^4 + 4 mu^2 s^2; Julier's n + kappa = 3 matches the Gaussian kurtosis
    m1, s2 = 0.7, 0.3
    ut1 = unscented_transform(lambda X: X**2, np.array([m1]), np.array([[s2]]), SigmaParams.julier())
    assert ut1.cov[0, 0] == pytest.approx(2 * s2**2 + 4 * m1**2 * s2, rel=1e-12)


def test_filters_equal_linear_kf_on_linear_model():
    rng = np.random.default_rng(3)
    n, m = 4, 2
    F = np.eye(n) + 0.1 * rng.normal(size=(n, n))
    H = rng.normal(size=(m, n))
    Q, R = _spd(rng, n) * 0.01, _spd(rng, m) * 0.1
    x, P = rng.normal(size=n), _spd(rng, n)
    xk, Pk = x.copy(), P.copy()
    xu, Pu = x.copy(), P.copy()
    xe, Pe = x.copy(), P.copy()
    params = SigmaParams.scaled(0.5, 2.0, 0.0)
    for _ in range(5):
        z = rng.normal(size=m)
        xk, Pk = kf_predict(xk, Pk, F, Q)
        xk, Pk, _, _ = kf_update(xk, Pk, z, H, R)
        xu, Pu = ukf_predict(xu, Pu, lambda X: X @ F.T, Q, params)
        xu, Pu, _, _ = ukf_update(xu, Pu, z, lambda X: X @ H.T, R, params)
        xe, Pe = kf_predict(xe, Pe, F, Q)
        xe, Pe, _, _ = ekf_update(xe, Pe, z, lambda X: X @ H.T, H, R)
    np.testing.assert_allclose(xu, xk, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(Pu, Pk, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(xe, xk, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(Pe, Pk, rtol=1e-9, atol=1e-9)


def test_range_jacobian_matches_finite_differences():
    rng = np.random.default_rng(4)
    a, b = rng.normal(size=(6, 3)) * 100, rng.normal(size=(6, 3)) * 100
    J = range_jacobian(a, b)
    h = 1e-5
    for i in range(3):
        e = np.zeros(3)
        e[i] = h
        fd = (ranges(a + e, b) - ranges(a - e, b)) / (2 * h)
        np.testing.assert_allclose(J[:, i], fd, atol=1e-7)


def test_network_frame_puts_frame_stations_on_constraints_and_preserves_ranges():
    rng = np.random.default_rng(5)
    phys = rng.uniform(0, 2000, size=(8, 3)) * [1, 1, 0.04]
    out, R, t = to_network_frame(phys, z_ref=3)
    assert np.allclose(out[0], 0) and np.allclose(out[1, 1:], 0) and out[2, 2] == 0 and out[3, 2] > 0
    assert out[1, 0] > 0
    np.testing.assert_allclose(np.linalg.det(R), 1.0)  # proper rotation, no mirror
    i, j = np.triu_indices(8, 1)
    np.testing.assert_allclose(ranges(out[i], out[j]), ranges(phys[i], phys[j]), rtol=1e-12)
    m = frame_free_mask(8)
    assert m.sum() == 8 * 3 - 6 and m[1].tolist() == [True, False, False] and m[2].tolist() == [True, True, False]


def test_survey_crlb_matches_finite_difference_fisher():
    rng = np.random.default_rng(6)
    n, sd = 6, 0.7
    pos, _, _ = to_network_frame(rng.uniform(0, 1000, size=(n, 3)) * [1, 1, 0.2])
    counts = rng.integers(0, 4, size=(n, n))
    np.fill_diagonal(counts, 0)
    free = frame_free_mask(n)
    J = survey_fim(pos, counts, sd, free, 10.0)
    # finite-difference Jacobian of all ranges w.r.t. theta
    pairs = [(i, j) for i in range(n) for j in range(n) if counts[i, j]]
    theta = pos[free]

    def h(th):
        X = pos.copy()
        X[free] = th
        return np.array([np.linalg.norm(X[i] - X[j]) for i, j in pairs])

    G = np.zeros((len(pairs), theta.size))
    for k in range(theta.size):
        e = np.zeros(theta.size)
        e[k] = 1e-6
        G[:, k] = (h(theta + e) - h(theta - e)) / 2e-6
    w = np.array([counts[i, j] for i, j in pairs]) / sd**2
    J_fd = G.T @ (w[:, None] * G) + np.eye(theta.size) / 100.0
    np.testing.assert_allclose(J, J_fd, rtol=1e-6, atol=1e-6)
    C = survey_crlb(pos, counts, sd, free, 10.0)
    assert np.all(C[0] == 0) and np.all(C[1][1:, :] == 0) and C[1][0, 0] > 0


def test_survey_fim_takes_each_links_own_noise():
    """Per-link sigma (a radio's SNR-dependent noise): equal sigmas give the scalar bound, and one
    noisier link is the finite-difference Fisher with that link's weight alone changed."""
    rng = np.random.default_rng(8)
    n = 5
    pos, _, _ = to_network_frame(rng.uniform(0, 1000, size=(n, 3)) * [1, 1, 0.2])
    counts = np.ones((n, n), int) - np.eye(n, dtype=int)
    free = frame_free_mask(n)
    np.testing.assert_array_equal(survey_fim(pos, counts, np.full((n, n), 0.7), free, 10.0),
                                  survey_fim(pos, counts, 0.7, free, 10.0))
    sig = np.full((n, n), 0.7)
    sig[1, 3] = sig[3, 1] = 2.0
    d = pos[1] - pos[3]
    u = d / np.linalg.norm(d)
    g = np.zeros(int(free.sum()))
    idx = -np.ones(free.shape, int)
    idx[free] = np.arange(int(free.sum()))
    g[idx[1][free[1]]] += u[free[1]]
    g[idx[3][free[3]]] -= u[free[3]]
    expect = survey_fim(pos, counts, 0.7, free, 10.0) - 2 * (1 / 0.7**2 - 1 / 2.0**2) * np.outer(g, g)
    np.testing.assert_allclose(survey_fim(pos, counts, sig, free, 10.0), expect, rtol=1e-12, atol=1e-12)


def test_batch_map_recovers_truth_without_noise():
    rng = np.random.default_rng(7)
    n = 6
    pos, _, _ = to_network_frame(rng.uniform(0, 1000, size=(n, 3)) * [1, 1, 0.3])
    free = frame_free_mask(n)
    i, j = np.triu_indices(n, 1)
    pairs = np.stack([i, j], 1)
    r = np.linalg.norm(pos[i] - pos[j], axis=1)
    prior = pos + rng.normal(0, 3.0, size=pos.shape) * free
    X = batch_map(pairs, r, 0.1, free, prior, None)
    np.testing.assert_allclose(X, pos, atol=1e-6)


def test_nees_is_chi_square_for_true_covariance():
    rng = np.random.default_rng(8)
    P = _spd(rng, 3, (4000,))
    e = np.einsum("kij,kj->ki", np.linalg.cholesky(P), rng.normal(size=(4000, 3)))
    assert nees(e, P).mean() == pytest.approx(3.0, abs=0.15)


def test_the_scalar_error_state_update_is_the_joseph_update_of_one_measurement():
    """nav.kalman.scalar_update (rank-one terms, O(n^2)) equals nav.kalman's Joseph-form update
    (kf_update, joseph) for one scalar measurement, batched over runs, and joseph's diagonal form equals
    its full form."""
    from nav.kalman import scalar_update
    from nav.kalman import joseph

    rng = np.random.default_rng(11)
    M, n = 4, 6
    A = rng.normal(size=(M, n, n))
    P = A @ np.swapaxes(A, -1, -2) + n * np.eye(n)
    h = rng.normal(size=(M, n))
    r = rng.uniform(0.5, 2.0, M)
    nu = rng.normal(size=M)
    dx, Pn, s = scalar_update(P, h, r, nu)
    H = h[:, None, :]
    x1, P1, nu1, S1 = kf_update(np.zeros((M, n)), P, nu[:, None], H, r[:, None, None])
    np.testing.assert_allclose(dx, x1, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(Pn, P1, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(s, S1[:, 0, 0], rtol=1e-13)
    K = rng.normal(size=(M, n, 3))  # any gain: the Joseph form holds for it
    H3 = rng.normal(size=(M, 3, n))
    rd = rng.uniform(0.5, 2.0, (M, 3))
    np.testing.assert_allclose(joseph(P, K, H3, rd, diagonal=True),
                               joseph(P, K, H3, rd[..., None] * np.eye(3)), rtol=1e-12, atol=1e-9)
