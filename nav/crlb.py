"""Centralized yardstick for the self-survey: Bayesian CRLB and batch MAP over all stations.

Only for *measuring* the decentralized estimators; no station ever uses it.

Unknowns ``theta`` are the free coordinates of all stations (``free`` mask (n, 3), seed 000
constraints (1)). A two-way range between stations i and j has gradient ``+u`` on i's free
coordinates and ``-u`` on j's, ``u = (c_i - c_j)/|c_i - c_j|``. The Bayesian information is

    J = P0^-1 + sum_links n_ij / sigma_d^2 g_ij g_ij^T,

and the bound on the covariance of any estimator is ``J^-1`` (prior ``P0 = sigma0^2 I`` on free
coordinates of the stations that have a coarse fix). ``n_ij`` counts two-way ranges' information: one
per addressed exchange, 4/3 per protocol v2 exchange closed by its final (:func:`poll_exchange_counts`).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
from scipy.optimize import least_squares


def _index(free: np.ndarray) -> np.ndarray:
    """(n, 3) int map from (station, axis) to the position in theta, -1 for constrained."""
    idx = -np.ones(free.shape, dtype=np.int64)
    idx[free] = np.arange(int(free.sum()))
    return idx


def survey_fim(pos_m: np.ndarray, counts: np.ndarray, sigma_d_m: float | np.ndarray, free: np.ndarray,
               sigma0_m: float | np.ndarray | None) -> np.ndarray:
    """Bayesian Fisher information of the free coordinates.

    Parameters
    ----------
    pos_m : (n, 3) true positions (network frame). counts : (n, n) ranges measured per ordered pair
        (initiator, responder), in units of one two-way range's information (float: protocol v2's
        exchanges count 4/3 when closed by their final, :func:`poll_exchange_counts`); the pair total
        ``counts + counts.T`` is what matters.
    sigma_d_m : range noise, scalar or (n, n) per link (a radio's SNR-dependent noise; only the pairs
        measured are read). free : (n, 3) bool. sigma0_m : prior sigma per coordinate, scalar or (n,)
        (``np.inf`` / None for no prior).

    Returns
    -------
    J : (p, p) with ``p = free.sum()``.
    """
    idx = _index(free)
    p = int(free.sum())
    J = np.zeros((p, p))
    if sigma0_m is not None:
        s0 = np.broadcast_to(np.asarray(sigma0_m, dtype=float), (len(pos_m),))
        for i in range(len(pos_m)):
            if np.isfinite(s0[i]) and s0[i] > 0:
                k = idx[i][free[i]]
                J[k, k] += 1.0 / s0[i] ** 2
    tot = counts + counts.T
    sig = np.broadcast_to(np.asarray(sigma_d_m, dtype=float), tot.shape)
    ii, jj = np.nonzero(np.triu(tot, 1))
    # each link (i, j) adds w g g^T, g = [u on i's free coordinates, -u on j's]: its four 3 x 3 blocks
    # scattered into J (cost per link, not per link times the field's size: a sparse graph stays cheap)
    d = pos_m[ii] - pos_m[jj]
    u = d / np.linalg.norm(d, axis=1)[:, None]  # (m, 3)
    w = tot[ii, jj] / sig[ii, jj] ** 2  # (m,)
    rows = np.concatenate([idx[ii], idx[jj]], axis=1)  # (m, 6): -1 on constrained coordinates
    g = np.concatenate([u, -u], axis=1)  # (m, 6)
    ok = rows >= 0
    g = np.where(ok, g, 0.0)
    r = np.where(ok, rows, 0)
    blocks = w[:, None, None] * g[:, :, None] * g[:, None, :]  # (m, 6, 6)
    np.add.at(J, (np.broadcast_to(r[:, :, None], blocks.shape), np.broadcast_to(r[:, None, :], blocks.shape)),
              blocks)
    return J


#: Fisher information on the distance of one protocol v2 exchange closed by its final, in units of one
#: two-way range's ``1 / sigma_d^2`` (:func:`poll_exchange_counts`)
POLL_EXCHANGE_INFO = 4.0 / 3.0


def poll_exchange_counts(replies: np.ndarray, finals: np.ndarray | None) -> np.ndarray:
    """Range-equivalent counts (n, n) of protocol v2's exchanges, for :func:`survey_fim` / :func:`survey_crlb`.

    One exchange between poller A and member B has three one-way receptions (poll A->B, reply
    B->A, final A->B), each arrival stamp with independent noise ``sigma_t = sqrt(2) sigma_d / c``
    (net/channel.py: a two-way range of two legs has ``sigma_d``). In range units, with durations on
    frequency-corrected clocks and ``theta`` the clocks' offset (B minus A) over the exchange::

        y1 = c (T2 - T1) = d + theta + e1      (poll)
        y2 = c (T4 - T3) = d - theta + e2      (reply)
        y3 = c (T6 - T5) = d + theta + e3      (final),   e ~ N(0, 2 sigma_d^2)

    The information on ``(d, theta)`` is ``H^T H / (2 sigma_d^2)``, ``H = [[1, 1], [1, -1], [1, 1]]``,
    i.e. ``[[3, 1], [1, 3]] / (2 sigma_d^2)``, whose inverse bounds ``d`` at ``3/4 sigma_d^2``: an
    exchange closed by its final carries ``4/3`` ranges' information (:data:`POLL_EXCHANGE_INFO`),
    attained by the mean of its two single-sided ranges (``stations.dstwr.sym_twr_range_m``). Without
    the final (``y1, y2``) it is one range: ``sigma_d^2``, the poller's single-sided range, and the
    addressed exchange's. The offset is a nuisance per exchange (the clocks are not assumed known to
    a fraction of a leg's noise between exchanges); the frequencies are the clock filter's.

    Parameters
    ----------
    replies : (n, n) replies heard by the poller, [poller, member] (the simulator's ``link_counts``).
    finals : (n, n) finals the member closed its exchange with, [member, poller]; None: none (the
        addressed protocol).

    Returns
    -------
    (n, n) float counts: ``replies + (4/3 - 1) finals^T`` (a final is only taken with its reply heard).
    """
    counts = np.asarray(replies, dtype=float)
    if finals is None:
        return counts
    return counts + (POLL_EXCHANGE_INFO - 1.0) * np.asarray(finals, dtype=float).T


def survey_crlb(pos_m, counts, sigma_d_m, free, sigma0_m) -> np.ndarray:
    """Per-station bound covariances (n, 3, 3) (zeros on constrained coordinates), from ``J^-1``;
    ``sigma_d_m`` scalar or (n, n) per link (:func:`survey_fim`)."""
    J = survey_fim(pos_m, counts, sigma_d_m, free, sigma0_m)
    C = sla.cho_solve(sla.cho_factor(J, lower=True), np.eye(len(J)))
    idx = _index(free)
    n = len(pos_m)
    out = np.zeros((n, 3, 3))
    for i in range(n):
        k = idx[i][free[i]]
        out[i][np.ix_(free[i], free[i])] = C[np.ix_(k, k)]
    return out


def batch_map(pairs: np.ndarray, ranges_m: np.ndarray, sigma_d_m: float, free: np.ndarray,
              prior_m: np.ndarray, sigma0_m: float | None, x0_m: np.ndarray | None = None) -> np.ndarray:
    """Centralized batch MAP (ML if ``sigma0_m`` is None) of all station positions.

    Parameters
    ----------
    pairs : (m, 2) station indices of each range. ranges_m : (m,).
    free : (n, 3). prior_m : (n, 3) prior means (coarse fixes; constrained entries = their fixed values).
    x0_m : (n, 3) starting point (default: the prior).

    Returns
    -------
    (n, 3) estimated positions.
    """
    prior_m = np.asarray(prior_m, dtype=float)
    base = prior_m.copy()
    start = (prior_m if x0_m is None else np.asarray(x0_m, float))[free]
    i, j = pairs[:, 0], pairs[:, 1]

    def resid(theta):
        X = base.copy()
        X[free] = theta
        d = np.linalg.norm(X[i] - X[j], axis=1)
        r = (ranges_m - d) / sigma_d_m
        if sigma0_m is not None:
            r = np.concatenate([r, (theta - prior_m[free]) / sigma0_m])
        return r

    idx = _index(free)
    p = start.size

    def jac(theta):
        X = base.copy()
        X[free] = theta
        d = X[i] - X[j]
        u = d / np.linalg.norm(d, axis=1)[:, None]
        G = np.zeros((len(ranges_m), p))
        rows = np.arange(len(ranges_m))
        for ax in range(3):
            fi, fj = free[i, ax], free[j, ax]
            G[rows[fi], idx[i[fi], ax]] -= u[fi, ax] / sigma_d_m
            G[rows[fj], idx[j[fj], ax]] += u[fj, ax] / sigma_d_m
        if sigma0_m is not None:
            G = np.vstack([G, np.eye(p) / sigma0_m])
        return G

    sol = least_squares(resid, start, jac=jac, method="lm" if len(ranges_m) > start.size else "trf", xtol=1e-10)
    X = base.copy()
    X[free] = sol.x
    return X
