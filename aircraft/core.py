"""One live core shape: what the Zenoh shell (:mod:`aircraft.node`) needs of an aircraft.

Three sans-I/O cores hold world + navigator + journal each: the radio aircraft
(:class:`aircraft.radio_core.RadioAircraftCore`), the inertial one (``--imu``,
:class:`aircraft.ins_core.InsAircraftCore`) and the triad (``--satellites``,
:class:`aircraft.triad_core.TriadAircraftCore`). :func:`make_core` picks one by configuration; the
node holds exactly one and never asks which kind it is. What a core returns are typed events
(:mod:`aircraft.events`: ``ac_truth``, ``ac_estimate``, ``ac_status``, the journal's ``ac_init`` /
``ac_input``); the node turns them into the wire's dicts (``to_msg``) as it publishes them.
"""

from __future__ import annotations

from collections import Counter
from typing import Any, Protocol

import numpy as np

from nav.geometry import range_jacobian
from net import streams

from .events import AcEstimate, AcEvent, AcTruth
from .journal import AcJournal
from .navigator import receiver as rx


class AircraftCore(Protocol):
    """A live aircraft core as the node drives it.

    * ``on_nav(msg, phy)``: one decoded station broadcast (with its true ``phy`` from the channel) ->
      the events to publish (``AcTruth``, ``AcEstimate``, ``AcStatus``; not the journal's);
    * ``tick(t_s)``: between broadcasts, at fleet time ``t_s`` (already ``lag_s`` behind): integrate
      up to it and return the events due (an inertial core's journal; the radio core: none);
    * ``journal``: the navigator's pending journal (``ac_init`` / ``ac_input``; ``None``: none), which
      the node publishes after each broadcast's messages and closes at exit;
    * ``status_line(t_s)``: the body of the periodic status line (``None``: nothing to say yet);
      ``summary()``: ``{"measurements", "estimates": {algo: {...}}}`` against the core's own truth.
    """

    name: str
    seq: Counter[str]
    stats: Counter[str]
    journal: AcJournal | None

    @property
    def algos(self) -> tuple[str, ...]: ...  # what it runs (the start line)

    @property
    def lag_s(self) -> float: ...  # wall seconds (x speed) behind fleet time the node ticks it

    @property
    def step_s(self) -> float: ...  # the node's inbox wait, s

    def on_nav(self, msg: dict, phy: dict) -> list[AcEvent]: ...

    def tick(self, t_s: float) -> list[AcEvent]: ...

    def status_line(self, t_s: float) -> str | None: ...

    def summary(self) -> dict[str, Any]: ...


class InertialCore:
    """The shell side the inertial and triad cores share (both integrate an IMU on a fixed grid).

    ``lag_s``: the node integrates the IMU this far behind fleet time, so that a broadcast delayed by
    the network (up to ``lag_s``) still falls into an IMU step not yet integrated; later ones are
    counted (``nav_bad_or_late``) and dropped. A subclass has ``algo``, ``tn`` (its tuning, ``dt_s``),
    ``ekf`` (``None`` until the start), ``preset``, ``imu_steps``, ``t0_s``, ``journal``, ``stats``,
    ``advance_to(t_s)`` and ``truth_n(t_s)``.
    """

    algo: str
    lag_s = 0.25

    @property
    def algos(self) -> tuple[str, ...]:
        return (self.algo,)

    @property
    def step_s(self) -> float:
        return self.tn.dt_s

    def tick(self, t_s: float) -> list[AcEvent]:
        """Integrate every IMU step that ends by ``t_s``; the journal's events now due."""
        self.advance_to(t_s)
        return self.journal.take()

    def status_line(self, t_s: float) -> str | None:
        """IMU, steps and, once started, the navigator's time, the true position and the error."""
        head = f"imu={self.preset.name} steps={self.imu_steps}"
        e = self.ekf
        if e is None:  # still in its start window (aircraft/navigator/ins_start.py; the triad's window fix)
            buffered = self.stats.get("start_buffered")
            return None if buffered is None else f"{head} starting: {buffered} broadcasts"
        pt = self.truth_n(e.t_s)[0]
        return (f"{head} t_ins={e.t_s:.2f}s pos=({pt[0]:.0f},{pt[1]:.0f},{pt[2]:.0f}) "
                f"meas={self.stats['measurements']} err {self.algo}={np.linalg.norm(e.p[0] - pt):.1f}m "
                f"late={self.stats['nav_bad_or_late']}")

    def station_update(self, t_rx: float, s_m: np.ndarray, cov_m2: np.ndarray, cvar: float, rho: float
                       ) -> list[AcEvent]:
        """The navigator's update with one station pseudorange ``rho`` received at ``t_rx`` (IMU
        integrated into the step that contains it) from ``s_m`` (3,) with covariance ``cov_m2`` (3, 3):
        its variance the nominal range variance, the station's along the line of sight and ``cvar``
        (the broadcast clock's and the link's); -> ``ac_estimate`` (when publishable) and
        ``ac_status`` when due."""
        if self.ekf.t_s < t_rx:
            self.advance_to(self.ekf.t_s + self.tn.dt_s)
        u = range_jacobian(self.ekf.position_at(t_rx)[0], s_m)
        var = self.tn.sigma_range_m**2 + float(u @ cov_m2 @ u) + cvar
        self.ekf.pseudorange(t_rx, s_m, np.array([rho]), var)
        self.stats["measurements"] += 1
        est = self.estimate_event()
        if not rx.publishable(est.pos_m, est.cov_m2):
            return self.status(t_rx, rx.NO_FIX)
        return [est] + self.status(t_rx, rx.TRACKING)

    def status(self, t_s: float, state: str, detail: str | None = None) -> list[AcEvent]:
        """The navigator's ``ac_status`` when due (aircraft/navigator/receiver.py StatusPacer)."""
        if not self._pacer.due(self.algo, state, t_s):
            return []
        return [rx.status_event(self.name, self.seq, self.algo, t_s, state, self.stats, detail)]

    def truth_event(self, t_rx: float) -> AcTruth:
        """World side: the ``ac_truth`` record of a measured broadcast (identifies it for re-flight)."""
        pt, vt, _ = self.truth_n(t_rx)
        self.seq["ac_truth"] += 1
        return AcTruth(self.name, self.seq["ac_truth"], t_rx, pt.tolist(), vt.tolist())

    def estimate_event(self) -> AcEstimate:
        """The navigator's estimate: position, velocity and their covariances, and the subclass's
        :meth:`extra` scalars."""
        e = self.ekf
        self.seq["ac_estimate"] += 1
        return AcEstimate(self.name, self.seq["ac_estimate"], float(e.t_s), self.algo, e.p[0].tolist(),
                          e.P[0, :3, :3].tolist(), int(e.n_updates), vel_m_s=e.v[0].tolist(),
                          vel_cov=e.P[0, 3:6, 3:6].tolist(), extra=self.extra())

    def summary(self) -> dict[str, Any]:
        """Measurements and, once started, the estimate against the truth with the IMU steps run and due."""
        out: dict[str, Any] = {"measurements": int(self.stats["measurements"]), "estimates": {}}
        e = self.ekf
        if e is not None:
            pt = self.truth_n(e.t_s)[0]
            due = int(np.floor((e.t_s - self.t0_s) * self.preset.rate_hz + 1e-9))
            out["estimates"][self.algo] = {"t_s": e.t_s, "err_m": float(np.linalg.norm(e.p[0] - pt)),
                                           "n_updates": e.n_updates, "imu_steps": self.imu_steps,
                                           "imu_steps_expected": due}
        return out


