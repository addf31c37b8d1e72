"""Integrity of the aircraft filters: innovation gating, a windowed residual test with leave-one-out
exclusion, and protection levels from the filter covariance (sans-I/O, batched over runs).

Every batch update of a :class:`aircraft.navigator.radio.tracker.CvTracker` returns its innovation ``nu`` (..., d)
and covariance ``S`` (..., d, d) about the prior (pseudoranges: ``d = m``; range differences against
the base: ``d = m - 1``). A fault on station ``i`` moves the innovation along ``f_i`` (pseudoranges:
the unit vector ``e_i``; differences: column ``i`` of ``G``). Per epoch (Teunissen's DIA / Baarda's
data snooping on the innovations):

* ``q = nu^T S^-1 nu`` (NIS), chi-square with ``d`` dof without a fault;
* ``w_i = (f_i^T S^-1 nu)^2 / (f_i^T S^-1 f_i)``, the normalized innovation of station ``i`` (the test of
  a bias on ``i`` alone), chi-square with 1 dof;
* ``q - w_i``: the NIS with station ``i``'s bias estimated, i.e. the consistency of the other
  measurements without ``i`` (leave-one-out), chi-square with ``d - 1`` dof.

**Gate** (each epoch): the station with the largest ``w_i`` is left out of this epoch's update when
``w_i > chi2.ppf(1 - p_gate, 1)`` (``p_gate = 1e-4``: 3.9 sigma, one clean measurement in 10^4; one
station per epoch: the single-fault assumption; after ``max_gated_streak`` consecutive gated updates
the gate opens for one update, so that a filter that is itself lost cannot lock its measurements out). **Window test**: over the last ``window`` epochs
``Q = sum q`` against ``chi2.ppf(1 - p_fa, sum d)`` (``p_fa`` = false-alarm probability per epoch's
test). On an alarm the station ``i`` with the largest window sum of ``w_i`` is excluded if the rest
passes without it: ``sum (q - w_i) <= chi2.ppf(1 - p_fa, sum d - n_i)`` (RTKLIB's leave-one-out, in
the filter's innovations); the window restarts after every alarm; at least ``min_stations`` stay in
use. The prediction supplies the redundancy a snapshot lacks: with 4 stations (seed001) a
pseudorange snapshot cannot detect, the filter can.

**Re-admission.** The window test has false alarms at its rate ``p_fa`` per epoch, and a false
exclusion leaves a 4-station field at ``min_stations``, unable to exclude a real fault that comes
later (seen: 3 of 400 seed-001 TDOA runs diverged to 10^5-10^6 m that way). So an excluded
station's measurements keep being tested, unused: its normalized innovation as if it were included,
``w'_i = (f_i^T S_i^-1 nu)^2 / (f_i^T S_i^-1 f_i)`` with ``S_i = S - (sigma_out^2 - sigma^2) f_i f_i^T``
(the innovation covariance with its nominal noise restored), chi-square with 1 dof for a healthy
station. Once the last ``window`` of its measurements are all tested and their sum passes
``chi2.ppf(1 - p_fa, window)``, the station is re-admitted (and the window test restarts). A
healthy station excluded just before a real fault elsewhere does not pass that test (the filter is
pulled by the fault), so an alarm that exclusion cannot resolve (``min_stations`` left) re-admits
every excluded station of that run instead, and the next window decides with full redundancy.

**Protection levels** (fault-free hypothesis, K-sigma on the filter covariance, integrity risk
``I`` per epoch for each of H and V): ``HPL = K_H sigma_major`` with ``sigma_major^2`` the largest
eigenvalue of the horizontal position covariance and ``K_H = sqrt(-2 ln I)`` (a 2-D Gaussian leaves
``|e_h| > k sigma_major`` with probability <= ``exp(-k^2 / 2)``, equality when circular);
``VPL = K_V sigma_z`` with ``K_V = Phi^-1(1 - I / 2)``. A fault below the gate and the window test
is not covered by them (the test's own false-alarm / detection figures are measured by
``larns bench integrity --aircraft``).

Implementation: an unbatched filter (the live aircraft) re-runs the update from the saved prior
without its masked measurements - a gated or excluded measurement is *dropped*, however far off it
is. A batch of Monte Carlo runs, whose masks differ per run, gives the masked
measurements a range sigma of ``sigma_out_m`` (1e5 m) instead, which removes their information (for
differences too: an inflated base variance leaves the others' differences) up to ``nu / sigma_out``
of an absurd value; a gated epoch is re-run from the saved prior with the gated station masked. The
statistics of the tests (the NIS and the ``w_i`` of the gate and the window) are those of the measurements
in use: for pseudoranges the masked ones are taken out of ``nu`` and ``S`` (:func:`kept_part`); the
re-admission test sees them all.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.special import chdtri, ndtri

from nav.kalman import chol_solve

from . import models as mdl


@dataclass(frozen=True)
class FdeConfig:
    """Integrity settings of the aircraft filters (see the module docstring)."""

    p_gate: float = 1e-4  # per measurement: gate threshold chi2(1) quantile
    p_fa: float = 1e-5  # per epoch: the window test's false-alarm probability
    window: int = 10  # epochs (batch updates) in the window test
    integrity_risk: float = 1e-3  # per epoch, for HPL and for VPL (fault-free K-sigma bound)
    arm_after: int = 20  # updates before the gate and the test start (the filter's first transient)
    min_stations: int = 3  # never exclude below this many stations
    sigma_out_m: float = 1e5  # range sigma given to a masked measurement
    max_gated_streak: int = 10  # consecutive gated updates after which the gate opens (a lost filter, not a station)


_Q_CACHE: dict = {}


def chi2_quantile(p: float, dof) -> np.ndarray:
    """``chi2.ppf(1 - p, dof)`` for integer dof >= 1 (array), cached per (p, dof)."""
    d = np.asarray(dof, dtype=int)
    if d.ndim == 0:  # one filter (the live aircraft): one look-up
        key = (p, int(d))
        if key not in _Q_CACHE:
            _Q_CACHE[key] = float(chdtri(float(d), p))
        return np.asarray(_Q_CACHE[key])
    u, inv = np.unique(d, return_inverse=True)
    vals = np.empty(u.shape)
    for k, v in enumerate(u):
        key = (p, int(v))
        if key not in _Q_CACHE:
            _Q_CACHE[key] = float(chdtri(float(v), p))
        vals[k] = _Q_CACHE[key]
    return vals[inv].reshape(d.shape)


def protection_levels(P_pos: np.ndarray, integrity_risk: float) -> tuple[np.ndarray, np.ndarray]:
    """HPL, VPL (...) from position covariances P_pos (..., 3, 3) (K-sigma, module docstring)."""
    a, b, c = P_pos[..., 0, 0], P_pos[..., 0, 1], P_pos[..., 1, 1]
    major = 0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b**2)
    k_h = np.sqrt(-2.0 * np.log(integrity_risk))
    k_v = ndtri(1.0 - 0.5 * integrity_risk)
    return k_h * np.sqrt(np.maximum(major, 0.0)), k_v * np.sqrt(np.maximum(P_pos[..., 2, 2], 0.0))


_F_CACHE: dict = {}


def fault_vectors(model: str, m: int, base: int = 0) -> np.ndarray:
    """F (d, m): the innovation direction of a unit bias on each station (read-only, shared)."""
    key = (model == "pr", m, base)
    F = _F_CACHE.get(key)
    if F is None:
        F = np.eye(m) if model == "pr" else mdl.g_matrix(m, base)
        F.setflags(write=False)
        _F_CACHE[key] = F
    return F


def snooping(nu: np.ndarray, S: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(q, w)``: the NIS (...) and each station's normalized innovation ``w`` (..., m)."""
    Fb = F.copy() if S.ndim == 2 else np.broadcast_to(F, S.shape[:-1] + F.shape[-1:]).copy()
    A = chol_solve(S, Fb)  # S^-1 F (..., d, m)
    g = np.einsum("...dm,...d->...m", A, nu)  # F^T S^-1 nu
    den = np.einsum("dm,...dm->...m", F, A)  # diag(F^T S^-1 F)
    Sinu = chol_solve(S, nu[..., None])[..., 0]
    q = np.einsum("...d,...d->...", nu, Sinu)
    return q, g**2 / np.maximum(den, 1e-300)


