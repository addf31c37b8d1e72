"""Self-survey estimators of one station's own coordinates (pure; no I/O, no RNG).

Two estimators share one interface:

``seed-ukf``  The decentralized UKF of seed 000 (Borzov & Mikaelyan 2016, eqs. 8-13): buffer ``l``
              ranges this station initiated together with the peers' estimates sent in the answers;
              stack ``x = [c_m, c_n1..c_nl]`` over *free* coordinates, ``P = blockdiag(P_m, P_n1..)``;
              Julier sigma points with ``n + kappa = 3``; update ``c_m``, ``P_m`` only.

``dmap``      Our default: a distributed maximum a posteriori estimator. Every exchange is used at
              *both* ends (the initiator shares the range in its nav broadcast). Because stations
              are static, a link's ranges are summarized losslessly by their count and mean. A station
              re-solves its own coordinates by Gauss-Newton on

                  (c - c0)^T P0^-1 (c - c0) + sum_j w_j (dbar_j - |c - c_j|)^2,
                  w_j = 1 / (sigma_d^2 / n_j + u_j^T P_j u_j),

              with the peers' *latest* estimates ``c_j, P_j``. Re-solving from all stored link
              statistics (instead of consuming each range once, as the UKF does) makes the network a
              block-coordinate (Gauss-Seidel) solver of the centralized MAP problem, which is
              efficient (reaches the Bayesian CRLB) once the peers have converged. The ``u^T P_j u``
              term charges each link with its peer's uncertainty, so poorly known peers (newcomers)
              neither pull the solution nor make the covariance overconfident.
              Own covariance: ``(P0^-1 + J^T W J)^-1`` over the free coordinates.

Coordinates constrained by the frame (station 1 all, station 2 y/z, station 3 z) are not state
while the founders hold the frame; ``DistributedMap.hold_datum`` ends that (docs/architecture.md,
"The frame datum"): the station becomes free in x, y, z and keeps its prior, moved with the field's
datum corrections (a founder's newly freed coordinates: a prior at the frame's values), so the field's
configuration, not any one station, carries the datum. A founder that (re)joins a running field is
built free (``founder=False``).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
try:  # np.einsum's own call (optimize=False) without its Python wrapper: the same results
    from numpy._core.multiarray import c_einsum as _einsum
except ImportError:  # NumPy < 2 (pyproject allows 1.26): the public function
    _einsum = np.einsum
from scipy.linalg.lapack import dpotrs, dtrtri

from nav.geometry import frame_free_mask
from nav.kalman import symmetrize, update
from nav.spd3 import spd_solve3
from nav.ut import SigmaParams, chol_lower, unscented_transform
from net.radio import range_var_m2


def free_mask(station_id: int, founder: bool = True) -> np.ndarray:
    """(3,) bool: which of x, y, z station ``station_id`` estimates (``founder=False``: a station
    1-3 that joined a running field, an ordinary station free in all three)."""
    return frame_free_mask(4)[station_id - 1].copy() if station_id <= 3 and founder else np.ones(3, bool)


def _clean_cov(P: np.ndarray, free: np.ndarray, floor_m2: float = 1e-8) -> np.ndarray:
    """Symmetrize, zero constrained rows/cols, keep the free block positive definite."""
    P = symmetrize(np.asarray(P, dtype=float))
    out = np.zeros((3, 3))
    if free.any():
        B = P[np.ix_(free, free)]
        w, V = np.linalg.eigh(B)
        if w.min() < floor_m2:
            B = (V * np.maximum(w, floor_m2)) @ V.T
        out[np.ix_(free, free)] = B
    return out


class SurveyEstimator(Protocol):
    name: str
    pos_m: np.ndarray  # (3,)
    cov_m2: np.ndarray  # (3, 3), zero on constrained coordinates
    n_updates: int
    initialized: bool

    def on_range(self, peer_id: int, range_m: float, t_s: float, initiated: bool,
                 peer_pos_m: np.ndarray | None, peer_cov_m2: np.ndarray | None) -> bool:
        """A range to ``peer_id``; returns True if the estimate changed."""

    def on_peer(self, peer_id: int, pos_m: np.ndarray, cov_m2: np.ndarray) -> None:
        """The peer's latest broadcast estimate."""

    def refresh(self) -> bool:
        """Bring the estimate up to date with everything received; True if it changed."""


class SeedUkf:
    """Seed 000 decentralized UKF (eqs. 8-13), with Julier sigma points ``n + kappa = 3``."""

    name = "seed-ukf"

    def __init__(self, station_id: int, pos0_m: np.ndarray, cov0_m2: np.ndarray, sigma_d_m: float,
                 ranges_per_update: int = 3):
        self.id = station_id
        self.free = free_mask(station_id)
        self.pos_m = np.asarray(pos0_m, dtype=float).copy()
        self.cov_m2 = _clean_cov(cov0_m2, self.free)
        self.sigma_d_m = float(sigma_d_m)
        self.radio = None  # the scenario's [radio] (DistributedMap.radio)
        self.l = int(ranges_per_update)
        self.buffer: list[tuple[int, float, np.ndarray, np.ndarray]] = []
        self.n_updates = 0
        self.initialized = True
        self.params = SigmaParams.julier()

    def on_peer(self, peer_id, pos_m, cov_m2) -> None:  # the paper uses the answers' estimates only
        return None

    def refresh(self) -> bool:  # updates happen in on_range, every l ranges
        return False

    def on_range(self, peer_id, range_m, t_s, initiated, peer_pos_m, peer_cov_m2) -> bool:
        if not initiated or peer_pos_m is None or not self.free.any():
            return False
        self.buffer.append((peer_id, float(range_m), np.asarray(peer_pos_m, float), np.asarray(peer_cov_m2, float)))
        if len(self.buffer) < self.l:
            return False
        self._update()
        self.buffer.clear()
        return True

    def _update(self) -> None:
        # eq. (8): stacked mean/covariance over free coordinates only
        blocks = [(self.pos_m, self.cov_m2, self.free)]
        for pid, _, pp, pc in self.buffer:
            blocks.append((pp, pc, free_mask(pid)))
        base = np.stack([b[0] for b in blocks])  # (l+1, 3)
        masks = np.stack([b[2] for b in blocks])  # (l+1, 3)
        x = np.concatenate([b[0][b[2]] for b in blocks])
        n = x.size
        P = np.zeros((n, n))
        k = 0
        for pos, cov, m in blocks:
            d = int(m.sum())
            P[k:k + d, k:k + d] = cov[np.ix_(m, m)] if d else 0.0
            k += d
        P = symmetrize(P) + 1e-9 * np.eye(n)
        z = np.array([b[1] for b in self.buffer])
        flat_idx = np.flatnonzero(masks.ravel())

        def h(X: np.ndarray) -> np.ndarray:  # eq. (11); X (..., 2n+1, n)
            full = np.broadcast_to(base.ravel(), X.shape[:-1] + (base.size,)).copy()
            full[..., flat_idx] = X
            full = full.reshape(X.shape[:-1] + base.shape)
            d = full[..., :1, :] - full[..., 1:, :]
            return np.sqrt(_einsum("...ki,...ki->...k", d, d))

        ut = unscented_transform(h, x, P, self.params)  # eq. (10)
        # range noise: sigma_d^2, or under [radio] each link's at the estimated geometry
        var = range_var_m2(self.pos_m, np.stack([b[2] for b in self.buffer]), self.radio, self.sigma_d_m)
        S = ut.cov + np.diag(np.broadcast_to(var, (len(z),)))
        nf = int(self.free.sum())
        xm, Pm = update(x[:nf], P[:nf, :nf], z - ut.mean, S, ut.cross[:nf])  # eqs. (12), (13)
        self.pos_m = self.pos_m.copy()
        self.pos_m[self.free] = xm
        P3 = np.zeros((3, 3))
        P3[np.ix_(self.free, self.free)] = Pm
        self.cov_m2 = _clean_cov(P3, self.free)
        self.n_updates += 1


