"""Station process: one :class:`~stations.core.StationCore` driven by the wall clock over Zenoh.

The node is a thin I/O shell around the same objects the in-process simulator runs
(``stations.sim.make_core`` -> ``StationCore`` + ``Clock``, ``net.channel.AirChannel``, seeded from
the same per-station streams):

* **time**: fleet (true) time ``t = (wall - epoch) * speed``; every process computes slot
  boundaries itself from the common epoch (no clock master). The core works on the station's
  *local* clock ``clock.to_local(t)``.
* **timers**: the core's ``next_deadline()`` (local) is converted to wall time; ``on_timer`` is
  called with the exact deadline. A request timer firing after half a slot is a *missed slot*.
* **transmit**: core outputs go to their keys (``net.messages.key_for``); air messages carry the
  physical part ``phy`` = true sender position + true transmit time (``clock.to_true(t_tx_s)``).
  The core's ``estimate`` is published with the true position on ``.../truth``. A nav goes out on
  ``larns/station/<id>/nav/<tile>``, the tile of the true position (``net/tiles.py``).
* **subscriptions**: the navs of the tiles within the radio's reach of the true position (all of
  them without ``[radio]``) and the range requests and replies addressed to this station.
* **receive**: bytes -> strict decode (malformed: counted and dropped, never a crash) -> key/src
  consistency -> wire faults (delay, jitter, loss, duplication; seeded) -> duplicate filter ->
  air channel (time of flight, clock, noise, NLOS, air loss) -> local rx timestamp. The core, not
  the node, decides on its own clock whether an exchange completed within its slot (the physical
  timestamps come from ``phy``, so host latency does not change them). ``phy`` is stripped before
  the core sees the message.
* **emulated-time order**: the nav timer of the own slot waits (at most ``lookahead_s`` of wall
  time) for the outstanding range reply, so the core consumes its exchange before its nav as in the
  simulator; a message handed to the core behind its clock is counted ``host_late`` (apart from
  ``air_lost``), and only a reply the core has already given up on is lost.

SIGINT / SIGTERM: clean exit (liveliness token withdrawn, session closed).

Profiling: with ``LARNS_PROFILE=DIR`` in the environment the main loop (timers and the batched nav
receive path) runs under cProfile and the stats go to ``DIR/station_<id>.prof`` at exit.
"""

from __future__ import annotations

import argparse
import gc
import heapq
import importlib
import logging
import math
import os
import sys
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from net import messages as M
from net import streams
from net.channel import AirChannel, scenario_senders, station_rng
from net.faults import WireFaults, merge_faults
from net.procsched import add_sched_args, apply_sched_args
from net.radio import may_link
from net.scenario import Scenario, joiner_position
from net.tiles import Tiling, parse_tile

from .shell import PublishPolicy, true_clock_error_s
from .shellfaults import ShellFaults
from .slots import reception_in_slot

log = logging.getLogger("larns.station")

# distributed assignment: a nav is held this long (wall s) after the end of its slot before it is
# judged (stations.slots.reception_in_slot), so that the navs sent in the same slot have reached us:
# the bus takes about a millisecond on one host, but a loaded host runs a station's nav timer late by
# tens of ms. Navs are not latency-critical (their timing comes from phy; with the fixed plan they
# wait up to a cycle for the batch before the own nav)
NAV_HOLD_WALL_S = 0.1

AIR_KINDS = M.AIR_MSG_KINDS  # addressed: range_req / range_rsp; protocol v2: poll / reply; nav
EXCHANGE_KINDS = ("range_req", "range_rsp", "poll", "reply")  # latency-critical: a callback each
PENDING_MAX = 4096  # messages held back by emulated wire delays (bounded under a flood)
SWITCH_INTERVAL_S = 0.0005  # GIL hand-over interval of a station process (Python default 5 ms)


def lookahead_default(scn: Scenario) -> float:
    """Wall seconds the own nav (a poll's final) waits for replies still awaited. The addressed
    exchange's one reply arrives within 3 ms on this host (p99, seed000 at speed 1); a poll's nine
    members all reply at once, contending for the cores: on the quiet 2-core box (seed000-poll, 60 s
    at speed 1) replies came 3.3 / 16.6 / 47 ms after the poll (p50 / p90 / p99), and a 50 ms wait let
    56-95 % of the polls be answered by every member against 96.6-98.3 % with 150 ms (the rest: the
    first and the last cycle; docs/protocol.md). Physics does not change (stamps come from ``phy``);
    the nav only leaves later in wall time."""
    return 0.15 if scn.tdma.poll else 0.05


def default_epoch(now_s: float | None = None) -> float:
    """Start of the current UTC day: a common epoch for processes started without ``--epoch``
    (fleet times stay small, so time differences keep sub-millimetre float resolution)."""
    now_s = time.time() if now_s is None else now_s
    return math.floor(now_s / 86400.0) * 86400.0


