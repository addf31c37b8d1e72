"""The stations' truth in the field's own datum (issue 30; evaluation only: no estimator sees it).

With ``[survey] datum = "field"`` the founders define the frame until they release it; from then on
the field holds it by a no-net-translation / no-net-rotation fit of the carriers' broadcasts against
*references*, their broadcasts frozen at the release (docs/architecture.md, "The frame datum";
``stations.core.StationCore._hold_frame``). The field's frame is then the references' frame, not the
founders': its rigid motion against the founders' frame at the release (the references' common
translation / rotation error) is the datum's definition, as the weights of the ensemble are network
time's (docs/sync.md). So the truth a station is judged against is the founders'-frame truth moved
by that rigid motion - an S-transformation of the truth, fixed from the freeze on.

Derivation. Carriers ``i = 1..k`` with true positions ``x_i`` (founders' frame), references ``q_i``
(their broadcasts at the freeze) and the broadcast covariances ``C_i`` of that moment. Each station
fits, before each nav, the small rigid motion ``(t, w)`` of the carriers' current estimates ``p_i``
against ``q_i`` (``stations.core.rigid_motion``: ``A_i = [I, -[q_i]x]``, ``r_i = p_i - q_i - A_i (t, w)``)
and removes it, so that after the correction

    (1)  sum_i A_i^T C_i^-1 (p_i - q_i) = 0        (no net translation or rotation against q).

The truth in the field's datum is ``S(x) = R x + s``, the rigid motion that takes the carriers' true
positions onto their references with the same weights:

    (2)  (R, s) = argmin sum_i |q_i - R x_i - s|^2_{C_i^-1},

solved by iterating the same linearized Helmert fit (``rigid_motion(q, C, S(x))`` gives the increment
``(ds, dw)``; ``R <- Exp(dw) R``, ``s <- Exp(dw) s + ds``) to convergence, where its normal equations read

    (3)  sum_i A_i^T C_i^-1 (q_i - S(x_i)) = 0     (``A_i`` linearized about ``S(x_i)`` = ``q_i`` to first order).

The errors ``e_i = p_i - S(x_i) = (p_i - q_i) + (q_i - S(x_i))`` then satisfy, by (1) + (3),

    (4)  sum_i A_i^T C_i^-1 e_i = 0,

so against ``S(x)`` the carriers' errors have no net translation or rotation: what the datum
defines is not counted as error, and what is left is the field's shape error and noise, which the
stations' covariances are meant to carry. (The stations weight (1) with their *current* broadcast
covariances, (2) uses those of the freeze: (4) holds up to the change in their relative weights.)
``S`` is fixed at the freeze: a later rigid drift ``d`` of the field (every ``p_i -> p_i + d``)
breaks (1) and shows in ``e`` as ``d``; re-fitting ``S`` to the estimates at each evaluation time
would absorb it. Before the freeze (and in the founders' datum) the truth is the founders'-frame
truth: ``S`` is the identity.

The freeze is read off the nav broadcasts, by the stations' own rule: the release is the first nav
after which no member (a station heard within ``dead_after_cycles`` cycles) broadcasts a frame
constraint (a zero variance) and at least ``datum_quorum`` members carry the datum (full rank,
horizontal sigma at most the convergence threshold); each carrier freezes its references at its own
first nav after it, to the carriers' latest broadcasts (its own: that of the nav before if it carried then). The stations thus hold
references one nav apart: a peer that spoke between two stations' navs has a newer reference at the
second (in seed000 seed 1, sigma_d 0.5 m, up to 0.39 m apart, mostly in height). ``q_i`` is the mean
over the stations of their references of carrier ``i`` (each station's correction pulls the field
toward its own references; (1) is their compromise to first order), and ``C_i`` its broadcast
covariance at the end of that cycle. ``tests/larns/test_datum_truth.py`` checks ``q`` against the
simulator's cores.
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

HELMERT_ITERATIONS = 5  # the linearized fit of (2) iterated: converged to < 1e-12 m in 2-3
HELMERT_TOL = 1e-12


def rotation_exp(w_rad: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of the rotation vector ``w_rad`` (3,) (Rodrigues)."""
    th = float(np.linalg.norm(w_rad))
    K = np.array([[0.0, -w_rad[2], w_rad[1]], [w_rad[2], 0.0, -w_rad[0]], [-w_rad[1], w_rad[0], 0.0]])
    if th < 1e-15:
        return np.eye(3) + K
    return np.eye(3) + math.sin(th) / th * K + (1.0 - math.cos(th)) / th**2 * (K @ K)


