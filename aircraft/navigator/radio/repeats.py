"""How many times one linearization error enters the estimate (``Tuning.linearization_corr_s``).

The second-order term of the ranges (:func:`.measurements.second_order`) is a function of the state
error, which changes slowly (the stations' clock biases, the hover), so the same linearization error
repeats at every update. It enters ``R`` scaled by the number of times it repeats: the longer of the
filter's memory time and the time since its start, at most ``linearization_corr_s`` long, over the
station's own measurement interval (0 = white, the textbook second-order EKF).

The error repeats while the estimation error it comes from persists: over the filter's memory time
(its memory in updates, prior variance over what an update removes, times the update step) or the
time since the start, whichever is longer. While a filter converges from a wide first prior its error
changes at every update (counted as repeating then, the prior would hold the measurements off); once
either has grown, the same error comes back. Within that time a station's range comes once per its
own measurement interval (one update step in synchronous epochs, one TDMA cycle when the stations
take turns); counting updates instead over-counts TDMA ranges by the number of stations in the
rotation (docs/aircraft.md, "Linearization error").
"""

from __future__ import annotations

import numpy as np


def scaled(S2: np.ndarray, k) -> np.ndarray:
    """``K^1/2 S2 K^1/2`` with ``K = diag(k)``, ``k`` (..., m) or a scalar: a covariance whose row ``j``
    counts ``k_j`` times (stays positive semi-definite)."""
    q = np.sqrt(np.asarray(k, dtype=float))
    if q.ndim == 0:
        return S2 * q**2
    return S2 * q[..., :, None] * q[..., None, :]


# every error counted once (no bookkeeping); shared, read-only
_ONCE = np.ones(())
_ONCE.setflags(write=False)

class RepeatCount:
    """``memory``: updates the filter averages over (per run), from the latest update; ``last_seen``:
    station key (``("id", id)``, or ``("pos", x, y, z)`` to 0.1 m) -> time of its latest measurement;
    ``t_start_s``: the filter's start."""

    def __init__(self, corr_s: float, t_start_s: float):
        self.corr_s = corr_s
        self.t_start_s = float(t_start_s)
        self.memory = 1.0
        self.last_seen: dict = {}

    @property
    def on(self) -> bool:
        return self.corr_s > 0  # else no station bookkeeping at all

    def keys(self, stations_m: np.ndarray, bias_ids) -> list:
        """The station keys of one batch (its ids if known, else its positions to 0.1 m)."""
        if not self.on:
            return []
        if bias_ids is not None:
            return [("id", sid) for sid in bias_ids]
        return [("pos", *row) for row in np.round(stations_m, 1).tolist()]

    def count(self, keys: list, t_s: float, step_s: float, tdoa_base: int | None) -> np.ndarray:
        """Repeats per measurement row (..., rows) (or a scalar), in ``[1, corr_s / interval]``;
        ``tdoa_base``: rows are differences against that station (its own key dropped)."""
        corr = self.corr_s
        if corr <= 0 or step_s <= 0:
            return _ONCE
        t, step = t_s, step_s
        # a station not heard within the window (or never) counts once: its error has not repeated
        dtj = np.array([max(step, t - self.last_seen.get(key, -np.inf)) for key in keys])
        if tdoa_base is not None:
            dtj = np.delete(dtj, tdoa_base)
        tau = np.maximum(np.asarray(self.memory) * step, t - self.t_start_s)
        return np.clip(tau[..., None] / dtj, 1.0, np.maximum(1.0, corr / dtj))

    def record(self, keys: list, t_s: float, P0: np.ndarray, P1: np.ndarray) -> None:
        """After an update from covariance ``P0`` to ``P1`` at ``t_s``: the stations seen, and the
        filter's memory in updates (prior variance over what one update removes, per run)."""
        for key in keys:
            self.last_seen[key] = t_s
        if len(self.last_seen) > 64:  # positions as keys move as the survey does: forget old ones
            old = t_s - max(self.corr_s, 0.0)
            self.last_seen = {key: t for key, t in self.last_seen.items() if t >= old}
        if self.on:
            tr0 = np.einsum("...ii->...", P0)
            gain = tr0 - np.einsum("...ii->...", P1)
            self.memory = tr0 / np.maximum(gain, 1e-9 * tr0)
