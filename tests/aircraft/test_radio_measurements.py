"""aircraft/navigator/radio/measurements.py: the pseudorange and range-difference models (value,
Jacobian, noise) and the ranges' second-order terms, each against an independent computation."""

import numpy as np
import pytest

from aircraft.navigator.radio import models as mdl
from aircraft.navigator.radio.measurements import make_model, second_order
from radio_support import fd_jac

ST = np.array([[50.0, 0.0, 0.0], [0.0, 50.0, 2.0], [-50.0, 0.0, 5.0], [0.0, -50.0, 0.0], [30.0, 30.0, 40.0]])


@pytest.mark.parametrize("kind", ["pr", "tdoa"])
@pytest.mark.parametrize("tdma", [False, True])
def test_jacobian_matches_central_differences(kind, tdma):
    rng = np.random.default_rng(1)
    n0 = 8 if kind == "pr" else 6
    nb = 3
    X = np.concatenate([rng.normal(0, 100, (4, 3)) + [0, 0, 300], rng.normal(0, 5, (4, 3)),
                        rng.normal(0, 10, (4, n0 - 6)), rng.normal(0, 1, (4, nb))], axis=-1)
    dt = np.array([-0.04, -0.03, -0.02, -0.01, 0.0]) if tdma else None
    D = np.zeros((5, nb))
    D[[0, 2, 4], [0, 1, 2]] = 1.0
    mod = make_model(kind, ST, n0, base=1, dt_s=dt, D=D)
    J = mod.jacobian(X)
    assert J.shape == (4, 5 if kind == "pr" else 4, n0 + nb)
    np.testing.assert_allclose(J, fd_jac(mod.value, X), atol=1e-7)
    # the value itself: ranges at the measurement times, clock and biases added (differences: cancelled)
    p = X[:, None, :3] + (0 if dt is None else X[:, None, 3:6] * dt[:, None])
    r = np.linalg.norm(p - ST, axis=-1) + X[:, n0:] @ D.T
    if kind == "pr":
        want = r + X[:, 6:7] + (0 if dt is None else X[:, 7:8] * dt)
    else:
        want = np.delete(r, 1, axis=-1) - r[:, 1:2]
    np.testing.assert_allclose(mod.value(X), want, rtol=0, atol=1e-9)


@pytest.mark.parametrize("kind", ["pr", "tdoa"])
def test_noise_is_range_variance_through_the_differencing(kind):
    rng = np.random.default_rng(2)
    X = np.concatenate([rng.normal(0, 100, (3, 3)) + [0, 0, 300], np.zeros((3, 3))], axis=-1)
    A = rng.normal(0, 0.3, (5, 3, 3))
    cov = A @ np.swapaxes(A, -1, -2)
    mod = make_model(kind, ST, 6, base=2)
    d = X[:, None, :3] - ST
    u = d / np.linalg.norm(d, axis=-1, keepdims=True)
    var = 0.25 + np.einsum("kmi,mij,kmj->km", u, cov, u)
    R = np.stack([np.diag(v) for v in var])
    if kind == "tdoa":
        G = np.delete(np.eye(5), 2, axis=0)
        G[:, 2] = -1.0
        R = G @ R @ G.T
    np.testing.assert_allclose(mod.noise(X, cov, 0.5), R, rtol=1e-12)


def test_second_order_mean_is_half_the_trace_of_the_range_hessian_times_P():
    rng = np.random.default_rng(3)
    X = np.concatenate([[20.0, -10.0, 60.0], [3.0, 1.0, -1.0], [5.0]])[None]
    A = rng.normal(0, 2, (7, 7))
    P = (A @ A.T)[None]
    dt = np.array([-0.3, -0.2, -0.1, 0.0, 0.1])
    c2, S2 = second_order(ST, dt, X, P)
    for j in range(5):
        def rj(Z):
            return mdl.h_pr(Z, ST, dt)[..., j] - Z[..., 6]
        H = fd_jac(lambda Z: fd_jac(rj, Z, 1e-3), X, 1e-3)[0]  # (7, 7) Hessian
        np.testing.assert_allclose(c2[0, j], 0.5 * np.trace(H @ P[0]), rtol=1e-5)
        np.testing.assert_allclose(S2[0, j, j], 0.5 * np.trace(H @ P[0] @ H @ P[0]), rtol=1e-5)
    np.testing.assert_allclose(S2, np.swapaxes(S2, -1, -2), rtol=1e-12)
