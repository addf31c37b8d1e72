"""Sans-I/O station core: TDMA slot timing, peer rotation, ranging protocol, slot claim on join,
measurement bookkeeping and the self-survey estimator.

The core owns no socket, clock or RNG. A shell (the in-process simulator or the Zenoh node) drives it:

* ``next_deadline()`` -> the local time at which the core wants ``on_timer`` to be called;
* ``on_timer(t_local_s)`` -> outgoing messages (a range request at the start of the own slot,
  the nav broadcast at a fixed offset inside the slot, slot claims while joining);
* ``on_message(msg, t_rx_local_s)`` -> outgoing messages (the answer to a request addressed to us,
  the nav broadcast after our own exchange) - ``t_rx_local_s`` is the reception time on the
  station's own clock, as radio hardware would timestamp it.

Outgoing air messages carry ``t_tx_s``: the local time at which the radio transmits them (the
shell stamps the physical part from it). ``estimate`` messages are for monitoring only.

Timeline of the own slot (offsets from the slot start, local clock)::

    0            range_req to the addressee of this cycle
    ~turnaround  range_rsp arrives (addressee's estimate + its measured turnaround)
    nav_offset   nav broadcast: own estimate, the ranges measured since the last nav, members
    slot end     a reply not heard by then is lost

Protocol v2 (``ranging="poll"``, issue 31, docs/protocol.md "Protocol v2")::

    0                      poll: the member list, in order (the poller stamps T1)
    o_k = turnaround + k S member k replies (its T2_k: poll heard, T3_k = T2_k + o_k: reply sent)
    o_N                    nav = the final: the poller's T1, T5 (its ``t_tx_s``) and its stamp T4_k of
                           every reply heard in its sub-slot, and the ranges / time transfers it formed

The poller forms each range single-sided (T1..T4, frequencies from the clock filter: it lacks T6_k),
member ``k`` the asymmetric double-sided one from its own T2, T3, T6 and the final's T1, T4_k, T5
(``stations/dstwr.py``) and the time transfer (V7) from T1..T4; listeners take the nav's entries.

Joining (``join=True``): listen for ``listen_cycles`` cycles, collecting the slots in use from the
nav broadcasts heard; claim the default slot (``id - 1``) if free, else the first free slot after it.
Two newcomers claiming the same slot both hear each other's nav in that slot: the lower id keeps it,
the higher id listens again and claims another one.

Distributed slot assignment (``slot_assignment="distributed"``, docs/slots.md): instead of the above,
every station (founders too) drives a :class:`stations.slots.SlotCore` at each cycle end on network
time (an extra deadline) with the navs heard cleanly in that cycle (sender, slot, claim cycle, its
``slots`` summary) and the slots its radio heard collide (:meth:`StationCore.on_garbage`, journalled
as ``["g", t]``); it listens for the first whole cycle, then transmits request and nav in
``SlotCore.slot`` and is silent while it holds none (or listens in its own slot). The choices draw on
the stream ``(slot_seed, id, net.streams.SLOTS)``.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtri  # chi-square inverse survival (scipy.stats costs ~0.5 s of start-up)

from nav.geometry import SPEED_OF_LIGHT_M_S
from nav.kalman import nees
from net import streams
from net.messages import MessageError, slot_summary
from net.radio import radio_from_dict, range_var_m2

from .admission import Admission, Bounds
from .clocksync import ClockEstimator, ClockModel
from .estimators import SurveyEstimator, make_estimator
from .integrity import StationIntegrity
from .dstwr import ds_twr_range_m, in_reply_window, reply_offset_s, sym_twr_range_m, time_transfer_s
from .slots import FREE, Heard, SlotConfig, SlotCore, SlotSummary
from .tdma import TdmaPlan

EXCHANGE_LOG = 4096  # own exchanges kept for the report (about an hour at a 1 s cycle)


@dataclass
class StationConfig:
    id: int
    tdma: TdmaPlan = field(default_factory=TdmaPlan)
    sigma_d_m: float = 0.5
    estimator: str = "dmap"
    ranges_per_update: int = 3
    known_ids: tuple[int, ...] = ()
    join: bool = False
    turnaround_s: float = 0.001
    nav_offset_s: float = 0.005
    listen_cycles: int = 1
    dead_after_cycles: int = 5
    max_range_m: float = 1e6
    # oscillator class (data sheet, not the realized clock): prior and noise of the clock estimator
    clock_offset_sigma_s: float = 0.0
    clock_freq_sigma: float = 0.0
    clock_q_wf_s: float = 0.0
    clock_q_rw_per_s: float = 0.0
    # plausibility bounds (stations/admission.py): the field's extent (largest distance of a station
    # from station 1; 0 = unknown, then max_range_m) plus a margin; the peer bound (0 = one per slot)
    field_radius_m: float = 0.0
    field_margin_m: float = 1000.0
    max_peers: int = 0
    # the frame datum carried by the field (docs/architecture.md, "The frame datum"): a station is
    # converged when its horizontal sigma is at most datum_converged_m (0: sigma_d / 2) after at least
    # datum_min_updates own navs (45: 45 cycles, after the survey's 40 s bar); a founder
    # hands the frame to the field once it hears datum_quorum converged stations free in x, y, z;
    # datum_damping_m: sigma of the prior on a founder's coordinates freed at the hand-over (at the
    # frame's values; DistributedMap.hold_datum); datum_converged_m < 0: never
    datum_converged_m: float = 0.0
    datum_min_updates: int = 45
    datum_quorum: int = 4
    datum_convention: bool = False  # keep the founders' convention while they are all heard (docs)
    datum_damping_m: float = 1.0
    # the scenario's [radio] in the network frame (net.radio.radio_dict): the survey, the integrity
    # tests and the clock filter weight each link by its SNR's timing noise; None: sigma_d everywhere
    radio: dict | None = None
    # the slot plan ([tdma] assignment, docs/slots.md): "fixed" (slot id - 1, the old default) or
    # "distributed" (stations/slots.py: a slot free in the two-hop view, among the first cycle_slots
    # slots of the cycle, chosen with the stream (slot_seed, id, streams.SLOTS))
    slot_assignment: str = "fixed"
    cycle_slots: int = 0
    slot_seed: int = 0
    # the ranging exchange ([tdma] ranging, docs/protocol.md): "addressed" (one range_req per slot) or
    # "poll" (protocol v2: one poll, every member replies turnaround_s + k reply_spacing_s after it;
    # guard_s widens each reply's sub-slot window, rule V2)
    ranging: str = "addressed"
    reply_spacing_s: float = 0.0005
    guard_s: float = 0.0001


SLOT_KEYS = ("slot_assignment", "cycle_slots", "slot_seed")  # in the init record only when distributed
POLL_KEYS = ("ranging", "reply_spacing_s", "guard_s")  # in the init record only with the poll
HEARD_CYCLES = 3  # cycles of receptions kept for the slot assignment's cycle ends (late timers)


class StationCore:
    """One station's protocol state machine (see module docstring)."""

    def __init__(self, cfg: StationConfig, init_pos_m: np.ndarray | None, init_cov_m2: np.ndarray | None,
                 start_s: float = 0.0, journal: bool = False):
        self.cfg = cfg
        # input journal: everything the core consumed, in order, for bit-exact offline replay
        self.journal = journal
        self._inputs: list[list] = []
        self.init_record = {
            "cfg": {k: (list(v) if isinstance(v, tuple) else v) for k, v in cfg.__dict__.items()
                    if k != "tdma" and (k not in SLOT_KEYS or cfg.slot_assignment != "fixed")
                    and (k not in POLL_KEYS or cfg.ranging != "addressed")},
            "tdma": [cfg.tdma.cycle_s, cfg.tdma.slot_s],
            "init_pos_m": None if init_pos_m is None else np.asarray(init_pos_m, float).tolist(),
            "init_cov_m2": None if init_cov_m2 is None else np.asarray(init_cov_m2, float).tolist(),
            "start_s": float(start_s),
        }
        self.id = cfg.id
        self.plan = cfg.tdma
        # a station 1-3 started with the field holds the frame until the field carries it; one that
        # joins a running field (a restarted founder included) is an ordinary station
        self.radio = radio_from_dict(cfg.radio)
        self.est: SurveyEstimator = make_estimator(cfg.estimator, cfg.id, init_pos_m, init_cov_m2,
                                                   cfg.sigma_d_m, cfg.ranges_per_update, founder=not cfg.join,
                                                   radio=self.radio,
                                                   **(dict(peer_corr_est=POLL_PEER_CORR_EST, clean_after_n=POLL_CLEAN_AFTER_N,
                                                           range_var_factor=POLL_RANGE_VAR_FACTOR)
                                                      if cfg.ranging == "poll" else {}))
        self.clk = ClockEstimator(cfg.id, ClockModel(cfg.clock_q_wf_s, cfg.clock_q_rw_per_s, cfg.clock_offset_sigma_s,
                                                     cfg.clock_freq_sigma), start_s, cfg.sigma_d_m)
        self.peers: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # peer -> its latest broadcast (pos_m, cov_m2)
        # the frame datum (docs/architecture.md): each carrier's reference position (its broadcast
        # position in its first nav as a carrier), ours included; the last datum correction (3,)
        self.datum_ref: dict[int, np.ndarray] = {}
        self.datum_shift_m = np.zeros(3)
        self.frame_released = False  # no member broadcasts a frame constraint any more
        self.field_datum = False  # a founder was missed since: the references are frozen
        self.integrity = StationIntegrity(cfg.id, cfg.sigma_d_m, radio=self.radio)  # peer consistency tests (issue 14)
        # own estimates at the last navs, (t_s, pos_m, cov_m2): what an exclusion rolls the solve back to
        self._pos_hist: deque[tuple[float, np.ndarray, np.ndarray]] = deque(maxlen=ROLLBACK_KEEP)
        # the peers' broadcasts at the last navs, peer -> (t_s, pos_m, cov_m2): the solve holds them at
        # the roll-back time until ``_hold_until_s``
        self._peer_hist: dict[int, deque] = {}
        self._hold_from_s = self._hold_until_s = -math.inf
        self.known: dict[int, float] = {p: start_s for p in cfg.known_ids if p != cfg.id}
        self._power_on_s = float(start_s)
        self.seq = {"range_req": 0, "range_rsp": 0, "nav": 0, "estimate": 0, "poll": 0, "reply": 0}
        self.pending: dict[int, tuple[int, float, float]] = {}  # req seq -> (dst, t_tx, slot end)
        # our own exchanges, newest last: [t_tx_s, addressee, replied in time] (reports, tests)
        self.exchanges: deque[list] = deque(maxlen=EXCHANGE_LOG)
        self._exchange_of: dict[int, list] = {}
        self.ranges_out: list[list] = []
        # protocol v2: our averaged ranges (V4b) of the polls we answered since our last nav,
        # [poller, range_m, poll seq] (the nav's ``closed``); our own polls' exchanges awaiting the
        # member's V4b, (member, poll seq) -> the single-sided range the survey and the integrity test
        # took meanwhile (None: none)
        self.closed_out: list[list] = []
        self._ss_open: dict[tuple[int, int], tuple[float | None, float | None]] = {}
        self.counters = {"requests": 0, "responses": 0, "lost": 0, "ranges_in": 0, "ignored": 0,
                         "rejected_ranges": 0, "late": 0, "sync_in": 0, "implausible": 0}
        # protocol v2: our open poll {seq, t1, index: member -> k, rx: member -> T4, entries}; the polls
        # we answered, poller -> {poll seq: (T2, T3, k, N)} (the latest POLLED_KEEP per poller: a process
        # may hear a poller's next poll before its final); the longest path a reply travels (window V2)
        self.poll = cfg.ranging == "poll"
        self._poll_out: dict | None = None
        self._polled: dict[int, dict[int, tuple[float, float, int, int]]] = {}
        self._path_m = min(cfg.max_range_m, 2.0 * cfg.field_radius_m) if cfg.field_radius_m > 0 else cfg.max_range_m
        if self.poll:
            self.counters.update(reply_window=0, final_window=0, final_lost=0, polls_answered=0, ss_gated=0,
                                 closed_in=0)
        # plausibility before trust: senders, ids, values and slot claims (stations/admission.py)
        self.slots: SlotCore | None = None  # the distributed assignment (None: the fixed plan)
        peer_bound = self.plan.slots_per_cycle + 1
        if cfg.slot_assignment == "distributed":
            C = cfg.cycle_slots or self.plan.slots_per_cycle
            self.slots = SlotCore(cfg.id, SlotConfig(C, listen_cycles=cfg.listen_cycles),
                                  streams.rng(cfg.slot_seed, cfg.id, streams.SLOTS))
            # stations outnumber the slots: the deployment's ids and as many newcomers as a slot table holds
            peer_bound = len(self.known) + 1 + self.slots.cfg.max_peers
        self.admission = Admission(Bounds.of(cfg), self.plan.cycle_s, cfg.max_peers or peer_bound)
        self.admission.ids.update([cfg.id, *self.known])
        # receptions per cycle for the slot assignment: cycle -> (sender -> Heard), garbage slots
        self._rx_heard: dict[int, dict[int, Heard]] = {}
        self._rx_garbage: dict[int, set[int]] = {}
        self._tick_T = float("inf")  # network time of the next cycle end the slot assignment acts on
        self._first_cycle = 0
        if self.slots is not None:
            self.state = "joining" if cfg.join else ("frame" if cfg.id == 1 else "surveying")
            self.slot = None  # listen first, then pick (stations/slots.py)
            self.listen_until_s = float("inf")
            self.heard_slots = {}
            T = self.clk.network_time(start_s)
            c0, _ = self.plan.locate(max(T, 0.0))
            # a cycle heard in part is not listened to: the first cycle the assignment acts on is whole
            self._first_cycle = c0 if abs(T - c0 * self.plan.cycle_s) < 1e-9 else c0 + 1
            self._tick_T = (self._first_cycle + 1) * self.plan.cycle_s
        elif cfg.join:
            self.state = "joining"
            self.slot: int | None = None
            self.listen_until_s = start_s + cfg.listen_cycles * self.plan.cycle_s
            self.heard_slots: dict[int, int] = {}
        else:
            self.state = "frame" if cfg.id == 1 else "surveying"
            self.slot = self.plan.default_slot(cfg.id)
            self.listen_until_s = start_s
            self.heard_slots = {}
        self._next_req_T, self._nav_s = self._schedule_after(start_s)

    # ------------------------------------------------------------------ timing
    def _schedule_after(self, t_s: float) -> tuple[float, float]:
        """Network time of the next own slot start after local time ``t_s``; the nav timer (off)."""
        if self.slot is None:
            return float("inf"), float("inf")
        cycle, t0 = self.plan.next_slot_start(self.slot, self.clk.network_time(t_s) - 1e-9)
        return t0, float("inf")

    @property
    def _next_req_s(self) -> float:
        """Local time of the next own slot start: slots live on (estimated) network time."""
        T = self._next_req_T
        return self.clk.local_time(T) if math.isfinite(T) else T

    def next_request_s(self) -> float | None:
        """Local time of the next range request (the own slot start), None without a slot."""
        t = self._next_req_s
        return t if math.isfinite(t) else None

    def network_time(self, t_s: float) -> float:
        """Estimated network time (station 1's clock) at local time ``t_s``."""
        return self.clk.network_time(t_s)

    def awaiting(self) -> int:
        """Replies still expected by our open exchange: the addressed request's (``pending``) or the
        members of our poll not heard yet that have transmitted since our power-on (protocol v2: a
        member answers only once it has transmitted in its slot, so one never heard from - a
        scenario's station at power-on - is not waited for). The Zenoh node holds the own nav's timer for them (a bounded wait,
        ``--lookahead``), as the simulator delivers in emulated-time order; the results do not depend
        on it (only when the final leaves in wall time)."""
        po = self._poll_out
        if po is None:
            return len(self.pending)
        t0 = self._power_on_s
        return len(self.pending) + sum(1 for p in po["index"]
                                       if p not in po["rx"] and (p in self.peers or self.known.get(p, t0) > t0))

    def next_deadline(self) -> float | None:
        """Local time of the next ``on_timer`` call the core needs."""
        times = [self._next_req_s, self._nav_s]
        if self.slots is not None:
            times.append(self.clk.local_time(self._tick_T))
        elif self.state == "joining" and self.slot is None:
            times.append(self.listen_until_s)
        t = min(times)
        return None if not math.isfinite(t) else t

    # ------------------------------------------------------------------ peers
    def members(self, t_s: float) -> list[int]:
        """Peers in the rotation: heard (or known at deployment) within ``dead_after_cycles``."""
        horizon = self.cfg.dead_after_cycles * self.plan.cycle_s
        return sorted(p for p, t in self.known.items() if t_s - t <= horizon and p != self.id)

    def _heard(self, pid: int, t_s: float) -> None:
        if pid != self.id:
            self.known[pid] = max(self.known.get(pid, -np.inf), t_s)

    # ------------------------------------------------------------------ outputs
    def _base(self, kind: str, t_s: float) -> dict:
        self.seq[kind] += 1
        return {"kind": kind, "src": self.id, "seq": self.seq[kind], "stamp_s": float(t_s)}

    def estimate_msg(self, t_s: float) -> dict:
        m = self._base("estimate", t_s)
        m.update(t_s=float(t_s), pos_m=self.est.pos_m.tolist(), cov_m2=self.est.cov_m2.tolist(),
                 n_updates=int(self.est.n_updates), estimator=self.est.name, state=self.state)
        c = self.clk.correction(t_s)
        m.update(clock_offset_s=c[1], clock_freq=c[2], clock_offset_sd_s=float(np.sqrt(c[3])),
                 clock_freq_sd=float(np.sqrt(c[5])))
        return m

    def _nav_msg(self, t_s: float) -> dict:
        m = self._base("nav", t_s)
        cycle, slot = self.plan.locate(max(self.clk.network_time(t_s), 0.0))
        m.update(cycle=cycle, slot=self.slot if self.slot is not None else slot, t_tx_s=float(t_s),
                 pos_m=self.est.pos_m.tolist(), cov_m2=self.est.cov_m2.tolist(),
                 n_updates=int(self.est.n_updates), state=self.state,
                 ranges=self.ranges_out, members=self.members(t_s), clock=self.clk.correction(t_s))
        if self.slots is not None:
            m["slots"] = self._slots_field()
        own = self.integrity.own_excluded
        if own:  # the quorum's input at the other stations (stations/integrity.py)
            m["excluded"] = sorted(own)
        po = self._poll_out
        if po is not None:  # the final of our poll: T1 and our stamp T4_k of each reply heard in time
            m["poll"] = {"seq": po["seq"], "t1": po["t1"], "rx": [[p, t4] for p, t4 in po["rx"].items()]}
            self.counters["lost"] += len(po["index"]) - len(po["rx"])
            self._poll_out = None
        if self.closed_out:  # our V4b of the polls we answered: the pollers' range of their exchange
            m["closed"] = self.closed_out
            self.closed_out = []
        self.ranges_out = []
        return m

    # ------------------------------------------------------------------ events
    def take_inputs(self) -> list[list]:
        """Journal entries since the last call: ``["t", t_local_s]`` or ``["m", t_rx_local_s, msg]``."""
        out, self._inputs = self._inputs, []
        return out

    @classmethod
    def from_init_record(cls, rec: dict) -> "StationCore":
        """Rebuild a core from its ``init_record`` (offline replay)."""
        cfg = dict(rec["cfg"])
        cfg["known_ids"] = tuple(cfg.get("known_ids", ()))
        cfg["tdma"] = TdmaPlan(*rec["tdma"])
        pos = None if rec["init_pos_m"] is None else np.asarray(rec["init_pos_m"], float)
        cov = None if rec["init_cov_m2"] is None else np.asarray(rec["init_cov_m2"], float)
        return cls(StationConfig(**cfg), pos, cov, start_s=rec["start_s"])

    def replay(self, inputs: list[list]) -> list[dict]:
        """Feed journal entries; returns every output in order."""
        out: list[dict] = []
        for e in inputs:
            if e[0] == "g":
                self.on_garbage(e[1])
            else:
                out += self.on_timer(e[1]) if e[0] == "t" else self.on_message(e[2], e[1])
        return out

    # ------------------------------------------------------------------ distributed slot assignment
    def _slots_field(self) -> dict:
        """The nav's ``slots``: the cycle's slot count, our claim cycle and our one-hop view of the
        last cycle (the non-free slots: [slot, state, owner, since]; net.messages.slot_summary)."""
        sc = self.slots
        s = sc.summary()
        ent = [] if s is None else [[int(k), int(s.state[k]), int(s.owner[k]), int(s.since[k])]
                                    for k in np.flatnonzero(s.state != FREE)]
        return {"n": sc.cfg.cycle_slots, "claim": int(sc.since) if sc.slot is not None else -1, "v": ent}

    def _summary_of(self, field: dict | None) -> tuple[int | None, SlotSummary | None]:
        """A nav's ``slots`` as (claim cycle, :class:`SlotSummary`): checked (hostile values: counted,
        ignored), None for a summary of another cycle size."""
        if field is None:
            return None, None
        try:
            f = slot_summary(field, "slots")
        except MessageError:
            self.counters["implausible"] += 1
            return None, None
        C = self.slots.cfg.cycle_slots
        if f["n"] != C:
            return f["claim"], None
        state, owner, since = np.zeros(C, np.int8), np.zeros(C, np.int64), np.full(C, -1, np.int64)
        for k, st, own, sn in f["v"]:
            state[k], owner[k], since[k] = st, own, sn
        return f["claim"], SlotSummary(state=state, owner=owner, since=since)

    def _slot_heard(self, msg: dict, t_rx_s: float) -> None:
        """A nav heard cleanly in its slot: kept for the end of the cycle it was heard in."""
        slot = msg.get("slot")
        if type(slot) is not int or not 0 <= slot < self.slots.cfg.cycle_slots:
            return
        cycle, _ = self.plan.locate(max(self.clk.network_time(t_rx_s), 0.0))
        claim, summary = self._summary_of(msg.get("slots"))
        buf = self._rx_heard.setdefault(cycle, {})
        if msg["src"] in buf or len(buf) < self.slots.cfg.max_peers:
            buf[msg["src"]] = Heard(msg["src"], slot, msg.get("cycle", cycle) if claim is None else claim, summary)
        self._trim_rx(cycle)

    def on_garbage(self, t_rx_s: float) -> None:
        """The radio heard energy and decoded nothing (two senders in one slot) at local ``t_rx_s``:
        the slot it falls in is garbage for this cycle (distributed assignment only)."""
        if self.journal:
            self._inputs.append(["g", float(t_rx_s)])
        if self.slots is None:
            return
        cycle, slot = self.plan.locate(max(self.clk.network_time(t_rx_s), 0.0))
        if slot < self.slots.cfg.cycle_slots:
            self._rx_garbage.setdefault(cycle, set()).add(slot)
            self._trim_rx(cycle)

    def _trim_rx(self, cycle: int) -> None:
        for buf in (self._rx_heard, self._rx_garbage):
            for c in [c for c in buf if c < cycle - HEARD_CYCLES]:
                del buf[c]

    def _cycle_ends(self, t_s: float) -> None:
        """Every cycle end due by local ``t_s``. A jump of our network-time estimate (a first sync)
        moves the next one to the cycle we are now in instead of replaying the cycles jumped over."""
        cyc = self.plan.cycle_s
        T_now = self.clk.network_time(t_s)
        if not -2.0 * cyc < self._tick_T - T_now < (HEARD_CYCLES + 1) * cyc:
            self._tick_T = (math.floor(T_now / cyc + 1e-9) + 1) * cyc
            self._next_req_T = float("inf") if self.slot is None else self._schedule_after(t_s)[0]
        while t_s >= self.clk.local_time(self._tick_T) - 1e-12:
            self._cycle_end()

    def _cycle_end(self) -> None:
        """End of a cycle on network time: the slot assignment takes what was heard in it, and the
        slot of the next cycle (None: silent, listening or none free) is scheduled."""
        T = self._tick_T
        cycle = int(round(T / self.plan.cycle_s)) - 1
        self._tick_T = T + self.plan.cycle_s
        if cycle < self._first_cycle:
            return
        heard = list(self._rx_heard.pop(cycle, {}).values())
        garbage = sorted(self._rx_garbage.pop(cycle, set()))
        self._trim_rx(cycle + 1)
        new = self.slots.on_cycle(cycle, heard, garbage)
        self.slot = None if self.slots.listening else new
        self._next_req_T = self.plan.slot_start_s(cycle + 1, self.slot) if self.slot is not None else float("inf")
        self._refresh_state()

    def on_timer(self, t_s: float) -> list[dict]:
        if self.journal:
            self._inputs.append(["t", float(t_s)])
        out: list[dict] = []
        if self.slots is not None:
            self._cycle_ends(t_s)
        if self.slots is None and self.state == "joining" and self.slot is None and t_s >= self.listen_until_s - 1e-12:
            self._claim_slot(t_s)
        if t_s >= self._nav_s - 1e-12:
            # the poll's final leaves at its sub-slot however late the host (its T5: its own stamp)
            t_nav = self._nav_s if self._poll_out is not None else t_s
            self._nav_s = float("inf")
            if self._hold_until_s != -math.inf and t_s >= self._hold_until_s:
                self._release_peers()
            out += self._integrity(t_s)
            self._converged_weights()
            self.est.refresh()
            self._pos_hist.append((float(t_s), self.est.pos_m.copy(), self.est.cov_m2.copy()))
            self._datum(t_s)
            self._hold_frame(t_s)
            self._refresh_state()
            out.append(self._nav_msg(t_nav))
            out.append(self.estimate_msg(t_s))
        if t_s >= self._next_req_s - 1e-9:
            t0 = self._next_req_s  # the radio transmits at the slot start, however late the host
            T0 = self._next_req_T
            cycle, _ = self.plan.locate(T0 + 1e-9)
            mem = self.members(t0)
            if self.poll:
                out += self._send_poll(t0, cycle, mem)
            elif mem:
                # the addressee rotates over the members from cycle to cycle
                dst = mem[(cycle + self.id) % len(mem)]
                m = self._base("range_req", t0)
                m.update(dst=dst, cycle=cycle, slot=self.slot, t_tx_s=float(t0))
                self.pending[m["seq"]] = (dst, t0, t0 + self.plan.slot_s)
                self._exchange_of[m["seq"]] = entry = [float(t0), int(dst), False]
                self.exchanges.append(entry)
                self.counters["requests"] += 1
                out.append(m)
            if self._poll_out is None:
                self._nav_s = t0 + self.cfg.nav_offset_s
            self._next_req_T = self.plan.slot_start_s(cycle + 1, self.slot)
            if self._next_req_s <= t0:  # the network-time estimate jumped ahead: next cycle's slot
                self._next_req_T, _ = self._schedule_after(t0)
            if self.slots is not None and self._next_req_T >= self._tick_T:
                self._next_req_T = float("inf")  # the next cycle's slot: set at this cycle's end
            # forget requests whose slot is over
            for s in [s for s, (_, _, end) in self.pending.items() if end < t0]:
                del self.pending[s]
                self._exchange_of.pop(s, None)
                self.counters["lost"] += 1
        return out

    def _send_poll(self, t0: float, cycle: int, mem: list[int]) -> list[dict]:
        """Protocol v2: the poll at the slot start ``t0`` (T1) naming the members in order; the final
        (our nav) is due in sub-slot N, ``turnaround_s + N reply_spacing_s`` later (rule V1)."""
        if self._poll_out is not None:  # a poll whose final never left (a slot collision): its replies lost
            self.counters["lost"] += len(self._poll_out["index"]) - len(self._poll_out["rx"])
            self._poll_out = None
        if not mem:
            return []
        m = self._base("poll", t0)
        m.update(cycle=cycle, slot=self.slot, t_tx_s=float(t0), members=list(mem))
        for key in [key for key in self._ss_open if key[1] <= m["seq"] - POLLED_KEEP - 1]:  # V4b never came
            del self._ss_open[key]
        self._poll_out = {"seq": m["seq"], "t1": float(t0), "index": {p: k for k, p in enumerate(mem)}, "rx": {},
                          "entries": {}}
        for p in mem:
            self._exchange_of[p] = entry = [float(t0), int(p), False]
            self.exchanges.append(entry)
        self.counters["requests"] += len(mem)
        self._nav_s = float(t0) + float(reply_offset_s(len(mem), self.cfg.turnaround_s, self.cfg.reply_spacing_s))
        return [m]

    def _claim_slot(self, t_s: float) -> None:
        used = set(self.heard_slots.values())
        n = self.plan.slots_per_cycle
        pref = self.plan.default_slot(self.id)
        for k in range(n):
            s = (pref + k) % n
            if s not in used:
                self.slot = s
                break
        else:
            self.listen_until_s = t_s + self.plan.cycle_s  # no free slot: keep listening
            return
        self._next_req_T, _ = self._schedule_after(t_s)
        self._refresh_state()

    def on_message(self, msg: dict, t_rx_s: float) -> list[dict]:
        """A received air message at local time ``t_rx_s`` (phy stripped); returns the replies."""
        if self.journal:
            self._inputs.append(["m", float(t_rx_s), msg])
        if msg.get("src") == self.id:
            return []
        handler = self._HANDLERS.get(msg.get("kind"))
        if handler is None or not self._admit(msg, t_rx_s):
            return []
        return handler(self, msg, t_rx_s)

    def _admit(self, msg: dict, t_rx_s: float) -> bool:
        """Plausibility before trust: the sender within the peer bound, the message's values within
        the field's physical bounds (``stations/admission.py``); else dropped and counted."""
        adm = self.admission
        if not adm.admit_sender(msg["src"]):
            self.counters["implausible"] += 1
            return False
        why = adm.station_fields(msg, t_rx_s)
        if why is not None:
            adm.drop(why)
            self.counters["implausible"] += 1
            return False
        return True

    def _transfer_var_s2(self, a: int, b: int) -> float | None:
        """Noise variance of a two-way time transfer between stations ``a`` and ``b`` under ``[radio]``:
        their link's range variance over ``c^2`` (both are half the sum of the two legs' timing errors)
        at the estimated geometry (ours, the peers' broadcasts); None without ``[radio]`` or while a
        position is unknown (the clock filter then takes ``(sigma_d / c)^2``)."""
        if self.radio is None:
            return None
        pos = [self.est.pos_m if s == self.id else self.peers.get(s, (None,))[0] for s in (a, b)]
        if pos[0] is None or pos[1] is None:
            return None
        return float(range_var_m2(pos[0], pos[1], self.radio, self.cfg.sigma_d_m)) / SPEED_OF_LIGHT_M_S**2

    def _plausible_entry(self, src: int, r: list, t_tx_s: float, t_rx_s: float) -> bool:
        """A nav's range entry: its values within bounds, its peer id admitted (counted if not)."""
        why = self.admission.range_entry(r, t_tx_s)
        if why is not None:
            self.admission.drop(why)
        elif self.admission.admit_named(src, r[0], t_rx_s):
            return True
        self.counters["implausible"] += 1
        return False

    def _on_range_req(self, msg: dict, t_rx_s: float) -> list[dict]:
        """A range request: answered after the turnaround if it is for us and still in its slot."""
        src = msg.get("src")
        self._heard(src, t_rx_s)
        if msg.get("dst") != self.id:
            return []
        t_tx = t_rx_s + self.cfg.turnaround_s
        if not self._in_slot(msg, t_tx):
            self.counters["late"] += 1
            return []
        m = self._base("range_rsp", t_tx)
        m.update(dst=src, req_seq=msg["seq"], turnaround_s=float(self.cfg.turnaround_s), t_tx_s=float(t_tx),
                 t_rx_s=float(t_rx_s), pos_m=self.est.pos_m.tolist(), cov_m2=self.est.cov_m2.tolist(),
                 n_updates=int(self.est.n_updates), state=self.state, clock=self.clk.correction(t_rx_s))
        return [m]

    def _on_range_rsp(self, msg: dict, t_rx_s: float) -> list[dict]:
        """The reply to our request: a two-way range and a two-way time transfer."""
        src = msg.get("src")
        self._heard(src, t_rx_s)
        if msg.get("dst") != self.id:
            return []
        pend = self.pending.pop(msg.get("req_seq"), None)
        done = self._exchange_of.pop(msg.get("req_seq"), None) if pend is not None else None
        if pend is None or pend[0] != src or t_rx_s > pend[2]:
            self.counters["ignored"] += 1
            return []
        _, t_tx, _ = pend
        if done is not None:
            done[2] = True
        t3 = msg.get("t_tx_s")
        t2 = None if t3 is None else msg.get("t_rx_s", t3 - msg["turnaround_s"])
        return self._own_exchange(src, msg, t_tx, t2, t3, msg["turnaround_s"], t_rx_s)

    def _on_poll(self, msg: dict, t_rx_s: float) -> list[dict]:
        """Protocol v2: a poll naming us answers in our sub-slot ``T3 = T2 + o_k`` (rule V1), if we hold
        a slot and have announced ourselves by transmitting in it (our poll, or our nav: in emulated time
        the final follows the poll within our own slot, so the two are one rule; in wall time a final
        held for its replies would otherwise make us ignore the next slot's poll) and the reply still
        falls in the poll's slot."""
        src = msg["src"]
        self._heard(src, t_rx_s)
        mem = msg["members"]
        if not self.poll or self.id not in mem:
            return []
        if self.slot is None or self.seq["nav"] + self.seq["poll"] == 0:
            self.counters["ignored"] += 1
            return []
        k = mem.index(self.id)
        t3 = float(t_rx_s) + float(reply_offset_s(k, self.cfg.turnaround_s, self.cfg.reply_spacing_s))
        if not self._in_slot(msg, t3):
            self.counters["late"] += 1
            return []
        answered = self._polled.setdefault(src, {})
        answered[msg["seq"]] = (float(t_rx_s), t3, k, len(mem))
        if len(answered) > POLLED_KEEP:  # the oldest one's final never came
            del answered[min(answered)]
            self.counters["final_lost"] += 1
        self.counters["polls_answered"] += 1
        m = self._base("reply", t3)
        m.update(dst=src, poll_seq=msg["seq"], t_rx_s=float(t_rx_s), t_tx_s=t3, pos_m=self.est.pos_m.tolist(),
                 cov_m2=self.est.cov_m2.tolist(), n_updates=int(self.est.n_updates), state=self.state,
                 clock=self.clk.correction(t_rx_s))
        return [m]

    def _on_reply(self, msg: dict, t_rx_s: float) -> list[dict]:
        """Protocol v2: a member's reply to our open poll (T4 = ``t_rx_s``), taken only inside its own
        sub-slot window (rule V2; else dropped and counted ``reply_window``): the single-sided range
        and the time transfer, as for an addressed reply, with the reply delay ``Db = T3 - T2``."""
        src = msg["src"]
        self._heard(src, t_rx_s)
        po = self._poll_out
        if msg["dst"] != self.id:
            return []
        if po is None or msg["poll_seq"] != po["seq"] or src not in po["index"] or src in po["rx"]:
            self.counters["ignored"] += 1
            return []
        c = self.cfg
        if not in_reply_window(po["t1"], t_rx_s, po["index"][src], c.turnaround_s, c.reply_spacing_s,
                               self._path_m, c.guard_s):
            self.counters["reply_window"] += 1
            return []
        po["rx"][src] = float(t_rx_s)
        done = self._exchange_of.pop(src, None)
        if done is not None:
            done[2] = True
        t2, t3 = msg["t_rx_s"], msg["t_tx_s"]
        return self._own_exchange(src, msg, po["t1"], t2, t3, t3 - t2, t_rx_s)

    def _own_exchange(self, src: int, msg: dict, t_tx: float, t2: float | None, t3: float | None,
                      delay_s: float, t_rx_s: float) -> list[dict]:
        """An exchange we initiated (request / poll sent at local ``t_tx``, reply heard at ``t_rx_s``;
        the responder's stamps ``t2`` (heard), ``t3`` (replied), its delay ``delay_s`` on its clock):
        the single-sided two-way range with both clocks' frequencies, the time transfer, the nav entry."""
        corr = msg.get("clock")
        f_me, f_peer = self.clk.freq(), (corr[2] if corr is not None else 0.0)
        # two-way ranging on each end's own clock, durations scaled to network seconds
        range_m = 0.5 * SPEED_OF_LIGHT_M_S * ((t_rx_s - t_tx) / (1.0 + f_me) - delay_s / (1.0 + f_peer))
        if not (0.0 < range_m < self.cfg.max_range_m):
            self.counters["rejected_ranges"] += 1
            return []
        self.counters["responses"] += 1
        pos, cov = self._peer_for_solve(src, *self._update_peer(src, msg), t_rx_s)
        entry = [src, float(range_m), float(t_rx_s)]
        if t3 is not None:
            # two-way time transfer: theta_me - theta_peer at the exchange midpoint (both ends'
            # midpoints are the same instant); the nav entry carries it to the other stations
            dtheta = 0.5 * ((t_rx_s - t3) - (t2 - t_tx))
            t_mid = 0.5 * (t_tx + t_rx_s)
            entry = [src, float(range_m), float(t_mid), float(dtheta)]
            if self.clk.on_exchange(self.id, src, self.clk.network_time(t_mid), dtheta,
                                    self.clk.offset_var_s2, self._transfer_var_s2(self.id, src)) is not None:
                self.counters["sync_in"] += 1
        self.ranges_out.append(entry)
        gated = self.poll and self._rate_bias_m(corr, delay_s) > SS_BIAS_GATE * self.cfg.sigma_d_m
        closes = self._takes_closed()
        if closes:  # the member's V4b of this exchange replaces (or stands in for) our single-sided range
            # (what the survey took, what the integrity test took), to be replaced by the V4b
            self._ss_open[(src, self._poll_out["seq"])] = (None if gated or not POLL_SS_BRIDGE else float(range_m),
                                                           None if gated else float(range_m))
        if gated:
            self.counters["ss_gated"] += 1  # the time transfer stands (V7 needs no frequency); the range not
            self._refresh_state()
            return []
        if not closes or POLL_SS_BRIDGE:
            self.est.on_range(src, range_m, t_rx_s, True, pos, cov)
        self.integrity.on_range(src, range_m, t_rx_s)
        self._refresh_state()
        return []

    def _takes_closed(self) -> bool:
        """Protocol v2 with ``dmap``: does the survey take the members' V4b ranges of our polls (a nav's
        ``closed``) as its range of those exchanges, instead of our single-sided one?"""
        return self.poll and POLL_CLOSED and self.est.name.startswith("dmap")

    def _on_closed(self, src: int, closed: list | None, t_rx_s: float, pos: np.ndarray, cov: np.ndarray) -> None:
        """Protocol v2: ``src``'s nav lists its averaged ranges (V4b) of the polls it answered; the ones of
        our polls whose reply we heard become our range of that exchange: they replace the single-sided
        range the survey took meanwhile (``POLL_SS_BRIDGE``), else they are its only range. One range per
        exchange either way; an entry of no exchange of ours awaiting it is ignored."""
        if not closed or not self._ss_open:
            return
        for peer, range_m, seq in closed:
            if peer != self.id or (src, seq) not in self._ss_open:
                continue
            ss, ss_test = self._ss_open.pop((src, seq))
            if not 0.0 < range_m < self.cfg.max_range_m:
                self.counters["rejected_ranges"] += 1
                continue
            self.counters["closed_in"] += 1
            if ss is None:
                self.est.on_range(src, float(range_m), t_rx_s, True, pos, cov)
            else:
                self.est.revise_range(src, ss, float(range_m))
            # the integrity test judges the link on the range the survey uses (a member lying in its
            # ``closed`` is tested as one lying in its reply stamps)
            if ss_test is None:
                self.integrity.on_range(src, float(range_m), t_rx_s)
            else:
                self.integrity.revise_range(src, ss_test, float(range_m))

    def _rate_bias_m(self, corr, delay_s: float) -> float:
        """Protocol v2, the poller's single-sided range: 1-sigma of its error from the two clocks'
        frequency uncertainty, ``c Db sqrt(P_ff,me + P_ff,peer) / 2`` (eq. V6 with the estimated
        frequencies; the peer's variance from its reply's clock correction, else the oscillator class)."""
        pff_peer = corr[5] if corr is not None else self.cfg.clock_freq_sigma ** 2
        return 0.5 * SPEED_OF_LIGHT_M_S * delay_s * math.sqrt(max(self.clk.freq_var(), 0.0) + max(pff_peer, 0.0))

    def _on_nav(self, msg: dict, t_rx_s: float) -> list[dict]:
        """A peer's nav broadcast: its estimate, slot, clock correction and the ranges it measured."""
        src = msg.get("src")
        self._heard(src, t_rx_s)
        pos, cov = self._peer_for_solve(src, *self._update_peer(src, msg), t_rx_s)
        slot = msg.get("slot")
        # a slot claim is believed only if the nav arrived inside that slot (and not too often changed)
        in_slot = "cycle" not in msg or self._in_slot(msg, t_rx_s)  # (every nav on the wire has a cycle)
        if self.slots is not None:
            if in_slot:  # claims change often in a cold start: no rate limit (the slot table is bounded)
                self._slot_heard(msg, t_rx_s)
            else:
                self.admission.drop("slot_time")
        elif slot is not None and self.admission.slot_claim(src, slot, in_slot, t_rx_s):
            self.heard_slots[src] = slot
            if self.slot is not None and slot == self.slot and src < self.id:
                # slot collision: the lower id keeps the slot, we listen again and re-claim
                self.slot = None
                self.state = "joining"
                self.listen_until_s = t_rx_s + self.plan.cycle_s
                self._next_req_T = self._nav_s = float("inf")
        self.est.on_peer(src, pos, cov)
        self.integrity.on_announcement(src, msg.get("excluded"), t_rx_s)
        corr = msg.get("clock")
        if corr is not None:
            self.clk.on_nav(src, t_rx_s, msg["t_tx_s"], corr)  # coarse, only while unknown
            self.clk.on_peer_scale(src, msg["t_tx_s"], corr)  # one time scale: consensus on its definition
        transfers = []  # the nav's time transfers: one batch update of the clock filter (on_exchanges)
        for r in msg.get("ranges", ()):
            if not self._plausible_entry(src, r, msg.get("t_tx_s", t_rx_s), t_rx_s):
                continue
            peer, range_m = r[0], r[1]
            if len(r) == 4 and corr is not None and 0.0 < range_m < self.cfg.max_range_m and not (
                    self.poll and peer == self.id):  # (poll: our end of it is formed from our stamps)
                # every exchange the network makes refines the network clock filter: ours (the
                # responder's end) and the others' alike
                transfers.append((peer, r[2], float(r[3])))
            if peer == self.id and 0.0 < range_m < self.cfg.max_range_m and not self.poll:
                self.counters["ranges_in"] += 1
                if self.est.name.startswith("dmap"):  # dmap, dmap-ls: ranges used at both ends
                    self.est.on_range(src, float(range_m), t_rx_s, False, pos, cov)
                self.integrity.on_range(src, float(range_m), t_rx_s)
        if transfers:
            self._nav_transfers(src, corr, transfers)
        if src in self._polled:
            self._on_final(src, msg, t_rx_s, corr, pos, cov)
        self._on_closed(src, msg.get("closed"), t_rx_s, pos, cov)
        self._refresh_state()
        return self._unconverged_solve(t_rx_s)

    def _unconverged_solve(self, t_s: float) -> list[dict]:
        """Protocol v2: a station whose horizontal sigma is above ``POLL_RESOLVE_SIGMA_D`` sigma_d re-solves
        on every nav it hears (the nav brought its final's range and the peer's newest estimate) and
        publishes the estimate (the next nav carries it). The solves of the field are block-coordinate
        sweeps of the joint problem; one per station and cycle spreads the first cycles' information one
        sweep per second, the extra ones act within the cycle. A converged station solves once per cycle,
        before its nav (docs/survey.md, "Protocol v2's poll")."""
        if not self.poll or POLL_RESOLVE_SIGMA_D <= 0.0 or self.state != "surveying":
            return []
        if self._horizontal_sigma_m(self.est.cov_m2) <= POLL_RESOLVE_SIGMA_D * self.cfg.sigma_d_m:
            return []
        return [self.estimate_msg(t_s)] if self.est.refresh() else []

    def _converged_weights(self) -> None:
        """Protocol v2: from the first nav at which our horizontal sigma is at most ``POLL_LATE_SIGMA_D``
        sigma_d and our vertical one at most ``POLL_LATE_SIGMA_Z_D`` sigma_d on, the dmap solve charges the
        peers' covariances ``POLL_PEER_CORR_LATE`` times (``POLL_PEER_CORR_EST`` before; docs/survey.md,
        "Protocol v2's poll", phase 4)."""
        c, sd = self.est.cov_m2, self.cfg.sigma_d_m
        if (not self.poll or POLL_PEER_CORR_LATE is None or not self.est.name.startswith("dmap")
                or self._horizontal_sigma_m(c) > POLL_LATE_SIGMA_D * sd or c[2, 2] > (POLL_LATE_SIGMA_Z_D * sd) ** 2):
            return
        self.est.peer_corr_est = POLL_PEER_CORR_LATE

    def _nav_transfers(self, src: int, corr, entries: list[tuple[int, float, float]]) -> None:
        """A nav's time transfers ``(peer, t_mid on src's clock, dtheta_s)``: placed in network time by
        our prior view of src's clock, then one batch update of the clock filter (``on_exchanges``)."""
        times = self.clk.peer_times(src, [t for _, t, _ in entries], corr)
        items = [(src, peer, T_mid, z, T_var, self._transfer_var_s2(src, peer))
                 for (peer, _, z), (T_mid, T_var) in zip(entries, times)]
        self.counters["sync_in"] += sum(v is not None for v in self.clk.on_exchanges(items))

    def _on_final(self, src: int, msg: dict, t_rx_s: float, corr, pos: np.ndarray, cov: np.ndarray) -> None:
        """Protocol v2: the nav of a poller we answered is the final (T5 its ``t_tx_s``, T6 = ``t_rx_s``),
        taken inside its sub-slot N (rule V2, else ``final_window``): with its T1 and T4 of our reply,
        the double-sided range (V4, both clocks' frequencies) and the time transfer (V7) - ours."""
        answered = self._polled[src]
        pf = msg.get("poll")
        seq = -1 if pf is None else pf["seq"]
        for s in [s for s in answered if s < seq or pf is None]:  # polls whose final this nav is not
            del answered[s]
            self.counters["final_lost"] += 1
        mine = answered.pop(seq, None)
        if not answered:
            del self._polled[src]
        if mine is None:
            return
        t2, t3, k, n = mine
        t4 = next((t for p, t in pf["rx"] if p == self.id), None)
        if t4 is None:  # the poller did not hear our reply (in its window)
            self.counters["final_lost"] += 1
            return
        c = self.cfg
        if not in_reply_window(t2, t_rx_s, n, c.turnaround_s, c.reply_spacing_s, self._path_m, c.guard_s):
            self.counters["final_window"] += 1
            return
        t1, t5 = pf["t1"], msg["t_tx_s"]
        f_src = corr[2] if corr is not None else 0.0
        # the exchange's bound (3/4 sigma_d^2): its two single-sided ranges averaged (V4b) once the
        # clocks' frequencies are known well enough for it (its rate bias acts on |Db - Da|, the gate
        # of the poller's range), else DS-TWR (V4), first-order free of them
        twr = sym_twr_range_m if self._rate_bias_m(corr, 0.5 * abs((t3 - t2) - (t5 - t4))) <= (
            SS_BIAS_GATE * self.cfg.sigma_d_m) else ds_twr_range_m
        range_m = twr(t1, t2, t3, t4, t5, t_rx_s, f_src, self.clk.freq()).item()
        if not (0.0 < range_m < self.cfg.max_range_m):
            self.counters["rejected_ranges"] += 1
            return
        self.counters["ranges_in"] += 1
        self.closed_out.append([src, float(range_m), int(seq)])
        dtheta = time_transfer_s(t1, t2, t3, t4)[0].item()  # the poller's clock minus ours
        # the exchange's midpoint on our clock (the same instant as (T1 + T4) / 2 on the poller's)
        if self.clk.on_exchange(src, self.id, self.clk.network_time(0.5 * (t2 + t3)), dtheta,
                                self.clk.offset_var_s2, self._transfer_var_s2(src, self.id)) is not None:
            self.counters["sync_in"] += 1
        if self.est.name.startswith("dmap"):  # dmap, dmap-ls: ranges used at both ends
            self.est.on_range(src, range_m, t_rx_s, False, pos, cov)
        self.integrity.on_range(src, range_m, t_rx_s)

    _HANDLERS = {"range_req": _on_range_req, "range_rsp": _on_range_rsp, "nav": _on_nav, "poll": _on_poll,
                 "reply": _on_reply}

    def _in_slot(self, req: dict, t_tx_s: float) -> bool:
        """Does a reply sent at local ``t_tx_s`` still fall inside the request's slot, on our estimate
        of network time (with our clock's 3-sigma uncertainty on either end as a guard)?"""
        start = self.plan.slot_start_s(int(req["cycle"]), int(req["slot"]))
        T = self.clk.network_time(t_tx_s)
        guard = 6.0 * math.sqrt(max(self.clk.offset_var_s2, 0.0)) + self.cfg.max_range_m / SPEED_OF_LIGHT_M_S
        return start - guard <= T <= start + self.plan.slot_s + guard

    def _integrity(self, t_s: float) -> list[dict]:
        """Test the peers (``stations/integrity.py``); excluded peers leave the survey solve."""
        if not self.est.initialized:
            return []
        out = []
        bodies = self.integrity.evaluate(t_s, self.est.pos_m, self.est.cov_m2, self.peers)
        for body in bodies + self.integrity.quorum(t_s, set(self.members(t_s))):
            self.seq.setdefault("integrity", 0)
            m = self._base("integrity", t_s)
            m.update(body)
            out.append(m)
        if hasattr(self.est, "excluded"):
            new = self.integrity.excluded - self.est.excluded
            self.est.excluded = self.integrity.excluded
            if new:
                self._roll_back(t_s)
            if out:
                self.est._dirty = self.est.nf > 0
        return out

    def _roll_back(self, t_s: float) -> None:
        """A peer newly excluded: restart the solve from our estimate of before the fault could show.

        The exclusion comes ``fail_to_exclude`` failing tests (one per cycle) after the fault shows in
        our ranges, and a quorum's a cycle later; meanwhile every solve took the faulty peer in, and in
        a flat field its bounded pull moves the weakly observed heights by tens of metres in one
        second, the whole field together (docs/survey.md, "Recovery after the exclusion"). Our later
        solves start where the last one ended, and with every neighbour contaminated the same way that
        place is a fixed point, so the excluded peer's lies would stay in the field. So, if our estimate
        has moved since ``fail_to_exclude + 2`` cycles earlier beyond its covariance of then (a false
        exclusion on clean data moves nothing: no roll-back), the solve restarts from that earlier
        estimate and, for ``HOLD_CYCLES`` cycles, takes every peer's broadcast of that time (the peers
        roll back within that hold too); the ranges themselves are all kept (the excluded link just
        leaves the solve). Measured in ``larns bench integrity --recovery`` (docs/survey.md)."""
        if not hasattr(self.est, "restart_from"):
            return
        cyc = self.plan.cycle_s
        holding = self._hold_until_s != -math.inf
        back = t_s - (self.integrity.fail_to_exclude + 2) * cyc
        back = min(back, self._hold_from_s) if holding else back
        old = [(p, c) for t, p, c in self._pos_hist if t <= back + 1e-9]
        if not old:
            return
        pos, cov = old[-1]
        if not holding and not _moved_beyond(self.est.pos_m - pos, cov, self.est.free):
            return  # we have not moved beyond our covariance since: nothing to undo
        self._hold_from_s, self._hold_until_s = back, t_s + HOLD_CYCLES * cyc
        self.est.restart_from(pos)
        for src, hist in self._peer_hist.items():
            self.est.on_peer(src, *self._held(hist))

    def _held(self, hist: deque) -> tuple[np.ndarray, np.ndarray]:
        """A peer's broadcast at the roll-back time (its oldest kept if none is that old)."""
        for t, pos, cov in reversed(hist):
            if t <= self._hold_from_s + 1e-9:
                return pos, cov
        return hist[0][1], hist[0][2]

    def _peer_for_solve(self, src: int, pos: np.ndarray, cov: np.ndarray, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Keep the peer's broadcast (one per cycle) and return what the solve takes: the broadcast
        itself, or during a roll-back hold the one of the roll-back time (:meth:`_roll_back`)."""
        hist = self._peer_hist.get(src)
        if hist is None:
            hist = self._peer_hist[src] = deque(maxlen=ROLLBACK_KEEP)
        if not hist or t_s - hist[-1][0] >= 0.5 * self.plan.cycle_s:
            hist.append((float(t_s), pos, cov))
        if self._hold_until_s == -math.inf:
            return pos, cov
        return self._held(hist)

    def _release_peers(self) -> None:
        """End of a roll-back hold: the solve takes the peers' latest broadcasts again."""
        self._hold_until_s = -math.inf
        for src, (pos, cov) in self.peers.items():
            self.est.on_peer(src, pos, cov)
        self.est._dirty = self.est.nf > 0

    def _converged_sigma_m(self) -> float:
        c = self.cfg.datum_converged_m
        return 0.5 * self.cfg.sigma_d_m if c == 0.0 else c

    @staticmethod
    def _horizontal_sigma_m(cov_m2: np.ndarray) -> float:
        return math.sqrt(max(float(cov_m2[0, 0] + cov_m2[1, 1]), 0.0))

    def carries_datum(self, cov_m2: np.ndarray) -> bool:
        """A broadcast covariance (3, 3) of a station that carries the datum: free in x, y and z
        (a founder still holding the frame broadcasts zero variance on its constrained coordinates)
        and converged (horizontal sigma at most the convergence threshold)."""
        thr = self._converged_sigma_m()
        return bool(thr >= 0.0 and np.all(np.diag(cov_m2) > 0.0) and self._horizontal_sigma_m(cov_m2) <= thr)

    def _datum(self, t_s: float) -> None:
        """The frame datum passes from the founders to the field (docs/architecture.md, "The frame
        datum"). A station that is converged enters the datum mode (:meth:`DistributedMap.hold_datum`);
        a founder still holding the frame does so only once it hears ``datum_quorum`` member stations
        that carry the datum, so the frame is never held by fewer stations than fix a position."""
        est = self.est
        thr = self._converged_sigma_m()
        if (thr < 0.0 or not hasattr(est, "hold_datum") or est.datum_sigma_m is not None or not est.initialized
                or est.n_updates == 0 and est.nf > 0):
            return
        if self._horizontal_sigma_m(est.cov_m2) > thr or self.seq["nav"] < self.cfg.datum_min_updates:
            return
        if est.nf < 3:
            mem = set(self.members(t_s))
            carriers = sum(1 for p, (_, cov) in self.peers.items() if p in mem and self.carries_datum(cov))
            if carriers < self.cfg.datum_quorum:
                return
        est.hold_datum(self.cfg.datum_damping_m)
        est.refresh()  # the nav that follows carries the estimate free in x, y, z
        if self.state == "frame":
            self.state = "surveying"

    def _hold_frame(self, t_s: float) -> None:
        """Keep our estimate in the field's datum (docs/architecture.md, "The frame datum"), once no
        member broadcasts a frame constraint any more (every station in the datum mode):

        * while the three founders are all heard, the datum is still theirs, now as a convention on
          their estimates: our estimate is moved by the rigid motion that puts the founders' current
          estimates at station 1 = origin, 2 on +X, 3 in the XY plane (:func:`founders_frame`);
        * from the first time a founder is not heard (``field_datum``), the carriers' references are
          frozen at their estimates of that moment and our estimate is moved by the inverse of the
          carriers' weighted rigid motion against them (:func:`rigid_motion`): no net translation or
          rotation of the field, whoever leaves.

        Every station computes the same motion from the same broadcasts and references, so the
        corrections move the field rigidly."""
        est = self.est
        if getattr(est, "datum_sigma_m", None) is None:
            return
        own = self.carries_datum(est.cov_m2)
        if not own:
            self.datum_ref.pop(self.id, None)
            return
        mem = set(self.members(t_s))
        if not self.frame_released:
            if any(not np.all(np.diag(self.peers[p][1]) > 0.0) for p in mem if p in self.peers):
                self.datum_ref[self.id] = est.pos_m.copy()
                return  # a founder still holds the frame
            self.frame_released = True
        if not self.field_datum and self.cfg.datum_convention:
            fpos = {p: (est.pos_m if p == self.id else self.peers[p][0]) for p in FOUNDERS
                    if p == self.id or (p in mem and p in self.peers)}
            if len(fpos) == len(FOUNDERS):
                R, o = founders_frame(fpos[1], fpos[2], fpos[3])
                new = R @ (est.pos_m - o)
                self.datum_shift_m = est.pos_m - new
                est.shift(new - est.pos_m)
                self.datum_ref[self.id] = est.pos_m.copy()
                return
        self.field_datum = True  # (with the convention: a founder is gone) the references freeze here
        if self.id not in self.datum_ref:
            self.datum_ref[self.id] = est.pos_m.copy()
        sets = [(est.pos_m, est.cov_m2, self.datum_ref[self.id])]
        for p in sorted(mem):
            if p in self.datum_ref and p in self.peers:
                sets.append((*self.peers[p], self.datum_ref[p]))
        # a carrier that fell silent is static: it is still where its last broadcast put it, so that
        # broadcast stays one of the datum's points and a departure leaves the datum as it was
        for p in sorted(self.datum_ref.keys() - mem - {self.id}):
            if p in self.peers:
                sets.append((*self.peers[p], self.datum_ref[p]))
        if len(sets) < self.cfg.datum_quorum:
            return
        t_m, w_rad = rigid_motion(*(np.stack(a) for a in zip(*sets)))
        shift = t_m + np.cross(w_rad, est.pos_m)
        est.shift(-shift)
        self.datum_shift_m = shift

    def _refresh_state(self) -> None:
        if self.state == "joining" and self.slot is not None and self.est.initialized:
            self.state = "surveying"

    def _update_peer(self, src: int, msg: dict) -> tuple[np.ndarray, np.ndarray]:
        """The peer's latest broadcast position and covariance (for the integrity tests), returned as
        arrays (read-only by convention: the estimators copy what they keep). A carrier's reference
        position is its latest broadcast while the founders hold the frame, then (from the first
        time a founder is not heard) its first broadcast as a carrier; one that stops carrying the datum (a restart) loses it until it converges again."""
        pc = self.peers[src] = (np.asarray(msg["pos_m"], float), np.asarray(msg["cov_m2"], float))
        if self.carries_datum(pc[1]):
            if src not in self.datum_ref or not self.field_datum:
                self.datum_ref[src] = pc[0].copy()
        else:
            self.datum_ref.pop(src, None)
        return pc


# the exclusion roll-back (StationCore._roll_back): own and peer estimates kept per nav, and how many
# cycles the solve holds the peers' broadcasts of the roll-back time (a peer's own exclusion comes up
# to a cycle before or after ours, a quorum's a cycle later, and its rolled-back nav a cycle after that)
ROLLBACK_KEEP = 8
HOLD_CYCLES = 4
# ... and only a station whose estimate moved since then beyond its covariance of then rolls back: the
# chi-square 1 - ROLLBACK_P quantile for its free coordinates (a static station's solve moves inside it)
ROLLBACK_P = 1e-3
def _moved_beyond(d_m: np.ndarray, cov_m2: np.ndarray, free: np.ndarray) -> bool:
    """True if the move ``d_m`` (3,) is outside the chi-square 99.9 % region of ``cov_m2`` (3, 3) over
    the coordinates free then and now (``free`` (3,) and a positive variance then: a founder that has
    since entered the datum mode had fixed coordinates)."""
    f = free & (np.diag(cov_m2) > 0.0)
    if not f.any():
        return False
    try:
        q = float(nees(d_m[f], cov_m2[np.ix_(f, f)]))
    except np.linalg.LinAlgError:
        return False
    return bool(q > chdtri(int(f.sum()), ROLLBACK_P))


# protocol v2: the polls of one poller a member keeps waiting for their finals (the poll of this cycle
# and the previous one's, whose final a process may take after the next poll: navs are read in batches)
POLLED_KEEP = 2
# protocol v2 with dmap: the poller's range of each exchange is the member's V4b from its next nav (the
# nav's ``closed``; StationCore._on_closed) and its single-sided range only bridges until it arrives
# (POLL_SS_BRIDGE) or is not taken by the survey (docs/survey.md, "Protocol v2's poll", phase 4)
POLL_CLOSED = True
POLL_SS_BRIDGE = True
# protocol v2 with the members' V4b taken: the dmap solve's range variance against a two-way range's
# (DistributedMap.range_var_factor): every range it keeps is then an exchange's averaged one (3/4
# sigma_d^2, nav.crlb.poll_exchange_counts; measured 0.71-0.78), but for the single-sided bridges of
# the last cycle and the first cycles' DS-TWR ranges (0.76-0.84)
POLL_RANGE_VAR_FACTOR = 0.75
# protocol v2: the poller's single-sided range enters the survey only once the clocks' frequency
# uncertainty biases it by at most this fraction of sigma_d (StationCore._rate_bias_m; docs/protocol.md)
SS_BIAS_GATE = 0.25
# protocol v2: the dmap solve's consider factor of the peers' covariances (DistributedMap.peer_corr_est,
# 0.5 in the addressed protocol). With nine ranges per link where the addressed protocol had one,
# sigma_d^2 / n falls nine times faster and the peer term u^T C_j u soon sets every link's weight,
# so the errors the peers share (the field's collective modes) must be charged more; the factor is
# measured, not derived (its table: docs/survey.md, "Protocol v2's poll")
POLL_PEER_CORR_EST = 3.0
# protocol v2: the factor once the station's horizontal sigma is at most POLL_LATE_SIGMA_D sigma_d and
# its vertical one at most POLL_LATE_SIGMA_Z_D sigma_d (StationCore._converged_weights; None:
# POLL_PEER_CORR_EST throughout). The large factor is for the start, when the peers are metres off;
# converged, it makes the sweeps' fixed point favour the links to well-known peers where the joint MAP
# weighs every link alike. 0 from the start, from a horizontal sigma_d on, or while the height was
# still 8 m uncertain (one trial of 100: the field's mirror image in height) let the field settle in a
# wrong configuration (docs/survey.md, "Protocol v2's poll", phases 3 and 4)
POLL_PEER_CORR_LATE: float | None = 0.5
POLL_LATE_SIGMA_D = 0.5
POLL_LATE_SIGMA_Z_D = 4.0
# protocol v2: ranges in links with two or more that a dmap station needs before it may judge its ranges
# clean (DistributedMap.clean_after_n, 20 in the addressed protocol). By its first solve a polling station
# holds two ranges of different exchanges (its own poll's and the peer's) on every link, so every link
# already shows whether its ranges agree: the NLOS evidence is there from the first solve, and holding
# the agreeing pairs weak until 20 ranges cost a whole cycle (docs/survey.md, "Protocol v2's poll")
POLL_CLEAN_AFTER_N = 0
# protocol v2: a station re-solves on every nav it hears while its horizontal sigma is above this many
# sigma_d (StationCore._unconverged_solve; 0: once per cycle only, before its nav)
POLL_RESOLVE_SIGMA_D = 1.0

FOUNDERS = (1, 2, 3)  # the stations whose estimates define the frame until one of them is gone


def founders_frame(p1_m: np.ndarray, p2_m: np.ndarray, p3_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The seed 000 frame convention on three estimates (3,) each, already close to it: ``x' = R (x - o)``
    puts ``p1`` at the origin, ``p2`` on +X and ``p3`` in the XY plane, keeping the side of +Z.
    Returns ``R`` (3, 3), ``o`` (3,)."""
    ex = p2_m - p1_m
    ex = ex / np.linalg.norm(ex)
    ez = np.cross(ex, p3_m - p1_m)
    ez = ez / np.linalg.norm(ez) * (1.0 if ez[2] >= 0.0 else -1.0)  # +Z kept (toward the z_ref station)
    return np.stack([ex, np.cross(ez, ex), ez]), np.asarray(p1_m, float).copy()


def rigid_motion(pos_m: np.ndarray, cov_m2: np.ndarray, ref_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted small-angle rigid motion of a set of points against their reference positions.

    Minimizes ``sum_i r_i^T C_i^-1 r_i``, ``r_i = pos_i - ref_i - (t + w x ref_i)`` (linearized
    Helmert transform without scale).

    Parameters
    ----------
    pos_m : (k, 3) current positions. cov_m2 : (k, 3, 3) their covariances. ref_m : (k, 3) references.

    Returns
    -------
    (t_m (3,), w_rad (3,)): translation and rotation vector.
    """
    k = len(pos_m)
    skew = np.zeros((k, 3, 3))  # w x ref = -[ref]x w
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = ref_m[:, 2], -ref_m[:, 1], ref_m[:, 0]
    skew[:, 1, 0], skew[:, 2, 0], skew[:, 2, 1] = -ref_m[:, 2], ref_m[:, 1], -ref_m[:, 0]
    A = np.concatenate([np.broadcast_to(np.eye(3), (k, 3, 3)), skew], axis=2)  # (k, 3, 6)
    W = np.linalg.inv(cov_m2)
    N = np.einsum("kia,kij,kjb->ab", A, W, A)
    b = np.einsum("kia,kij,kj->a", A, W, pos_m - ref_m)
    L = np.linalg.cholesky(N)  # positive definite for three or more points not on one line
    x = np.linalg.solve(L.T, np.linalg.solve(L, b))
    return x[:3], x[3:]