@dataclass
class NodeOptions:
    station_id: int
    join: bool = False
    speed: float = 1.0
    epoch_unix_s: float | None = None
    duration_s: float | None = None  # stop at this fleet time (seconds since the epoch); None = forever
    run_s: float | None = None       # or: run this many fleet seconds from power-on (--duration)
    start_at_s: float | None = None  # fleet time at which the station powers on (None: now)
    estimator: str | None = None
    seed: int | None = None
    status_every_s: float = 5.0       # fleet seconds between status lines (0 = never)
    quiet: bool = False
    journal: bool = True              # publish the core journal (larns/station/<id>/init, .../input)
    lookahead_s: float | None = None  # wall seconds the nav timer waits for outstanding replies (None: lookahead_default)


class StationNode:
    """Wall-clock shell around a station core. ``run()`` blocks until stopped or the duration ends."""

    def __init__(self, scn: Scenario, opts: NodeOptions, bus: Any):
        from .sim import make_core

        if opts.station_id not in scn.ids:
            raise ValueError(f"station {opts.station_id} is not in scenario {scn.name} (ids {scn.ids}); "
                             "a station from outside the scenario hot-joins with --join")
        if opts.speed <= 0:
            raise ValueError("--speed must be > 0")
        self.scn = scn
        self.opts = opts
        self.id = opts.station_id
        self.bus = bus
        self.epoch = default_epoch() if opts.epoch_unix_s is None else float(opts.epoch_unix_s)
        self.speed = float(opts.speed)
        self.seed = scn.seed if opts.seed is None else opts.seed
        self._stop = threading.Event()
        self.true_pos = np.asarray(scn.true_pos(self.id), float)
        # the wire's spatial tiles (net/tiles.py): the own nav's key, the tiles within radio reach
        self.tiling = Tiling.of(scn)
        self.nav_key = self.tiling.nav_key(self.id, self.true_pos)
        self._make_core = make_core
        self.core = None
        self.clock = None
        self.air = AirChannel(scn.channel, station_rng(self.seed, self.id, streams.AIR), (self.seed, self.id))
        from .sim import station_clock

        self.senders = scenario_senders(scn, self.seed, self._true_clock)  # the channel's truth of each sender
        self.ref_clock = station_clock(scn, scn.ids[0], self.seed)  # station 1's clock (truth side only)
        self.true_clocks = {i: station_clock(scn, i, self.seed) for i in scn.ids}  # network time's truth side
        self._last_input_s = -math.inf  # local time of the core's latest input
        self.shell = ShellFaults(scn, self.id)  # per-link channel, [[faults]] (as in the simulator)
        self.wire = WireFaults(scn.net, station_rng(self.seed, self.id, streams.WIRE))
        self.slot_s = scn.tdma.slot_s
        self.lookahead_s = lookahead_default(scn) if opts.lookahead_s is None else float(opts.lookahead_s)
        self._end_s = math.inf  # fleet time the run stops (run(): --until or --duration)
        self.cycle_s = scn.tdma.cycle_s
        self.drops = M.DropCounter(f"station {self.id}")
        self.stats: Counter[str] = Counter()
        self.max_lateness_s = 0.0
        self._lock = threading.RLock()  # core, channel and fault models: one thread at a time
        self._wake = threading.Event()
        self._pending: list = []  # heap of (wall deliver time, order, msg, phy)
        self._order = 0
        self._seen: set = set()
        self._seen_q: deque = deque()
        self.policy = PublishPolicy(self.id, journal=opts.journal)  # estimate/truth/journal decorations
        self._journal_thread: threading.Thread | None = None
        self._journal_q: Any = None
        self._last_status = -math.inf
        self._wire_delay_s: deque = deque(maxlen=10000)  # recent range message delivery delays
        self._nav_subs: list = []
        self._power_on_s: float | None = None  # fleet time of start_core (the bus counters' time base)
        self._last_drain = -math.inf
        # distributed assignment, the world side of the radio in a slot (stations.slots.reception_in_slot):
        # per sender of the world, the slot it last announced on the air (its nav's and request's
        # ``slot``), the fleet time of that, and whether its radio reaches ours (true positions)
        self._air_slots: dict[int, tuple[int, float, bool]] | None = {} if scn.tdma.distributed else None
        # (key, bytes) -> (msg, phy); --secure: rate limit, signature, replay first (net/security.py)
        sec = getattr(bus, "security", None)
        self._decode = (lambda key, data: M.decode(data)) if sec is None else \
            sec.station_guard(self.cycle_s, self.fleet_now, self.speed).decode  # (limiter: monotonic clock)

    # ------------------------------------------------------------------ time
    def fleet_now(self) -> float:
        return (time.time() - self.epoch) * self.speed

    def wall_of(self, t_true_s: float) -> float:
        return self.epoch + t_true_s / self.speed

    def _sleep_until_fleet(self, t_s: float) -> None:
        while not self._stop.is_set():
            dt = self.wall_of(t_s) - time.time()
            if dt <= 0:
                return
            time.sleep(min(dt, 0.1))

    def stop(self, *_: Any) -> None:
        self._stop.set()
        self._wake.set()

    # ------------------------------------------------------------------ receive path
    def _on_bytes(self, key: str, data: bytes) -> None:
        """Zenoh thread: the whole receive path runs here (no hand-over to the main thread, one
        context switch less per message); the lock serializes it with the timer loop."""
        recv = time.time()
        with self._lock:
            if self.core is None or self._stop.is_set():
                return
            core = self.core
            sched = (core.slot, core.state, core.awaiting())  # a message re-schedules the core via these
            self._ingest(recv, key, data)
            self._deliver_due()
            if self._pending or (core.slot, core.state, core.awaiting()) != sched:
                self._wake.set()  # the main loop re-computes when to wake up (else: <= 0.1 s anyway)

    def _drain_every_s(self) -> float:
        """Wall seconds between nav drains when no own nav is due: a station with a slot drains
        right before its own nav (``_drain_due``), this is only a fallback; a station without a
        slot (listening to join) drains 4 times per cycle."""
        frac = 1.5 if self.core is not None and self.core.slot is not None else 0.25
        return frac * self.cycle_s / self.speed

    def _drain_due(self, t: float) -> bool:
        """Navs are read in one batch per cycle, right before the station's own nav: a whole cycle
        of peer estimates feeds the solve behind that nav, and the batch never competes with the
        station's own range exchange at the start of its slot (it ran 5 ms earlier) nor wakes the
        process at other times. Fallback: :meth:`_drain_every_s`."""
        if not self._nav_subs:
            return False
        now = time.time()
        if now - self._last_drain >= self._drain_every_s():
            return True
        if t < 0 or self.core is None:
            return False
        dl = self.core.next_deadline()
        return dl is not None and not self._is_slot_start(dl) and self.wall_of(self.clock.to_true(dl)) <= now

    def _closes_too_late(self, t_local_s: float) -> bool:
        """Whether the own slot starting at ``t_local_s`` would end, with its final's bounded wait for
        the replies (``--lookahead``), after the run's end: such a slot is not begun, so a run stopped
        at its duration leaves no poll or request whose nav never went out."""
        return self.clock.to_true(t_local_s) + self.slot_s + self.lookahead_s * self.speed > self._end_s

    def _is_slot_start(self, t_local_s: float) -> bool:
        """The core's own-slot (request) timer: its slot start on network time, on its local clock."""
        t = self.core.next_request_s() if self.core is not None else None
        return t is not None and abs(t_local_s - t) < 1e-9

    def _drain_navs(self) -> None:
        """Feed the navs waiting in the ring buffer through the normal receive path. The node lock
        is taken per nav, not for the whole batch: a range request or reply arriving meanwhile on
        a Zenoh thread gets in between two navs instead of waiting for the batch."""
        for key, data in self._ring_batch():
            with self._lock:
                if self._stop.is_set():
                    return
                self._ingest(time.time(), key, data)
                if self._air_slots is None:
                    self._deliver_due()
        if self._air_slots is not None:  # the whole batch noted before any nav of it is judged
            with self._lock:
                if not self._stop.is_set():
                    self._deliver_due()

    def _ring_batch(self) -> list:
        """Every ``(key, bytes)`` waiting in the navs' ring buffers (the drain's time noted)."""
        self._last_drain = time.time()
        return [kd for sub in self._nav_subs for kd in self.bus.drain(sub)]

    def _deliver_due(self) -> None:
        """Hand the core every held message that is due (lock held). With the distributed assignment
        the navs waiting in the ring buffers are noted first (:meth:`_ingest`): a held nav is due
        once the other navs of its slot have arrived, and they must be known when it is judged."""
        if not self._pending or self._pending[0][0] > time.time():
            return
        if self._air_slots is not None:
            for key, data in self._ring_batch():
                self._ingest(time.time(), key, data)
        now = time.time()
        while self._pending and self._pending[0][0] <= now:
            _, _, msg, phy = heapq.heappop(self._pending)
            self._deliver(msg, phy)

    def _check_key(self, key: str, msg: dict) -> bool:
        pk = M.parse_key(key)
        if pk is None or pk[0] != "station" or pk[1] != msg["src"]:
            return False
        rest = pk[2]
        kind = msg["kind"]
        if kind == "nav":  # its tile (net/tiles.py), or none (a recording from before tiles, replayed)
            return rest == ["nav"] or (len(rest) == 2 and rest[0] == "nav" and parse_tile(rest[1]) is not None)
        if kind == "range_req":
            return rest == ["range", "req", str(self.id)] and msg["dst"] == self.id
        if kind == "range_rsp":
            return rest == ["range", "rsp", str(self.id)] and msg["dst"] == self.id
        if kind == "poll":
            return rest == ["poll"]
        if kind == "reply":
            return rest == ["reply", str(self.id)] and msg["dst"] == self.id
        return False

    def _ingest(self, recv_wall: float, key: str, data: bytes) -> None:
        self.stats["bus_rx"] += 1  # every sample the bus delivered (larns bench wire)
        try:
            msg, phy = self._decode(key, data)
        except M.MessageError as e:
            self.drops.drop_error(e)
            return
        if msg["kind"] not in AIR_KINDS or phy is None:
            self.drops.drop("kind", f"{msg['kind']} on {key} (phy {'present' if phy else 'absent'})")
            return
        if not self._check_key(key, msg):
            self.drops.drop("key", f"{msg['kind']} from {msg['src']} on {key}")
            return
        if msg["src"] == self.id:
            return
        hold = recv_wall
        if self._air_slots is not None and msg["kind"] not in ("range_rsp", "reply"):
            self._announced(msg)
            if msg["kind"] == "nav":  # judged once the slot is over and its other navs are in
                hold = min(max(recv_wall, self.wall_of(float(phy["t_true_s"]) + self.slot_s) + NAV_HOLD_WALL_S),
                           recv_wall + 1.0)
        for delay in self.wire.deliveries():
            self._order += 1
            heapq.heappush(self._pending, (hold + delay / self.speed, self._order, msg, phy))
            if len(self._pending) > PENDING_MAX:  # bounded under a flood: the longest-waiting one goes
                heapq.heappop(self._pending)
                self.drops.drop("pending_full", f"more than {PENDING_MAX} messages held by wire delays")
        if not self.wire.active:
            return
        self.stats["wire_in"] += 1

    def _deliver(self, msg: dict, phy: dict) -> None:
        ident = (msg["kind"], msg["src"], msg["seq"])
        if ident in self._seen:
            self.stats["duplicates"] += 1
            return
        self._seen.add(ident)
        self._seen_q.append(ident)
        if len(self._seen_q) > 4096:
            self._seen.discard(self._seen_q.popleft())
        if msg["kind"] in EXCHANGE_KINDS:
            self._wire_delay_s.append((self.fleet_now() - phy["t_true_s"]) / self.speed)  # wall: tx -> here
        # the channel owns physics: the named sender's true position and clock, not its phy claims
        tx = self.senders.receive(msg, phy, self.fleet_now())
        if isinstance(tx, str):
            self.drops.drop(tx, f"{msg['kind']} from station {msg['src']}: "
                            + ("stamped far from now" if tx == "time" else "not in the scenario"))
            return
        if self._air_slots is not None and self._lost_in_slot(msg, tx[1]):
            return
        t_rx_local = self.shell.arrival_local_s(self.air, msg["src"], tx[0], tx[1], self.true_pos, self.clock)
        if t_rx_local is None:
            self.stats["air_lost"] += 1
            return
        self.stats["rx_" + msg["kind"]] += 1
        if msg["kind"] in EXCHANGE_KINDS:  # (navs are fed in batches by design)
            if t_rx_local < self._last_input_s:
                self.stats["host_late"] += 1  # behind the core's clock: handed over anyway, the core decides
            self._last_input_s = max(self._last_input_s, t_rx_local)
        lost = self.core.counters["ignored"] + self.core.counters["late"]
        try:
            outs = self.core.on_message(msg, t_rx_local)  # phy stripped: the core sees msg only
        except Exception as e:  # noqa: BLE001 - the delivery loop survives any core exception
            self._core_error("on_message", e)
            return
        if self.core.counters["ignored"] + self.core.counters["late"] != lost:
            self.stats["core_late"] += 1
        self._send(outs)

    def _announced(self, msg: dict) -> None:
        """Note the slot a sender of the world transmits in (distributed assignment). The entry's
        reach is the radio's between the two true positions (``net.radio.may_link``)."""
        src, slot = msg["src"], msg.get("slot")
        pos = self.senders.positions.get(src)
        if pos is None or slot is None:
            return
        old = self._air_slots.get(src)
        reach = old[2] if old is not None else bool(may_link(np.stack([pos, self.true_pos]), self.scn.channel.radio)[0, 1])
        self._air_slots[src] = (int(slot), self.fleet_now(), reach)

    def _lost_in_slot(self, msg: dict, t_tx_true_s: float) -> bool:
        """Whether this radio loses ``msg`` to another sender in its slot (or to its own transmission
        there): the holders are the senders that announced the slot within 1.5 cycles (each
        announces it every cycle), so a slot claimed this cycle is seen a cycle late; the simulator
        reads the cores' slots instead. A nav lost to another sender is garbage for the core."""
        mine = self.core.slot
        s = mine if msg["kind"] in ("range_rsp", "reply") else msg.get("slot")
        if s is None:
            return False
        src, now, horizon = msg["src"], self.fleet_now(), 1.5 * self.cycle_s
        other = any(h != src and sl == s and reach and now - t <= horizon
                    for h, (sl, t, reach) in self._air_slots.items())
        lost, garbage = reception_in_slot(msg["kind"], mine == s, other)
        if garbage:
            self.stats["slot_garbage"] += 1
            self.core.on_garbage(self.clock.to_local(t_tx_true_s + 1e-6))
        self.stats["slot_lost"] += lost
        return lost

    def _true_clock(self, sid: int):
        """Station ``sid``'s true oscillator, shared with the truth side (one realization per process:
        extending one to late fleet times costs seconds and megabytes)."""
        from .sim import station_clock

        clk = self.true_clocks.get(sid)  # (a joiner from outside the scenario: its own, kept by SenderTruth)
        return station_clock(self.scn, sid, self.seed) if clk is None else clk

    def _core_error(self, where: str, e: Exception) -> None:
        """A core exception: counted (``core_errors``, drop reason ``core``), logged at a limited rate
        (the drop counter's), the traceback at debug level; the node keeps running."""
        self.stats["core_errors"] += 1
        self.drops.drop("core", f"{where}: {type(e).__name__}: {e}")
        log.debug("station %d: core %s failed", self.id, where, exc_info=True)

    # ------------------------------------------------------------------ transmit path
    def _send(self, outs: list[dict]) -> None:
        for m in outs:
            kind = m["kind"]
            try:
                if kind in AIR_KINDS:
                    t_true = self.clock.to_true(m["t_tx_s"])
                    m = self.shell.outgoing(m, t_true)
                    data = M.encode(m, {"pos_m": self.true_pos, "t_true_s": t_true})
                elif kind == "estimate":
                    m = self.policy.estimate(m, self.core.slot, self.drops.total)
                    data = M.encode(m)
                    self._publish_truth(m)
                else:
                    data = M.encode(m)
            except M.MessageError as e:  # a core bug: report loudly, keep running
                log.error("station %d: refusing to send invalid %s: %s", self.id, kind, e)
                self.stats["tx_invalid"] += 1
                continue
            self.bus.publish(self.nav_key if kind == "nav" else M.key_for(m), data)
            self.stats["tx_" + kind] += 1
            self.policy.sent(kind)
        for kind, fields in self.policy.after_outputs(self.core, outs):
            self._journal_submit(kind, fields)

    # ------------------------------------------------------------------ core journal
    def _journal_submit(self, kind: str, fields: dict) -> None:
        """Hand a journal message to the sender thread: it is encoded (validated, split when too
        big) and published there, outside the node lock, so a big journal never delays the reply
        to a range request. Journal samples go out with congestion control BLOCK (a journal with a
        hole cannot be replayed bit for bit, while an air message dropped under load is just a lost
        measurement); a slow recorder can stall that thread, never the station's timing. The FIFO
        is bounded; overflow is counted (``journal_dropped``)."""
        stamp_s = self.fleet_now()
        if getattr(self.bus, "session", None) is None:  # a test double without a Zenoh session
            self._journal_emit(kind, fields, stamp_s, self.bus.publish)
            return
        if self._journal_thread is None:
            import queue

            self._journal_q = queue.Queue(maxsize=512)
            self._journal_thread = threading.Thread(target=self._journal_sender, name="journal", daemon=True)
            self._journal_thread.start()
        try:
            self._journal_q.put_nowait((kind, fields, stamp_s))
        except Exception:  # queue.Full
            self.stats["journal_dropped"] += 1

    def _journal_emit(self, kind: str, fields: dict, stamp_s: float, publish) -> None:
        """Encode one journal item (``PublishPolicy.encode_journal``: a core_input split while too
        big) and publish it."""
        for key, data in self.policy.encode_journal(kind, fields, stamp_s, self._journal_error):
            publish(key, data)

    def _journal_error(self, kind: str, n_entries: int, e: M.MessageError) -> None:
        if kind == "core_init":
            log.error("station %d: cannot publish core_init: %s", self.id, e)
            return
        log.error("station %d: dropping %d journal entries: %s", self.id, n_entries, e)
        self.stats["journal_invalid"] += 1

    def _journal_sender(self) -> None:
        def publish(key: str, data: bytes) -> None:
            self.bus.publish(key, data, block=True)

        while True:
            item = self._journal_q.get()
            if item is None:
                return
            try:
                self._journal_emit(item[0], item[1], item[2], publish)
            except Exception:  # session closing
                log.debug("journal sample not sent", exc_info=True)

    def _flush_journal(self, timeout_s: float = 2.0) -> None:
        """At exit: let the queued journal samples leave before the session closes."""
        if self._journal_thread is not None:
            try:
                self._journal_q.put(None, timeout=timeout_s)
            except Exception:
                pass
            self._journal_thread.join(timeout_s)

    def _publish_truth(self, est: dict) -> None:
        tau = self.clock.to_true(float(est["stamp_s"]))  # the estimate's instant
        m = self.policy.truth(est, self.fleet_now(), self.true_pos,
                              clock_error_s=true_clock_error_s(self.core.clk, {**self.true_clocks, self.id: self.clock},
                                                               self.id, tau))
        self.bus.publish(M.key_for(m), M.encode(m))

    # ------------------------------------------------------------------ main loop
    def _fire_timers(self) -> None:
        for _ in range(16):  # bounded: a core asking for the past repeatedly must not spin
            dl = self.core.next_deadline()
            if dl is None:
                return
            wall = self.wall_of(self.clock.to_true(dl))
            now = time.time()
            if wall > now:
                return
            lateness = now - wall
            is_req = self._is_slot_start(dl)
            if is_req and self._closes_too_late(dl):
                return
            if not is_req and self.core.awaiting() and now < wall + self.lookahead_s:
                return  # emulated-time order: the outstanding replies first (bounded wait)
            self._last_input_s = max(self._last_input_s, dl)
            try:
                outs = self.core.on_timer(dl)
            except Exception as e:  # noqa: BLE001 - the timer loop survives any core exception
                self._core_error("on_timer", e)
                return
            if is_req:
                self.stats["slots"] += 1
                self.max_lateness_s = max(self.max_lateness_s, lateness * self.speed)
                if lateness * self.speed > 0.5 * self.slot_s:
                    self.stats["missed_slots"] += 1
            self._send(outs)

    def _next_wake(self) -> float:
        t = time.time() + 0.1
        dl = self.core.next_deadline()
        if dl is not None and self._is_slot_start(dl) and self._closes_too_late(dl):
            dl = None  # not begun: wake at the end (run())
        if dl is not None:
            w = self.wall_of(self.clock.to_true(dl))
            if not self._is_slot_start(dl) and self.core.awaiting() and time.time() >= w:
                w += self.lookahead_s  # waiting for the outstanding replies
            t = min(t, w)
        if self._pending:
            t = min(t, self._pending[0][0])
        return t

    def _status(self, t: float) -> None:
        if self.opts.quiet or self.opts.status_every_s <= 0 or t - self._last_status < self.opts.status_every_s:
            return
        self._last_status = t
        est = self.core.est
        err = float(np.linalg.norm(np.asarray(est.pos_m) - self.true_pos)) if est.pos_m is not None else math.nan
        print(f"[station {self.id}] t={t:7.1f}s state={self.core.state} slot={self.core.slot} "
              f"updates={est.n_updates} err={err:.2f} m drops={self.drops.total} "
              f"late={self.stats['core_late']} host_late={self.stats['host_late']} missed={self.stats['missed_slots']} "
              f"sync={self._sync_ns():.2f} ns rx={self._rx_total()} next={self._next_in_s():+.1f}s",
              file=sys.stderr, flush=True)

    def _rx_total(self) -> int:
        """Air messages handed to the core so far: a number that stops growing means a deaf station."""
        return sum(v for k, v in self.stats.items() if k.startswith("rx_"))

    def _next_in_s(self) -> float:
        """Fleet seconds until the core's next deadline (its slot or its nav; NaN if none): a number
        far above the cycle means the station's network time jumped away from the others'."""
        dl = self.core.next_deadline()
        return math.nan if dl is None else (self.wall_of(self.clock.to_true(dl)) - time.time()) * self.speed

    def _sync_ns(self) -> float:
        """Current clock error against network time (estimate minus truth), ns - for status lines."""
        t = self.fleet_now()
        true_s = true_clock_error_s(self.core.clk, {**self.true_clocks, self.id: self.clock}, self.id, t)
        if true_s is None:
            return math.nan
        return (self.core.clk.ensemble_offset_at(self.clock.to_local(t))[0] - true_s) * 1e9

    def start_core(self) -> None:
        """Power on: build the core at the current fleet time (what ``run`` does first)."""
        t0 = max(0.0, self.fleet_now())
        self._power_on_s = t0
        self.core, self.clock = self._make_core(self.scn, self.id, estimator=self.opts.estimator,
                                                join=self.opts.join, start_s=t0, seed=self.seed)
        for kind, fields in self.policy.start(self.core):
            self._journal_submit(kind, fields)

    def run(self) -> dict:
        bus = self.bus
        me = self.id
        if self.opts.start_at_s is not None:
            self._sleep_until_fleet(self.opts.start_at_s)
            if self._stop.is_set():
                return self.report()
        self.start_core()
        if self.scn.tdma.poll:  # protocol v2: every poll (a broadcast), the replies to ours
            bus.subscribe("larns/station/*/poll", self._on_bytes)
            bus.subscribe(f"larns/station/*/reply/{me}", self._on_bytes)
        else:
            bus.subscribe(f"larns/station/*/range/req/{me}", self._on_bytes)
            bus.subscribe(f"larns/station/*/range/rsp/{me}", self._on_bytes)
        # navs (one per neighbour and cycle, not latency-critical: their timing comes from phy) go
        # through Zenoh ring buffers drained in batches, one per tile within radio reach
        # (net/tiles.py); range requests/replies wake us immediately
        for keyexpr in self.tiling.nav_subscriptions(self.true_pos):
            if hasattr(bus, "subscribe_ring"):
                self._nav_subs.append(bus.subscribe_ring(keyexpr, 16384))
            else:  # a bus without ring buffers: one callback per nav
                bus.subscribe(keyexpr, self._on_bytes)
        bus.declare_token(M.alive_key("station", me))
        end = math.inf if self.opts.duration_s is None else self.opts.duration_s
        if self.opts.run_s is not None:  # --duration: counted from power-on, after the start-up
            end = max(0.0, self.fleet_now()) + self.opts.run_s
        self._end_s = end
        if not self.opts.quiet:
            print(f"[station {me}] scenario {self.scn.name}, join={self.opts.join}, speed={self.speed}, "
                  f"epoch={self.epoch:.3f}, slot={self.core.slot}", file=sys.stderr, flush=True)
        while not self._stop.is_set():
            t = self.fleet_now()
            if t >= end:
                break
            if self._drain_due(t):
                self._drain_navs()
            with self._lock:
                if t >= 0:
                    self._fire_timers()
                self._deliver_due()
                self._status(t)
                wake = self._next_wake()
                self._wake.clear()
            if end < math.inf:
                wake = min(wake, self.wall_of(end))
            if self._nav_subs:
                wake = min(wake, self._last_drain + self._drain_every_s())
            timeout = wake - time.time()
            if timeout > 0:
                self._wake.wait(timeout)
        with self._lock:
            self._stop.set()  # callbacks still in flight become no-ops
        self._flush_journal()
        return self.report()

    def report(self) -> dict:
        if self.core is None:
            return {"id": self.id, "state": "off", "slot": None, "n_updates": 0, "pos_m": [math.nan] * 3,
                    "err_m": math.nan, "slots": 0, "missed_slots": 0, "late": 0, "duplicates": 0,
                    "air_lost": 0, "max_lateness_ms": 0.0, "drops": self.drops.as_dict(), "counters": {},
                    "exchanges": [], "tx": {}, "rx": {}}
        est = self.core.est
        pos = np.asarray(est.pos_m, float) if est.pos_m is not None else np.full(3, np.nan)
        return {
            "id": self.id, "state": self.core.state, "slot": self.core.slot,
            "n_updates": int(est.n_updates), "pos_m": pos.tolist(),
            "err_m": float(np.linalg.norm(pos - self.true_pos)),
            "slots": int(self.stats["slots"]), "missed_slots": int(self.stats["missed_slots"]),
            "late": int(self.stats["core_late"]), "duplicates": int(self.stats["duplicates"]),
            "range_delay_ms": ({f"p{q}": float(np.percentile(self._wire_delay_s, q)) * 1e3 for q in (50, 90, 99)}
                               if self._wire_delay_s else {}),
            "air_lost": int(self.stats["air_lost"]), "slot_lost": int(self.stats["slot_lost"]),
            "slot_garbage": int(self.stats["slot_garbage"]), "max_lateness_ms": self.max_lateness_s * 1e3,
            "host_late": int(self.stats["host_late"]), "core_late": int(self.stats["core_late"]),
            "sync_err_ns": self._sync_ns(),
            "journal_dropped": int(self.stats["journal_dropped"]),
            "drops": self.drops.as_dict(), "counters": dict(self.core.counters),
            "implausible": dict(self.core.admission.dropped),  # by reason (stations/admission.py)
            "core_errors": int(self.stats["core_errors"]),
            "exchanges": [list(e) for e in self.core.exchanges],  # [t_tx_s local, addressee, replied]
            "tx": {k[3:]: v for k, v in self.stats.items() if k.startswith("tx_")},
            "rx": {k[3:]: v for k, v in self.stats.items() if k.startswith("rx_")},
            "bus_rx": int(self.stats["bus_rx"]), "bus_s": self._bus_s(),
        }

    def _bus_s(self) -> float:
        """Fleet seconds since power-on: the time base of ``bus_rx`` (samples the bus delivered)."""
        return 0.0 if self._power_on_s is None else max(0.0, self.fleet_now() - self._power_on_s)


