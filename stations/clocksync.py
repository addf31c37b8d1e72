"""Decentralized network time: each station estimates its own clock against station 1's (pure, sans-I/O).

Network time is station 1's clock, as station 1 is the origin of the frame. Station ``m`` estimates
``theta_m(t) = t - T(t)`` (its local time ``t`` minus network time ``T``) and its fractional frequency
``f_m = d theta_m / dt`` with the two-state clock model of ``net/clock.py`` (state ``[theta, f]``,
``F = [[1, dt], [0, 1]]``, ``Q(dt)`` from the oscillator class ``q_wf``, ``q_rw``).

Measurements:

* **Two-way time transfer** inside every range exchange (initiator ``m``, responder ``j``; ``t1`` request
  sent and ``t4`` reply received on ``m``'s clock, ``t2`` request received and ``t3`` reply sent on
  ``j``'s clock)::

      dtheta = ((t4 - t3) - (t2 - t1)) / 2 = theta_m - theta_j      (at the exchange's midpoint)
      range  = c ((t4 - t1) / (1 + f_m) - (t3 - t2) / (1 + f_j)) / 2

  exact for linear clocks whatever their offsets and frequencies (the midpoints ``(t1 + t4) / 2`` and
  ``(t2 + t3) / 2`` are the same true instant); each arrival's timing noise ``sigma_t = sqrt(2)
  sigma_d / c`` gives ``var(dtheta) = sigma_d^2 / c^2``. Both ends use the exchange: the initiator on
  the reply, the responder from the initiator's nav broadcast (which carries ``dtheta``).
* The peer's broadcast **clock correction** ``[t_ref, theta, f, P_tt, P_tf, P_ff]`` (on the peer's own
  clock) predicted to the exchange with the model: ``theta_m = dtheta + theta_j``, measurement variance
  ``sigma_d^2 / c^2 + gamma P_j(t)``. As in the position survey (``estimators.DistributedMap``) a
  consider factor ``gamma = 2`` on the peer term keeps the covariance honest about the errors peers
  share; the gain uses ``gamma_est = 1`` and the covariance the Joseph form with ``gamma``.
* **Coarse sync** while the clock is unknown to more than ``coarse_gate_s``: a nav broadcast received
  at ``t_rx`` with transmit stamp ``t_tx`` gives ``theta_m = t_rx - (t_tx - theta_j(t_tx)) - d / c`` with
  the distance ``d`` unknown (variance ``(coarse_range_m / c)^2``): microseconds from the first nav heard.

Station 1 is the time reference: ``theta = f = 0`` exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nav.geometry import SPEED_OF_LIGHT_M_S
from net.clock import transition

C = SPEED_OF_LIGHT_M_S


@dataclass(frozen=True)
class ClockModel:
    """What a station knows of its oscillator class (data-sheet values, not its realized clock)."""

    q_wf_s: float = 0.0
    q_rw_per_s: float = 0.0
    offset_sigma_s: float = 0.0
    freq_sigma: float = 0.0


def predict_correction(corr, t_s: float, model: ClockModel) -> tuple[float, float]:
    """A broadcast clock correction ``[t_ref, theta, f, P_tt, P_tf, P_ff]`` evaluated at ``t_s`` (same
    clock as ``t_ref``): offset (s) and its variance (s^2), process noise of ``model`` included (twice:
    the station's oscillator and network time's, station 1's, both wander)."""
    t_ref, th, f, ptt, ptf, pff = (float(v) for v in corr)
    dt = t_s - t_ref
    _, Q = transition(dt, model.q_wf_s, model.q_rw_per_s)
    var = ptt + 2.0 * dt * ptf + dt * dt * pff + 2.0 * Q[0, 0]
    return th + f * dt, max(var, 0.0)


class ClockEstimator:
    """Network clock filter of one station (see module docstring): a Kalman filter of every known
    station's ``[theta, f]`` against network time, fed by all two-way exchanges the station takes part
    in or hears in the nav broadcasts, plus coarse one-way nav timing while a clock is unknown.

    States are functions of network time ``T``; the station converts its local time with its own
    estimate, ``T = t - theta_me(T)``. Station 1 (``theta = f = 0``) is not a state. Network time is
    itself an oscillator: ``theta_k = x_k - x_1`` wanders with its own noise and station 1's, which
    all stations share, so the process noise is ``Q(dt) (x) (I + 1 1^T)``.

    Parameters
    ----------
    station_id : this station (1: the reference, exact). model : oscillator class (prior and noise of
    every clock). t0_s : local time of the prior. sigma_d_m : two-way range noise (sets the TWTT noise).
    """

    def __init__(self, station_id: int, model: ClockModel, t0_s: float, sigma_d_m: float,
                 coarse_range_m: float = 5000.0, coarse_gate_s: float = 1e-6):
        self.id = station_id
        self.ref = station_id == 1
        self.model = model
        self.T_s = float(t0_s)
        self.index: dict[int, int] = {}
        self.x = np.zeros(0)
        self.P = np.zeros((0, 0))
        self.var_z = (sigma_d_m / C) ** 2
        self.coarse_var = (coarse_range_m / C) ** 2
        self.coarse_gate_s = coarse_gate_s
        self.n_updates = 0
        self.n_coarse = 0
        self.exact = model.offset_sigma_s == 0 and model.freq_sigma == 0 and model.q_wf_s == 0 \
            and model.q_rw_per_s == 0  # perfect clocks: nothing to estimate
        if not self.ref:
            self._add(station_id)

    # ------------------------------------------------------------------ state bookkeeping
    def _add(self, sid: int) -> int:
        k = self.index.get(sid)
        if k is None:
            k = self.index[sid] = len(self.index)
            n = 2 * len(self.index)
            P = np.zeros((n, n))
            P[: n - 2, : n - 2] = self.P
            P[n - 2, n - 2] = self.model.offset_sigma_s**2
            P[n - 1, n - 1] = self.model.freq_sigma**2
            self.P = P
            self.x = np.concatenate([self.x, [0.0, 0.0]])
        return k

    def _own(self) -> tuple[float, float, float, float, float]:
        """Own ``theta, f`` at ``T_s`` and their covariance ``P_tt, P_tf, P_ff``."""
        if self.ref:
            return 0.0, 0.0, 0.0, 0.0, 0.0
        k = 2 * self.index[self.id]
        P = self.P
        return self.x[k], self.x[k + 1], P[k, k], P[k, k + 1], P[k + 1, k + 1]

    # ------------------------------------------------------------------ time conversions
    @property
    def known(self) -> bool:
        """Own clock known to better than the coarse gate (station 1: always)."""
        return self.ref or self._own()[2] <= self.coarse_gate_s**2

    @property
    def offset_var_s2(self) -> float:
        return self._own()[2]

    def network_time(self, t_local_s: float) -> float:
        """Estimated network time at local time ``t_local_s``."""
        a, f = self._own()[:2]
        return (t_local_s - a + f * self.T_s) / (1.0 + f)

    def local_time(self, t_net_s: float) -> float:
        """Local time at which the estimated network time is ``t_net_s``."""
        a, f = self._own()[:2]
        return t_net_s + a + f * (t_net_s - self.T_s)

    def offset_at(self, t_local_s: float) -> float:
        """Estimated own offset (local minus network time) at local time ``t_local_s``, s."""
        return t_local_s - self.network_time(t_local_s)

    def freq(self) -> float:
        return float(self._own()[1])

    def variance_at(self, t_local_s: float) -> float:
        """Own offset variance at local ``t_local_s`` (predicted; the state unchanged), s^2."""
        _, _, ptt, ptf, pff = self._own()
        dt = self.network_time(t_local_s) - self.T_s
        _, Q = transition(dt, self.model.q_wf_s, self.model.q_rw_per_s)
        return float(ptt + 2 * dt * ptf + dt * dt * pff + (2.0 * Q[0, 0] if dt > 0 else 0.0))

    def correction(self, t_local_s: float) -> list[float]:
        """Broadcast clock correction at local time ``t_s``: ``[t_ref, theta, f, P_tt, P_tf, P_ff]``."""
        if self.ref:
            return [float(t_local_s), 0.0, 0.0, 0.0, 0.0, 0.0]
        self.predict(self.network_time(t_local_s))
        a, f, ptt, ptf, pff = self._own()
        dt = self.network_time(t_local_s) - self.T_s  # 0 unless t_local_s lies in the filter's past
        return [float(t_local_s), float(a + f * dt), float(f), float(ptt + 2 * dt * ptf + dt * dt * pff),
                float(ptf + dt * pff), float(pff)]

    # ------------------------------------------------------------------ filter steps
    def predict(self, T_s: float) -> None:
        """Move every clock to network time ``T_s`` (no-op for the past: late inputs use ``H = [1, dt]``)."""
        dt = T_s - self.T_s
        if dt <= 0 or not len(self.x):
            self.T_s = max(self.T_s, T_s)
            return
        x, P = self.x, self.P
        x[0::2] += dt * x[1::2]
        # F P F^T with F = I + dt E (E: theta <- f in each 2x2 block)
        P[0::2, :] += dt * P[1::2, :]
        P[:, 0::2] += dt * P[:, 1::2]
        _, Q = transition(dt, self.model.q_wf_s, self.model.q_rw_per_s)
        n = len(x) // 2
        i = np.arange(n) * 2
        # network time's (station 1's) own wander, common to every station's offset
        P[0::2, 0::2] += Q[0, 0]
        P[0::2, 1::2] += Q[0, 1]
        P[1::2, 0::2] += Q[1, 0]
        P[1::2, 1::2] += Q[1, 1]
        P[i, i] += Q[0, 0]
        P[i, i + 1] += Q[0, 1]
        P[i + 1, i] += Q[1, 0]
        P[i + 1, i + 1] += Q[1, 1]
        self.P = 0.5 * (P + P.T)
        self.T_s = float(T_s)

    def _row(self, T_s: float, terms: list[tuple[int, float]]) -> np.ndarray:
        h = np.zeros(len(self.x))
        dt = T_s - self.T_s  # <= 0 for late inputs
        for sid, sign in terms:
            if sid == 1:
                continue
            k = 2 * self._add(sid)
            if len(h) < len(self.x):
                h = np.concatenate([h, np.zeros(len(self.x) - len(h))])
            h[k] += sign
            h[k + 1] += sign * dt
        return h

    def _update(self, h: np.ndarray, z: float, r: float) -> float:
        PH = self.P @ h
        s_prior = float(h @ PH)
        S = s_prior + r
        K = PH / S
        nu = z - float(h @ self.x)
        self.x = self.x + K * nu
        # Joseph form (I - K h) P (I - K h)^T + r K K^T, expanded as rank-1 terms
        P = self.P - np.outer(K, PH) - np.outer(PH, K) + S * np.outer(K, K)
        self.P = 0.5 * (P + P.T)
        self.n_updates += 1
        return nu * nu / S

    def on_exchange(self, a: int, b: int, T_s: float, dtheta_s: float, t_var_s2: float = 0.0) -> float | None:
        """Two-way time transfer ``theta_a - theta_b = dtheta_s`` at network time ``T_s``; the NIS.

        ``t_var_s2``: variance of ``T_s`` itself (it comes from a clock estimate): an error ``e`` in the
        time of the measurement shifts it by ``(f_a - f_b) e``, charged as ``E[(f_a - f_b)^2] t_var``
        (matters only before a station's first fine sync)."""
        if self.exact or (a == 1 and b == 1):
            return None
        self.predict(T_s)
        h = self._row(T_s, [(a, 1.0), (b, -1.0)])
        r = self.var_z
        if t_var_s2 > 0:
            hf = np.zeros(len(self.x))
            hf[1::2] = h[0::2]  # f_a - f_b
            r += (float(hf @ self.x) ** 2 + float(hf @ self.P @ hf)) * t_var_s2
        return self._update(h, dtheta_s, r)

    def on_nav(self, src: int, t_rx_s: float, t_tx_src_s: float, corr) -> bool:
        """Coarse one-way timing of a nav from ``src`` (``t_tx`` on its clock, ``corr`` its broadcast
        correction) while ``theta_me - theta_src`` is unknown to more than the gate; True if used."""
        if self.exact or corr is None or src == self.id:
            return False
        T = self.network_time(t_rx_s)
        if self._coarse_var_at(T, src) <= self.coarse_gate_s**2:  # the common case once synced
            return False  # (the filter stays where it is: the next input predicts it)
        self.predict(T)
        h = self._row(T, [(self.id, 1.0), (src, -1.0)])
        if float(h @ self.P @ h) <= self.coarse_gate_s**2:
            return False
        # t_rx - t_tx = d / c + theta_me - theta_src: the distance unknown (coarse variance)
        self._update(h, t_rx_s - t_tx_src_s, self.coarse_var)
        self.n_coarse += 1
        return True

    def _coarse_var_at(self, T_s: float, src: int) -> float:
        """Variance of ``theta_me - theta_src`` predicted to network time ``T_s`` without moving the
        filter (only the two clocks' 2x2 blocks: O(1) instead of a full predict). The wander common to
        every offset cancels in the difference (not against the reference, station 1); each
        non-reference clock adds its own ``Q_tt``."""
        dt = max(T_s - self.T_s, 0.0)
        idx, h = [], []
        for sid, sign in ((self.id, 1.0), (src, -1.0)):
            k = self.index.get(sid)
            if sid == 1:
                continue
            if k is None:
                return float("inf")  # not in the filter yet: unknown
            idx += [2 * k, 2 * k + 1]
            h += [sign, sign * dt]
        if not idx:
            return 0.0
        hv = np.asarray(h)
        var = float(hv @ self.P[np.ix_(idx, idx)] @ hv)
        if dt > 0:  # each clock's own wander, plus the common one where it does not cancel
            _, Q = transition(dt, self.model.q_wf_s, self.model.q_rw_per_s)
            var += (len(idx) // 2 + float(hv[0::2].sum()) ** 2) * Q[0, 0]
        return var

    def peer_time(self, sid: int, t_peer_s: float, corr=None) -> tuple[float, float]:
        """Network time at station ``sid``'s local time ``t_peer_s`` and its variance, from this filter's
        own (prior) estimate of that clock; a station not in the filter yet: from its broadcast."""
        if sid == 1:
            return float(t_peer_s), 0.0
        k = self.index.get(sid)
        if k is None:
            if corr is None:
                return float(t_peer_s), self.model.offset_sigma_s**2
            th, var = predict_correction(corr, t_peer_s, self.model)
            return t_peer_s - th, var
        a, f = self.x[2 * k], self.x[2 * k + 1]
        T = (t_peer_s - a + f * self.T_s) / (1.0 + f)
        dt = T - self.T_s
        P = self.P
        var = P[2 * k, 2 * k] + 2 * dt * P[2 * k, 2 * k + 1] + dt * dt * P[2 * k + 1, 2 * k + 1]
        return float(T), float(max(var, 0.0))
