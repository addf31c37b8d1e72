"""Filter start from the stations' broadcasts alone (navigator side: no truth, no scenario).

Inputs are what the aircraft receives: the broadcast station positions and covariances (their own
self-survey estimates) and the pseudoranges of one batch. Output: the filter's initial mean and
covariance.

* **Snapshot** where the geometry allows it: a multi-start Gauss-Newton LSQ fix (starts spread around
  the *broadcast* station centroid at several heights, bearings and distances; the fix with the lowest
  weighted residual wins, reflected above the station plane), with its own covariance
  ``(H^T W H)^-1`` (seed 001 eqs. 14-16/18), standard deviations doubled (one epoch, linearized at
  the fix) plus the spread of the other roots that fit as well, where that position standard
  deviation is at most ``max_fix_sigma_m`` and the batch's cost rises over that uncertainty as its
  linearization says (:func:`linear_over_sigma`).
* **Wide prior** where it does not (the fix's position standard deviation above ``max_fix_sigma_m``
  or the cost flat along some axis,
  e.g. in the far field of a small-base system where one epoch's fix is off by kilometres): the fix as
  the mean with an isotropic covariance of ``wide_sigma_m`` (never smaller than the fix's own) for the
  position and the clock.

Velocity: one snapshot does not measure it; the start is zero with ``vel_sigma_m_s``. The clock rate
starts at zero with the tuning's ``p0.drift_m_s``.

This module must never import the world side (``aircraft.world``, ``aircraft.montecarlo``, scenarios):
tests check the import boundary.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from . import models as mdl
from .lsq import lsq_cov, lsq_pr, lsq_tdoa
from .tuning import Tuning

if TYPE_CHECKING:
    from .batch_start import StationCross


@dataclass(frozen=True)
class InitConfig:
    """How the start is formed. ``max_fix_sigma_m``: a snapshot fix is used with its own covariance
    (standard deviations scaled by ``fix_inflation``: one epoch, linearized at the fix) only if its
    position standard deviation ``sqrt(tr C_pos)`` is at most this; ``wide_sigma_m``: the position /
    clock standard deviation of the wide prior; ``vel_sigma_m_s``: the velocity prior;
    ``defer_batches``: a batch without redundancy (at most 4 stations: 4 pseudoranges for ``x y z b``,
    3 differences for ``x y z``) whose fix is not a snapshot is set aside up to this many times in a
    row, waiting for a batch with more stations, before the wide prior is taken (an aircraft that
    starts while the stations are still coming up hears 4 of 5; its one exact root there can be
    kilometres off, and a filter started from a wide prior about it did not come back)."""

    max_fix_sigma_m: float = 300.0
    fix_inflation: float = 2.0
    wide_sigma_m: float = 2000.0
    vel_sigma_m_s: float = 30.0
    defer_batches: int = 4


@dataclass
class InitResult:
    """``x0`` (n,) and ``P0`` (n, n) of the filter state; ``snapshot`` True if the fix's own covariance
    is used (False: wide prior); ``fix`` the LSQ solution (4,) pr / (3,) tdoa; ``fix_sigma_m`` its
    position standard deviation; ``cost`` its weighted residual sum of squares; ``station_cross`` the
    stations' position errors as the start leaves them (:class:`.batch_start.StationCross`: a start
    over many cycles; None: counted as independent of ``x0``)."""

    x0: np.ndarray
    P0: np.ndarray
    snapshot: bool
    fix: np.ndarray
    fix_sigma_m: float
    cost: float
    station_cross: StationCross | None = None


def start_points(pos_m: np.ndarray) -> np.ndarray:
    """Multi-start positions (k, 3) around the broadcast station centroid: heights of 1, 5 and 30
    station spreads above it, straight above and at 8 bearings at 5, 30 and 100 spreads."""
    pos_m = np.asarray(pos_m, dtype=float)
    c = pos_m.mean(axis=0)
    spread = max(float(np.sqrt(np.mean(np.sum((pos_m - c) ** 2, axis=1)))), 10.0)
    pts = []
    for hz in (1.0, 5.0, 30.0):
        pts.append(c + [0.0, 0.0, hz * spread])
        for rad in (5.0, 30.0, 100.0):
            for az in np.radians(np.arange(0.0, 360.0, 45.0)):
                pts.append(c + [rad * spread * np.cos(az), rad * spread * np.sin(az), hz * spread])
    return np.array(pts)


def batch_cost(model: str, x: np.ndarray, pos_m: np.ndarray, cov_m2: np.ndarray | None, rho_m: np.ndarray,
               sigma_m: float) -> np.ndarray:
    """Weighted residual sum of squares of one batch at candidate fixes ``x`` (k, 4) pr / (k, 3) tdoa
    (range variances evaluated at each candidate, seed 001 eqs. 14/18). Returns (k,)."""
    x = np.atleast_2d(x)
    k, m = x.shape[0], pos_m.shape[0]
    rho = np.broadcast_to(rho_m, (k, m))
    if model == "pr":
        X = np.concatenate([x[:, :3], np.zeros((k, 3)), x[:, 3:4]], axis=1)
        res = rho - mdl.h_pr(X, pos_m)
        return np.sum(res**2 / mdl.range_var(X, pos_m, cov_m2, sigma_m), axis=1)
    X = np.concatenate([x, np.zeros((k, 3))], axis=1)
    res = np.einsum("ij,kj->ki", mdl.g_matrix(m, 0), rho) - mdl.h_tdoa(X, pos_m, 0)
    Rd = mdl.r_tdoa(mdl.range_var(X, pos_m, cov_m2, sigma_m), 0)
    return np.einsum("ki,ki->k", res, np.linalg.solve(Rd, res[..., None])[..., 0])


def linear_over_sigma(model: str, fix: np.ndarray, C: np.ndarray, pos_m: np.ndarray, cov_m2: np.ndarray | None,
                      rho_m: np.ndarray, sigma_m: float, min_rise: float = 1.0) -> bool:
    """Whether the batch's cost behaves as its linearization over the fix's own uncertainty: stepping
    2 standard deviations along each principal axis of ``C`` must raise the cost by about 4 (the
    linear prediction); True if every rise is at least ``min_rise``. Far outside a small array the
    cost is flat (or still falling) along the range direction and other roots fit as well: then the
    linearized ``C`` does not describe the fix and the start must be wide."""
    if not np.all(np.isfinite(C)):
        return False
    lam, V = np.linalg.eigh(0.5 * (C + C.T))
    steps = 2.0 * np.sqrt(np.clip(lam, 0.0, None)) * V  # (n, n): column j = step along axis j
    c0 = batch_cost(model, fix, pos_m, cov_m2, rho_m, sigma_m)[0]
    cand = np.concatenate([fix + steps.T, fix - steps.T])
    rise = batch_cost(model, cand, pos_m, cov_m2, rho_m, sigma_m) - c0
    n = steps.shape[1]
    return bool(np.all(np.minimum(rise[:n], rise[n:]) >= min_rise))


def snapshot_fix(
    model: str, pos_m: np.ndarray, cov_m2: np.ndarray | None, rho_m: np.ndarray, sigma_m: float,
    floor_z_m: float | None = 0.0,
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Multi-start LSQ fix of one batch. Returns ``(fix, C, cost, ambiguity_m)``: fix (4,)
    ``[x y z b]`` for pr, (3,) for tdoa, its covariance ``(H^T W H)^-1``, the weighted residual sum of
    squares and the largest distance from the fix to another start's solution that fits as well
    (cost within 4 of the best: other roots of a batch with little redundancy). Those roots are
    added to ``C`` (their second moment about the fix), so the start covers them."""
    pos_m = np.asarray(pos_m, dtype=float)
    rho_m = np.asarray(rho_m, dtype=float)
    m = pos_m.shape[0]
    starts = start_points(pos_m)
    k = starts.shape[0]
    var = sigma_m**2
    kw = dict(floor_z_m=floor_z_m, iters=60, max_step_m=5000.0, tol_m=1e-6)
    rho = np.broadcast_to(rho_m, (k, m))
    if model == "pr":
        b0 = rho_m.mean() - np.linalg.norm(starts[:, None, :] - pos_m, axis=-1).mean(axis=1)
        x = lsq_pr(rho, pos_m, np.column_stack([starts, b0]), var, cov_m2, **kw)
    else:
        x = lsq_tdoa(rho, pos_m, starts, var, cov_m2, **kw)
    cost = batch_cost(model, x, pos_m, cov_m2, rho_m, sigma_m)
    cost = np.where(np.all(np.isfinite(x), axis=1), cost, np.inf)
    i = int(np.argmin(cost))
    fix = x[i]
    # other solutions that fit as well (no redundancy: 4 pseudoranges for 4 unknowns have several)
    alike = cost <= cost[i] + 4.0
    dev = x[alike] - fix  # (j, k) other roots relative to the fix
    amb = float(np.max(np.linalg.norm(dev[:, :3], axis=1)))
    try:
        C = lsq_cov(fix[None], pos_m, var, model, cov_m2)[0]
    except np.linalg.LinAlgError:
        C = np.full((fix.size, fix.size), np.inf)
    # roots that fit as well enter the covariance (second moment about the fix): the start covers them
    C = C + dev.T @ dev / max(len(dev), 1)
    return fix, C, float(cost[i]), amb