def tukey_weight(z: np.ndarray, c: float) -> np.ndarray:
    """Tukey biweight IRLS weights ``(1 - (z/c)^2)^2`` for ``|z| < c``, else 0 (redescending)."""
    q = np.maximum(1.0 - (np.asarray(z) / c) ** 2, 0.0)  # = np.clip(., 0, None), without its wrapper
    return q * q


def huber_weight(z: np.ndarray, k: float) -> np.ndarray:
    """Huber IRLS weights ``min(1, k/|z|)`` (monotone: a unique solution from any start)."""
    # k / max(|z|, k): exactly 1 wherever |z| <= k (k / k), k / |z| elsewhere
    if k > 0:
        return k / np.maximum(np.abs(np.asarray(z)), k)
    return np.minimum(k / np.maximum(np.abs(np.asarray(z)), 1e-300), 1.0)


def los_cluster(ranges_m: np.ndarray, width_m: float) -> tuple[float, int]:
    """Line-of-sight centre of one link's repeated ranges: the lowest densest cluster.

    NLOS only lengthens a range (positive excess), so the direct path is the shortest value that
    recurs. Over the sorted ranges, the window ``[d_i, d_i + width_m]`` holding the most ranges
    (the lowest such window on a tie) is the LOS cluster; returns its median and its count.

    Parameters
    ----------
    ranges_m : (k,) ranges of one link, k >= 1. width_m : window width (about 4 sigma_d).

    Returns
    -------
    (centre_m, support): support 1 means no two ranges agree (unconfirmed link).
    """
    # plain Python on the sorted values (a link holds a few to a few hundred ranges: NumPy's per-call
    # overhead dominated); the same float operations as np.searchsorted / np.median
    s = sorted(np.asarray(ranges_m, dtype=float).tolist())
    best, lo, j = 0, 0, 0
    for i, v in enumerate(s):  # window [s_i, s_i + width_m] ends before s_j; j never moves left
        top = v + width_m
        while j < len(s) and s[j] <= top:
            j += 1
        if j - i > best:  # strictly more: the lowest window wins a tie
            best, lo = j - i, i
    mid = lo + best // 2  # the window's median
    return (s[mid] if best % 2 else (s[mid - 1] + s[mid]) / 2.0), best


def _spd_solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``A^-1 b`` for a symmetric positive definite ``A`` (n, n) and ``b`` (n,): Cholesky factor and
    triangular solves by LAPACK ``potrf`` / ``potrs`` (raises ``LinAlgError`` unless ``A`` is positive
    definite, like ``np.linalg.cholesky``)."""
    if A.shape == (3, 3):  # on Python floats (nav.spd3: the call costs exceed the arithmetic)
        x = spd_solve3(A.tolist(), b.tolist())
        if x is None:
            raise np.linalg.LinAlgError("matrix is not positive definite")
        return np.array(x)
    x, info = dpotrs(chol_lower(A), b, lower=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"potrs info {info}")
    return x


def _chol_inv_factor(A: np.ndarray) -> np.ndarray:
    """``L^-1`` (n, n) of the lower Cholesky factor of a symmetric positive definite ``A`` (n, n), so
    that ``A^-1 = L^-T L^-1`` (LAPACK ``potrf`` / ``trtri``)."""
    Linv, info = dtrtri(chol_lower(A), lower=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"trtri info {info}")
    return Linv


def common_lower_bound(C: np.ndarray, rel_floor: float = 1e-9) -> np.ndarray | None:
    """A common part ``X`` (3, 3) of the covariances ``C`` (k, 3, 3): ``0 <= X <= C_j`` for every j
    (Loewner order), a large one (no unique largest exists) found by taking, peer after peer, the
    joint-eigenbasis minimum
    ``X' = X^(1/2) V min(D, I) V^T X^(1/2)``, ``V D V^T = X^(-1/2) C_j X^(-1/2)``, from the peer
    of smallest trace. None if some ``C_j`` is zero (a peer without error shares none).
    Coordinates a peer's covariance pins (a founder's) are floored at ``rel_floor`` of the trace.
    """
    tr = _einsum("kii->k", C)
    if not len(C) or tr.min() <= 0.0:
        return None
    order = np.argsort(tr)
    X = C[order[0]]
    for j in order[1:]:
        lam, V = np.linalg.eigh(X + rel_floor * tr[j] * np.eye(3))
        R = (V * np.sqrt(lam)) @ V.T  # X^(1/2) (floored)
        Ri = (V / np.sqrt(lam)) @ V.T
        d, Q = np.linalg.eigh(Ri @ C[j] @ Ri)
        if d.max() >= 1.0 and d.min() >= 1.0:
            continue  # C_j >= X already
        B = R @ Q
        X = (B * np.minimum(d, 1.0)) @ B.T
        X = 0.5 * (X + X.T)
    return X


# the mirror test of a first fix without a coarse fix (DistributedMap._flip_ambiguous): iterations
# from the mirror image, and the cost margin (chi-square units: 3 sigma) the solution must win by
FLIP_ITERS = 10
FLIP_MARGIN = 9.0
FLIP_SAME_M = 1.0  # a mirror start that converges within this (plus 3 sigma) found the same solution


def holds_fix(cov_m2, no_fix_sigma_m: float = 1000.0) -> bool:
    """True if a broadcast covariance (3, 3) holds a fix: both horizontal variances below a quarter
    of the no-fix prior's (a station without a fix broadcasts ``no_fix_sigma_m`` on its free
    coordinates; a located station of a flat field may have a height sigma as large)."""
    lim = (0.5 * no_fix_sigma_m) ** 2
    return bool(cov_m2[0][0] < lim and cov_m2[1][1] < lim)


def _trilateration_start(dbar_m: np.ndarray, peers_m: np.ndarray, free: np.ndarray, up_m: float) -> np.ndarray:
    """Start (3,) of a station's first solve from the mean ranges ``dbar_m`` (k,) to fixed peers at
    ``peers_m`` (k, 3) (docs/survey.md, "A station without a fix"): their centroid, moved along the
    frame's sign convention so that Gauss-Newton converges to the solution on that side of the
    peers' line or plane (ranges alone cannot tell a mirror image): station 2 by the mean range
    along +x, station 3 along +y; any other station by ``up_m`` along +z, up (a small step: the peers
    of a ground field are nearly coplanar, and from far above the plane the solve would trade
    height for horizontal distance); fixed coordinates 0."""
    x = peers_m.mean(axis=0)
    last = np.flatnonzero(free)[-1]
    x[last] += up_m if last == 2 else float(np.mean(dbar_m))
    x[~free] = 0.0
    return x


class _SolveCache:
    """What one :meth:`DistributedMap.solve` reads of the store and does not change while it runs: the
    kept ranges ``rk`` (nr,) peer slots and ``rv`` (nr,) m, the links' archives ``n_arch`` (m,) (weight)
    and ``sum_arch`` (m,) m (weighted sum of the archived ranges), the peers' estimates ``pos`` (m, 3) m and
    covariances ``cov`` (m, 3, 3) m^2 (views), ``cov_sum = cov + P`` (m, 3, 3) m^2 with our own
    covariance of the last solve, the usable peers ``known`` (m,) bool (known estimate, not
    excluded) and, for the robust weights, the within-link consensus ``gate`` (nr,), the ranges
    judged by the Huber loss ``huber_sel`` (nr,) bool (``loss_mix``: 1 all, 0 none, None some) and the inlier floor
    ``min_inlier_frac * sum(gate)``. Formed once per solve, read by every IRLS iteration."""

    __slots__ = ("m", "rk", "rv", "n_arch", "sum_arch", "pos", "cov", "cov_sum", "known", "all_known", "gate",
                 "huber_sel", "loss_mix", "ones", "inlier_floor", "_x", "_dr", "_u")

    def __init__(self, est: "DistributedMap", robust: bool):
        m, nr = len(est._index), est._nr
        self.m = m
        self.rk, self.rv = est._rk[:nr], est._rv[:nr]
        self.n_arch, self.sum_arch = est._n[:m], est._sum[:m]
        self.pos, self.cov = est._pos[:m], est._cov[:m]
        self.cov_sum = self.cov + est.cov_m2
        self.known = est._peer_sel()
        self.all_known = bool(self.known.all())
        if robust and est.robust is not None:
            if est.link_consensus:
                self.gate, confirmed = est._consensus(self.rk, self.rv, m)
            else:
                self.gate, confirmed = np.ones(nr), np.zeros(nr, bool)
            self.huber_sel = confirmed & (est.confirmed_loss is not None)
            self.loss_mix = 1 if self.huber_sel.all() else 0 if not self.huber_sel.any() else None
            self.ones = np.ones(nr)
            self.inlier_floor = est.min_inlier_frac * self.gate.sum()
        self._x = self._dr = self._u = None

    def dist(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``x - pos`` (m, 3) m and the distances ``r`` (m,) m from every peer's estimate to ``x`` (3,),
        kept for the latest ``x`` (an iterate is never modified once it is read)."""
        if x is not self._x:
            diff = x - self.pos
            self._x, self._dr, self._u = x, (diff, np.sqrt(_einsum("ki,ki->k", diff, diff))), None
        return self._dr

    def unit(self, x: np.ndarray) -> np.ndarray:
        """(m, 3) unit vectors from every peer's estimate to ``x`` (3,) (a distance below 1 nm taken as 1 nm)."""
        diff, r = self.dist(x)
        if self._u is None:
            self._u = diff / np.maximum(r, 1e-9)[:, None]
        return self._u


