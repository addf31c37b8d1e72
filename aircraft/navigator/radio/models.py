"""Aircraft measurement and motion models (pure, vectorized over leading axes).

State layouts (all in the network frame, metres and seconds; :class:`StateLayout`, defined in
:mod:`aircraft.navigator.radio.state`):

* ``pr``   : ``[x y z vx vy vz b]`` with ``b = c * dtau`` the receiver clock offset in metres
  (seed 001 eq. 11 extended by velocity, the paper's Theta_rho for the filters);
* ``pr`` with ``drift=True`` : ``[x y z vx vy vz b bdot]`` (clock offset and its rate, m and m/s);
* ``tdoa`` : ``[x y z vx vy vz]`` (seed 001 Theta_drho for the filters).

Measurements (seed 001 eqs. 5, 10, 13), each optionally taken ``dt_j`` seconds away from the
state's time (TDMA slots inside one batch; zero for synchronous epochs):

* pseudorange ``rho_j = |p + v dt_j - s_j| + b (+ bdot dt_j) + xi_j``;
* range difference to base ``b``: ``rho_j - rho_b`` for ``j != b`` (the clock cancels).

Noise: each pseudorange has variance ``sigma^2 + u_j^T P_j u_j`` where ``P_j`` is the 3x3
covariance of station ``j``'s broadcast self-survey position and ``u_j`` the line-of-sight unit
vector (first-order propagation of the station position error into the range). Differences are
weighted with ``G R G^T`` (seed 001 eq. 18), ``G`` = identity with a ``-1`` column at ``b``.
"""

from __future__ import annotations

import numpy as np

from nav.geometry import line_of_sight, ranges

from .state import CLOCK, CLOCK_RATE, POS, VEL
from .state import StateLayout  # noqa: F401  (the layout with named blocks lives there)

ALGOS = ("lsq-pr", "lsq-tdoa", "ekf-pr", "ekf-tdoa", "ukf-pr", "ukf-tdoa")


def g_matrix(m: int, base: int) -> np.ndarray:
    """Differencing matrix ``G`` (m-1, m): identity with a ``-1`` column at ``base`` (seed 001 eq. 18)."""
    G = np.zeros((m - 1, m))
    rows = [j for j in range(m) if j != base]
    G[np.arange(m - 1), rows] = 1.0
    G[:, base] = -1.0
    return G


def _positions(X: np.ndarray, dt: np.ndarray | None) -> np.ndarray:
    """Aircraft positions at the measurement times: (..., m, 3) (or (..., 1, 3) if dt is None)."""
    p = X[..., None, POS]
    if dt is None:
        return p
    return p + X[..., None, VEL] * np.asarray(dt, dtype=float)[:, None]