# --------------------------------------------------------------------------- command line

def add_args(p: argparse.ArgumentParser) -> None:
    from net import cli

    p.add_argument("--id", type=int, required=True, help="station id (1..65535; 1-3 define the frame)")
    p.add_argument("--join", action="store_true",
                   help="hot-join a running fleet: listen for a cycle, claim a free slot, initialize")
    p.add_argument("--start-at", type=float, default=None, metavar="T",
                   help="power on at fleet time T (with --join: hot-join at T); default: now")
    p.add_argument("--estimator", default=None, help="override the scenario's survey estimator")
    cli.add_process_args(p, scenario="seed000", what="station")
    add_sched_args(p)
    p.add_argument("--nice", type=int, default=0, metavar="N",
                   help="change the scheduling niceness by N (negative = higher priority, needs privileges); "
                        "helps real-time behaviour on a busy machine")
    p.add_argument("--lookahead", type=float, default=None, metavar="S",
                   help="wall seconds the own nav waits for outstanding replies (default 0.05, 0.15 with the poll)")
    p.add_argument("--no-journal", action="store_true",
                   help="do not publish the core journal (larns/station/<id>/init and .../input, "
                        "needed for bit-exact offline re-estimation)")
    cli.add_output_args(p)


def load_scenario(args: argparse.Namespace) -> Scenario:
    """The scenario of ``--scenario`` / ``--n-stations`` with the ``--net-*`` faults merged in."""
    from dataclasses import replace

    from net import scenario as S

    scn = S.load_cli(args.scenario, args.n_stations)
    net = merge_faults(scn.net, args.net_delay, args.net_jitter, args.net_loss, args.net_dup)
    scn = replace(scn, net=net)
    if getattr(args, "join", False) and args.id not in scn.ids:
        scn = with_joiner(scn, args.id)
    return scn


