"""Station oscillators as they are (pure, seeded): a two-state clock model.

State of one free-running clock against true time ``tau``: phase (time error) ``x(tau)`` in seconds,
``t_local = tau + x(tau)``, and fractional frequency ``y = dx/dtau``. The standard two-state model
(e.g. Zucca & Tavella 2005; the GNSS receiver clock model ``q_wf``/``q_rw``)::

    dx/dtau = y + w_1      white frequency noise,        E[w_1 w_1] = q_wf  delta   (q_wf in s)
    dy/dtau = w_2          random-walk frequency noise,  E[w_2 w_2] = q_rw  delta   (q_rw in 1/s)

has the Allan variance ``sigma_y^2(tau) = q_wf / tau + q_rw tau / 3`` and, over a step ``h``, the exact
discrete transition ``F = [[1, h], [0, 1]]`` with noise covariance
``Q(h) = [[q_wf h + q_rw h^3/3, q_rw h^2/2], [q_rw h^2/2, q_rw h]]``.

Presets (``docs/scenarios.md``, section ``[clock]``):

========  =============  ==============  ============  =============  ====================
preset    offset sigma   freq. sigma     q_wf (s)      q_rw (1/s)     ADEV 1 s / 100 s
========  =============  ==============  ============  =============  ====================
tcxo      1 ms           2 ppm           1e-20         3e-22          1.0e-10 / 1.0e-10
ocxo      1 ms           0.05 ppm        1e-24         3e-28          1.0e-12 / 1.0e-12
========  =============  ==============  ============  =============  ====================

The emulated phase is generated on a grid of ``h = 1 s`` from true time 0 (the fleet epoch) with the
exact discrete model, and interpolated linearly in between (so time is continuous and monotonic and
the Allan deviation at multiples of ``h`` is the model's). Steps are drawn in fixed-size chunks from
the clock's own stream, so any process asking for any times sees the same clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nav.geometry import SPEED_OF_LIGHT_M_S

PRESETS: dict[str, dict[str, float]] = {
    "perfect": {"offset_s": 0.0, "freq_ppm": 0.0, "q_wf_s": 0.0, "q_rw_per_s": 0.0},
    "tcxo": {"offset_s": 1e-3, "freq_ppm": 2.0, "q_wf_s": 1e-20, "q_rw_per_s": 3e-22},
    "ocxo": {"offset_s": 1e-3, "freq_ppm": 0.05, "q_wf_s": 1e-24, "q_rw_per_s": 3e-28},
}


@dataclass(frozen=True)
class ClockParams:
    """Oscillator class of every station: initial offset / frequency sigmas and the noise densities."""

    model: str = "perfect"
    offset_s: float = 0.0      # sigma of the offset at the fleet epoch
    freq_ppm: float = 0.0      # sigma of the fractional frequency offset, ppm
    q_wf_s: float = 0.0        # white frequency noise density, s (sigma_y(1 s)^2)
    q_rw_per_s: float = 0.0    # random-walk frequency noise density, 1/s

    @property
    def freq_sigma(self) -> float:
        return self.freq_ppm * 1e-6

    @property
    def stochastic(self) -> bool:
        return self.q_wf_s > 0 or self.q_rw_per_s > 0

    @property
    def perfect(self) -> bool:
        return self.offset_s == 0 and self.freq_ppm == 0 and not self.stochastic

    def adev(self, tau_s: np.ndarray | float) -> np.ndarray:
        """Model Allan deviation ``sqrt(q_wf / tau + q_rw tau / 3)``."""
        tau = np.asarray(tau_s, float)
        return np.sqrt(self.q_wf_s / tau + self.q_rw_per_s * tau / 3.0)


def clock_params(raw: dict | None, legacy_offset_s: float = 0.0, legacy_drift_ppm: float = 0.0) -> ClockParams:
    """``[clock]`` section -> :class:`ClockParams`: ``model`` preset, any key overrides the preset.

    Without a ``[clock]`` section the legacy ``[channel] clock_offset_s / clock_drift_ppm`` describe a
    clock without noise (both 0: perfect clocks)."""
    raw = dict(raw or {})
    if not raw:
        return ClockParams("perfect" if not (legacy_offset_s or legacy_drift_ppm) else "custom",
                           float(legacy_offset_s), float(legacy_drift_ppm))
    model = str(raw.pop("model", "tcxo"))
    if model not in PRESETS and model != "custom":
        raise ValueError(f"[clock] model: unknown {model!r}; choose from {sorted(PRESETS) + ['custom']}")
    vals = dict(PRESETS.get(model, PRESETS["perfect"]))
    for k, v in raw.items():
        if k not in vals:
            raise ValueError(f"[clock] {k}: unknown key; keys are model, {', '.join(sorted(vals))}")
        v = float(v)
        if not (v >= 0 and math.isfinite(v)):
            raise ValueError(f"[clock] {k}: must be a finite number >= 0")
        vals[k] = v
    return ClockParams(model, **vals)


def transition(dt_s: float, q_wf_s: float, q_rw_per_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact discrete two-state model over ``dt_s``: ``F`` (2, 2), ``Q`` (2, 2). A negative step (back
    in time) gets ``F(dt)`` and the noise of ``|dt|`` (what a late input needs)."""
    h = float(dt_s)
    a = abs(h)
    F = np.array([[1.0, h], [0.0, 1.0]])
    Q = np.array([[q_wf_s * a + q_rw_per_s * a**3 / 3.0, q_rw_per_s * a * h / 2.0],
                  [q_rw_per_s * a * h / 2.0, q_rw_per_s * a]])
    return F, Q


