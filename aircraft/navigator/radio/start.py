"""The start test of the radio aircraft (aircraft/navigator/receiver.py rule 2), used by
:class:`.estimator.AircraftEstimator` before a filter starts from the broadcasts alone."""

from __future__ import annotations

from collections import Counter

import numpy as np

from .. import receiver as rx
from .initializer import batch_cost, initial_state


def consistent_start(model: str, cfg, stats: Counter, init, pos, cov, rho):
    """The batch's weighted residual sum of squares at the fix against chi-square with ``m - 4`` dof;
    a failing batch is refused unless leaving out exactly one station makes it pass. ``cov`` must be the
    covariances the fix ``init`` was weighted with (the caller adds the aircraft's motion across a TDMA
    batch: ``AircraftEstimator._snapshot_cov``), so that the test judges the fix by its own weights.

    model : "pr" or "tdoa". cfg : the estimator's ``EstimatorConfig`` (``receiver``, ``init``,
    ``tuning``). stats : counts ``start_left_one_out`` / ``start_inconsistent``. init : the
    ``InitResult`` of the whole batch; pos (m, 3), cov (m, 3, 3) or None, rho (m,).
    Returns the start to use, or None.
    """
    rcfg, m = cfg.receiver, len(rho)

    def cost(r, k):
        c = None if cov is None else cov[k]
        return float(batch_cost(model, r.fix, pos[k], c, rho[k], cfg.tuning.sigma_m)[0])

    if rx.consistent(cost(init, np.arange(m)), m - 4, rcfg.p_start):
        return init
    if m - 5 >= 1:
        keep = [np.flatnonzero(np.arange(m) != j) for j in range(m)]
        subs = [initial_state(model, cfg.tuning, pos[k], None if cov is None else cov[k], rho[k], cfg.init)
                for k in keep]
        j = rx.leave_one_out(np.array([cost(r, k) for r, k in zip(subs, keep)]), m - 5, rcfg.p_start)
        if j is not None:
            stats["start_left_one_out"] += 1
            return subs[j]
    stats["start_inconsistent"] += 1
    return None