class DistributedMap:
    """Distributed MAP by block Gauss-Newton on stored link statistics (see module docstring).

    ``robust`` (default ``"tukey"``): every range is kept (stations are static, so this is the
    lossless record) and re-weighted at every solve. First, geometry-free, within each link
    (``link_consensus="cluster"``): NLOS only lengthens a range, so the link's line-of-sight value is
    its lowest densest cluster of ranges (``los_cluster``); ranges more than ``consensus_gate``
    sigma_d from it get weight 0. A link whose cluster holds ``confirm_n`` (3) ranges is *confirmed*;
    a link where no two ranges agree keeps only its shortest range, down-weighted by
    ``unconfirmed_weight`` (0.01: a range not yet confirmed counts like one with sigma 5 m). Then
    against the geometry, on the normalized innovation ``z = (d - |c - c_j|) / s``,
    ``s^2 = sigma_d^2 + u^T (P + C_j) u`` (range noise plus the predicted range's uncertainty from
    both estimates): the convex Huber loss on confirmed links (bounded pull of a lying peer, but never
    a dropped link: a redescending loss there let whole networks settle in wrong configurations that
    rejected their links to station 1), the redescending Tukey biweight on unconfirmed ones. A weight
    is never frozen. When fewer than half of the weight survives (our own fix is far off, e.g. a bad
    coarse fix), the solve falls back to Huber weights, whose convex loss converges from any start,
    and the next solve redescends from there (an MM scheme).
    ``robust=None`` gives the plain least-squares MAP (count + mean per link).
    """

    name = "dmap"

    def __init__(self, station_id: int, pos0_m: np.ndarray | None, cov0_m2: np.ndarray | None,
                 sigma_d_m: float, *, max_iter: int = 3, tol_m: float = 1e-3,
                 no_fix_sigma_m: float = 1000.0, no_fix_height_sigma_m: float = 100.0,
                 min_peers_to_init: int = 3, extrinsic: bool = True,
                 peer_corr: float = 2.0, peer_corr_est: float = 0.5, extrinsic_est: bool = False,
                 robust: str | None = "tukey", tukey_c: float = 4.685, huber_k: float = 2.0,
                 min_inlier_frac: float = 0.5, keep_per_link: int = 256, link_consensus: str | None = "cluster",
                 consensus_gate: float = 4.0, cluster_width: float = 4.0, unconfirmed_weight: float = 0.01,
                 confirm_n: int = 3, weak_below: int = 3, confirmed_loss: str | None = "huber",
                 restart_from_prior: bool = True, restart_iter: int = 6,
                 weak_below_nlos: int | None = None, nlos_min_outliers: int = 2, nlos_min_frac: float = 0.02,
                 clean_after_n: int = 0, founder: bool = True, peer_corr_datum: float = 0.5,
                 common_mode: bool | None = None):
        self.id = station_id
        # reported covariance with the error the peers share (in a multi-hop field they inherit the
        # same upstream error), not only independent per-link consider terms (_common_mode_cov;
        # docs/survey.md); off in the datum mode. None: with a coarse fix only (without one it cost
        # the horizontal: docs/survey.md)
        self.common_mode = common_mode
        self.free = free_mask(station_id, founder)
        # None while the prior is the coarse fix (or the founders' frame); else the damping sigma of
        # the datum mode (:meth:`hold_datum`)
        self.datum_sigma_m: float | None = None
        self.nf = int(self.free.sum())
        self.sigma_d_m = float(sigma_d_m)
        # the scenario's [radio] (net/radio.py), network frame: each link's range variance from the
        # SNR at the estimated geometry (range_var_m2); None: sigma_d^2 on every link
        self.radio = None
        # the kept ranges' variance against a two-way range's (1; protocol v2's averaged exchange ranges:
        # 3/4, nav.crlb.poll_exchange_counts): the link variance in the solve's weights, not the
        # within-link consensus widths (those stay sigma_d)
        self.range_var_factor = 1.0
        self.max_iter = max_iter
        self.tol_m = tol_m
        self.no_fix_sigma_m = no_fix_sigma_m
        # without a fix, the height prior of a ground station: the plane of its located peers at its
        # position (_ground_height_m), this sigma (ranges between nearly coplanar stations hardly see
        # height; docs/survey.md)
        self.no_fix_height_sigma_m = no_fix_height_sigma_m
        self.min_peers_to_init = min_peers_to_init
        self.extrinsic = extrinsic
        self.peer_corr = peer_corr
        self.peer_corr_est = peer_corr_est
        # consider factor of the reported covariance in the datum mode: with no frame station every
        # peer's covariance holds its neighbours' (ours among them), and the factor 2 that accounts
        # for the frame modes under the founders' frame made that loop grow (docs/architecture.md)
        self.peer_corr_datum = peer_corr_datum
        self.extrinsic_est = extrinsic_est
        if robust not in (None, "tukey"):
            raise ValueError(f"unknown robust loss {robust!r}; choose 'tukey' or None")
        self.robust = robust
        if robust is None:
            self.name = "dmap-ls"
        self.tukey_c = tukey_c
        self.huber_k = huber_k
        self.min_inlier_frac = min_inlier_frac
        self.link_consensus = link_consensus
        self.consensus_gate = consensus_gate
        self.cluster_width = cluster_width
        self.unconfirmed_weight = unconfirmed_weight
        self.confirm_n = confirm_n
        self.weak_below = weak_below
        # adaptive link weakness: ``weak_below_nlos`` applies while this station's own kept ranges show
        # NLOS or too few ranges to tell (:meth:`_adapt_weakness`); None: ``weak_below`` always
        self.weak_below_nlos = weak_below_nlos
        self.nlos_min_outliers = nlos_min_outliers
        self.nlos_min_frac = nlos_min_frac
        self.clean_after_n = clean_after_n
        self.nlos_seen = False
        self._support = np.zeros(0, np.int64)
        self.confirmed_loss = confirmed_loss
        self._centre_factor = np.zeros(0)
        self._confirmed = np.zeros(0, bool)
        self.restart_from_prior = restart_from_prior
        self.restart_iter = restart_iter
        self.keep_per_link = keep_per_link
        self.n_updates = 0
        self.excluded: set[int] = set()  # peers excluded by integrity monitoring (not used in the solve)
        # per-peer arrays: archived (weight, weighted sum) of old ranges, latest estimate and covariance
        self._index: dict[int, int] = {}
        self._n = np.zeros(0)
        self._sum = np.zeros(0)
        self._pos = np.zeros((0, 3))
        self._cov = np.zeros((0, 3, 3))
        self._known = np.zeros(0, bool)
        # every kept range: peer slot and value; robust weights of the last solve
        self._rk = np.zeros(0, np.int64)
        self._rv = np.zeros(0)
        self._nr = 0
        self._n_kept: dict[int, int] = {}  # peer slot -> its kept ranges (in _rk)
        self._rver = 0  # bumped whenever the kept ranges change (cache key of the link centres)
        self._centre_key: tuple[int, int] | None = None
        self._consensus_out: tuple[np.ndarray, np.ndarray] = (np.zeros(0), np.zeros(0, bool))
        self._lver = np.zeros(0, np.int64)  # per peer slot: bumped when that link's kept ranges change
        self._centre_ver = np.zeros(0, np.int64)  # per peer slot: the version its cached centre is of
        self._centre = np.zeros(0)
        self._sdl = self.sigma_d_m  # the links' noise sigma of the last consensus (_link_sigma)
        self.range_weight = np.zeros(0)
        self._dirty = False
        # (3, 3) the last solve's covariance relative to the peers (without the error shared with them)
        self._cov_local = np.zeros((3, 3))
        if pos0_m is None or cov0_m2 is None or not np.any(np.diag(cov0_m2)[self.free] > 0) and self.nf:
            # no coarse fix: trilaterate once enough peers are known
            self.initialized = self.nf == 0
            self.pos_m = np.zeros(3) if pos0_m is None else np.asarray(pos0_m, float).copy()
            self.cov_m2 = self._no_fix_cov()
            self.prior_mean = None
            self.prior_info = np.zeros((self.nf, self.nf))
            # (no coarse fix to restart from: the prior set at the first solve only regularizes it)
            self.restart_from_prior = False
            self.no_fix = True
            self.common_mode = bool(common_mode)
        else:
            self.no_fix = False
            self.common_mode = bool(common_mode is None or common_mode)
            self.initialized = True
            self.pos_m = np.asarray(pos0_m, dtype=float).copy()
            self.cov_m2 = _clean_cov(cov0_m2, self.free)
            self.prior_mean = self.pos_m[self.free].copy()
            self.prior_info = np.linalg.inv(self.cov_m2[np.ix_(self.free, self.free)]) if self.nf else np.zeros((0, 0))

    def _slot(self, peer_id: int) -> int:
        k = self._index.get(peer_id)
        if k is None:
            k = self._index[peer_id] = len(self._index)
            if k >= len(self._n):  # grow the peer arrays
                grow = max(8, len(self._n))
                self._n = np.concatenate([self._n, np.zeros(grow)])
                self._sum = np.concatenate([self._sum, np.zeros(grow)])
                self._pos = np.concatenate([self._pos, np.zeros((grow, 3))])
                self._cov = np.concatenate([self._cov, np.zeros((grow, 3, 3))])
                self._known = np.concatenate([self._known, np.zeros(grow, bool)])
                self._lver = np.concatenate([self._lver, np.zeros(grow, np.int64)])
        return k

    def on_peer(self, peer_id, pos_m, cov_m2) -> None:
        """A peer's broadcast estimate. One without a fix yet (a station that has not trilaterated
        broadcasts its no-fix prior, ``no_fix_sigma_m`` on its free coordinates) carries no position:
        its links wait, their ranges kept, until it has one (:func:`holds_fix`; docs/survey.md)."""
        k = self._slot(peer_id)
        self._pos[k] = pos_m
        self._cov[k] = cov_m2
        self._known[k] = holds_fix(cov_m2, self.no_fix_sigma_m)

    def link_ranges(self, peer_id: int) -> tuple[np.ndarray, np.ndarray]:
        """Kept ranges of the link to ``peer_id`` (oldest first) and their weights of the last solve."""
        k = self._index.get(peer_id)
        if k is None:
            return np.zeros(0), np.zeros(0)
        sel = self._rk[:self._nr] == k
        w = self.range_weight[sel] if len(self.range_weight) == self._nr else np.ones(int(sel.sum()))
        return self._rv[:self._nr][sel].copy(), w

    @property
    def links(self) -> dict[int, tuple[int, float]]:
        """Link statistics {peer: (count, mean range)} over every range received (unweighted)."""
        nr = self._nr
        cnt = np.bincount(self._rk[:nr], minlength=len(self._n)).astype(float)
        tot = np.bincount(self._rk[:nr], weights=self._rv[:nr], minlength=len(self._n))
        out = {}
        for p, k in self._index.items():
            c = cnt[k] + self._n[k]
            if c > 0:
                out[p] = (int(round(c)), float((tot[k] + self._sum[k]) / c))
        return out

    def on_range(self, peer_id, range_m, t_s, initiated, peer_pos_m, peer_cov_m2) -> bool:
        if peer_pos_m is not None:
            self.on_peer(peer_id, peer_pos_m, peer_cov_m2)
        k = self._slot(peer_id)
        if self._nr == len(self._rv):
            grow = max(64, self._nr)
            self._rk = np.concatenate([self._rk, np.zeros(grow, np.int64)])
            self._rv = np.concatenate([self._rv, np.zeros(grow)])
        self._rk[self._nr] = k
        self._rv[self._nr] = float(range_m)
        self._nr += 1
        self._rver += 1
        self._lver[k] += 1
        kept = self._n_kept[k] = self._n_kept.get(k, 0) + 1
        if self.keep_per_link and kept > self.keep_per_link:
            self._archive(k)
        self._dirty = self.nf > 0
        return False

    def revise_range(self, peer_id: int, old_m: float, new_m: float) -> bool:
        """Replace the newest kept range of the link to ``peer_id`` equal to ``old_m`` by ``new_m`` (a better
        measurement of the same exchange: protocol v2's member V4b for the poller's single-sided range).
        False (nothing changed) if no kept range equals it (archived, or never taken)."""
        k = self._index.get(peer_id)
        if k is None:
            return False
        hit = np.flatnonzero((self._rk[:self._nr] == k) & (self._rv[:self._nr] == old_m))
        if not len(hit):
            return False
        self._rv[hit[-1]] = float(new_m)
        self._rver += 1
        self._lver[k] += 1
        self._dirty = self.nf > 0
        return True

    def _archive(self, k: int) -> None:
        """Fold the older half of link ``k``'s ranges into its (weight, weighted sum) archive, with
        the weights of the last solve (bounded memory and cost on long runs)."""
        nr = self._nr
        idx = np.flatnonzero(self._rk[:nr] == k)[: self.keep_per_link // 2]
        w = self.range_weight[idx] if len(self.range_weight) == nr else np.ones(len(idx))
        self._n[k] += float(w.sum())
        self._sum[k] += float(w @ self._rv[idx])
        self._n_kept[k] -= len(idx)
        keep = np.ones(nr, bool)
        keep[idx] = False
        self._rk = self._rk[:nr][keep]
        self._rv = self._rv[:nr][keep]
        if len(self.range_weight) == nr:
            self.range_weight = self.range_weight[keep]
        self._nr = len(self._rv)
        self._rver += 1
        self._lver[k] += 1

    def hold_datum(self, damping_sigma_m: float) -> None:
        """From now on the field carries the datum (docs/architecture.md, "The frame datum").

        A founder's frame constraints end: all of x, y, z become free. The station keeps its prior
        (the coarse fix, or without one the weak start prior and the ground height): the ranges are
        all kept and re-solved, so the information a solve has apart from its ranges is exactly that
        prior, and counting anything else (a damping term centred on the previous solve of the same
        ranges) would count the ranges twice. A founder's newly freed coordinates get a prior
        ``N(current value, damping_sigma_m^2)``: the founders' frame they held, known in the field's
        datum to the frame error of the hand-over. The datum corrections move the prior's mean with
        the estimate (:meth:`shift`), so the prior is in the field's datum too.
        """
        if self.datum_sigma_m is not None:
            return
        self.datum_sigma_m = float(damping_sigma_m)
        if self.nf < 3:
            nf = self.nf  # the free coordinates are the first nf
            info = np.zeros((3, 3))
            info[:nf, :nf] = self.prior_info
            info[np.arange(nf, 3), np.arange(nf, 3)] = 1.0 / self.datum_sigma_m**2
            mean = self.pos_m.copy()
            if self.prior_mean is not None:
                mean[:nf] = self.prior_mean
            self.prior_info, self.prior_mean = info, mean
            self.free = np.ones(3, bool)
            self.nf = 3
            cov = self.cov_m2.copy()
            cov[np.diag_indices(3)] = np.maximum(np.diag(cov), 1e-6)
            self.cov_m2 = _clean_cov(cov, self.free)
        self.initialized = True
        self._dirty = True

    def restart_from(self, pos_m: np.ndarray) -> None:
        """Start the next solve from ``pos_m`` (3,) (its free coordinates): the core's roll-back after an
        exclusion (``StationCore._roll_back``)."""
        self.pos_m = np.where(self.free, np.asarray(pos_m, float), self.pos_m)
        self._dirty = True

    def shift(self, delta_m: np.ndarray) -> None:
        """Move the estimate by ``delta_m`` (3,) (the datum correction of the core, datum mode only), and
        the prior's mean with it (the prior is in the field's datum: :meth:`hold_datum`)."""
        d = np.asarray(delta_m, float) * self.free
        self.pos_m = self.pos_m + d
        if self.prior_mean is not None:
            self.prior_mean = self.prior_mean + d[self.free]

    def refresh(self) -> bool:
        """Re-solve if new ranges arrived since the last solve (the core calls this before its nav)."""
        if not self._dirty:
            return False
        self._dirty = not self.solve()
        return not self._dirty

    def _peer_sel(self) -> np.ndarray:
        """(m,) bool over peer slots: known estimate, not excluded."""
        m = len(self._index)
        sel = self._known[:m].copy()
        for p in self.excluded:
            k = self._index.get(p)
            if k is not None:
                sel[k] = False
        return sel

    def _link_var(self, x: np.ndarray, Pj: np.ndarray):
        """Range noise variance of the links from ``x`` (3,) to the peers at ``Pj`` (k, 3): ``sigma_d^2``
        (a scalar), or under ``[radio]`` (k,) with each link's timing CRLB (:func:`net.radio.range_var_m2`),
        times ``range_var_factor`` (the kept ranges' variance against a two-way range's: 3/4 for protocol
        v2's averaged ranges, docs/survey.md)."""
        return self.range_var_factor * range_var_m2(x, Pj, self.radio, self.sigma_d_m)

    def _link_sigma(self, m: int):
        """Range noise sigma of the first ``m`` peer slots at the current estimate (scalar without ``[radio]``)."""
        if self.radio is None:
            return self.sigma_d_m
        return np.sqrt(self._link_var(self.pos_m, self._pos[:m]))

    def _z(self, x: np.ndarray, sc: "_SolveCache | None" = None) -> np.ndarray:
        """(nr,) normalized innovation of every kept range against the range predicted at ``x``:
        ``(d - |x - c_j|) / s``, ``s^2 = sigma_j^2 + u^T (P + C_j) u`` (``sigma_j = sigma_d`` without ``[radio]``).
        ``sc``: the solve's fixed arrays (:class:`_SolveCache`), else read from the store."""
        if sc is None:
            sc = _SolveCache(self, False)
        r = sc.dist(x)[1]
        u = sc.unit(x)
        s2 = self._link_var(x, sc.pos) + _einsum("ki,kij,kj->k", u, sc.cov_sum, u)
        return (sc.rv - r[sc.rk]) / np.sqrt(s2[sc.rk])

    def _weights(self, x: np.ndarray, robust: bool, sc: "_SolveCache | None" = None) -> np.ndarray:
        """(nr,) robust weight of every kept range at own position ``x`` (``sc``: as in :meth:`_z`)."""
        if not robust or self.robust is None:
            return np.ones(self._nr)
        if sc is None:
            sc = _SolveCache(self, True)
        z = self._z(x, sc)
        # a confirmed link (its LOS cluster holds >= confirm_n ranges) is judged against the geometry
        # by the convex Huber loss only: its pull is bounded (a lying peer until it is excluded) but
        # never zero, so the network cannot settle in a wrong configuration that drops its links to
        # the frame stations; the redescending Tukey loss judges the ranges of unconfirmed links
        zh = huber_weight(z, self.huber_k)
        zc = zh if self.confirmed_loss == "huber" else sc.ones
        if sc.loss_mix == 1:  # every range's link confirmed
            w = zc * sc.gate
        elif sc.loss_mix == 0:  # none
            w = tukey_weight(z, self.tukey_c) * sc.gate
        else:
            w = np.where(sc.huber_sel, zc, tukey_weight(z, self.tukey_c)) * sc.gate
        if np.add.reduce(w) < sc.inlier_floor:  # (w.sum() without its wrapper)
            # far from everything: convex start (MM scheme), still within the links' consensus
            w = zh * sc.gate
        return w

    def _consensus(self, rk: np.ndarray, rv: np.ndarray, m: int) -> np.ndarray:
        """(nr,) within-link consensus factor of every kept range, independent of any geometry.

        ``"cluster"``: the link's line-of-sight centre is its lowest densest cluster of ranges
        (``los_cluster``; NLOS only lengthens a range, so the direct path is the shortest repeated
        value); a range more than ``consensus_gate * sigma_d`` from it gets 0, and while no two ranges
        of the link agree (one range, or all disagree) every range of the link but the shortest gets 0
        and the shortest gets ``unconfirmed_weight``. ``"median"``: distance to the link's median (of
        two ranges that disagree: the shorter). Depends on the kept ranges only: cached per link, recomputed
        for the links whose ranges changed; the per-range factors are cached until the kept ranges change.
        """
        if self._centre_key != (self._rver, m):
            # only the links whose kept ranges changed since their centre was computed
            n_old = len(self._centre)
            if n_old < m:
                self._centre = np.concatenate([self._centre, np.zeros(m - n_old)])
                self._centre_factor = np.concatenate([self._centre_factor, np.ones(m - n_old)])
                self._confirmed = np.concatenate([self._confirmed, np.zeros(m - n_old, bool)])
                self._centre_ver = np.concatenate([self._centre_ver, np.full(m - n_old, -1, np.int64)])
                self._support = np.concatenate([self._support, np.zeros(m - n_old, np.int64)])
            centre, factor, conf, supp = self._centre, self._centre_factor, self._confirmed, self._support
            self._sdl = sdl = self._link_sigma(m)
            for k in np.flatnonzero(self._centre_ver[:m] != self._lver[:m]):
                sd = sdl if getattr(sdl, "ndim", 0) == 0 else sdl[k]
                v = rv[rk == k]
                centre[k], factor[k], conf[k], supp[k] = 0.0, 1.0, False, 0
                self._centre_ver[k] = self._lver[k]
                if not len(v):
                    continue
                if self.link_consensus == "cluster":
                    centre[k], supp[k] = los_cluster(v, self.cluster_width * sd)
                    if supp[k] < self.weak_below:
                        factor[k] = self.unconfirmed_weight
                    conf[k] = supp[k] >= self.confirm_n
                else:
                    centre[k] = v.min() if len(v) == 2 and np.ptp(v) > 3.0 * np.sqrt(2.0) * sd else np.median(v)
            if self.weak_below_nlos is not None and self.link_consensus == "cluster":
                self._adapt_weakness(rk, rv, m)
            self._centre_key = (self._rver, m)
            ok = np.abs(rv - self._centre[rk]) <= self.consensus_gate * self._range_sigma(rk)
            self._consensus_out = ok * self._centre_factor[rk], self._confirmed[rk]
        return self._consensus_out

    def _range_sigma(self, rk: np.ndarray):
        """Noise sigma of each kept range's link (scalar without ``[radio]``), as of the last consensus."""
        sdl = self._sdl
        return sdl if getattr(sdl, "ndim", 0) == 0 else sdl[rk]

    def _adapt_weakness(self, rk: np.ndarray, rv: np.ndarray, m: int) -> None:
        """Adaptive link weakness (``weak_below_nlos``): NLOS evidence from this station's own ranges.

        A range of a link with two or more ranges that lies more than ``consensus_gate`` sigma_d from
        its link's line-of-sight centre is an *outlier*. On clean ranges outliers are rare (two ranges
        of a link disagree by more than the 4 sigma_d cluster width with probability 0.5 %, a range
        lies 4 sigma_d from a well-supported centre with 6e-5); NLOS legs make them common (each
        reflected range with an excess above 2 m). While this station holds at least
        ``nlos_min_outliers`` outliers forming at least ``nlos_min_frac`` of those ranges, or fewer than
        ``clean_after_n`` ranges in links with two or more (too little evidence either way: at 5 % NLOS
        legs the first outliers come after the first agreeing pairs, and one frame station that gave
        full weight to them early settled 1.5 m off with the whole network), a link stays weak until
        ``weak_below_nlos`` of its ranges agree (two agreeing NLOS ranges are then possible), otherwise
        until ``weak_below`` agree. Recomputed whenever the kept ranges change; the weights are never
        frozen, so the decision applies to every past range at the next solve."""
        supp = self._support[:m]
        multi = np.bincount(rk, minlength=m)[:m] >= 2
        inl = multi[rk]
        out = inl & (np.abs(rv - self._centre[rk]) > self.consensus_gate * self._range_sigma(rk))
        n_out, n_in = int(out.sum()), int(inl.sum())
        self.nlos_seen = ((n_out >= self.nlos_min_outliers and n_out >= self.nlos_min_frac * max(n_in, 1))
                          or n_in < self.clean_after_n)
        wb = self.weak_below_nlos if self.nlos_seen else self.weak_below
        self._centre_factor[:m] = np.where((supp > 0) & (supp < wb), self.unconfirmed_weight, 1.0)

    def robust_cost(self, x: np.ndarray, sc: "_SolveCache | None" = None) -> float:
        """Robust MAP objective at ``x``: prior Mahalanobis term + sum of Tukey losses
        ``rho(z) = c^2/3 (1 - (1 - (z/c)^2)^3)`` (``~ z^2`` near 0, ``c^2/3`` for a rejected range)."""
        c = self.tukey_c
        z = self._z(x, sc)
        q = np.maximum(1.0 - (z / c) ** 2, 0.0)  # (= np.clip(., 0, None), without its wrapper)
        d0 = x[self.free] - self.prior_mean
        return float(d0 @ self.prior_info @ d0 + np.add.reduce(c * c / 3.0 * (1.0 - q**3)))

    def _arrays(self, w: np.ndarray, sc: "_SolveCache | None" = None):
        """Per-link (effective count, weighted mean range, peer estimate, peer covariance) of the links
        in use (a known, not excluded peer with weight); None if there is none (``sc``: as in :meth:`_z`)."""
        if sc is None:
            sc = _SolveCache(self, False)
        m = sc.m
        n = sc.n_arch + np.bincount(sc.rk, weights=w, minlength=m)
        tot = sc.sum_arch + np.bincount(sc.rk, weights=w * sc.rv, minlength=m)
        sel = (n > 1e-6) if sc.all_known else (n > 1e-6) & sc.known
        k = np.count_nonzero(sel)
        if k == m:  # every link: the stored arrays themselves
            return n, tot / n, sc.pos, sc.cov
        if k == 0:
            return None
        return n[sel], tot[sel] / n[sel], sc.pos[sel], sc.cov[sel]

    def _extrinsic(self, x, n, Pj, Cj):
        """Peer covariances with this station's own link removed (Gaussian BP extrinsic message).

        Peer j's information ``P_j^-1`` contains the link to us, weighted (from j's side) by
        ``1/(sigma^2/n + u^T P_m u)``. Using it again here would count that link twice (the length-2
        loop that makes naive decentralized fusion overconfident), so subtract it before use.
        """
        diff = x - Pj
        u = diff / np.linalg.norm(diff, axis=1)[:, None]
        w = 1.0 / (self._link_var(x, Pj) / n + _einsum("ki,ij,kj->k", u, self.cov_m2, u))
        # rank-1 downdate of the information, (C^-1 - w u u^T)^-1, by Sherman-Morrison; positive
        # definite iff w u^T C u < 1 (else the peer's information is mostly ours: keep C as is)
        Cu = _einsum("kij,kj->ki", Cj, u)
        s = w * _einsum("ki,ki->k", u, Cu)
        ok = s < 0.99
        g = np.where(ok, w / np.where(ok, 1.0 - s, 1.0), 0.0)
        return Cj + g[:, None, None] * Cu[:, :, None] * Cu[:, None, :]

    def _normal(self, x, n, dbar, Pj, Cj, gamma, sc: "_SolveCache | None" = None):
        """Normal equations of the local MAP problem at ``x``: information ``A`` (nf, nf) and ``b`` (nf,).

        Link variance: ``sigma_d^2 / n_j + gamma u_j^T C_j u_j`` (gamma: consider factor of the peer error).
        Also returns the link weights ``w`` and the distances ``r`` (k,) to the peers at ``x``.
        ``sc``: the solve's fixed arrays when ``Pj`` is every peer's (``sc.pos``): the geometry read there.
        """
        nf = self.nf  # the free coordinates are the first nf (frame_free_mask): slices, not masks
        if sc is not None and Pj is sc.pos:
            r, u = sc.dist(x)[1], sc.unit(x)
        else:
            diff = x - Pj
            r = np.sqrt(_einsum("ki,ki->k", diff, diff))
            u = diff / r[:, None]
        w = 1.0 / (self._link_var(x, Pj) / n + gamma * _einsum("ki,kij,kj->k", u, Cj, u))
        J = u[:, :nf] if nf < 3 else u
        A = self.prior_info + (J.T * w) @ J
        b = J.T @ (w * (dbar - r)) + self._prior_pull(x)
        return A, b, w, r

    def _objective(self, x, n, dbar, Pj, wl, r=None, sc: "_SolveCache | None" = None) -> float:
        """Local MAP objective at ``x`` with the link weights ``wl`` held fixed (``r``: the distances to
        the peers at ``x`` when known; ``sc``: as in :meth:`_normal`)."""
        if r is None and sc is not None and Pj is sc.pos:
            r = sc.dist(x)[1]
        elif r is None:
            diff = x - Pj
            r = np.sqrt(_einsum("ki,ki->k", diff, diff))
        return self._prior_term(x) + float(wl @ (dbar - r) ** 2)

    def _prior_pull(self, x: np.ndarray):
        """``prior_info (prior_mean - x_free)`` (nf,) (the free coordinates are the first nf); a list of
        floats for nf = 3."""
        if self.nf != 3:
            return self.prior_info @ (self.prior_mean - x[:self.nf])
        d0, d1, d2 = (b - a for a, b in zip(x.tolist(), self.prior_mean.tolist()))
        return [p0 * d0 + p1 * d1 + p2 * d2 for p0, p1, p2 in self.prior_info.tolist()]

    def _prior_term(self, x: np.ndarray) -> float:
        """``d^T prior_info d``, ``d = x_free - prior_mean`` (nf,) (the free coordinates are the first nf);
        on Python floats for nf = 3."""
        if self.nf != 3:
            d = x[:self.nf] - self.prior_mean
            return float(d @ self.prior_info @ d)
        d0, d1, d2 = (a - b for a, b in zip(x.tolist(), self.prior_mean.tolist()))
        (p00, p01, p02), (p10, p11, p12), (p20, p21, p22) = self.prior_info.tolist()
        return (d0 * (p00 * d0 + p01 * d1 + p02 * d2) + d1 * (p10 * d0 + p11 * d1 + p12 * d2)
                + d2 * (p20 * d0 + p21 * d1 + p22 * d2))

    def _irls(self, x: np.ndarray, iters: int, robust: bool, sc: "_SolveCache") -> np.ndarray | None:
        """Iteratively re-weighted, backtracked Gauss-Newton from ``x`` (3,); None if no usable link.
        ``sc``: the solve's fixed arrays (:class:`_SolveCache`)."""
        nf = self.nf
        for _ in range(iters):
            w = self._weights(x, robust, sc)
            arr = self._arrays(w, sc)
            if arr is None:
                return None
            n, dbar, Pj, Cj = arr
            Ce = self._extrinsic(x, n, Pj, Cj) if self.extrinsic_est and self.initialized else Cj
            A, b, wl, r = self._normal(x, n, dbar, Pj, Ce, self.peer_corr_est, sc)
            dx = _spd_solve(A, b)
            # backtracking on the (fixed-weight) objective: near-flat geometry makes the range nearly
            # quadratic in height, so a full Gauss-Newton step can overshoot far along z
            f0 = self._objective(x, n, dbar, Pj, wl, r)
            for _ in range(20):
                if nf == 3:
                    xt = x + dx
                else:
                    xt = x.copy()
                    xt[:nf] += dx
                if self._objective(xt, n, dbar, Pj, wl, sc=sc) <= f0 + 1e-12:
                    break
                dx = 0.5 * dx
            x = xt
            if max(map(abs, dx.tolist())) < self.tol_m:
                break
        return x

    def _no_fix_cov(self) -> np.ndarray:
        """(3, 3) the broadcast covariance of a station without a fix: ``no_fix_sigma_m`` on its free
        coordinates."""
        return np.diag(self.free * self.no_fix_sigma_m**2).astype(float)

    def _ground_height_m(self, x: np.ndarray) -> float:
        """The height prior of a station without a fix at horizontal position ``x[:2]``: the plane
        ``z = a + b x + c y`` through the located peers' estimates (least squares), else their mean
        height. The network frame's XY plane is the founders', tilted against the ground by their
        own height differences, so across a large field the ground lies far from z = 0 while
        neighbours stay near one plane (docs/survey.md)."""
        m = len(self._index)
        Pj = self._pos[:m][self._peer_sel()]
        if len(Pj) < 3:
            return float(Pj[:, 2].mean()) if len(Pj) else float(x[2])
        G = np.column_stack([np.ones(len(Pj)), Pj[:, 0] - x[0], Pj[:, 1] - x[1]])
        coef, _, rank, _ = np.linalg.lstsq(G, Pj[:, 2], rcond=1e-6)
        return float(coef[0]) if rank == 3 else float(Pj[:, 2].mean())

    def solve(self) -> bool:
        if self._nr == 0 and not (self._n > 0).any():
            return False
        iters = self.max_iter
        robust = self.initialized
        if not self.initialized:
            arr = self._arrays(np.ones(self._nr))
            # enough fixed peers: nf for a founder (station 2 from station 1, station 3 from 1 and 2, on
            # the frame's sign convention), min_peers_to_init for any other station
            if arr is None or len(arr[0]) < (self.min_peers_to_init if self.nf == 3 else self.nf):
                return False
            self.pos_m = _trilateration_start(arr[1], arr[2], self.free, self.sigma_d_m)
            # weak prior at the start: keeps the solve on the start's side of a mirror ambiguity
            self.prior_mean = self.pos_m[self.free].copy()
            sig = np.where(np.arange(3)[self.free] == 2, self.no_fix_height_sigma_m, self.no_fix_sigma_m)
            self.prior_info = np.diag(1.0 / sig**2)
            iters = 50
        elif self.no_fix and self.nf == 3:
            self.prior_mean[2] = self._ground_height_m(self.pos_m)
        sc = _SolveCache(self, robust)
        first = not self.initialized
        try:
            if not self._solve_from(iters, robust, sc):
                return False
            if first and self.no_fix and self.nf == 3 and self._flip_ambiguous(sc):
                # not located yet: wait for peers that tell the solution from its mirror image
                self.initialized = False
                self.n_updates -= 1
                self.cov_m2 = self._no_fix_cov()
                return False
            return True
        except np.linalg.LinAlgError:  # a degenerate geometry (e.g. a start on a peer): no update
            return False

    def _common_mode_cov(self, x, n, Pj, Cj, gamma: float) -> tuple[np.ndarray, np.ndarray] | None:
        """(nf, nf) covariances of the solution at ``x`` relative to the peers (``A^-1``) and with the
        error the peers share; None when they share none (a peer without error, station 1: the
        per-link terms alone).

        Peers of a multi-hop field inherit the same upstream error. Peer j's error is taken as
        ``e_j = e_c + eps_j``: a part ``e_c ~ N(0, C_c)`` common to all the peers and an independent
        rest. ``C_c`` (3, 3) is as large a common part as the peers' covariances ``C_j`` (k, 3, 3)
        (extrinsic) allow, ``C_c <= C_j`` for every j (:func:`common_lower_bound`): the most the peers
        can share. The rest enters each link's variance as ``gamma u_j^T (C_j - C_c) u_j`` (the
        per-link consider term, ``gamma = peer_corr``). Linearized, a
        common shift of all peers moves the solution by ``G e_c``,
        ``G = A^-1 sum_j w_j J_j^T u_j^T`` (nf, 3) (``= I`` with three free coordinates and no prior:
        ranges cannot tell a common shift of all the peers), so the covariance is
        ``A^-1 + G C_c G^T``, where per-link terms alone average ``e_c`` away over the k links.
        (Without a fix the height prior, the plane through the peers' estimates, rises with them too;
        counting that made the heights' variance grow hop by hop, and through ``u_z^2 C_j`` in every
        link's weight it cost the horizontal: docs/survey.md.)
        """
        Cc = common_lower_bound(Cj)
        if Cc is None:
            return None
        nf = self.nf
        diff = x - Pj
        u = diff / np.linalg.norm(diff, axis=1)[:, None]  # (k, 3)
        rest = np.maximum(_einsum("ki,kij,kj->k", u, Cj, u) - _einsum("ki,ij,kj->k", u, Cc, u), 0.0)
        w = 1.0 / (self._link_var(x, Pj) / n + gamma * rest)
        J = u[:, :nf]
        Linv = _chol_inv_factor(self.prior_info + (J.T * w) @ J)
        Ainv = Linv.T @ Linv
        G = Ainv @ ((J.T * w) @ u)  # (nf, 3): the solution's shift per common shift of the peers
        return Ainv, Ainv + G @ Cc @ G.T

    def _flip_ambiguous(self, sc: "_SolveCache") -> bool:
        """A first fix from ranges alone is ambiguous if the located peers lie nearly on a line: the
        solution's mirror image across their principal line fits about as well. Re-solve from the
        mirror (plain least squares, ``FLIP_ITERS`` iterations) and call it ambiguous when it ends
        elsewhere with a cost (the local MAP objective) within ``FLIP_MARGIN`` of ours (docs/survey.md)."""
        arr = self._arrays(np.ones(self._nr), sc)
        if arr is None:
            return True
        n, dbar, Pj, Cj = arr
        c = Pj[:, :2].mean(axis=0)
        D = Pj[:, :2] - c
        e = np.linalg.eigh(D.T @ D)[1][:, 1]  # the peers' principal direction
        x = self.pos_m
        v = x[:2] - c
        xm = x.copy()
        xm[:2] = c + 2.0 * e * (e @ v) - v
        x2 = self._irls(xm, FLIP_ITERS, False, sc)
        if x2 is None or not np.all(np.isfinite(x2)):
            return False

        # (our sigma relative to these peers: the error we share with them moves the mirror image too)
        P = self._cov_local
        if np.hypot(*(x2[:2] - x[:2])) <= FLIP_SAME_M + 3.0 * np.sqrt(P[0, 0] + P[1, 1]):
            return False  # back to the same solution: there is one

        def cost(y: np.ndarray) -> float:
            w, r = self._normal(y, n, dbar, Pj, Cj, self.peer_corr_est)[2:]
            return self._objective(y, n, dbar, Pj, w, r)

        return cost(x2) - cost(x) < FLIP_MARGIN

    def _solve_from(self, iters: int, robust: bool, sc: "_SolveCache") -> bool:
        """:meth:`solve` from the current estimate: IRLS, the second start, the covariance."""
        f = self.free
        x = self._irls(self.pos_m.copy(), iters, robust, sc)
        if x is None or not np.all(np.isfinite(x)):
            return False
        if (robust and self.robust is not None and self.restart_from_prior and self.prior_mean is not None
                and self.datum_sigma_m is None):  # (not in the datum mode: converged by then)
            # second start from the coarse fix: IRLS with a redescending loss only finds a local
            # minimum, and early NLOS ranges (not yet separable from a 10 m fix error) can drag the
            # weakly observed height into a wrong basin that later clean ranges keep consistent.
            # Keep whichever start has the lower robust objective.
            x0 = self.pos_m.copy()
            x0[f] = self.prior_mean
            x2 = self._irls(x0, self.restart_iter, robust, sc)
            if x2 is not None and self.robust_cost(x2, sc) < self.robust_cost(x, sc):
                x = x2
        w = self._weights(x, robust, sc)
        arr = self._arrays(w, sc)
        if arr is None:
            return False
        n, dbar, Pj, Cj = arr
        Cx = self._extrinsic(x, n, Pj, Cj) if self.extrinsic and self.initialized else Cj
        cov = np.zeros((3, 3))
        Cm = None
        if self.common_mode and self.datum_sigma_m is None:
            Cm = self._common_mode_cov(x, n, Pj, Cx, self.peer_corr)
        if Cm is not None:
            cov[:self.nf, :self.nf] = Cm[1]
            self._cov_local = np.zeros((3, 3))
            self._cov_local[:self.nf, :self.nf] = Cm[0]
        else:
            gamma = self.peer_corr if self.datum_sigma_m is None else self.peer_corr_datum
            A = self._normal(x, n, dbar, Pj, Cx, gamma)[0]
            Linv = _chol_inv_factor(A)
            cov[:self.nf, :self.nf] = Linv.T @ Linv  # (the free coordinates are the first nf)
            self._cov_local = cov
        self.range_weight = w
        self.pos_m = x
        self.cov_m2 = symmetrize(cov)
        self.initialized = True
        self.n_updates += 1
        return True


ESTIMATORS = {"dmap": DistributedMap, "dmap-nlos": DistributedMap, "dmap-ls": DistributedMap, "seed-ukf": SeedUkf}


def make_estimator(name: str, station_id: int, pos0_m, cov0_m2, sigma_d_m: float,
                   ranges_per_update: int = 3, founder: bool = True, radio=None,
                   peer_corr_est: float | None = None, clean_after_n: int | None = None,
                   range_var_factor: float | None = None) -> SurveyEstimator:
    """``dmap`` (robust, default: a link weak while no two of its ranges agree, or until 3 agree while
    the station's own ranges show NLOS, :meth:`DistributedMap._adapt_weakness`), ``dmap-nlos`` (the
    same, always weak until 3 agree: slower clean convergence, docs/survey.md), ``dmap-ls`` (the same
    without the robust weights) or ``seed-ukf``. ``founder=False``: stations 1-3 free in x, y, z
    (a founder that joins a running field; ``seed-ukf`` keeps the paper's frame). ``peer_corr_est``:
    the dmap solve's consider factor of the peers' covariances instead of its default (protocol v2's
    poll sets its own, stations/core.py ``POLL_PEER_CORR_EST``); ``clean_after_n``: how many ranges in links
    with two or more a station holds before it may judge its ranges clean (:meth:`DistributedMap._adapt_weakness`;
    the poll sets its own, ``POLL_CLEAN_AFTER_N``); ``range_var_factor``: the ranges' variance against
    a two-way range's (:meth:`DistributedMap._link_var`; the poll's averaged ranges, ``POLL_RANGE_VAR_FACTOR``)."""
    est = _make(name, station_id, pos0_m, cov0_m2, sigma_d_m, ranges_per_update, founder)
    est.radio = radio  # [radio]: each link weighted by its SNR's timing noise (net/radio.py range_var_m2)
    if peer_corr_est is not None and isinstance(est, DistributedMap):
        est.peer_corr_est = float(peer_corr_est)
    if clean_after_n is not None and isinstance(est, DistributedMap):
        est.clean_after_n = int(clean_after_n)
    if range_var_factor is not None and isinstance(est, DistributedMap):
        est.range_var_factor = float(range_var_factor)
    return est


def _make(name: str, station_id: int, pos0_m, cov0_m2, sigma_d_m: float, ranges_per_update: int,
          founder: bool) -> SurveyEstimator:
    if name == "seed-ukf":
        if pos0_m is None:
            raise ValueError("seed-ukf needs an initial fix (scenario init.sigma0_m > 0)")
        return SeedUkf(station_id, pos0_m, cov0_m2, sigma_d_m, ranges_per_update)
    if name == "dmap":
        return DistributedMap(station_id, pos0_m, cov0_m2, sigma_d_m, weak_below=2, weak_below_nlos=3, clean_after_n=20,
                              founder=founder)
    if name == "dmap-nlos":
        dm = DistributedMap(station_id, pos0_m, cov0_m2, sigma_d_m, weak_below=3, founder=founder)
        dm.name = "dmap-nlos"
        return dm
    if name == "dmap-ls":
        return DistributedMap(station_id, pos0_m, cov0_m2, sigma_d_m, robust=None, founder=founder)
    raise ValueError(f"unknown estimator {name!r}; choose from {sorted(ESTIMATORS)}")
