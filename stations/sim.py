"""In-process simulator: drives N station cores over the air-channel model in virtual time.

No Zenoh, no sleeping: a discrete-event loop ordered by true time. The objects are exactly the
ones the Zenoh node runs (``StationCore`` + ``AirChannel`` + ``Clock``), and the world is drawn from
the same per-station seeded streams (``net.channel.station_rng``), so a result measured here holds
in the networked emulator. With ``publish=`` it also hands out what each station's shell would put
on the bus (``stations/shell.py``: decorated estimates, truth, and with ``journal=True`` the core
journal), which ``larns bench replay`` writes as a recording.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from net import streams
from net.channel import AirChannel, Clock, coarse_fix, draw_clock, station_rng
from net.clock import true_network_offset_s
from net.messages import AIR_MSG_KINDS
from net.radio import may_link, radio_dict
from net.scenario import DEPARTURE_KINDS, Scenario

from .admission import field_radius
from .core import StationConfig, StationCore
from .shell import PublishPolicy
from .shellfaults import ShellFaults
from .slots import reception_in_slot
from .tdma import TdmaPlan


@dataclass
class SimResult:
    """Snapshots of the estimates. Shapes: K snapshot times, n stations (scenario order)."""

    ids: list[int]
    times_s: np.ndarray  # (K,)
    truth_m: np.ndarray  # (n, 3) network frame
    pos_m: np.ndarray  # (K, n, 3); NaN before a station exists
    cov_m2: np.ndarray  # (K, n, 3, 3)
    n_updates: np.ndarray  # (K, n)
    link_counts: np.ndarray  # (K, n, n) cumulative ranges measured, [initiator, responder]
    # (K, n, n) protocol v2: cumulative exchanges a member closed with the poller's final, [member,
    # poller] (its own range of the exchange); None in the addressed protocol
    final_counts: np.ndarray | None = None
    counters: dict[int, dict] = field(default_factory=dict)
    clock_err_s: np.ndarray | None = None  # (K, n) estimated minus true clock offset vs network time
    clock_var_s2: np.ndarray | None = None  # (K, n) the estimator's offset variance
    clock_true_s: np.ndarray | None = None  # (K, n) true offset vs network time (the ensemble, each
    # station's definition of it evaluated on the true clocks: net.clock.true_network_offset_s)
    time_scales: dict[int, list] = field(default_factory=dict)  # station id -> its TimeScale log


def station_clock(scn: Scenario, station_id: int, seed: int | None = None):
    """The station's oscillator, from its own stream of the world seed (simulator and node alike)."""
    seed = scn.seed if seed is None else seed
    return draw_clock(scn.clock, station_rng(seed, station_id, streams.CLOCK))


def network_offset_s(clock, ref_clock, t_true_s: float) -> float:
    """True offset of a clock against station 1's clock (``ref_clock``) at true time ``t_true_s``."""
    return clock.error_s(t_true_s) - ref_clock.error_s(t_true_s)