def with_joiner(scn: Scenario, station_id: int) -> Scenario:
    """``scn`` plus a hot-joining station ``station_id`` that it does not list, at
    :func:`joiner_position` (world side only: channel, truth topic, coarse fix - never the
    estimator)."""
    from dataclasses import replace

    if station_id < 1 or station_id > 65535:
        raise ValueError(f"--id {station_id}: expected a station id in 1..65535")
    ids = sorted([*scn.ids, station_id])
    pos = dict(zip(scn.ids, np.asarray(scn.pos_m, float)))
    pos[station_id] = joiner_position(scn, station_id)
    return replace(scn, ids=ids, pos_m=np.array([pos[i] for i in ids]),
                   join_ids=sorted([*scn.join_ids, station_id]))


def main_args(args: argparse.Namespace) -> int:
    from net import cli
    from net.bus import Bus

    cli.setup_logging()
    stop_early = cli.early_stop()  # a signal during start-up (Zenoh open) still means: exit cleanly
    if getattr(args, "nice", 0):
        try:
            os.nice(args.nice)
        except OSError as e:
            log.warning("station %d: cannot change niceness by %d: %s", args.id, args.nice, e)
    # a Zenoh thread delivering a range request must not wait up to 5 ms (the default switch
    # interval) for the GIL while the main thread works through a batch of navs
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    apply_sched_args(args, f"station {args.id}", log)  # before Zenoh starts its threads: they inherit it
    try:
        scn = load_scenario(args)
    except ValueError as e:  # (ScenarioError included) one line, exit 2
        print(f"error: station {args.id}: {e}", file=sys.stderr)
        return 2
    opts = NodeOptions(station_id=args.id, join=args.join, speed=args.speed, epoch_unix_s=args.epoch,
                       duration_s=args.duration, run_s=getattr(args, "run_s", None), start_at_s=args.start_at,
                       estimator=args.estimator, seed=args.seed,
                       status_every_s=args.status_every, quiet=args.quiet,
                       journal=not getattr(args, "no_journal", False),
                       lookahead_s=getattr(args, "lookahead", None))
    args.secure_cn = f"station-{args.id}"
    bus = cli.open_bus(f"station {args.id}", lambda: Bus(**_bus_kwargs(args, scn)))
    # larns fleet's start barrier (--epoch-from): the epoch once every process is up - its imports
    # included: the node's own (the core, the simulator's world, scipy) took 0.9 s on an idle machine
    # and 2 s under load after the epoch, so stations powered on after their cycle-0 slots
    importlib.import_module("stations.sim")
    opts = replace(opts, epoch_unix_s=cli.await_epoch(args, f"station {args.id}", stop_early))
    rep = cli.serve(args, bus, lambda: StationNode(scn, opts, bus), run=_run, stop=stop_early)
    if rep is None:
        return 2
    if not args.quiet:
        print(f"[station {args.id}] stopped: updates={rep['n_updates']} err={rep['err_m']:.2f} m "
              f"drops={rep['drops']['total']} late={rep['late']} host_late={rep['host_late']} "
              f"lost={rep['counters'].get('lost', 0)} missed_slots={rep['missed_slots']} sync={rep['sync_err_ns']:.2f} ns "
              f"range delay ms {' '.join(f'{k}={v:.1f}' for k, v in rep['range_delay_ms'].items())} "
              f"bus_rx={rep.get('bus_rx', 0)} in {rep.get('bus_s', 0.0):.1f} s",
              file=sys.stderr, flush=True)
    return 0