class OscillatorClock:
    """One station's oscillator: ``to_local(tau)``, ``to_true(t_local)``, ``error_s(tau)`` = ``x(tau)``.

    Parameters
    ----------
    params : the oscillator class. rng : the clock's own stream (``station_rng(seed, id, 0)``).
    step_s : grid of the generated phase (1 s).
    """

    CHUNK = 512

    def __init__(self, params: ClockParams, rng: np.random.Generator, step_s: float = 0.1):
        self.params = params
        self.rng = rng
        self.h = float(step_s)
        x0 = float(rng.normal(0.0, params.offset_s)) if params.offset_s > 0 else 0.0
        y0 = float(rng.normal(0.0, params.freq_sigma)) if params.freq_ppm > 0 else 0.0
        self._x = np.array([x0])  # phase at grid points k h
        self._y = np.array([y0])  # frequency at grid points
        _, Q = transition(self.h, params.q_wf_s, params.q_rw_per_s)
        self._L = np.linalg.cholesky(Q + 1e-300 * np.eye(2)) if params.stochastic else None

    # ------------------------------------------------------------------ generation
    def _extend(self, k: int) -> None:
        """Make grid points up to index ``k`` exist (in fixed chunks: query order never matters)."""
        while len(self._x) <= k + 1:
            n = self.CHUNK
            x0, y0 = self._x[-1], self._y[-1]
            if self._L is None:
                idx = np.arange(1, n + 1) * self.h
                xs, ys = x0 + y0 * idx, np.full(n, y0)
            else:
                w = self.rng.standard_normal((n, 2)) @ self._L.T  # (n, 2): [w_x, w_y]
                ys = y0 + np.cumsum(w[:, 1])
                y_prev = np.concatenate([[y0], ys[:-1]])
                xs = x0 + np.cumsum(self.h * y_prev + w[:, 0])
            self._x = np.concatenate([self._x, xs])
            self._y = np.concatenate([self._y, ys])

    def _seg(self, k: int) -> tuple[float, float]:
        """Phase at grid point ``k`` and the slope of segment ``[k, k+1]``."""
        if k < 0:
            return float(self._x[0]) + float(self._y[0]) * k * self.h, float(self._y[0])
        if len(self._x) <= k + 1:
            self._extend(k)
        x = self._x
        x0 = x.item(k)
        return x0, (x.item(k + 1) - x0) / self.h

    # ------------------------------------------------------------------ conversions
    def error_s(self, t_true_s: float) -> float:
        """Phase (time error) ``x(tau)``, s: local minus true time."""
        k = math.floor(t_true_s / self.h)
        x0, s = self._seg(k)
        return x0 + s * (t_true_s - k * self.h)

    def freq_at(self, t_true_s: float) -> float:
        """Fractional frequency of the emulated (piecewise-linear) phase at ``tau``."""
        return self._seg(math.floor(t_true_s / self.h))[1]

    def to_local(self, t_true_s: float) -> float:
        return t_true_s + self.error_s(t_true_s)

    def to_true(self, t_local_s: float) -> float:
        tau = t_local_s - self.error_s(t_local_s)  # |x| << h: the right segment or a neighbour
        k = math.floor(tau / self.h)
        for _ in range(4):
            x0, s = self._seg(k)
            tau = (t_local_s - x0 + s * k * self.h) / (1.0 + s)
            kk = math.floor(tau / self.h)
            if kk == k:
                break
            k = kk
        return tau

    def phase_grid(self, n: int) -> np.ndarray:
        """Phase at the first ``n`` grid points (n,) - for statistics."""
        self._extend(n)
        return self._x[:n].copy()