def los(X: np.ndarray, stations_m: np.ndarray, dt: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Ranges (..., m) and unit line-of-sight vectors station->aircraft (..., m, 3)."""
    return line_of_sight(_positions(X, dt), stations_m)


def _ranges(X: np.ndarray, stations_m: np.ndarray, dt: np.ndarray | None = None) -> np.ndarray:
    """Ranges (..., m) only (no line-of-sight vectors)."""
    return ranges(_positions(X, dt), stations_m)


def h_pr(X: np.ndarray, stations_m: np.ndarray, dt: np.ndarray | None = None) -> np.ndarray:
    """Pseudoranges (..., m) for states X (..., n>=7) (seed 001 eq. 13)."""
    r = _ranges(X, stations_m, dt)
    b = X[..., CLOCK : CLOCK + 1]
    if X.shape[-1] > CLOCK_RATE and dt is not None:
        b = b + X[..., CLOCK_RATE : CLOCK_RATE + 1] * np.asarray(dt, dtype=float)
    return r + b


def h_tdoa(X: np.ndarray, stations_m: np.ndarray, base: int, dt: np.ndarray | None = None) -> np.ndarray:
    """Range differences (..., m-1) ``r_j - r_base`` for j != base, in station order (seed 001 eq. 10)."""
    r = _ranges(X, stations_m, dt)
    return np.delete(r, base, axis=-1) - r[..., base : base + 1]


def jac_pr(X: np.ndarray, stations_m: np.ndarray, dt: np.ndarray | None = None) -> np.ndarray:
    """Jacobian of :func:`h_pr`: (..., m, n) (seed 001 eq. 15 with velocity columns)."""
    _, u = los(X, stations_m, dt)
    m = stations_m.shape[0]
    H = np.zeros(X.shape[:-1] + (m, X.shape[-1]))
    H[..., POS] = u
    if dt is not None:
        H[..., VEL] = u * np.asarray(dt, dtype=float)[:, None]
    H[..., CLOCK] = 1.0
    if X.shape[-1] > CLOCK_RATE and dt is not None:
        H[..., CLOCK_RATE] = dt
    return H


def jac_tdoa(X: np.ndarray, stations_m: np.ndarray, base: int, dt: np.ndarray | None = None) -> np.ndarray:
    """Jacobian of :func:`h_tdoa`: (..., m-1, 6) (seed 001 eq. 17 with velocity columns)."""
    _, u = los(X, stations_m, dt)
    m = stations_m.shape[0]
    Hr = np.zeros(X.shape[:-1] + (m, 6))
    Hr[..., POS] = u
    if dt is not None:
        Hr[..., VEL] = u * np.asarray(dt, dtype=float)[:, None]
    return np.delete(Hr, base, axis=-2) - Hr[..., base : base + 1, :]


def range_var(
    X: np.ndarray, stations_m: np.ndarray, station_cov_m2: np.ndarray | None, sigma_m: float | np.ndarray,
    dt: np.ndarray | None = None,
) -> np.ndarray:
    """Per-pseudorange noise variance (..., m): ``sigma^2 + u^T P_station u``."""
    if station_cov_m2 is None and np.ndim(sigma_m) == 0:
        return np.full(X.shape[:-1] + (stations_m.shape[0],), float(sigma_m) ** 2)
    sig2 = np.asarray(sigma_m, dtype=float) ** 2  # (m,) or per run (..., m)
    if station_cov_m2 is None:
        sig2 = np.broadcast_to(sig2, np.broadcast_shapes(sig2.shape, (stations_m.shape[0],)))
        return np.broadcast_to(sig2, np.broadcast_shapes(X.shape[:-1] + (stations_m.shape[0],), sig2.shape)).copy()
    _, u = los(X, stations_m, dt)  # the sum below broadcasts sig2 to (..., m)
    return sig2 + np.einsum("...mi,mij,...mj->...m", u, station_cov_m2, u)


def r_pr(var: np.ndarray) -> np.ndarray:
    """Diagonal pseudorange covariance (..., m, m) from variances (..., m) (seed 001 eq. 16)."""
    if var.ndim == 1:
        return np.diag(var)
    return var[..., :, None] * np.eye(var.shape[-1])


def r_tdoa(var: np.ndarray, base: int) -> np.ndarray:
    """Range-difference covariance ``G R G^T`` (..., m-1, m-1) (seed 001 eq. 18)."""
    G = g_matrix(var.shape[-1], base)
    return np.einsum("ij,...j,kj->...ik", G, var, G)


_AX = np.arange(3)  # the three axes: position index i, velocity i + 3


def cv_transition(n: int, dt_s: float) -> np.ndarray:
    """Constant-velocity transition (n, n) (seed 001 F_rho / F_drho); clock ``b += bdot dt`` if n == 8."""
    F = np.eye(n)
    F[_AX, _AX + 3] = dt_s
    if n == 8:
        F[CLOCK, CLOCK_RATE] = dt_s
    return F


def cv_noise(n: int, dt_s: float, q_acc: float, q_clock: float, q_drift: float) -> np.ndarray:
    """Process noise (n, n) of the discretized continuous white-noise models.

    Position/velocity per axis: white acceleration of spectral density ``q_acc`` (m^2/s^3):
    ``q [[dt^3/3, dt^2/2], [dt^2/2, dt]]``. Clock offset: random walk ``q_clock`` (m^2/s); clock rate
    (if ``n == 8``): random walk ``q_drift`` (m^2/s^3) integrated into the offset.
    """
    Q = np.zeros((n, n))
    Q[_AX, _AX] = q_acc * (dt_s**3 / 3.0)
    Q[_AX, _AX + 3] = Q[_AX + 3, _AX] = q_acc * (dt_s**2 / 2.0)
    Q[_AX + 3, _AX + 3] = q_acc * dt_s
    if n >= 7:
        Q[CLOCK, CLOCK] = q_clock * dt_s
    if n == 8:
        Q[CLOCK, CLOCK] += q_drift * dt_s**3 / 3.0
        Q[CLOCK, CLOCK_RATE] = Q[CLOCK_RATE, CLOCK] = q_drift * dt_s**2 / 2.0
        Q[CLOCK_RATE, CLOCK_RATE] = q_drift * dt_s
    return Q