def _run(node: StationNode) -> dict:
    """Run the node with the collector out of the way and, with ``LARNS_PROFILE=DIR``, under cProfile."""
    # everything allocated so far (modules, numpy/scipy/zenoh objects: ~36k) never becomes
    # garbage; moved out of the collector's sight, a full collection takes microseconds instead
    # of ~20 ms, which would otherwise land on a random slot now and then
    gc.freeze()
    prof_dir = os.environ.get("LARNS_PROFILE")  # cProfile of the main loop (timers + nav drain)
    if not prof_dir:
        return node.run()
    import cProfile

    prof = cProfile.Profile()
    prof.enable()
    try:
        return node.run()
    finally:
        prof.disable()
        os.makedirs(prof_dir, exist_ok=True)
        prof.dump_stats(os.path.join(prof_dir, f"station_{node.id}.prof"))


def _bus_kwargs(args: argparse.Namespace, scn: Scenario) -> dict:
    """The station's bus settings; with ``--secure`` the Zenoh ingress flood guard for this
    scenario's TDMA (net/security.py)."""
    from net.bus import bus_kwargs
    from net.security import Keystore, flood_guard
    from net.tiles import station_nav_keys

    kw = bus_kwargs(args)
    if "secure" in kw:
        ids = sorted(set(Keystore(kw["secure"][0]).reserved) | set(scn.ids))
        kw["secure"] = (*kw["secure"], flood_guard(scn.tdma.cycle_s, scn.tdma.slot_s, args.speed, ids, args.id,
                                                   nav_keys=station_nav_keys(scn, ids)))
    return kw


def build_parser() -> argparse.ArgumentParser:
    from net import cli

    return cli.build_parser("python -m stations", __doc__, add_args)


def main(argv: list[str] | None = None) -> int:
    from net import cli

    return cli.main(argv, "python -m stations", __doc__, add_args, main_args)