def split_ins(algos: tuple[str, ...], imu: str | None) -> tuple[tuple[str, ...], tuple[str, ...], str | None]:
    """(inertial algorithms, the others, the IMU preset). ``--imu`` without ``ins-ekf`` adds it;
    ``ins-ekf`` without ``--imu`` uses the adis16480 preset."""
    ins = tuple(a for a in algos if a == "ins-ekf")
    if imu and not ins:
        ins = ("ins-ekf",)
    if ins and not imu:
        imu = "adis16480"
    rest = tuple(a for a in algos if a != "ins-ekf")
    if ins and rest:  # one world per aircraft: the 6-DOF one of --imu (its own truth and channel)
        raise ValueError(f"ins-ekf runs alone in its 6-DOF world; drop {list(rest)} or run another aircraft")
    return ins, rest, imu


def make_core(scn, ac, opts, seed: int, t0_s: float, net_clock=None) -> AircraftCore:
    """The live core of ``opts`` (:class:`aircraft.node.AircraftOptions`): the triad with
    ``satellites`` or algorithm ``triad``, the inertial aircraft with ``imu`` or ``ins-ekf``, else the
    radio aircraft running ``algos``. ``seed``: the world's; ``t0_s``: the inertial cores' start on the
    fleet axis; ``net_clock``: network time as the field realizes it. Each core draws from its own
    streams of ``(seed, kind, name)``, as the node always did."""
    tag = streams.name_key(opts.name)
    if opts.satellites is not None or "triad" in opts.algos:  # the triad: aircraft/triad_core.py
        if set(opts.algos) - {"triad"}:
            raise ValueError(f"triad runs alone in its 6-DOF world; drop {sorted(set(opts.algos) - {'triad'})}")
        from .triad_core import TriadAircraftCore

        return TriadAircraftCore(scn, ac, opts.name, n_sv=4 if opts.satellites is None else opts.satellites,
                                 imu=opts.imu, height_m=opts.height_m, seed=seed, t0_s=t0_s, net_clock=net_clock)
    ins, rest, imu = split_ins(tuple(opts.algos), opts.imu)
    if ins:  # the inertial aircraft: own world (6-DOF, IMU) and ins-ekf (aircraft/ins_core.py)
        from .ins_core import InsAircraftCore

        return InsAircraftCore(scn, ac, opts.name, streams.rng(seed, streams.AIRCRAFT_INS, tag), imu=imu,
                               height_m=opts.height_m, seed=seed, t0_s=t0_s, net_clock=net_clock)
    from .radio_core import RadioAircraftCore

    return RadioAircraftCore(ac, rest, opts.name, streams.rng(seed, streams.AIRCRAFT_RADIO, tag), opts.height_m,
                             horizon_s=(opts.duration_s or 7200.0) + 10.0, net_clock=net_clock)
