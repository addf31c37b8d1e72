"""How the radio aircraft starts and keeps going like a receiver (navigator side: no truth, no I/O).

A field that has just been switched on broadcasts clock corrections that are honest but useless: in
the first cycle a station's clock is known to about a millisecond (``sqrt(c^2 P_theta)`` of 10^5 m),
after its first exchanges to microseconds (10^3 m), and only after a few cycles to nanoseconds
(docs/aircraft.md "Cold start" measures it on seed000). Five rules turn that into a receiver:

1. **Usable broadcasts** (:func:`unusable_reason`): a broadcast is used only when its own clock and
   position covariance put its range error within ``max_broadcast_sigma_m``, i.e. the station has
   been synchronized and surveyed to a level a position fix can use; below that it is weighted by its
   covariance (the bias states of the filter, the range variance of the snapshot). Without this gate
   the first batch (10^5 m) starts the filter 10^3 km off and it never comes back.
2. **A consistent start** (:func:`consistent`): a snapshot fix with redundancy (``dof >= 1``) starts
   the filter only if its weighted residual sum of squares passes ``chi2.ppf(1 - p_start, dof)``;
   otherwise the set is refused, or one station is left out if exactly that makes it pass
   (:func:`leave_one_out`).
3. **Divergence** (:class:`DivergenceMonitor`): the normalized innovations of the running filter,
   summed over ``window`` updates, against ``chi2.ppf(1 - p_diverge, dof)``; beyond it the filter is
   lost (not a single station: the integrity monitor handles those) and restarts from the next
   consistent set. So does a filter whose own Gaussian lies more than ``floor_lost_sigma`` below the
   height floor: its truncated moments sit on the floor, confident, with small innovations.
4. **Publish only what is defensible** (:func:`publishable`): a finite estimate with a
   positive semi-definite covariance whose position sigma is below ``max_publish_sigma_m``; otherwise
   the process publishes a status (``ac_status``) instead. A snapshot LSQ's covariance is its batch's
   own ``(H^T W H)^-1`` only where the batch defends it as a filter start's snapshot (with redundancy;
   :func:`aircraft.navigator.radio.initializer.defended`), otherwise the wide prior's.
5. **Start on a surveyed field** (:func:`start_members`): a filter starts only from a batch whose every
   station is known to ``start_station_sigma_m`` along its line of sight to the batch's fix (clock and
   position); from the surveyed stations alone where they are enough for a snapshot with redundancy;
   from the whole batch once ``start_wait_s`` have passed since the first batch that could start it.
   A station's position error is a bias the filter's white range noise does not model: from a fix
   over stations still 8 m uncertain, 1.5 km out and 300 m up, the filter settled on another root of
   the ranges or stalled (docs/aircraft.md "Cold start").
"""

from __future__ import annotations

import functools
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from net.plausible import cholesky3_ok

from ..events import AcStatus


# statuses a navigator reports (``ac_status.state``)
WAITING = "waiting"  # no usable set of broadcasts yet (unsynchronized / too few stations)
TRACKING = "tracking"  # a filter runs and its estimates are published
RESTARTING = "restarting"  # the filter diverged and waits for a consistent set
NO_FIX = "no fix"  # a filter runs but its estimate is not defensible (not published)


@dataclass(frozen=True)
class ReceiverConfig:
    """The receiver rules (module docstring). ``max_broadcast_sigma_m``: largest range sigma of a
    broadcast (clock and position) that is used; ``p_start``: false-refusal probability of the start
    test; ``p_diverge`` / ``window``: the divergence test over ``window`` updates;
    ``max_publish_sigma_m``: largest position sigma ``sqrt(tr P)`` of a published estimate;
    ``floor_lost_sigma``: a filter whose Gaussian lies this many sigma under the height floor is lost
    (rule 3; None: not tested); ``start_station_sigma_m`` / ``start_wait_s``: the start's survey level
    and longest wait (rule 5); ``lsq_restart_s``: a snapshot LSQ whose fix rule 4 dropped starts from
    the broadcasts again (multi-start) at most once in this time; in between it starts from that
    multi-start's fix (None: every drop restarts from the broadcasts); ``lsq_retry_s``: where that
    fix was itself not publishable (no anchor), the next multi-start after this time, the batches
    between waiting (docs/aircraft.md, "Its restarts are rationed")."""

    max_broadcast_sigma_m: float = 30.0
    p_start: float = 1e-3
    p_diverge: float = 1e-9
    window: int = 20
    max_publish_sigma_m: float = 1.0e4
    floor_lost_sigma: float | None = 5.0
    start_station_sigma_m: float = 3.0
    start_wait_s: float = 10.0
    lsq_restart_s: float | None = 1.5
    lsq_retry_s: float = 0.5


