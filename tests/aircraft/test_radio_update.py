"""aircraft/navigator/radio/update.py: the EKF and UKF strategies (plain and iterated) reduce to the
linear Kalman update on a linear measurement model."""

import dataclasses

import numpy as np
import pytest

from aircraft.navigator.radio.tracker import CvTracker
from aircraft.navigator.radio.tuning import Tuning
from nav.kalman import kf_update


class LinearModel:
    kind = "pr"
    stations_m = None
    dt_s = None

    def __init__(self, H, b):
        self.H, self.b = H, b

    def value(self, X):
        return np.einsum("ij,...j->...i", self.H, X) + self.b

    def jacobian(self, X):
        return np.broadcast_to(self.H, X.shape[:-1] + self.H.shape).copy()

    def project(self, c2, S2):
        return c2, S2


@dataclasses.dataclass(frozen=True)
class _EveryRunIterated(Tuning):
    """The textbook filters iterated ``passes`` times on every run (no threshold)."""

    passes: int = 3

    @property
    def iterations(self) -> int:
        return self.passes

    @property
    def iterate_threshold(self) -> float:
        return 0.0


@pytest.mark.parametrize("kind", ["ekf", "ukf"])
@pytest.mark.parametrize("iterations", [1, 3])
def test_strategy_is_the_linear_kalman_update_on_a_linear_model(kind, iterations):
    rng = np.random.default_rng(8)
    tu = _EveryRunIterated(rules=(), floor_z_m=None, passes=iterations)
    x0 = rng.normal(0, 10, (4, 8))
    A = rng.normal(0, 1, (4, 8, 8))
    P0 = A @ np.swapaxes(A, -1, -2) + np.eye(8)
    trk = CvTracker(kind, "pr", x0, tu, P0=P0)
    H, b = rng.normal(0, 1, (5, 8)), rng.normal(0, 1, 5)
    R = np.diag(rng.uniform(0.2, 2.0, 5))
    z = rng.normal(0, 10, (4, 5))
    x1, P1, nu, S = trk.strategy(trk, LinearModel(H, b), z, np.broadcast_to(R, (4, 5, 5)), 1.0)
    xk, Pk, nuk, Sk = kf_update(x0, P0, z - b, H, R)
    np.testing.assert_allclose(x1, xk, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(P1, Pk, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(nu, nuk, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(S, Sk, rtol=1e-8, atol=1e-8)