def allan_deviation(phase_s: np.ndarray, step_s: float, m: int) -> float:
    """Overlapping Allan deviation at ``tau = m step_s`` from phase samples (n,)."""
    x = np.asarray(phase_s, float)
    d2 = x[2 * m:] - 2.0 * x[m:-m] + x[: -2 * m]
    tau = m * step_s
    return float(np.sqrt(np.mean(d2**2) / (2.0 * tau**2)))


# --------------------------------------------------------------------------- broadcast clock correction

def broadcast_time_error_s(msg: dict | None, t_tx_true_s: float, t_rx_true_s: float, net_clock=None) -> float:
    """Receiver-side time error of a pseudorange formed from a station's broadcast, seconds.

    ``rho = c (t_rx_ac - T_tx)`` with ``t_rx_ac`` read on a receiver running on network time (station
    1's oscillator ``net_clock``; ``None``: perfect) and ``T_tx`` the station-stamped transmit time
    ``msg.t_tx_s`` corrected by the broadcast clock correction ``msg.clock = [t_ref, offset, freq, ...]``.
    Returned as a difference of small terms (float resolution): network time minus true time at
    reception, minus (stamp minus true time at transmission), plus the broadcast offset. Without
    ``msg.t_tx_s`` the true transmit time is used (a stamp-less source).
    """
    dt_s = net_clock.error_s(t_rx_true_s) if net_clock is not None else 0.0
    if msg is not None and "t_tx_s" in msg:
        dt_s -= float(msg["t_tx_s"]) - t_tx_true_s
        corr = msg.get("clock")
        if corr is not None:
            dt_s += corr[1] + corr[2] * (float(msg["t_tx_s"]) - corr[0])
    return dt_s


def broadcast_clock_var_m2(msg: dict) -> float:
    """Variance of the broadcast clock correction at the transmit time as a range variance, m^2."""
    corr = msg.get("clock")
    if corr is None or "t_tx_s" not in msg:
        return 0.0
    dt = float(msg["t_tx_s"]) - corr[0]
    return SPEED_OF_LIGHT_M_S**2 * max(corr[3] + 2 * dt * corr[4] + dt * dt * corr[5], 0.0)


# --------------------------------------------------------------------------- ensemble network time

