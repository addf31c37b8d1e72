"""The stations' residual clock errors as filter states (``Tuning.clock_bias == "states"``).

After the broadcast clock correction each station's range keeps a slowly varying sync error
(docs/sync.md). Each station heard gets one first-order Gauss-Markov range bias, stationary variance
= its broadcast clock variance ``c^2 P_theta``, correlation time ``clock_bias_tau_s``; added as the
station is first heard, dropped (marginalized) after ``clock_bias_drop_s`` without a measurement.

A station's broadcast position error persists too (its survey's error, minutes): with
``Tuning.survey_bias_tau_s > 0`` each station heard also gets a range bias ``u^T e_j`` (``e_j`` its
position error, ``u`` the line of sight) of stationary variance ``u^T C_j u`` (its broadcast position
covariance ``C_j`` at the filter's estimate), correlation time ``survey_bias_tau_s``, held as a
*consider* (Schmidt) state: its covariance with the rest is carried, so the filter does not average
that error away, but it is never estimated (its mean stays 0): a station whose survey is wrong and
whose covariance does not say so is not absorbed, its innovations keep the bias the integrity test
must see. Its id is ``(POS_ERROR, station_id)``; the clock bias's is the station id.
"""

from __future__ import annotations

import numpy as np

from nav.pcrb import gauss_markov_diag

POS_ERROR = "pos"  # the first element of a position-error state's id
_NO_STATES = np.zeros(0, dtype=int)


def _position_errors(ids) -> np.ndarray:
    """Which of the state ids ``ids`` (m,) are position errors (``(POS_ERROR, station id)``): bool (m,)."""
    return np.array([isinstance(i, tuple) for i in ids], dtype=bool)


class ClockBiases:
    """``ids``: ids of the bias states (a station id: its clock bias; ``(POS_ERROR, station id)``: its
    position error, a consider state), in state order after the ``n_base`` base states; ``var`` their
    stationary variances (latest broadcast), m^2; ``t`` when each was last measured. ``tau_s`` /
    ``pos_tau_s``: the correlation times of the clock and position-error states."""

    def __init__(self, n_base: int, tau_s: float, drop_s: float, pos_tau_s: float = 0.0):
        self.n_base = n_base
        self.tau_s = tau_s
        self.pos_tau_s = pos_tau_s
        self.drop_s = drop_s
        self.ids: list = []
        self.var = np.zeros(0)
        self.t = np.zeros(0)

    def process(self, F: np.ndarray, Q: np.ndarray, dt: float):
        """``(F, Q)`` of the base states extended by the independent Gauss-Markov bias states."""
        nb, n = len(self.ids), F.shape[-1]
        if not nb:
            return F, Q
        pe = _position_errors(self.ids) if self.pos_tau_s > 0 else np.zeros(nb, dtype=bool)
        a, qb = np.empty((2, nb))
        for tau_s, m in ((self.tau_s, ~pe), (self.pos_tau_s, pe)):
            if m.any():
                a[m], qb[m] = gauss_markov_diag(int(m.sum()), self.var[m], tau_s, dt)
        Fx, Qx = np.zeros((2, n + nb, n + nb))
        Fx[:n, :n], Qx[:n, :n] = F, Q
        k = np.arange(n, n + nb)
        Fx[k, k], Qx[k, k] = a, qb
        return Fx, Qx

    def consider(self) -> np.ndarray:
        """State indices (k,) of the consider states (the position errors), in the full state."""
        if not self.pos_tau_s > 0:  # (no position-error states without their correlation time)
            return _NO_STATES
        return self.n_base + np.flatnonzero(_position_errors(self.ids))

    def _rescale(self, P: np.ndarray, ids, idx: np.ndarray, var: np.ndarray) -> np.ndarray:
        """``P`` with the position errors' rows and columns scaled to their new variances ``var`` (m,)
        (states ``idx``): such a variance follows the broadcast covariance and the line of sight, and the
        error is taken to scale with it (its covariance with the rest too); a clock bias keeps its state."""
        pe = _position_errors(ids)
        if not pe.any():
            return P
        f = np.ones(P.shape[-1])
        f[self.n_base + idx[pe]] = np.sqrt(var[pe] / self.var[idx[pe]])
        return P * f[:, None] * f[None, :]

    def use(self, x: np.ndarray, P: np.ndarray, ids, var_m2, t_s: float):
        """Bias states for the stations ``ids`` (m,) with broadcast variances ``var_m2`` (m,) at ``t_s``:
        adds a state ``N(0, var)`` (independent of the rest) for a station heard for the first time,
        keeps the latest broadcast variance as its stationary variance, drops the states of stations
        unheard for ``drop_s``. A station id ``None`` or a variance <= 0 (no clock correction
        broadcast): no bias for that measurement (row of zeros).

        Returns ``(x, P, D, changed)``: the filter's state with the bias states added/dropped, ``D``
        (m, nb) (measurement j sees bias ``D[j] @ beta``), and whether the process model changed."""
        changed = False
        var_all = np.asarray(var_m2, dtype=float)
        if var_all.shape != (len(ids),):
            var_all = np.broadcast_to(var_all, (len(ids),))
        rows = [j for j, (sid, v) in enumerate(zip(ids, var_all)) if sid is not None and v > 0]
        m_all = len(var_all)
        ids = [ids[j] for j in rows]
        var = var_all[rows]
        stale = [k for k, sid in enumerate(self.ids) if sid not in ids and t_s - self.t[k] > self.drop_s]
        if stale:
            keep = np.setdiff1d(np.arange(x.shape[-1]), self.n_base + np.array(stale))
            x = x[..., keep]
            P = P[..., keep[:, None], keep]
            self.ids = [sid for k, sid in enumerate(self.ids) if k not in stale]
            kb = np.setdiff1d(np.arange(len(self.var)), stale)
            self.var, self.t = self.var[kb], self.t[kb]
            changed = True
        new = [(sid, v) for sid, v in zip(ids, var) if sid not in self.ids]
        if new:
            k, n = len(new), x.shape[-1]
            vn = np.array([v for _, v in new])
            x = np.concatenate([x, np.zeros(x.shape[:-1] + (k,))], axis=-1)
            P1 = np.zeros(P.shape[:-2] + (n + k, n + k))
            P1[..., :n, :n] = P
            P1[..., n:, n:] = np.diag(vn)
            P = P1
            self.ids += [sid for sid, _ in new]
            self.var = np.concatenate([self.var, vn])
            self.t = np.concatenate([self.t, np.full(k, t_s)])
            changed = True
        idx = np.array([self.ids.index(sid) for sid in ids], dtype=int)
        if not np.array_equal(self.var[idx], var):
            P = self._rescale(P, ids, idx, var)
            self.var[idx] = var
            changed = True
        self.t[idx] = t_s
        D = np.zeros((m_all, len(self.ids)))
        D[rows, idx] = 1.0
        return x, P, D, changed