def broadcast_sigma_m(clock_var_m2: float, station_cov_m2: np.ndarray | None) -> float:
    """Range-equivalent sigma of one broadcast: ``sqrt(c^2 P_theta + lambda_max(P_pos))`` (m)."""
    pos_var = 0.0
    if station_cov_m2 is not None:
        cov = np.asarray(station_cov_m2, dtype=float).reshape(3, 3)
        pos_var = float(np.max(np.linalg.eigvalsh(0.5 * (cov + cov.T))))
    return float(np.sqrt(max(float(clock_var_m2), 0.0) + max(pos_var, 0.0)))


def _clearly_synchronized(clock_var_m2: float, station_cov_m2: np.ndarray | None, max_sigma_m: float) -> bool:
    """Whether :func:`broadcast_sigma_m` is within ``max_sigma_m`` by the trace alone: for a positive
    definite (Cholesky) finite covariance ``lambda_max <= tr P``; the 1e-6 margin covers the rounding
    of the eigenvalue and the square root, so the answer is that of the eigendecomposition."""
    cv = max(float(clock_var_m2), 0.0)
    if station_cov_m2 is None:
        return False
    cov = np.asarray(station_cov_m2, dtype=float).reshape(3, 3)
    sym = 0.5 * (cov + cov.T)
    return cholesky3_ok(sym) and cv + float(sym[0, 0] + sym[1, 1] + sym[2, 2]) <= max_sigma_m**2 * (1.0 - 1e-6)


def unusable_reason(clock_var_m2: float, station_cov_m2: np.ndarray | None, cfg: ReceiverConfig) -> str | None:
    """Why a broadcast is not used (a counter name), or None if it is usable."""
    if not np.isfinite(clock_var_m2) or clock_var_m2 < 0:
        return "nav_bad_clock"
    if station_cov_m2 is not None and not np.all(np.isfinite(station_cov_m2)):
        return "nav_bad_cov"
    if _clearly_synchronized(clock_var_m2, station_cov_m2, cfg.max_broadcast_sigma_m):
        return None
    if broadcast_sigma_m(clock_var_m2, station_cov_m2) > cfg.max_broadcast_sigma_m:
        return "nav_unsynchronized"
    return None


@functools.lru_cache(maxsize=1024)
def chi2_upper(p: float, dof: float) -> float:
    """``chi2.ppf(1 - p, dof)`` (cached: the tests ask for a few (p, dof) pairs at every update)."""
    from scipy.special import chdtri  # here, not at import: the CLI starts without scipy

    return float(chdtri(float(dof), p))


def consistent(cost: float, dof: int, p: float) -> bool:
    """The start test: a batch without redundancy (``dof < 1``) cannot be tested and passes."""
    if dof < 1:
        return bool(np.isfinite(cost))
    return bool(np.isfinite(cost) and cost <= chi2_upper(p, dof))


def leave_one_out(costs: np.ndarray, dof: int, p: float) -> int | None:
    """Index of the one station whose removal makes the batch pass (``costs[j]``: the cost without
    station ``j``, ``dof`` the redundancy without it); None if none or several do."""
    ok = [j for j, c in enumerate(np.asarray(costs, float)) if consistent(float(c), dof, p) and dof >= 1]
    return ok[0] if len(ok) == 1 else None


class DivergenceMonitor:
    """Windowed, leave-one-out NIS test of a running filter (rule 3).

    ``push(q, dof, w)`` takes one update's NIS ``q`` with ``dof`` degrees of freedom and each station's
    normalized innovation ``w`` {station id: w_i} (aircraft/navigator/radio/fde.py ``snooping``). Over the last
    ``window`` updates, ``Q - W_i`` (the NIS with station ``i``'s bias estimated, chi-square with
    ``D - N_i`` dof, ``N_i`` its measurements in the window) is tested for the station ``i`` with the
    largest ``W_i``: a single faulty station passes (the integrity monitor excludes it), a filter
    whose every station disagrees with it fails; True means the filter is lost."""

    def __init__(self, cfg: ReceiverConfig):
        self.cfg = cfg
        self.win: deque = deque(maxlen=cfg.window)

    def reset(self) -> None:
        self.win.clear()

    def push(self, q: float, dof: int, w: dict | None = None) -> bool:
        if not math.isfinite(q):
            return True
        win = self.win
        win.append((float(q), int(dof), dict(w or {})))
        if len(win) < self.cfg.window:
            return False
        D = sum(e[1] for e in win)
        W: dict = {}
        N: dict = {}
        for _, _, ws in win:
            for i, wi in ws.items():
                W[i] = W.get(i, 0.0) + float(wi)
                N[i] = N.get(i, 0) + 1
        if W:
            i = max(W, key=W.get)
            # Q - W_i update by update: the part of an update's NIS left once station i's bias is
            # estimated, known only to the rounding of that NIS (a measurement 1e12 m off leaves 1e8 of
            # rounding in a difference of two 1e24 sums, which would read as a lost filter)
            Q = sum(_rest(q, ws.get(i, 0.0)) for q, _, ws in win)
            D = D - N[i]
        else:
            Q = sum(e[0] for e in win)
        return D > 0 and Q > chi2_upper(self.cfg.p_diverge, D)


