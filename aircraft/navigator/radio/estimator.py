"""The radio aircraft's message-level API: :class:`AircraftEstimator`, one algorithm (LSQ / EKF / UKF x
pseudorange / TDOA) for one aircraft, shared by the aircraft node, the bench and a replay:
``on_measurement`` (one TDMA slot), ``on_epoch`` (synchronous epoch), ``estimate()``.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from .. import receiver as rx
from . import coords as crd
from . import models as mdl
from .batch_start import BatchStart, BatchStartConfig
from .fde import FdeConfig, FilterFde, fault_vectors, protection_levels, snooping
from .initializer import InitConfig, defended, initial_state, wide_cov
from .lsq import lsq_cov, lsq_pr, lsq_tdoa
from .start import consistent_start
from .state import CLOCK, POS, VEL, StateLayout
from .tracker import CvTracker
from .tuning import Tuning

ALGOS = mdl.ALGOS


# --------------------------------------------------------------------------- message-level API
@dataclass
class EstimatorConfig:
    """Configuration of one :class:`AircraftEstimator` (defaults = the bench's shared tuning)."""

    tuning: Tuning = field(default_factory=Tuning)
    min_stations: int = 4
    # coarse external fix (like a station's init.sigma0_m): if set, filters start from the guess with
    # this position sigma instead of a snapshot LSQ fix (needed in the far field of a small-base system,
    # where one epoch's fix is off by kilometres)
    guess_sigma_m: float | None = None
    max_batch_age_s: float = 5.0  # TDMA: measurements older than this are dropped from a batch
    # start from the broadcasts alone (aircraft/navigator/radio/initializer.py): snapshot fix or wide prior
    init: InitConfig | None = None
    # filters: innovation gate, windowed residual test, exclusion, HPL/VPL (aircraft/navigator/radio/fde.py); None = off
    fde: FdeConfig | None = field(default_factory=FdeConfig)
    # the receiver rules (aircraft/navigator/receiver.py): usable broadcasts, consistent start,
    # divergence restart, publishable estimates; None = off (the benches feed synthetic epochs)
    receiver: rx.ReceiverConfig | None = field(default_factory=rx.ReceiverConfig)
    # filters: start from a fit of many cycles with the motion modelled (aircraft/navigator/radio/batch_start.py);
    # None = from one cycle's start
    batch_start: BatchStartConfig | None = field(default_factory=BatchStartConfig)


class AircraftEstimator:
    """One algorithm for one aircraft, fed by messages; no I/O, no clocks, no truth.

    ``on_measurement(t_s, station_id, station_pos_m, station_cov_m2, rho_m, clock_var_m2)`` takes one
    TDMA slot; ``on_epoch(t_s, station_pos_m, station_cov_m2, rho_m, station_ids, clock_var_m2)`` a
    synchronous epoch. ``clock_var_m2``: the broadcast clock variance ``c^2 P_theta`` of the station
    (:func:`net.clock.broadcast_clock_var_m2`): the filters carry each station's residual clock
    error as ``tuning.clock_bias`` says (a Gauss-Markov bias state per station by default); snapshot
    LSQ and the filter start add it to the range variance (one epoch sees each residual once).
    Filters start from a snapshot LSQ fix of the first complete batch. ``estimate()`` returns a dict
    or None.
    """

    def __init__(self, algo: str, config: EstimatorConfig | None = None, x0_guess_m: np.ndarray | None = None):
        if algo not in ALGOS:
            raise ValueError(f"unknown algorithm {algo!r}; choose from {', '.join(ALGOS)}")
        self.algo = algo
        self.method, self.model = algo.split("-")
        self.cfg = config or EstimatorConfig()
        self.tracker: CvTracker | None = None
        self.fix: np.ndarray | None = None  # LSQ state (4,) or (3,)
        self.t_s: float | None = None
        self.guess = np.array([0.0, 0.0, 1000.0]) if x0_guess_m is None else np.asarray(x0_guess_m, float)
        self._pending: dict[int, tuple[float, np.ndarray, np.ndarray, float, float]] = {}
        self._last_geom: tuple | None = None  # the latest batch (pos, cov, rho): the LSQ's covariance
        self._fix_cov_memo: tuple | None = None  # ((fix, batch), covariance) of the latest _fix_cov
        self.n_updates = 0
        self.n_dropped = 0
        self.n_resets = 0
        self.n_deferred = 0  # batches set aside in a row at the start (InitConfig.defer_batches)
        self.t_first_batch_s: float | None = None  # the first batch that could start a filter (rule 5)
        self.init = None  # the InitResult of the latest start (broadcast initializer)
        # snapshot LSQ (receiver rule 4, ReceiverConfig.lsq_restart_s / lsq_retry_s): (t_s, fix,
        # publishable) of its latest start from the broadcasts (the anchor), the fix a dropped one
        # restarts from at the next batch, and the time before which it starts from nothing
        self._anchor: tuple[float, np.ndarray, bool] | None = None
        self._restart_from: np.ndarray | None = None
        self._wait_until_s: float | None = None
        self.fde = None if self.cfg.fde is None else FilterFde(self.cfg.fde)
        rcfg = self.cfg.receiver
        self.monitor = None if rcfg is None else rx.DivergenceMonitor(rcfg)
        self.stats: Counter[str] = Counter()  # broadcasts not used, refused starts, restarts (by reason)
        self.status = rx.WAITING
        bcfg = self.cfg.batch_start
        self.batch_start = None if bcfg is None or self.method == "lsq" else \
            BatchStart(bcfg, self.cfg.tuning, (self.cfg.init or InitConfig()).vel_sigma_m_s)

    # -- input
    def on_epoch(self, t_s: float, station_pos_m, station_cov_m2, rho_m, station_ids=None,
                 clock_var_m2=None) -> None:
        pos = np.asarray(station_pos_m, float)
        cov = None if station_cov_m2 is None else np.asarray(station_cov_m2, float)
        rho = np.asarray(rho_m, float)
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(rho))) or pos.shape[0] != rho.shape[0]:
            self.n_dropped += 1
            return
        m = len(rho)
        ids = list(range(m)) if station_ids is None else list(station_ids)
        cvar = np.zeros(m) if clock_var_m2 is None else np.broadcast_to(np.asarray(clock_var_m2, float), (m,))
        if not np.all(np.isfinite(cvar)) or len(ids) != m:
            self.n_dropped += 1
            return
        self._batch(t_s, pos, cov, rho, np.zeros(m), ids, cvar)

    def on_measurement(self, t_s: float, station_id: int, station_pos_m, station_cov_m2, rho_m: float,
                       clock_var_m2: float = 0.0) -> None:
        pos = np.asarray(station_pos_m, float).reshape(3)
        cov = np.zeros((3, 3)) if station_cov_m2 is None else np.asarray(station_cov_m2, float).reshape(3, 3)
        cvar = float(clock_var_m2 or 0.0)
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(cov)) and np.isfinite(rho_m)
                and np.isfinite(cvar) and cvar >= 0):
            self.n_dropped += 1
            return
        why = None if self.cfg.receiver is None else rx.unusable_reason(cvar, cov, self.cfg.receiver)
        if why is not None:  # not yet synchronized / surveyed to a usable level: not used at all
            self.stats[why] += 1
            return
        if self.tracker is not None and self.model == "pr":
            # sequential scalar update at the slot's own time
            try:
                self.tracker.predict_to(t_s)
                self._update(pos[None], np.array([rho_m]), cov[None], None, [station_id],
                             bias_ids=[station_id], bias_var_m2=np.array([cvar]))
            except np.linalg.LinAlgError:
                self._reset()
                return
            if self.tracker is None:  # the divergence monitor restarted it
                return
            self.t_s = t_s
            self.n_updates += 1
            return
        # batch: LSQ, TDOA, and filter initialisation collect one cycle (a station repeats -> flush)
        if station_id in self._pending:
            self._flush(t_s)
        self._pending[station_id] = (t_s, pos, cov, float(rho_m), cvar)
        self._pending = {k: v for k, v in self._pending.items() if t_s - v[0] <= self.cfg.max_batch_age_s}

    def _flush(self, t_now: float) -> None:
        items = sorted(self._pending.items(), key=lambda kv: kv[1][0])
        self._pending.clear()
        if len(items) < self.cfg.min_stations:
            return
        t_last = items[-1][1][0]
        pos = np.array([v[1] for _, v in items])
        cov = np.array([v[2] for _, v in items])
        rho = np.array([v[3] for _, v in items])
        cvar = np.array([v[4] for _, v in items])
        dt = np.array([v[0] for _, v in items]) - t_last
        self._batch(t_last, pos, cov, rho, dt, [k for k, _ in items], cvar)

    def _batch(self, t_s, pos, cov, rho, dt, ids=None, cvar=None) -> None:
        m = len(rho)
        bias_kw, cov_trk = {}, cov
        if cvar is not None and np.any(cvar > 0):
            bias_kw = {"bias_ids": list(ids), "bias_var_m2": cvar}
            # snapshot uses (LSQ, the filter start): each residual seen once, as range variance
            # (an isotropic term on the station covariance: u^T (P + s I) u = u^T P u + s)
            cov = (np.zeros((m, 3, 3)) if cov is None else cov) + cvar[:, None, None] * np.eye(3)
        cov_snap = self._snapshot_cov(cov, dt)  # the snapshot's weights (LSQ, the start)
        self._last_geom = (pos, cov_snap if self.method == "lsq" else cov, rho)
        if m < self.cfg.min_stations:
            self.n_dropped += 1
            return
        if self.tracker is None:
            self._start(t_s, pos, cov, cov_snap, rho, dt, ids, cvar)
            return
        try:
            self.tracker.predict_to(t_s)
            self._update(pos, rho, cov_trk, dt if np.any(dt) else None, ids, **bias_kw)
        except np.linalg.LinAlgError:
            self._reset()
            return
        if self.tracker is None:  # the divergence monitor restarted it
            return
        if not np.all(np.isfinite(self.tracker.x)):
            self._reset()
            return
        self.t_s = t_s
        self.n_updates += 1

    def _update(self, pos, rho, cov, dt, ids, **bias_kw) -> None:
        """One filter update, through the integrity monitor when there is one; the divergence monitor
        sees its innovation."""
        if self.fde is None:
            nu, S = self.tracker.update(pos, rho, cov, dt, **bias_kw)
        else:
            nu, S = self.fde.update(self.tracker, pos, rho, list(range(len(rho))) if ids is None else ids, cov,
                                    dt, **bias_kw)
        self._watch(nu, S, ids)

    def _watch(self, nu, S, ids) -> None:
        """Feed one update's innovation ``nu`` (d,) and covariance ``S`` (d, d) to the divergence monitor
        with each station's normalized innovation
        (aircraft/navigator/radio/fde.py ``snooping``); a lost filter restarts."""
        if self.monitor is None:
            return
        nu = np.atleast_1d(np.asarray(nu, dtype=float))
        S = np.asarray(S, dtype=float)
        S = np.atleast_2d(S)
        ids = list(range(nu.size + (self.model != "pr"))) if ids is None else list(ids)
        done = None if self.fde is None else self.fde.last_snooping
        try:
            if done is not None and done[0] is nu and done[1] is S:  # the integrity monitor's own test
                q, w = done[2], done[3]
            else:
                q, w = snooping(nu, S, fault_vectors(self.model, len(ids), self.tracker.base))
        except np.linalg.LinAlgError:
            q, w = np.inf, np.zeros(len(ids))
        why = "diverged" if self.monitor.push(float(q), nu.size, dict(zip(ids, np.atleast_1d(w).tolist()))) \
            else "under_floor" if self._under_floor() else None
        if why is not None:
            self.stats[why] += 1
            self._reset()
            self.status = rx.RESTARTING

    def _under_floor(self) -> bool:
        """Rule 3's second test (aircraft/navigator/receiver.py): the filter's own Gaussian lies more
        than ``floor_lost_sigma`` below the height floor. Its truncated moments then sit on the floor,
        confident, where no range has a height gradient, and its innovations stay small."""
        k = self.cfg.receiver.floor_lost_sigma
        return k is not None and bool(np.any(self.tracker.floor_depth() > k))

    def _start_members(self, t_s: float, fix_m: np.ndarray, pos: np.ndarray, cov) -> np.ndarray | None:
        """The receiver's rule 5 (aircraft/navigator/receiver.py) for a filter's start: the batch's
        members (m,) bool it starts from, or None to wait for a better surveyed batch; ``fix_m`` (3,)
        the batch's snapshot fix, which gives each station's line of sight."""
        m = pos.shape[0]
        if self.method == "lsq" or cov is None:
            return np.ones(m, dtype=bool)
        if self.t_first_batch_s is None:
            self.t_first_batch_s = t_s
        sigma = np.sqrt(np.maximum(mdl.range_var(np.asarray(fix_m, float), pos, cov, 0.0), 0.0))
        keep = rx.start_members(sigma, t_s, self.t_first_batch_s, self.cfg.min_stations + 1, self.cfg.receiver)
        if keep is None:
            self.stats["start_wait_survey"] += 1
        elif not keep.all():
            self.stats["start_surveyed_subset"] += 1
        return keep

    def _snapshot_cov(self, cov, dt):
        """The station covariances a snapshot of a TDMA batch uses (LSQ, the filter start): the aircraft's
        unknown motion over each member's ``dt`` is noise to one fix, an isotropic ``(v dt)^2`` with the
        start's velocity prior ``v`` (``InitConfig.vel_sigma_m_s``), in its weights, its consistency test
        and the covariance it reports (the fix and its test use the same variances: docs/aircraft.md,
        receiver rule 2). cov (m, 3, 3) or None, dt (m,) or None; returns (m, 3, 3) or None."""
        if self.cfg.receiver is None or dt is None or not np.any(dt):
            return cov
        v_sig = (self.cfg.init or InitConfig()).vel_sigma_m_s
        motion = ((v_sig * np.asarray(dt, float)) ** 2)[:, None, None] * np.eye(3)
        return motion if cov is None else cov + motion

    def _start(self, t_s, pos, cov, cov_snap, rho, dt=None, ids=None, cvar=None) -> None:
        """No filter yet: a snapshot fix from the batch (LSQ), or the filter's start. ``cov``: the
        broadcast covariances (the clock variances ``cvar`` (m,) included); ``cov_snap``: the snapshot's
        (:meth:`_snapshot_cov`)."""
        if self.fix is None and self._restart_from is not None:  # LSQ: warm again from its anchor
            self.fix, self._restart_from = self._restart_from, None
            self.stats["lsq_anchor_restart"] += 1
        elif self.fix is None and self._wait_until_s is not None and t_s < self._wait_until_s:
            self.stats["lsq_restart_wait"] += 1  # the latest multi-start was not publishable: retry later
            return
        if self.cfg.guess_sigma_m is None and (self.fix is None or self.method != "lsq"):
            self._start_from_broadcasts(t_s, pos, cov, cov_snap, rho, dt, ids, cvar)
            return
        tu = self.cfg.tuning
        var = tu.sigma_m**2
        first = self.fix is None
        if first:
            self.fix = np.append(self.guess, 0.0) if self.model == "pr" else self.guess.copy()
        # the first fix may start far away: more iterations and a wide trust region
        kw = dict(floor_z_m=tu.floor_z_m, iters=50 if first else 10, max_step_m=5000.0 if first else 200.0)
        if self.model == "pr":
            x0 = self.fix if self.fix.size == 4 else np.append(self.fix, 0.0)
            self.fix = lsq_pr(rho, pos, x0, var, cov_snap, **kw)  # one run: (4,)
        else:
            self.fix = lsq_tdoa(rho, pos, self.fix[:3], var, cov_snap, **kw)  # (3,)
        self.t_s = t_s
        self.n_updates += 1
        if self.method == "lsq":
            self._drop_runaway_fix()
            return
        self.fix, self.tracker = start_from_guess(self.method, self.model, tu, self.guess, self.cfg.guess_sigma_m,
                                                  self.fix, t_s, pos, rho)

    def _initial(self, pos, cov, cov_snap, rho):
        """The start's snapshot fix weighted with the aircraft's motion over the batch (``cov_snap``)
        where it is still a snapshot; otherwise the fix without the motion, about which the start is
        the wide prior (:func:`.initializer.initial_state`): weighted with the motion, a small array's
        far-field fix spreads over kilometres and the wide prior would take that spread
        (docs/aircraft.md, receiver rule 2). An LSQ restarting (it has had a fix) from a batch without
        redundancy (at most 4 stations) takes the fix without the motion at once: the weights do not
        move an exactly determined batch's root, and whether that root is a snapshot (what the motion
        weights are for) decides nothing for it any more (it does not defer; each batch's published
        covariance is judged by :meth:`_fix_cov`)."""
        tu = self.cfg.tuning
        if self.method == "lsq" and self._anchor is not None and len(rho) <= 4:
            return initial_state(self.model, tu, pos, cov, rho, self.cfg.init)
        init = initial_state(self.model, tu, pos, cov_snap, rho, self.cfg.init)
        if init.snapshot or cov_snap is cov:
            return init
        return initial_state(self.model, tu, pos, cov, rho, self.cfg.init)

    def _start_from_broadcasts(self, t_s, pos, cov, cov_snap, rho, dt=None, ids=None, cvar=None) -> None:
        """Start from the broadcasts alone: multi-start snapshot fix (or a wide prior), from a batch that
        passes the start test when the receiver rules are on. The fix is weighted by ``cov_snap``; the
        members' survey is judged by ``cov``. A filter with a batch start (``EstimatorConfig.batch_start``)
        starts from the fit of the batches that passed, when it says so (:meth:`_batch_started`);
        ``dt`` (m,) the members' times relative to ``t_s``, ``ids`` (m,) their station ids, ``cvar`` (m,)
        their clock variances (in ``cov``)."""
        m = len(rho)
        dt = np.zeros(m) if dt is None else np.asarray(dt, float)
        ids = np.arange(m) if ids is None else np.asarray(ids)
        cvar = np.zeros(m) if cvar is None else np.asarray(cvar, float)
        tu = self.cfg.tuning
        init = self._initial(pos, cov, cov_snap, rho)
        if self.cfg.receiver is not None:
            keep = self._start_members(t_s, init.fix[:3], pos, cov)
            if keep is None:
                return
            if not keep.all():  # the surveyed stations alone (enough for a snapshot with redundancy)
                pos, rho, dt, ids, cvar = pos[keep], rho[keep], dt[keep], ids[keep], cvar[keep]
                same = cov_snap is cov  # (no motion: one array, kept one)
                cov = None if cov is None else cov[keep]
                cov_snap = cov if same else cov_snap[keep]
                init = self._initial(pos, cov, cov_snap, rho)
            init = consistent_start(self.model, self.cfg, self.stats, init, pos, cov_snap, rho)
            if init is None:
                return
        # (an LSQ that has had a fix restarts at once: it starts no filter, and waiting repeats its
        # multi-start for every batch set aside)
        if not init.snapshot and len(rho) <= 4 and self._anchor is None and \
                self.n_deferred < (self.cfg.init or InitConfig()).defer_batches:
            self.n_deferred += 1  # no redundancy, no snapshot: wait for a batch with more stations
            return
        self.n_deferred = 0
        if self.batch_start is not None and (len(rho) > self.cfg.min_stations or self.batch_start.cycles):
            # cycles with redundancy only (docs/aircraft.md: seed001's 4-station far field fitted over many
            # cycles was overconfident); one without, while a window is collected, is waited past
            init = self._batch_started(t_s, pos, cov, rho, dt, ids, init, cvar) if len(rho) > self.cfg.min_stations \
                else None
            if init is None:
                return
        self.fix = init.fix.copy()
        self.init = init
        self.t_s = t_s
        self.n_updates += 1
        self.status = rx.TRACKING
        if self.method == "lsq":
            self._anchor = (t_s, self.fix.copy(), rx.publishable(self.fix[:3], self._fix_cov(), self.cfg.receiver
                                                                 or rx.DEFAULT_RECEIVER))
        else:
            self.tracker = CvTracker(self.method, self.model, init.x0, tu, t0_s=t_s, P0=init.P0,
                                     ref_m=crd.reference_point(pos),
                                     ref_radius_m=crd.array_radius(pos), station_cross=init.station_cross)

    def _batch_started(self, t_s, pos, cov, rho, dt, ids, init, cvar=None):
        """One more cycle that passed the start rules into the batch start
        (:class:`.batch_start.BatchStart`): the start to use now (the fit, or ``init`` where the fit failed
        over a full window), or None to wait for more cycles."""
        rcfg = self.cfg.receiver

        def test(cost, dof):
            return rcfg is None or rx.consistent(cost, dof, rcfg.p_start)

        start = self.batch_start.offer(self.model, t_s, t_s + dt, pos, cov, rho, ids, init, test, self.stats,
                                       cvar)
        if start is not None:
            self.batch_start.reset()
        return start

    def _reset(self) -> None:
        """A filter whose covariance lost positive definiteness restarts from the next batch's fix."""
        if self.tracker is not None:
            self.guess = np.asarray(self.tracker.x[POS], dtype=float).copy()
        self.tracker = None
        self.fix = None
        self.n_resets += 1
        self._pending.clear()
        if self.batch_start is not None:
            self.batch_start.reset()
        if self.monitor is not None:
            self.monitor.reset()
        if self.fde is not None:  # exclusions stand; the new filter's transient passes before the gate
            self.fde.restart()

    def _drop_runaway_fix(self) -> None:
        """Receiver rule 4 for the snapshot LSQ (aircraft/navigator/receiver.py): each batch's fix starts
        from the previous one (a warm start, up to 10 steps of 200 m). Where the batch cannot fix the
        range (seed001's far field: four stations of a 50 m array, no redundancy) that chain can walk
        off along it, batch by batch, to hundreds of kilometres, with a covariance that says so: a fix
        that is not publishable is dropped, and the next batch starts from the broadcasts again
        (multi-start, as the first), or, within ``ReceiverConfig.lsq_restart_s`` of the latest
        multi-start, warm from that multi-start's fix; where that fix was not publishable itself, the
        batches wait ``lsq_retry_s`` after it for the next multi-start. In that far field the warm chain
        is dropped every few tenths of a second, and a multi-start each time cost about a second of CPU
        per second of flight (docs/aircraft.md, "Its restarts are rationed")."""
        if self.cfg.receiver is None or self.fix is None:
            return
        C = self._fix_cov()
        if not rx.publishable(self.fix[:3], C, self.cfg.receiver):
            self.stats["lsq_runaway"] += 1
            self.fix = None
            every, retry = self.cfg.receiver.lsq_restart_s, self.cfg.receiver.lsq_retry_s
            if every is None or self._anchor is None:
                return
            t_a, fix_a, usable = self._anchor
            if usable and self.t_s - t_a < every:
                self._restart_from = fix_a.copy()
            elif not usable:  # no anchor: the next multi-start after retry_s (far beyond the bar)
                self._wait_until_s = t_a + retry

    def _fix_cov(self) -> list | None:
        """The LSQ fix's position covariance (3 x 3 list; None where ``(H^T W H)`` is singular): its own
        ``(H^T W H)^-1`` over the latest batch, where that batch defends it as a snapshot with
        redundancy (:func:`.initializer.defended`); otherwise, with the receiver rules on, the wide
        prior's (:func:`.initializer.wide_cov`): an exactly determined far-field batch fits its ranges
        whatever its error, and its linearized covariance, taken where the error put the fix, can be
        a hundred times too small (docs/aircraft.md, "seed001's far field")."""
        if self._last_geom is None:
            return None
        key = (self.fix, self._last_geom)  # the batch's check (_drop_runaway_fix) and its estimate share it
        if self._fix_cov_memo is not None and all(a is b for a, b in zip(self._fix_cov_memo[0], key)):
            return self._fix_cov_memo[1]
        C = self._fix_cov_of_batch()
        self._fix_cov_memo = (key, C)
        return C

    def _fix_cov_of_batch(self) -> list | None:
        """:meth:`_fix_cov` computed for the current fix and batch."""
        pos, cov, rho = self._last_geom
        sigma = self.cfg.tuning.sigma_m
        try:
            C = lsq_cov(self.fix[None], pos, sigma**2, self.model, cov)[0]
        except np.linalg.LinAlgError:
            return None
        if self.cfg.receiver is not None:
            init = self.cfg.init or InitConfig()
            ok, sig = defended(self.model, self.fix, C, pos, cov, rho, sigma, init, need_redundancy=True)
            if not ok:
                C = wide_cov(self.fix.size, sig, init)
        return C[:3, :3].tolist()

    def tracker_or_fix(self) -> bool:
        """Whether there is anything to estimate from (a running filter, or an LSQ fix)."""
        return self.tracker is not None or (self.method == "lsq" and self.fix is not None)

    # -- output
    def estimate(self) -> dict | None:
        """Latest estimate: ``t_s``, ``pos_m`` [3], ``cov_m2`` [3][3] (LSQ: its ``(H^T W H)^-1``), ``vel_m_s``,
        ``clock_m``, ``n_updates``; filters with integrity monitoring (``config.fde``) add ``hpl_m``,
        ``vpl_m`` (aircraft/navigator/radio/fde.py) and ``excluded`` (station ids)."""
        if self.t_s is None:
            return None
        if self.tracker is None:
            if self.method != "lsq" or self.fix is None:
                return None
            C = self._fix_cov()
            return {"t_s": self.t_s, "pos_m": self.fix[:3].tolist(), "cov_m2": C, "vel_m_s": None,
                    "clock_m": float(self.fix[3]) if self.fix.size == 4 else None, "n_updates": self.n_updates}
        x, P = self.tracker.x, self.tracker.P
        out = {"t_s": self.tracker.t_s, "pos_m": x[POS].tolist(), "cov_m2": P[POS, POS].tolist(),
               "vel_m_s": x[VEL].tolist(), "clock_m": float(x[CLOCK]) if self.tracker.layout.has_clock else None,
               "n_updates": self.n_updates}
        if self.fde is not None:
            hpl, vpl = protection_levels(P[POS, POS], self.fde.cfg.integrity_risk)
            out.update(hpl_m=float(hpl), vpl_m=float(vpl), excluded=self.fde.excluded())
        return out