@dataclass(frozen=True)
class TimeScale:
    """Definition of network time as an ensemble of clocks (a paper clock), valid from ``T_ref_s`` on.

    Network time ``E`` at an instant, in phase against true time, relative to any reference clock
    ``x_R`` (every clock's phase ``x_k``; ``theta_k = x_k - x_R``; the weights sum to 1, so the choice of
    ``R`` does not matter)::

        E - x_R = sum_k w_k theta_k + a_s + b (T - T_ref_s)

    ``T`` is the time axis on which the instant is placed (the station clock filter's own; the world
    side uses the same: what the reference clock reads, true time plus its phase). ``a_s``, ``b`` keep network time
    continuous in phase and in rate across a change of the members or their weights
    (:func:`ensemble_change`); ``jump_s`` is the phase term ``sum (w_old - w_new) theta`` the change
    applied, on the clocks as the changer estimated them (the world side compares it with the true
    clocks: :func:`ensemble_step_s`)."""

    weights: tuple[tuple[int, float], ...]
    a_s: float = 0.0
    b: float = 0.0
    T_ref_s: float = 0.0
    jump_s: float = 0.0

    @property
    def w(self) -> dict[int, float]:
        return dict(self.weights)

    def offset_s(self, theta_s: dict[int, float], T_s: float) -> float:
        """``E - x_R`` at ``T_s`` from the members' offsets ``theta_s`` against ``x_R`` (s)."""
        return sum(w * theta_s[k] for k, w in self.weights) + self.a_s + self.b * (T_s - self.T_ref_s)


def ensemble_change(scale: TimeScale, weights: dict[int, float], theta_s: dict[int, float],
                    freq: dict[int, float], T_s: float) -> TimeScale:
    """The time scale with new ``weights`` from ``T_s`` on, continuous in phase and rate at ``T_s``.

    ``theta_s`` / ``freq``: offsets and fractional frequencies, against one common reference clock, of
    every clock in the old or the new weights, at ``T_s``. With the true (noise-free) clocks the new
    scale equals the old one at every later instant of a linear world; with estimates the phase step
    against the true clocks is ``sum (w_old - w_new)`` times their errors (``jump_s``)."""
    old = scale.w
    ks = set(old) | set(weights)
    dw = {k: old.get(k, 0.0) - weights.get(k, 0.0) for k in ks}
    jump = sum(d * theta_s[k] for k, d in dw.items())
    a = scale.a_s + scale.b * (T_s - scale.T_ref_s) + jump
    b = scale.b + sum(d * freq[k] for k, d in dw.items())
    return TimeScale(tuple(sorted(weights.items())), float(a), float(b), float(T_s), float(jump))


def scale_at(log: list[TimeScale], T_s: float) -> TimeScale:
    """The definition in force at ``T_s`` (``log`` in order of ``T_ref_s``; the first before it)."""
    cur = log[0]
    for s in log[1:]:
        if s.T_ref_s > T_s:
            break
        cur = s
    return cur


def true_network_offset_s(clocks: dict, log: list[TimeScale], sid: int, t_true_s: float,
                          ref_id: int = 1) -> float:
    """True offset of clock ``sid`` against network time at true time ``t_true_s``: its phase minus
    the time scale of ``log`` evaluated on the true clocks (``clocks``: id -> oscillator with
    ``error_s``, every member included; ``ref_id``: the clock the scale's time axis is placed on)."""
    x_r = clocks[ref_id].error_s(t_true_s)
    T = t_true_s + x_r  # what the reference clock reads
    scale = scale_at(log, T)
    th = {k: clocks[k].error_s(t_true_s) - x_r for k, _ in scale.weights}
    return clocks[sid].error_s(t_true_s) - x_r - scale.offset_s(th, T)


def ensemble_step_s(clocks: dict, prev: TimeScale, scale: TimeScale, ref_id: int = 1) -> float:
    """Step of network time at the change ``prev`` -> ``scale``, against the true clocks: the phase term
    the change applied (``scale.jump_s``, from estimates) minus the one the true clocks call for."""
    T = scale.T_ref_s
    tau = T
    for _ in range(3):  # true time at which the reference clock reads T
        tau = T - clocks[ref_id].error_s(tau)
    x_r = clocks[ref_id].error_s(tau)
    old, new = prev.w, scale.w
    true = sum((old.get(k, 0.0) - new.get(k, 0.0)) * (clocks[k].error_s(tau) - x_r) for k in set(old) | set(new))
    return scale.jump_s - true