def defended(model: str, fix: np.ndarray, C: np.ndarray, pos_m, cov_m2, rho_m, sigma_m: float,
             cfg: InitConfig, need_redundancy: bool = False) -> tuple[bool, float]:
    """Whether one batch's fix is a snapshot its linearized covariance ``C`` describes, and the fix's
    position standard deviation ``sqrt(tr C_pos)`` (inf where ``C`` is not finite): at most
    ``max_fix_sigma_m`` and the cost rising over that uncertainty as its linearization says
    (:func:`linear_over_sigma`); with ``need_redundancy`` also more ranges than unknowns (a batch
    without redundancy fits exactly whatever its errors: a station's persisting survey error, the
    curvature of a small array's far field, nothing in its residuals says it is off)."""
    sig = float(np.sqrt(np.trace(C[:3, :3]))) if np.all(np.isfinite(C)) else np.inf
    rho_m = np.asarray(rho_m, dtype=float)
    if need_redundancy and rho_m.shape[-1] - (model != "pr") <= fix.size:
        return False, sig
    ok = bool(np.isfinite(sig) and sig <= cfg.max_fix_sigma_m) and \
        linear_over_sigma(model, fix, C, np.asarray(pos_m, dtype=float), cov_m2, rho_m, sigma_m)
    return ok, sig


