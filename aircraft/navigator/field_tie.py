"""Tying a LARNS field to the Earth (navigator side, no truth): the field's self-surveyed network frame
is local and arbitrary (seed 000 eq. 1); a few stations also carry surveyed geodetic positions (seed
002's "geodetically tied" reference points). A least-squares rigid fit (Kabsch/Procrustes, no scale)
of the network-frame positions of those tie stations onto their surveyed local (ENU) positions maps
every station into the triad's Earth-tied frame; the fit's covariance is propagated to first order
(numerical Jacobian of the whole map) into each station's local position, and from there into the
pseudorange variance ``sigma^2 + u^T Sigma_j u``.

The tie error is constant over a flight: our filter carries the ranged stations' position errors as
random-constant states with the tie's joint covariance as their prior (:class:`FieldTie.cov_full_m2`);
:meth:`FieldTie.range_var_m2` is the cheaper white treatment (the paper's filter, which assumes
exactly known stations, uses it). docs/triad.md measures both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nav.geometry import range_jacobian


def kabsch(a_m: np.ndarray, b_m: np.ndarray, w: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rigid ``R`` (3, 3), ``t`` (3,) minimizing ``sum w_i |R a_i + t - b_i|^2`` over points (k, 3), k >= 3
    not collinear (proper rotation: the SVD's reflection is removed)."""
    a, b = np.asarray(a_m, float), np.asarray(b_m, float)
    w = np.ones(len(a)) if w is None else np.asarray(w, float)
    ca = (w[:, None] * a).sum(0) / w.sum()
    cb = (w[:, None] * b).sum(0) / w.sum()
    H = ((a - ca) * w[:, None]).T @ (b - cb)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, cb - R @ ca


@dataclass
class FieldTie:
    """Stations mapped to the local frame: ``stations_m`` (..., m, 3) and their covariances ``cov_m2``
    (..., m, 3, 3) (leading axes: runs, see :func:`stack`)."""

    stations_m: np.ndarray
    cov_m2: np.ndarray
    R: np.ndarray
    t: np.ndarray
    cov_full_m2: np.ndarray | None = None  # (..., 3m, 3m) joint covariance (station-major)

    def range_var_m2(self, p_m: np.ndarray, sigma_m: float | np.ndarray) -> np.ndarray:
        """Pseudorange variances (M, m) seen from positions (M, 3): ``sigma^2 + u^T Sigma_j u``."""
        u = range_jacobian(np.asarray(p_m, float)[:, None, :], self.stations_m)
        return np.asarray(sigma_m, float) ** 2 + np.einsum("...ji,...jik,...jk->...j", u, self.cov_m2, u)

    def subset(self, idx) -> "FieldTie":
        """The stations ``idx`` only (last station axis)."""
        i = np.asarray(idx, dtype=int)
        r = (3 * i[:, None] + np.arange(3)).ravel()
        full = None if self.cov_full_m2 is None else self.cov_full_m2[..., r[:, None], r[None, :]]
        return FieldTie(self.stations_m[..., i, :], self.cov_m2[..., i, :, :], self.R, self.t, full)


def stack(ties: list[FieldTie]) -> FieldTie:
    """One tie per run -> arrays with a leading run axis (M, m, ...)."""
    return FieldTie(np.stack([t.stations_m for t in ties]), np.stack([t.cov_m2 for t in ties]),
                    np.stack([t.R for t in ties]), np.stack([t.t for t in ties]),
                    np.stack([t.cov_full_m2 for t in ties]))


def tie(stations_n_m: np.ndarray, sigma_n_m: float, tie_idx: np.ndarray, tie_local_m: np.ndarray,
        sigma_tie_m: np.ndarray, eps_m: float = 1e-3) -> FieldTie:
    """Tie the field (module doc).

    Parameters
    ----------
    stations_n_m : (m, 3) self-surveyed network-frame positions, each coordinate with ``sigma_n_m``.
    tie_idx : (k,) indices of the surveyed stations; tie_local_m : (k, 3) their surveyed local (ENU)
    positions with per-axis sigmas ``sigma_tie_m`` (3,) (e.g. horizontal, horizontal, vertical).

    Returns
    -------
    FieldTie with every station's local position and covariance.
    """
    pn = np.asarray(stations_n_m, float)
    pt = np.asarray(tie_local_m, float)
    idx = np.asarray(tie_idx)
    m = len(pn)

    def f(theta: np.ndarray) -> np.ndarray:
        a = theta[: 3 * m].reshape(m, 3)
        b = theta[3 * m:].reshape(-1, 3)
        R, t = kabsch(a[idx], b)
        return (a @ R.T + t).ravel()

    theta = np.concatenate([pn.ravel(), pt.ravel()])
    R, t = kabsch(pn[idx], pt)
    J = np.empty((3 * m, theta.size))
    for i in range(theta.size):  # central differences: the map is smooth in its inputs
        e = np.zeros(theta.size)
        e[i] = eps_m
        J[:, i] = (f(theta + e) - f(theta - e)) / (2.0 * eps_m)
    var = np.concatenate([np.full(3 * m, sigma_n_m**2), np.tile(np.asarray(sigma_tie_m, float) ** 2, len(idx))])
    C = (J * var) @ J.T
    cov = np.stack([C[3 * j:3 * j + 3, 3 * j:3 * j + 3] for j in range(m)])
    return FieldTie(pn @ R.T + t, 0.5 * (cov + np.swapaxes(cov, -1, -2)), R, t, 0.5 * (C + C.T))


def perfect(stations_local_m: np.ndarray) -> FieldTie:
    """A yardstick only: stations at given local positions with zero covariance."""
    s = np.asarray(stations_local_m, float)
    return FieldTie(s, np.zeros((len(s), 3, 3)), np.eye(3), np.zeros(3), np.zeros((3 * len(s), 3 * len(s))))