def make_core(scn: Scenario, station_id: int, *, estimator: str | None = None, join: bool = False,
              start_s: float = 0.0, seed: int | None = None, clock: Clock | None = None
              ) -> tuple[StationCore, Clock]:
    """Build a station core the way a station process does: clock and coarse fix from the world seed
    (``clock``: another oscillator than the seed's, for tests)."""
    seed = scn.seed if seed is None else seed
    clock = station_clock(scn, station_id, seed) if clock is None else clock
    if scn.sigma0_m > 0:
        # a founder joining a running field (a restart) is an ordinary station: its coarse fix is
        # off in all three coordinates (station id 4 stands for "no frame constraint")
        pos0, cov0 = coarse_fix(scn.true_pos(station_id), station_id if not join else max(station_id, 4),
                                scn.sigma0_m, station_rng(seed, station_id, streams.COARSE_FIX))
    elif station_id == 1 and not join:
        pos0, cov0 = np.zeros(3), np.zeros((3, 3))
    else:
        pos0, cov0 = None, None
    shell = ShellFaults(scn, station_id)  # scenario [[faults]]: bad_fix, clock_jump
    clock = shell.clock(clock)
    pos0, cov0 = shell.fix(pos0, cov0, scn.sigma0_m)
    cfg = StationConfig(
        id=station_id,
        tdma=TdmaPlan(scn.tdma.cycle_s, scn.tdma.slot_s),
        sigma_d_m=scn.channel.sigma_d_m,
        estimator=estimator or scn.estimator,
        ranges_per_update=scn.ranges_per_update,
        known_ids=tuple(i for i in scn.initial_ids if i != station_id) if not join else (),
        join=join,
        turnaround_s=scn.channel.turnaround_s,
        clock_offset_sigma_s=scn.clock.offset_s,
        clock_freq_sigma=scn.clock.freq_sigma,
        clock_q_wf_s=scn.clock.q_wf_s,
        clock_q_rw_per_s=scn.clock.q_rw_per_s,
        field_radius_m=field_radius(scn.pos_m, scn.ids),
        # the frame datum: the founders' throughout, or handed to the converged field ([survey] datum)
        datum_converged_m=0.0 if scn.datum == "field" else -1.0,
        radio=radio_dict(scn.channel.radio),
        **({"slot_assignment": "distributed", "cycle_slots": scn.tdma.assigned_slots, "slot_seed": int(seed)}
           if scn.tdma.distributed else {}),
        **({"ranging": "poll", "reply_spacing_s": scn.tdma.reply_spacing_s, "guard_s": scn.tdma.guard_s}
           if scn.tdma.poll else {}),
    )
    return StationCore(cfg, pos0, cov0, start_s=clock.to_local(start_s)), clock