def start_from_guess(method: str, model: str, tu: Tuning, guess_m: np.ndarray, guess_sigma_m: float,
                     fix: np.ndarray, t_s: float, pos: np.ndarray, rho: np.ndarray) -> tuple[np.ndarray, CvTracker]:
    """A filter started from an external coarse fix ``guess_m`` (3,) with position sigma ``guess_sigma_m``
    (``EstimatorConfig.guess_sigma_m``): the snapshot ``fix`` (4,) or (3,) takes the guessed position and,
    for pseudoranges, the clock from the ranges ``rho`` (m,) to it from the stations ``pos`` (m, 3).
    Returns the fix and the tracker; the rest of the prior is the tuning's ``prior_cov``."""
    fix = np.array(fix, dtype=float)
    fix[:3] = guess_m
    C = np.diag([guess_sigma_m**2] * 3 + ([(tu.p0.clock_m + guess_sigma_m) ** 2] if model == "pr" else []))
    if model == "pr":
        fix[3] = float(np.mean(rho - np.linalg.norm(guess_m - pos, axis=1)))
    x0 = np.concatenate([fix[:3], np.zeros(3)])
    if model == "pr":
        x0 = np.append(x0, [fix[3], 0.0])
    layout = StateLayout(model, drift=model == "pr")
    P0 = tu.prior_cov(layout)
    idx = layout.pos_clock
    P0[np.ix_(idx, idx)] = C
    return fix, CvTracker(method, model, x0, tu, t0_s=t_s, P0=P0, ref_m=crd.reference_point(pos),
                          ref_radius_m=crd.array_radius(pos))
