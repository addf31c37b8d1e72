"""Sans-I/O radio aircraft for the live process (algorithms ``ukf-pr``, ``ekf-pr``, ``lsq-pr``, ``*-tdoa``).

World side: the true trajectory (:mod:`aircraft.world.trajectory`, from the scenario's
``[aircraft.trajectory]``) and the channel layer: reception at ``t_rx = t_true_tx + |r(t_rx) - p_tx| / c``
(the sender's true position and transmit time, as the node's :class:`net.channel.UserIntake` hands
them over) read on the aircraft's receiver clock, which runs on network time (station 1's
oscillator) plus ``c dtau(t) = df lambda t + c tau0`` (seed 001) and timing noise ``sigma_m``;
pseudorange ``rho = c (t_rx_local - (t_tx - theta_hat(t_tx)))`` from the *station-stamped* transmit
time ``t_tx`` corrected by the broadcast clock correction ``theta_hat`` (``msg.clock``). Each station's
residual sync error reaches the aircraft as in reality; the filters carry it as one Gauss-Markov bias
state per station whose stationary variance is the broadcast clock variance ``c^2 P_theta``
(``tuning.clock_bias``; snapshot LSQ and the filter start add it to the range variance; docs/sync.md).

Navigator side: one :class:`aircraft.navigator.radio.estimator.AircraftEstimator` per algorithm; it sees
the broadcast's *estimated* station position and covariance (``msg.pos_m``, ``msg.cov_m2``), never
``phy``. Journal (aircraft/journal.py): every measured broadcast as an ``m`` entry;
:meth:`RadioAircraftCore.from_record` rebuilds the navigator without a world for a re-flight.

One of the three live cores (:class:`aircraft.core.AircraftCore`); it integrates nothing between
broadcasts (``lag_s = 0``, :meth:`tick` a no-op): its journal goes out with its broadcasts.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

import numpy as np

from net.clock import broadcast_clock_var_m2
from net.radio import link_var_m2, reception_sigma_m

from .events import AcEstimate, AcEvent, AcTruth
from .journal import AcJournal
from .navigator import receiver as rx
from .world import radio as wradio

class RadioAircraftCore:
    """Sans-I/O radio aircraft: channel layer + estimators. ``on_nav(msg, phy)`` returns messages to publish.

    Pure apart from its own seeded generator; the node and tests drive it with decoded messages.
    """

    lag_s = 0.0  # nothing to integrate behind fleet time
    step_s = 0.1  # the node's inbox wait, s

    def __init__(self, ac, algos, name: str, rng: np.random.Generator,
                 height_m: float | None = None, horizon_s: float = 7200.0, net_clock=None):
        from .world import trajectory

        self.ac = ac  # aircraft.config.AircraftConfig: the world reads ac.world, the navigator gets ac.nav
        self.rng = rng
        w = ac.world
        dt = 1.0 / max(w.rate_hz, 10.0)
        t = np.arange(0.0, horizon_s + dt, dt)
        h = height_m if height_m is not None else w.height_m
        self.track = trajectory.from_config(dict(w.trajectories.get(w.trajectory.get("kind"), {}), **w.trajectory),
                                            t, w.centre_m, h)
        self.net_clock = net_clock  # station 1's oscillator: network time (None: perfect clocks)
        self.bounds = ac.nav.field_bounds  # the deployment plan's plausibility bounds
        record = radio_record(ac.nav, algos)
        self._navigator(record, name, tuple(algos))
        # the navigator's journal (aircraft/journal.py); none without an algorithm
        self.journal = AcJournal(name, record) if algos else None

    def _navigator(self, record: dict, name: str, algos: tuple[str, ...]) -> None:
        """The navigator side: the estimators of ``algos`` configured by the init record."""
        from .navigator.radio.estimator import AircraftEstimator

        self.name = name
        self.algos = tuple(algos)
        self.estimators = {a: AircraftEstimator(a, estimator_config(record)) for a in algos}
        self.seq: Counter[str] = Counter()
        self.stats: Counter[str] = Counter()
        self._pacer = rx.StatusPacer()

    @classmethod
    def from_record(cls, record: dict, name: str, algos: tuple[str, ...]) -> "RadioAircraftCore":
        """The navigator alone (no world, no journal) for a replay of ``ac_input`` entries
        (:func:`aircraft.journal.replay`; :meth:`measurement`)."""
        core = cls.__new__(cls)
        core.journal = None
        core._navigator(record, name, algos)
        return core

    def measure(self, phy: dict, msg: dict | None = None) -> tuple[float, float, np.ndarray, float] | None:
        """Channel layer: (t_rx true, pseudorange, true aircraft position at reception, one-way
        timing sigma in m), or ``None`` where the scenario's ``[radio]`` has no link.

        ``rho = c (t_rx_ac - T_tx)``: ``t_rx_ac`` the receiver clock (network time at the true reception
        plus the seed-001 receiver clock), ``T_tx`` the station's stamped transmit time ``msg.t_tx_s``
        minus its broadcast offset ``msg.clock`` (without ``msg``: the true transmit time); timing
        noise of sigma ``sigma_m`` in quadrature with the link's TOA CRLB (:func:`net.radio.reception_sigma_m`)."""
        p_tx = np.asarray(phy["pos_m"], float)
        t_tx = float(phy["t_true_s"])
        t_rx, p = wradio.heard(lambda t: self.track.at(t)[0], p_tx, t_tx)
        w = self.ac.world
        sigma = reception_sigma_m(p_tx, p, w.radio, w.sigma_m)
        if sigma is None:
            return None
        rho = wradio.pseudorange_m(p, p_tx, t_tx, t_rx, msg, w.clock, self.net_clock) \
            + sigma * float(self.rng.standard_normal())
        return t_rx, rho, p, sigma

    @staticmethod
    def clock_var_m2(msg: dict) -> float:
        """Broadcast clock variance at the transmit time as a range variance, m^2."""
        return broadcast_clock_var_m2(msg)

    def on_nav(self, msg: dict, phy: dict) -> list[AcEvent]:
        """One station nav broadcast -> ``ac_truth`` + one ``ac_estimate`` per algorithm that has one."""
        from .navigator import plausible  # an implausible nav never reaches the channel or a filter

        if plausible.unusable(msg, float(phy["t_true_s"]), self.bounds, self.stats):
            return []
        got = self.measure(phy, msg)
        if got is None:
            self.stats["no_link"] += 1  # [radio]: beyond the horizon or the link budget
            return []
        t_rx, rho, p_true, sigma = got
        # the link's timing variance above the nominal sigma_m, known to the receiver from its SNR,
        # as an isotropic part of the transmitter's covariance: the radio filters weight a range by
        # sigma_m^2 + u^T C u, and u^T (C + s^2 I) u = u^T C u + s^2 (their clock variance feeds the
        # stations' clock-bias states, which are not white)
        st_cov = np.asarray(msg["cov_m2"], float) + link_var_m2(sigma, self.ac.nav.sigma_range_m) * np.eye(3)
        cvar = self.clock_var_m2(msg)
        if not (np.all(np.isfinite(msg["pos_m"])) and math.isfinite(t_rx)):
            self.stats["nav_bad"] += 1
            return []
        self.stats["measurements"] += 1
        self.seq["ac_truth"] += 1
        out: list[AcEvent] = [AcTruth(self.name, self.seq["ac_truth"], t_rx, p_true.tolist(),
                                      self.track.at(t_rx)[1].tolist())]
        if self.journal is not None:
            self.journal.m(t_rx, int(msg["src"]), msg["pos_m"], st_cov, cvar, rho)
        return out + self.measurement(t_rx, int(msg["src"]), msg["pos_m"], st_cov, cvar, rho)

    def measurement(self, t_rx: float, src: int, pos_m, st_cov, cvar: float, rho: float) -> list[AcEvent]:
        """Navigator side: one measured broadcast (a journal ``m`` entry) -> ``ac_estimate`` /
        ``ac_status`` events."""
        out: list[AcEvent] = []
        st_cov = np.asarray(st_cov, float)
        for algo, est in self.estimators.items():
            n = est.n_updates
            est.on_measurement(t_rx, src, pos_m, st_cov, rho, clock_var_m2=cvar)
            e = est.estimate() if est.n_updates != n and est.tracker_or_fix() else None
            state = est.status
            if e is not None and not rx.publishable(e["pos_m"], e["cov_m2"], est.cfg.receiver or rx.DEFAULT_RECEIVER):
                e, state = None, rx.NO_FIX
            out.extend(self._status_events(algo, t_rx, state, est))
            if e is None:
                continue
            self.seq["ac_estimate"] += 1
            out.append(AcEstimate(self.name, self.seq["ac_estimate"], float(e["t_s"]), algo, e["pos_m"],
                                  np.asarray(e["cov_m2"], float).tolist(), int(e["n_updates"]),
                                  vel_m_s=e["vel_m_s"], **integrity_fields(e)))
        return out

    def _status_events(self, algo: str, t_s: float, state: str, est) -> list[AcEvent]:
        """An ``ac_status`` when an algorithm's state changes, and once per second of fleet time: what
        the navigator is doing when it publishes no estimate (docs/aircraft.md "Cold start")."""
        if not self._pacer.due(algo, state, t_s):
            return []
        return [rx.status_event(self.name, self.seq, algo, t_s, state, {**self.stats, **est.stats})]

    def tick(self, t_s: float) -> list[AcEvent]:
        """Nothing to do between broadcasts (the journal goes out with them)."""
        return []

    def status_line(self, t_s: float) -> str:
        """The status line's body at fleet time ``t_s``: true position, measurements, each algorithm's error."""
        p, _ = self.track.at(max(t_s, 0.0))
        parts = []
        for a, est in self.estimators.items():
            e = est.estimate()
            if e is None:
                parts.append(f"{a}=init")
            else:
                pt, _ = self.track.at(e["t_s"])
                parts.append(f"{a}={np.linalg.norm(np.asarray(e['pos_m']) - pt):.1f}m")
        return f"pos=({p[0]:.0f},{p[1]:.0f},{p[2]:.0f}) meas={self.stats['measurements']} err {' '.join(parts)}"

    def summary(self) -> dict[str, Any]:
        """Measurements and each algorithm's last estimate against the truth (the process's report)."""
        out: dict[str, Any] = {"measurements": int(self.stats["measurements"]), "estimates": {}}
        for a, est in self.estimators.items():
            e = est.estimate()
            if e is not None:
                pt, _ = self.track.at(e["t_s"])
                out["estimates"][a] = {"t_s": e["t_s"], "err_m": float(np.linalg.norm(np.asarray(e["pos_m"]) - pt)),
                                       "n_updates": e["n_updates"], **({"excluded": e["excluded"]}
                                                                       if e.get("excluded") else {})}
        return out