class Simulator:
    """Discrete-event simulation of a station network.

    Parameters
    ----------
    scn : the scenario (true positions, TDMA, channel).
    estimator : override the scenario's estimator.
    seed : override the world seed.
    start_s : {station id: true start time}; stations in ``scn.join_ids`` default to joining.
    stop_s : {station id: true time the station dies (SIGKILL-like: silent from then on)}; the scenario's
        ``[[faults]]`` of kind ``leave`` / ``kill`` add theirs (``at_s``) unless given here.
    restart_s : {station id: true time a stopped station powers on again}: a fresh core (no memory, the
        same oscillator and coarse fix), joining the running field like ``larns fleet --restart``.
    core_factory : builds a station's ``(core, clock)``; same signature as :func:`make_core` (the
        default). The injection point for tests and tools that change how a core is built.
    journal : the stations' shells publish their core journal (``core_init``, ``core_input``).
    publish : ``publish(t_true_s, station_id, msg, phy)`` receives everything the stations' shells
        publish, in order: air messages (``phy`` = true sender position and transmit time),
        decorated estimates with their truth, journal messages (``phy`` None) - what
        ``stations/node.py`` puts on the bus (``stations/shell.py``). Default: nothing is published.
    """

    def __init__(self, scn: Scenario, *, estimator: str | None = None, seed: int | None = None,
                 start_s: dict[int, float] | None = None, stop_s: dict[int, float] | None = None,
                 restart_s: dict[int, float] | None = None, core_factory: Callable[..., tuple[StationCore, Clock]] | None = None, journal: bool = False,
                 publish: Callable[[float, int, dict, dict | None], Any] | None = None):
        self.scn = scn
        self.core_factory = make_core if core_factory is None else core_factory
        self.publish = publish
        self.policy = [PublishPolicy(i, journal=journal) for i in scn.ids]
        self.seed = scn.seed if seed is None else seed
        self.estimator = estimator
        self.start_s = dict(start_s or {})
        self.stop_s = {f.station: f.at_s for f in scn.faults if f.kind in DEPARTURE_KINDS}
        self.stop_s.update(stop_s or {})
        self.restart_s = dict(restart_s or {})
        for sid, t in self.restart_s.items():
            if not t > self.stop_s.get(sid, np.inf):
                raise ValueError(f"station {sid}: restart_s {t} must follow its stop ({self.stop_s.get(sid)})")
        for j in scn.join_ids:
            self.start_s.setdefault(j, 20.0)
        n = len(scn.ids)
        self.cores: list[StationCore | None] = [None] * n
        self.clocks: list[Clock] = [Clock()] * n
        self.ref_clock = station_clock(scn, scn.ids[0], self.seed)  # network time = station 1's clock
        self.air = [AirChannel(scn.channel, station_rng(self.seed, i, streams.AIR), (self.seed, i))
                    for i in scn.ids]
        self.shell = [ShellFaults(scn, i) for i in scn.ids]  # per-link channel, [[faults]]
        self.net_rng = np.random.default_rng([self.seed, 0, 3])
        self.links = np.zeros((n, n), dtype=np.int64)
        self.finals = np.zeros((n, n), dtype=np.int64)  # protocol v2: [member, poller], see SimResult
        self._index = {sid: k for k, sid in enumerate(scn.ids)}
        # [k]: the stations that may hear station k (the radio's horizon and budget; static positions)
        reach = may_link(scn.pos_m, scn.channel.radio)
        self._hear = [[j for j in range(n) if j != k and reach[k, j]] for k in range(n)]
        self._reach = reach.tolist()
        self.range_log: list[tuple[float, int, int, float]] = []  # (t_true, initiator idx, responder idx, range_m)
        # indices into range_log of the protocol v2 pollers' single-sided ranges that their survey did
        # not take (ss_gated: the clocks' frequencies not known yet; their nav still carries them)
        self.gated_log: set[int] = set()
        self._gated_peers: list[set[int]] = [set() for _ in range(n)]  # per station, since its last nav
        self.exchange_log: list[tuple[float, int, int]] = []  # (t_true reply rx, initiator idx, responder idx)
        self.collisions = 0  # distributed assignment: navs lost at a receiver to another sender in their slot
        self.collision_log: list[tuple[float, int, int]] = []  # (t_true tx, sender idx, receiver idx) of each
        self._heap: list = []
        self._order = 0
        self._timer_ver = [0] * n
        self.now_s = 0.0
        for k, sid in enumerate(scn.ids):
            t0 = self.start_s.get(sid, 0.0)
            self._push(t0, ("start", k))
            if sid in self.restart_s:
                self._push(self.restart_s[sid], ("restart", k))

    # ------------------------------------------------------------------ event plumbing
    def _push(self, t: float, ev: tuple) -> None:
        self._order += 1
        heapq.heappush(self._heap, (t, self._order, ev))

    def _alive(self, k: int, t: float) -> bool:
        sid = self.scn.ids[k]
        return self.cores[k] is not None and (t < self.stop_s.get(sid, np.inf) or t >= self.restart_s.get(sid, np.inf))

    def _arm(self, k: int) -> None:
        core = self.cores[k]
        dl = core.next_deadline()
        self._timer_ver[k] += 1
        if dl is not None:
            self._push(self.clocks[k].to_true(dl), ("timer", k, self._timer_ver[k]))

    def _emit(self, k: int, outs: list[dict]) -> None:
        ids, index, loss = self.scn.ids, self._index, self.scn.net.loss_prob
        for m in outs:
            kind = m["kind"]
            if kind not in AIR_MSG_KINDS:  # (published, not on air)
                self._publish_local(k, m)
                continue
            t_tx_true = self.clocks[k].to_true(m["t_tx_s"])
            m = self.shell[k].outgoing(m, t_tx_true)
            if self.publish is not None:
                self.publish(self.now_s, ids[k], m, {"pos_m": self.scn.pos_m[k], "t_true_s": t_tx_true})
            self.policy[k].sent(kind)
            if kind == "nav":
                gated, self._gated_peers[k] = self._gated_peers[k], set()
                for peer, rng_m, *_ in m["ranges"]:
                    if peer in index:
                        if index[peer] in gated:
                            self.gated_log.add(len(self.range_log))
                        self.range_log.append((t_tx_true, k, index[peer], float(rng_m)))
            if kind in ("nav", "poll"):  # broadcasts
                # a wire loss is drawn for every station, so only then are the others all visited
                targets = [j for j in range(len(ids)) if j != k] if loss > 0 else self._hear[k]
            else:  # to the addressee only (a v2 reply: no other core uses it in protocol v2's first phase)
                targets = [index[m["dst"]]] if m["dst"] in index else []
            holders = self._holders(k, m) if self.scn.tdma.distributed else None
            for j in targets:
                if self.cores[j] is None and ids[j] not in self.start_s:
                    continue
                if loss > 0 and self.net_rng.random() < loss:
                    continue
                if not self._reach[k][j]:
                    continue
                if holders and self._collided(k, j, m, holders, t_tx_true):
                    continue
                t_local = self.shell[j].arrival_local_s(self.air[j], ids[k], self.scn.pos_m[k], t_tx_true,
                                                        self.scn.pos_m[j], self.clocks[j])
                if t_local is None:
                    continue
                self._push(self.clocks[j].to_true(t_local), ("rx", j, m, t_local))
        self._journal(k, self.policy[k].after_outputs(self.cores[k], outs))

    def _holders(self, k: int, m: dict) -> list[int]:
        """Distributed assignment: the other stations transmitting in the slot of ``m`` (sent by station
        index ``k``) this cycle - the slot they hold now (a range reply falls in its requester's slot)."""
        if m["kind"] == "range_rsp":
            j = self._index.get(m["dst"])
            s = None if j is None or self.cores[j] is None else self.cores[j].slot
        else:
            s = m.get("slot")
        if s is None:
            return []
        return [h for h, c in enumerate(self.cores)
                if h != k and c is not None and c.slot == s and self._alive(h, self.now_s)]

    def _collided(self, k: int, j: int, m: dict, holders: list[int], t_tx_true: float) -> bool:
        """Does receiver index ``j`` lose ``m`` to another sender in its slot (``holders``)? A station
        transmitting in the slot hears nothing in it (half duplex); one in range of another sender there
        decodes neither, and a nav lost that way is reported to its core as garbage (energy heard)."""
        lost, garbage = reception_in_slot(m["kind"], j in holders, any(self._reach[h][j] for h in holders if h != j))
        if garbage and self.cores[j] is not None:
            self.collisions += 1
            self.collision_log.append((t_tx_true, k, j))
            self._push(t_tx_true + 1e-6, ("garbage", j, self.clocks[j].to_local(t_tx_true + 1e-6)))
        return lost

    def _publish_local(self, k: int, m: dict) -> None:
        """A core output that does not go on air: an estimate goes out decorated after its truth (the
        node's order; the simulator's truth carries the position only, no clock error, as the
        recordings it synthesizes always did); integrity announcements as they are."""
        if self.publish is None:
            return
        if m["kind"] == "estimate":
            pol = self.policy[k]
            m = pol.estimate(m, self.cores[k].slot)
            self.publish(self.now_s, self.scn.ids[k], pol.truth(m, self.now_s, self.scn.pos_m[k]), None)
        self.publish(self.now_s, self.scn.ids[k], m, None)

    def _journal(self, k: int, items: list[tuple[str, dict]]) -> None:
        for kind, fields in items:
            m = self.policy[k].journal_msg(kind, self.now_s, **fields)
            if self.publish is not None:
                self.publish(self.now_s, self.scn.ids[k], m, None)

    def _handle(self, t: float, ev: tuple) -> None:
        what, k = ev[0], ev[1]
        sid = self.scn.ids[k]
        if what in ("start", "restart"):
            join = what == "restart" or sid in self.scn.join_ids or self.start_s.get(sid, 0.0) > 0.0
            core, clock = self.core_factory(self.scn, sid, estimator=self.estimator, join=join, start_s=t,
                                            seed=self.seed)
            self.cores[k], self.clocks[k] = core, clock
            self._journal(k, self.policy[k].start(core))
            self._arm(k)
            return
        if not self._alive(k, t):
            return
        core = self.cores[k]
        if what == "garbage":
            core.on_garbage(ev[2])  # journalled with the core's next nav
            return
        if what == "timer":
            if ev[2] != self._timer_ver[k]:
                return
            outs = core.on_timer(self.clocks[k].to_local(t))
        else:  # rx
            m, t_local = ev[2], ev[3]
            cnt = core.counters
            before, fin, gated = cnt["responses"], cnt["ranges_in"], cnt.get("ss_gated", 0)
            outs = core.on_message(m, t_local)
            src = self._index.get(m["src"])
            if cnt["responses"] != before:
                self.links[k, src] += 1
                self.exchange_log.append((t, k, src))
            if self.scn.tdma.poll and cnt["ranges_in"] != fin:  # (v2: only a final adds to ranges_in)
                self.finals[k, src] += 1
            if cnt.get("ss_gated", 0) != gated:
                self._gated_peers[k].add(src)
        self._emit(k, outs)
        self._arm(k)

    # ------------------------------------------------------------------ running
    def run(self, until_s: float, snapshot_s: np.ndarray | list[float]) -> SimResult:
        snaps = np.asarray(sorted(snapshot_s), dtype=float)
        n = len(self.scn.ids)
        K = len(snaps)
        pos = np.full((K, n, 3), np.nan)
        cov = np.full((K, n, 3, 3), np.nan)
        nup = np.zeros((K, n), dtype=np.int64)
        links = np.zeros((K, n, n), dtype=np.int64)
        finals = np.zeros((K, n, n), dtype=np.int64)
        cerr = np.full((K, n), np.nan)
        cvar = np.full((K, n), np.nan)
        ctrue = np.full((K, n), np.nan)
        si = 0
        while si < K:
            t_next = self._heap[0][0] if self._heap else np.inf
            if t_next > snaps[si] or t_next > until_s:
                for k, c in enumerate(self.cores):
                    if c is not None and self._alive(k, snaps[si]):
                        pos[si, k] = c.est.pos_m
                        cov[si, k] = c.est.cov_m2
                        nup[si, k] = c.est.n_updates
                        t_loc = self.clocks[k].to_local(snaps[si])
                        ctrue[si, k] = self.true_clock_offset_s(k, snaps[si])
                        off, cvar[si, k] = c.clk.ensemble_offset_at(t_loc)
                        cerr[si, k] = off - ctrue[si, k]
                links[si] = self.links
                finals[si] = self.finals
                si += 1
                continue
            t, _, ev = heapq.heappop(self._heap)
            self.now_s = t
            self._handle(t, ev)
        return SimResult(ids=list(self.scn.ids), times_s=snaps, truth_m=self.scn.pos_m.copy(), pos_m=pos,
                         cov_m2=cov, n_updates=nup, link_counts=links,
                         final_counts=finals if self.scn.tdma.poll else None,
                         counters={sid: dict(c.counters) for sid, c in zip(self.scn.ids, self.cores) if c},
                         clock_err_s=cerr, clock_var_s2=cvar, clock_true_s=ctrue,
                         time_scales={sid: list(c.clk.scale_log) for sid, c in zip(self.scn.ids, self.cores) if c})

    def true_clocks(self) -> dict:
        """Station id -> its true oscillator (stations not started yet: drawn from the world seed)."""
        return {sid: (self.clocks[k] if self.cores[k] is not None else station_clock(self.scn, sid, self.seed))
                for k, sid in enumerate(self.scn.ids)}

    def definition_spread_s(self, r, times_s) -> np.ndarray:
        """How far the stations' definitions of network time are apart at each of ``times_s`` (K,), s:
        each station's network time on the true clocks, ``E_k - x_1 = x_k - x_1 - its true offset``
        (``r.clock_true_s`` (K, n) of :meth:`run` at those times), largest minus smallest over the
        stations alive."""
        clocks = self.true_clocks()
        x = np.array([[clocks[sid].error_s(t) for sid in r.ids] for t in times_s])  # (K, n)
        E = x - x[:, :1] - r.clock_true_s
        return np.nanmax(E, axis=1) - np.nanmin(E, axis=1)

    def true_clock_offset_s(self, k: int, t_true_s: float) -> float:
        """True offset of station index ``k``'s clock against network time as that station defines it
        (its ensemble's members and constants, :attr:`ClockEstimator.scale_log`), on the true clocks."""
        return true_network_offset_s(self.true_clocks(), self.cores[k].clk.scale_log, self.scn.ids[k], t_true_s)