def _rest(q: float, w: float) -> float:
    """``q - w`` (``0 <= w <= q``: a station's share of an NIS), 0 within the rounding of ``q``."""
    r = q - float(w)
    return r if r > 1e-9 * q else 0.0


def nis(nu: np.ndarray, S: np.ndarray) -> tuple[float, int]:
    """``(nu^T S^-1 nu, dim)`` of one innovation ``nu`` (d,) with covariance ``S`` (d, d) (Cholesky)."""
    from nav.kalman import nis as nis_of  # (it imports scipy: kept out of the command line's start)

    nu = np.atleast_1d(np.asarray(nu, dtype=float))
    S = np.atleast_2d(np.asarray(S, dtype=float))
    try:
        return float(nis_of(nu, 0.5 * (S + S.T))), nu.size
    except np.linalg.LinAlgError:
        return float("inf"), nu.size


def start_members(range_sigma_m: np.ndarray, t_s: float, t_first_s: float, min_kept: int,
                  cfg: ReceiverConfig) -> np.ndarray | None:
    """Rule 5: the members (m,) bool of a batch a filter may start from, or None to wait for a better
    surveyed batch. ``range_sigma_m`` (m,) each station's broadcast sigma along its line of sight to
    the batch's fix (clock and position: ``sqrt(u^T C u + c^2 P_theta)``), ``t_s`` the batch time,
    ``t_first_s`` that of the first batch that could have started the filter, ``min_kept`` the fewest
    surveyed stations a start uses without the others (a snapshot with redundancy). Every member once
    all are surveyed or ``start_wait_s`` has passed."""
    ok = np.asarray(range_sigma_m, dtype=float) <= cfg.start_station_sigma_m
    if ok.all() or t_s - t_first_s > cfg.start_wait_s:
        return np.ones(ok.shape, dtype=bool)
    return ok if int(ok.sum()) >= min_kept else None


DEFAULT_RECEIVER = ReceiverConfig()


def publishable(pos_m, cov_m2, cfg: ReceiverConfig = DEFAULT_RECEIVER) -> bool:
    """A finite position with a finite, symmetric PSD covariance whose ``sqrt(tr P)`` is at most
    ``max_publish_sigma_m``."""
    p = np.asarray(pos_m, dtype=float)
    if p.shape != (3,) or not np.all(np.isfinite(p)) or cov_m2 is None:
        return False
    P = np.asarray(cov_m2, dtype=float)
    if P.shape != (3, 3) or not np.all(np.isfinite(P)):
        return False
    sym = 0.5 * (P + P.T)
    if cholesky3_ok(sym):  # positive definite: sum(lambda) is the trace
        return bool(math.sqrt(float(sym[0, 0] + sym[1, 1] + sym[2, 2])) <= cfg.max_publish_sigma_m)
    lam = np.linalg.eigvalsh(sym)
    return bool(lam[0] >= -1e-9 * max(lam[-1], 1.0) and np.sqrt(max(np.sum(lam), 0.0)) <= cfg.max_publish_sigma_m)


class StatusPacer:
    """When a navigator's status is due: at every change of state, and every ``every_s`` of fleet time
    while it stays the same (one pacer per aircraft, keyed by algorithm)."""

    def __init__(self, every_s: float = 1.0):
        self.every_s = float(every_s)
        self._last: dict[str, tuple[str, float]] = {}

    def due(self, algo: str, state: str, t_s: float) -> bool:
        last = self._last.get(algo)
        if last is not None and last[0] == state and t_s - last[1] < self.every_s:
            return False
        self._last[algo] = (state, float(t_s))
        return True


STATUS_TEXT = {WAITING: "waiting for synchronized stations", TRACKING: "tracking",
               RESTARTING: "diverged: restarting from a consistent set", NO_FIX: "no fix (estimate not defensible)"}


def status_event(name: str, seq, algo: str, t_s: float, state: str, counts: dict, detail: str | None = None
                 ) -> AcStatus:
    """An ``ac_status`` event (``seq``: the aircraft's per-kind sequence counter, advanced here)."""
    seq["ac_status"] += 1
    return AcStatus(name, seq["ac_status"], float(t_s), algo, state, (detail or STATUS_TEXT.get(state, state))[:64],
                    {str(k)[:64]: float(v) for k, v in sorted(counts.items())[:16]})