def radio_record(nav, algos) -> dict:
    """The radio navigator's init record (``ac_init``) from its configuration ``nav``
    (:class:`aircraft.config.NavigatorConfig`): the algorithms, the filter tuning and the start's wide
    prior. Every aircraft journal carries the tuning, so the radio filters can re-run on any
    aircraft's measurements."""
    from dataclasses import asdict

    return {"kind": "radio", "algos": list(algos), "tuning": asdict(nav.tuning),
            "init_sigma_m": None if not nav.init_sigma_m else float(nav.init_sigma_m)}


def estimator_config(record: dict):
    """The :class:`aircraft.navigator.radio.estimator.EstimatorConfig` of an init record. The filters start from the
    broadcasts alone (aircraft/navigator/radio/initializer.py), never from the truth or the scenario's station
    positions; ``init_sigma_m`` only widens the wide prior."""
    from .navigator.radio.estimator import EstimatorConfig, Tuning
    from .navigator.radio.initializer import InitConfig

    s = record.get("init_sigma_m")
    init = InitConfig() if not s else InitConfig(wide_sigma_m=max(InitConfig.wide_sigma_m, float(s)))
    return EstimatorConfig(tuning=Tuning(**record["tuning"]), init=init)


def integrity_fields(e: dict) -> dict:
    """The optional ``ac_estimate`` integrity fields of an estimate: ``hpl_m``, ``vpl_m`` (finite only),
    ``excluded`` (station ids)."""
    out = {k: float(e[k]) for k in ("hpl_m", "vpl_m") if e.get(k) is not None and math.isfinite(e[k])}
    if e.get("excluded") is not None:
        out["excluded"] = [int(i) for i in e["excluded"]]
    return out