def kept_part(nu: np.ndarray, S: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pseudorange innovations ``nu`` (..., m) and covariance ``S`` (..., m, m) reduced to the measurements
    ``keep`` (..., m) bool: the others' innovation set to 0 and their rows and columns to those of the
    identity, so that ``nu^T S^-1 nu`` and every ``w_i`` are those of the kept measurements alone (the
    marginal of a Gaussian). A masked measurement's innovation - with ``sigma_out_m`` an absurd value
    still adds ``nu^2 / sigma_out^2``, 29 for 540 km - never reaches the window test (else copies of
    an excluded station's navs, replayed by an insider, would have the test exclude a healthy one)."""
    k = keep.astype(float)
    m = nu.shape[-1]
    Sk = S * (k[..., :, None] * k[..., None, :]) + np.eye(m) * (1.0 - k)[..., None, :]
    return nu * k, Sk


class FilterFde:
    """Gate, window test and exclusion for one batched :class:`CvTracker` (runs ``shape``)."""

    def __init__(self, cfg: FdeConfig, shape: tuple = ()):
        self.cfg = cfg
        self.shape = tuple(shape)
        self.out: dict = {}  # station id -> (shape) bool: excluded
        self.win: deque = deque()  # (ids, q, d, w, valid) per epoch, the last ``window`` epochs
        self.W: dict = {}  # station id -> window sums of (w, measurements) per run
        self.Q = self.D = np.zeros(self.shape)  # window sums of the NIS and of its dof per run
        self.n_updates = 0
        self.alarms = np.zeros(self.shape, dtype=int)  # window-test alarms per run
        self.gated = np.zeros(self.shape, dtype=int)  # measurements gated per run
        self.events: list[tuple] = []  # (t_s, run index, station id, statistic, threshold)
        self.readmitted: list[tuple] = []  # the same for re-admissions
        self.rwin: dict = {}  # station id -> deque of (w', tested) of its last ``window`` measurements
        self.g_thr = float(chi2_quantile(cfg.p_gate, 1))
        self.streak = np.zeros(self.shape, dtype=int)  # consecutive gated updates per run
        self.dropped_updates = 0  # unbatched updates left out whole (every measurement masked)
        # (nu, S, q, w) of the latest update's test over all its measurements (none masked), for the
        # divergence monitor, which tests the same innovation
        self.last_snooping: tuple | None = None

    def restart(self) -> None:
        """A new filter (after a reset): empty window, unarmed; the exclusions stand."""
        self.win.clear()
        self.W = {}
        self.Q = self.D = np.zeros(self.shape)
        self.n_updates = 0
        self.streak = np.zeros(self.shape, dtype=int)

    # -- state
    def excluded(self, run=None) -> list:
        """Excluded station ids (of one run; ``run=None`` for an unbatched filter)."""
        return sorted(i for i, v in self.out.items() if (v if run is None else v[run]))

    def mask(self, ids) -> np.ndarray:
        """(shape + (m,)) bool: measurement j of the batch is excluded."""
        if not self.shape:
            out = self.out
            return np.array([i in out and bool(out[i]) for i in ids], dtype=bool)
        cols = [self.out.get(i, np.zeros(self.shape, dtype=bool)) for i in ids]
        return np.stack(cols, axis=-1) if cols else np.zeros(self.shape + (0,), dtype=bool)

    def _sigma(self, tuning, masked: np.ndarray):
        return None if not masked.any() else np.where(masked, self.cfg.sigma_out_m, tuning.sigma_m)

    def _apply(self, trk, masked, stations_m, rho_m, station_cov_m2, dt_s, bias_kw) -> None:
        """The update that counts. An unbatched filter (the live aircraft) *drops* its masked
        measurements: they are left out of the update, so a value however far off moves nothing (a
        1e12 m position given ``sigma_out_m`` would still move the aircraft hundreds of metres). A batch of
        Monte Carlo runs (``shape``), whose masks differ per run, gives them ``sigma_out_m`` instead."""
        if self.shape or not masked.any():
            trk.update(stations_m, rho_m, station_cov_m2, dt_s, sigma_m=self._sigma(trk.tuning, masked), **bias_kw)
            return
        keep = np.flatnonzero(~masked)
        if keep.size < (1 if trk.layout.kind == "pr" else 2):
            self.dropped_updates += 1  # nothing usable left: the prior stands
            return
        m = masked.size
        kw = dict(bias_kw)
        if kw.get("bias_ids") is not None:
            kw["bias_ids"] = [kw["bias_ids"][j] for j in keep]
        if kw.get("bias_var_m2") is not None and np.ndim(kw["bias_var_m2"]):
            kw["bias_var_m2"] = np.asarray(kw["bias_var_m2"])[keep]
        sig = trk.tuning.sigma_m
        sig = None if np.ndim(sig) == 0 else np.broadcast_to(np.asarray(sig, float), (m,))[keep]
        trk.update(np.asarray(stations_m)[keep], np.asarray(rho_m)[..., keep],
                   None if station_cov_m2 is None else np.asarray(station_cov_m2)[keep],
                   None if dt_s is None else np.asarray(dt_s)[keep], sigma_m=sig, **kw)

    # -- the update
    def update(self, trk, stations_m, rho_m, ids, station_cov_m2=None, dt_s=None, **bias_kw):
        """``trk.update`` with the gate, the window test and exclusion; returns its (nu, S) (about the
        prior, every measurement of the batch, the masked ones with ``sigma_out_m``: the tests' view)."""
        ids = list(ids)
        self.last_snooping = None
        masked = self.mask(ids)
        armed = self.n_updates >= self.cfg.arm_after
        drop = not self.shape and bool(masked.any())  # unbatched: masked measurements are dropped
        saved = trk.save() if armed or drop else None
        nu, S = trk.update(stations_m, rho_m, station_cov_m2, dt_s, sigma_m=self._sigma(trk.tuning, masked),
                           **bias_kw)
        self.n_updates += 1
        if not armed:
            if drop:
                trk.restore(saved)
                self._apply(trk, masked, stations_m, rho_m, station_cov_m2, dt_s, bias_kw)
            return nu, S
        F = fault_vectors(trk.layout.kind, len(ids), trk.base)
        if trk.layout.kind == "pr" and masked.any():
            q, w = snooping(*kept_part(nu, S, ~masked), F)  # the tests see only what is in use
        else:
            q, w = snooping(nu, S, F)
            self.last_snooping = (nu, S, q, w)
        w = np.where(masked, 0.0, w)
        if masked.any():
            self._readmission(trk, ids, nu, S, F, masked)
        d = (~masked).sum(-1) - (trk.layout.kind != "pr")
        jmax = np.argmax(w, axis=-1)
        wmax = w[jmax] if w.ndim == 1 else np.take_along_axis(w, jmax[..., None], -1)[..., 0]
        gate = (wmax > self.g_thr) & (self.streak < self.cfg.max_gated_streak)
        self.streak = np.where(gate, self.streak + 1, 0)
        if np.any(gate):
            trk.restore(saved)
            masked2 = masked | (gate[..., None] & (np.arange(len(ids)) == jmax[..., None]))
            self._apply(trk, masked2, stations_m, rho_m, station_cov_m2, dt_s, bias_kw)
            self.gated += gate
        elif drop:
            trk.restore(saved)
            self._apply(trk, masked, stations_m, rho_m, station_cov_m2, dt_s, bias_kw)
        self._push(ids, q, d, w)
        self._test(trk.t_s)
        return nu, S

    def _readmission(self, trk, ids, nu, S, F, masked) -> None:
        """Test the excluded stations of this batch unused and re-admit those found healthy (module
        docstring: Re-admission)."""
        sig = np.broadcast_to(np.asarray(trk.tuning.sigma_m, dtype=float), (len(ids),))
        n = self.cfg.window
        T = float(chi2_quantile(self.cfg.p_fa, n))
        for j in np.flatnonzero(masked.reshape(-1, len(ids)).any(axis=0)):
            i, f, mj = ids[j], F[:, j], masked[..., j]
            c = self.cfg.sigma_out_m**2 - sig[j] ** 2
            Sj = S - np.where(mj[..., None, None], c * np.outer(f, f), 0.0)
            A = chol_solve(Sj, np.broadcast_to(f, S.shape[:-1])[..., None].copy())[..., 0]  # S_i^-1 f
            wj = np.einsum("...d,...d->...", A, nu) ** 2 / np.maximum(np.einsum("d,...d->...", f, A), 1e-300)
            win = self.rwin.setdefault(i, deque(maxlen=n))
            win.append((np.where(mj, wj, 0.0), mj.copy()))
            if len(win) < n:
                continue
            tested = np.all([e[1] for e in win], axis=0)
            tot = np.sum([e[0] for e in win], axis=0)
            back = tested & (tot <= T)
            if np.any(back):
                self._readmit(i, back, trk.t_s, tot, T)
                self._restart(back)

    def _readmit(self, i, back: np.ndarray, t_s: float, stat, thr) -> None:
        """Station ``i`` back in use in the runs ``back`` (bool, shape); its re-admission window cleared."""
        self.out[i] = self.out[i] & ~back
        for e in self.rwin.get(i, ()):
            e[1][...] = e[1] & ~back
        stat, thr = np.broadcast_to(stat, self.shape), np.broadcast_to(thr, self.shape)
        for r in zip(*np.nonzero(np.atleast_1d(back))):
            self.readmitted.append((t_s, int(r[0]) if self.shape else None, i,
                                    float(np.atleast_1d(stat)[r]), float(np.atleast_1d(thr)[r])))

    def _push(self, ids, q, d, w) -> None:
        """Add one epoch to the window sums (dropping the oldest beyond ``window`` epochs)."""
        if len(self.win) == self.cfg.window:
            self._add(*self.win.popleft(), sign=-1.0)
        entry = (ids, q, d, w, np.ones(self.shape, dtype=bool))
        self.win.append(entry)
        self._add(*entry, sign=1.0)

    def _add(self, ids, q, d, w, valid, sign: float) -> None:
        if not self.shape:
            self._add_one(ids, q, d, w, bool(valid), sign)
            return
        z = np.zeros(self.shape)
        self.Q = self.Q + sign * np.where(valid, q, 0.0)
        self.D = self.D + sign * np.where(valid, d, 0)
        for j, i in enumerate(ids):
            Wi, Ni = self.W.get(i, (z, z))
            self.W[i] = (Wi + sign * np.where(valid, w[..., j], 0.0), Ni + sign * (valid & (w[..., j] > 0)))

    def _add_one(self, ids, q, d, w, valid: bool, sign: float) -> None:
        """:meth:`_add` of an unbatched filter (``valid`` a bool): the same sums."""
        self.Q = self.Q + sign * (q if valid else 0.0)
        self.D = self.D + sign * (d if valid else 0)
        W = self.W
        for j, i in enumerate(ids):
            wj = w[j]
            e = W.get(i)
            Wi, Ni = (np.zeros(()), np.zeros(())) if e is None else e
            W[i] = (Wi + sign * (wj if valid else 0.0), Ni + sign * (valid and bool(wj > 0)))

    def _restart(self, runs: np.ndarray) -> None:
        """Empty the window of the runs ``runs`` (bool, shape)."""
        for e in self.win:
            e[4][...] = e[4] & ~runs
        self.Q = np.where(runs, 0.0, self.Q)
        self.D = np.where(runs, 0.0, self.D)
        self.W = {i: (np.where(runs, 0.0, a), np.where(runs, 0.0, b)) for i, (a, b) in self.W.items()}

    def _test(self, t_s: float) -> None:
        """The window test and leave-one-out exclusion (module docstring)."""
        Q, D = self.Q, np.rint(self.D)
        if not self.shape and not (D > 0 and Q > chi2_quantile(self.cfg.p_fa, np.maximum(D, 1))):
            return  # unbatched, no alarm
        T = np.where(D > 0, chi2_quantile(self.cfg.p_fa, np.maximum(D, 1)), np.inf)
        alarm = Q > T
        if not np.any(alarm):
            return
        self.alarms += alarm
        cand = list(self.W)
        Ws = np.stack([self.W[i][0] for i in cand], axis=-1)
        k = np.argmax(Ws, axis=-1)
        R = Q - np.take_along_axis(Ws, k[..., None], -1)[..., 0]
        Dr = D - np.rint(np.take_along_axis(np.stack([self.W[i][1] for i in cand], axis=-1), k[..., None], -1)[..., 0])
        ok = np.where(Dr > 0, R <= chi2_quantile(self.cfg.p_fa, np.maximum(Dr, 1)), True)
        n_in = len(cand) - np.stack([self.out.get(i, np.zeros(self.shape, dtype=bool)) for i in cand], -1).sum(-1)
        excl = alarm & ok & (n_in > self.cfg.min_stations)
        # an alarm that exclusion cannot resolve (at min_stations) questions the earlier exclusions:
        # every excluded station comes back and the next window decides with the full redundancy
        stuck = alarm & ~excl & (n_in <= self.cfg.min_stations)
        if np.any(stuck):
            for i in [i for i, v in self.out.items() if np.any(v & stuck)]:
                self._readmit(i, self.out[i] & stuck, t_s, Q, T)
        for j, i in enumerate(cand):
            hit = excl & (k == j)
            if np.any(hit):
                self.out[i] = self.out.get(i, np.zeros(self.shape, dtype=bool)) | hit
                for r in zip(*np.nonzero(np.atleast_1d(hit))):
                    self.events.append((t_s, int(r[0]) if self.shape else None, i, float(np.atleast_1d(Q)[r]),
                                        float(np.atleast_1d(T)[r])))
        self._restart(alarm)