def datum_transform(truth_m: np.ndarray, ref_m: np.ndarray, cov_m2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rigid motion ``x -> R x + s`` that takes the true positions ``truth_m`` (k, 3) onto the
    references ``ref_m`` (k, 3), weighted by ``cov_m2`` (k, 3, 3): eq. (2) of the module docstring.
    Returns ``R`` (3, 3), ``s`` (3,)."""
    from stations.core import rigid_motion

    R, s = np.eye(3), np.zeros(3)
    y = np.asarray(truth_m, float).copy()
    for _ in range(HELMERT_ITERATIONS):
        ds, dw = rigid_motion(np.asarray(ref_m, float), np.asarray(cov_m2, float), y)
        E = rotation_exp(dw)
        R, s, y = E @ R, E @ s + ds, y @ E.T + ds
        if max(np.abs(ds).max(), np.abs(dw).max() * max(np.abs(y).max(), 1.0)) < HELMERT_TOL:
            break
    return R, s


class FieldDatumTruth:
    """The truth in the field's datum, from the nav broadcasts (module docstring).

    Parameters
    ----------
    truth_m : {station id: (3,) true position in the founders' frame}.
    converged_m : the horizontal sigma at most which a broadcast carries the datum (the stations'
        ``datum_converged_m``, sigma_d / 2 by default).
    quorum : carriers needed (the stations' ``datum_quorum``).
    member_s : how long a station counts as a member after its last nav (``dead_after_cycles`` x cycle).
    cycle_s : the TDMA cycle: every station freezes its references at its first nav after the release.
    min_updates : the navs a station sends before it may enter the datum mode (``datum_min_updates``).

    ``observe(t_s, src, pos_m, cov_m2)`` every nav in time order; then ``frozen_s`` (None before the
    freeze), ``ref_sets`` {station: {carrier: (3,)}} (the stations that froze in the cycle after the
    release; a station converging later freezes later and is not one of them), ``refs`` {carrier: (3,)}
    (their mean), ``R`` (3, 3), ``s`` (3,) and :meth:`truth` / :meth:`truth_at`.
    """

    def __init__(self, truth_m: Mapping[int, np.ndarray], converged_m: float, quorum: int = 4,
                 member_s: float = 5.0, cycle_s: float = 1.0, min_updates: int = 45):
        self.true_m = {int(k): np.asarray(v, float) for k, v in truth_m.items()}
        self.converged_m = float(converged_m)
        self.quorum = int(quorum)
        self.member_s = float(member_s)
        self.cycle_s = float(cycle_s)
        self.min_updates = int(min_updates)
        self._seq: dict[int, int | None] = {}
        self._last: dict[int, tuple[float, np.ndarray, np.ndarray]] = {}
        self._released_s: float | None = None
        self.ref_sets: dict[int, dict[int, np.ndarray]] = {}  # station -> its references
        self.frozen_s: float | None = None
        self.refs: dict[int, np.ndarray] = {}
        self.ref_cov: dict[int, np.ndarray] = {}
        self.R, self.s = np.eye(3), np.zeros(3)

    @classmethod
    def for_scenario(cls, scn) -> "FieldDatumTruth":
        """The scenario's stations and the stations' own thresholds (``stations.core.StationConfig``)."""
        from stations.core import StationConfig

        c = StationConfig.datum_converged_m
        return cls({sid: scn.true_pos(sid) for sid in scn.ids},
                   0.5 * scn.channel.sigma_d_m if c == 0.0 else c, StationConfig.datum_quorum,
                   StationConfig.dead_after_cycles * scn.tdma.cycle_s, scn.tdma.cycle_s,
                   StationConfig.datum_min_updates)

    def carries(self, cov_m2: np.ndarray) -> bool:
        """``stations.core.StationCore.carries_datum`` on a broadcast covariance (3, 3)."""
        return bool(np.all(np.diag(cov_m2) > 0.0)
                    and math.sqrt(max(float(cov_m2[0, 0] + cov_m2[1, 1]), 0.0)) <= self.converged_m)

    def observe(self, t_s: float, src: int, pos_m, cov_m2, seq: int | None = None) -> None:
        """A nav broadcast of station ``src`` at (true) time ``t_s``: position (3,), covariance (3, 3),
        its sequence number ``seq`` (the count of its navs; None: taken as past ``min_updates``)."""
        if self.frozen_s is not None:
            return
        pos, cov = np.asarray(pos_m, float), np.asarray(cov_m2, float)
        if pos.shape != (3,) or cov.shape != (3, 3) or not (np.isfinite(pos).all() and np.isfinite(cov).all()):
            return
        src = int(src)
        if self._released_s is not None and t_s > self._released_s + self.cycle_s:
            self._freeze()
            return
        prev = self._last.get(src)
        self._last[src] = (float(t_s), pos, cov)
        prev_seq, self._seq[src] = self._seq.get(src), seq
        mem = {p: v for p, v in self._last.items() if t_s - v[0] <= self.member_s}
        if self._released_s is None:
            if not self._releases(mem):
                return
            self._released_s = float(t_s)
        # the station's first nav after the release: its references are the carriers' latest
        # broadcasts; its own is its previous one if it was in the datum mode then (StationCore._hold_frame
        # runs just before each nav and kept its own reference at its estimate of the nav before), else
        # this one (it entered the datum mode at this nav: converged, after datum_min_updates navs)
        if src not in self.ref_sets and self.carries(cov):
            refs = {p: v[1] for p, v in mem.items() if self.carries(v[2]) and p in self.true_m}
            was = (prev is not None and self.carries(prev[2])
                   and (prev_seq is None or prev_seq - 1 >= self.min_updates))
            refs[src] = prev[1] if was else pos
            self.ref_sets[src] = refs

    def _releases(self, mem: dict[int, tuple[float, np.ndarray, np.ndarray]]) -> bool:
        """Do the members' latest broadcasts ``mem`` release the frame: no frame constraint (a founder
        still holding it broadcasts a zero variance) and ``quorum`` carriers."""
        if any(not np.all(np.diag(c) > 0.0) for _, _, c in mem.values()):
            return False
        return sum(1 for p, (_, _, c) in mem.items() if self.carries(c) and p in self.true_m) >= self.quorum

    def _freeze(self) -> None:
        """The references: per carrier, the mean of the stations' references of it (they froze one
        nav apart within the cycle that follows the release, so peers that spoke in between differ);
        the weights: the carriers' broadcast covariances at the end of that cycle."""
        self.frozen_s = self._released_s
        ids = sorted({p for refs in self.ref_sets.values() for p in refs})
        self.refs = {p: np.mean([refs[p] for refs in self.ref_sets.values() if p in refs], axis=0) for p in ids}
        self.ref_cov = {p: self._last[p][2].copy() for p in ids}
        self.R, self.s = datum_transform(np.stack([self.true_m[p] for p in ids]),
                                         np.stack([self.refs[p] for p in ids]),
                                         np.stack([self.ref_cov[p] for p in ids]))

    def finish(self) -> "FieldDatumTruth":
        """Freeze now if the release was seen but the cycle after it did not end in the stream."""
        if self.frozen_s is None and self.ref_sets:
            self._freeze()
        return self

    def truth(self, sid: int) -> np.ndarray:
        """Station ``sid``'s true position in the field's datum (3,) (the founders' frame before the freeze)."""
        return self.R @ self.true_m[int(sid)] + self.s

    def truth_at(self, t_s: float, sid: int) -> np.ndarray:
        """As :meth:`truth`, at time ``t_s``: the founders'-frame truth before the freeze."""
        if self.frozen_s is None or t_s < self.frozen_s:
            return self.true_m[int(sid)].copy()
        return self.truth(sid)


def sim_datum_truth(scn, sim) -> FieldDatumTruth:
    """A :class:`FieldDatumTruth` fed with simulator ``sim``'s nav broadcasts as they go on air (it
    takes ``sim.publish``, which must be unset). Run the simulator, then read it."""
    if sim.publish is not None:
        raise ValueError("the simulator already publishes")
    dt = FieldDatumTruth.for_scenario(scn)

    def publish(t_s, sid, m, phy):
        if m.get("kind") == "nav" and phy is not None:
            dt.observe(phy["t_true_s"], sid, m["pos_m"], m["cov_m2"], m["seq"])

    sim.publish = publish
    return dt


def truth_series(dt: FieldDatumTruth, ids, times_s) -> np.ndarray:
    """The truth in the field's datum at each time: (K, n, 3) for station ``ids`` (n) at ``times_s`` (K)."""
    dt.finish()
    return np.stack([np.stack([dt.truth_at(float(t), sid) for sid in ids]) for t in times_s])


def recording_datum_truth(rec, scn=None) -> FieldDatumTruth | None:
    """The truth in the field's datum of a recording (:class:`larns.log.series.Recording`), or None
    when its stations keep the founders' datum. The datum mode and the thresholds come from ``scn``
    (a :class:`net.scenario.Scenario`), else from the recorded ``core_init`` (journal), else from the
    scenario the recording's metadata names; the true positions from the truth topics (``scn``'s
    for stations without one); the navs in log order, timed by their stamps."""
    from stations.core import StationConfig

    cfg = (rec.init_record or {}).get("cfg") if scn is None else None
    if scn is None and cfg is None and rec.meta.get("scenario"):
        from net.scenario import ScenarioError, load

        try:
            scn = load(rec.meta["scenario"])
        except (ScenarioError, OSError, ValueError):
            return None
    if scn is not None:
        if scn.datum != "field":
            return None
        dt = FieldDatumTruth.for_scenario(scn)
    elif cfg is not None:
        conv = float(cfg.get("datum_converged_m", StationConfig.datum_converged_m))
        if conv < 0.0:
            return None
        cycle_s = float(rec.init_record["tdma"][0])
        dt = FieldDatumTruth({}, 0.5 * float(cfg["sigma_d_m"]) if conv == 0.0 else conv,
                             int(cfg.get("datum_quorum", StationConfig.datum_quorum)),
                             int(cfg.get("dead_after_cycles", StationConfig.dead_after_cycles)) * cycle_s, cycle_s,
                             int(cfg.get("datum_min_updates", StationConfig.datum_min_updates)))
    else:
        return None
    dt.true_m.update({sid: np.asarray(p, float) for sid, p in rec.truth_positions.items()})
    for _, msg in rec.records:
        if msg is not None and msg.get("kind") == "nav" and isinstance(msg.get("src"), int):
            dt.observe(float(msg["stamp_s"]), msg["src"], msg["pos_m"], msg["cov_m2"], msg.get("seq"))
            if dt.frozen_s is not None:
                break
    dt.finish()
    return dt if dt.frozen_s is not None else None