def wide_cov(k: int, sig: float, cfg: InitConfig, amb: float = 0.0) -> np.ndarray:
    """The wide prior's covariance (k, k) about a fix that is no snapshot: isotropic, standard deviation
    ``wide_sigma_m``, never below the fix's own ``sig`` (where finite) or the distance ``amb`` to other
    roots that fit as well."""
    return np.eye(k) * max(cfg.wide_sigma_m, sig if np.isfinite(sig) else 0.0, amb) ** 2


def initial_state(
    model: str, tuning: Tuning, pos_m: np.ndarray, cov_m2: np.ndarray | None, rho_m: np.ndarray,
    config: InitConfig | None = None,
) -> InitResult:
    """Initial filter mean and covariance from one batch of broadcasts (see the module docstring).

    Parameters
    ----------
    model : "pr" or "tdoa". tuning : the filter's :class:`~aircraft.navigator.radio.tuning.Tuning` (noise,
        drift state, clock-rate prior, floor). pos_m : (m, 3) broadcast station positions.
    cov_m2 : (m, 3, 3) their broadcast covariances or None. rho_m : (m,) pseudoranges of the batch.
    """
    cfg = config or InitConfig()
    layout = mdl.StateLayout(model, drift=model == "pr")
    fix, C, cost, amb = snapshot_fix(model, pos_m, cov_m2, rho_m, tuning.sigma_m, tuning.floor_z_m)
    snapshot, sig = defended(model, fix, C, pos_m, cov_m2, rho_m, tuning.sigma_m, cfg)
    if snapshot:
        C = C * cfg.fix_inflation**2
    else:
        C = wide_cov(fix.size, sig, cfg, amb)
    n = layout.n
    x0 = np.zeros(n)
    P0 = np.zeros((n, n))
    idx = [0, 1, 2, 6] if model == "pr" else [0, 1, 2]
    x0[idx] = fix
    P0[np.ix_(idx, idx)] = C
    P0[3:6, 3:6] = np.eye(3) * cfg.vel_sigma_m_s**2
    if layout.drift:
        P0[7, 7] = tuning.p0.drift_m_s**2
    return InitResult(x0, 0.5 * (P0 + P0.T), snapshot, fix, sig, cost)
