"""Distributed TDMA slot assignment with spatial reuse (issue 33 item 4): one station's state machine.

Sans-I/O. It is driven, one call per TDMA cycle, by the station core (``stations/core.py``, with
``[tdma] assignment = "distributed"``; the nav carries :meth:`SlotCore.summary` as its ``slots``,
``net/messages.py``), by the MAC simulator :mod:`stations.slotsim` and by the tests (docs/slots.md).

Model. A cycle has ``C`` slots; stations within two hops of each other must not share one (a
receiver in range of two senders in the same slot decodes neither: the hidden terminal), stations
farther apart may (spatial reuse). That is a distance-2 colouring of the link graph, built without a
coordinator in the manner of STDMA (the AIS self-organized TDMA, ITU-R M.1371: a station picks a slot
it does not hear in use) extended with the two-hop view of DRAND (Rhee et al., "DRAND: distributed
randomized TDMA scheduling for wireless ad hoc networks", IEEE TMC 2009) and the neighbourhood
reports of 802.11s MCCA advertisements: every transmission carries the sender's **one-hop view**, the
:class:`SlotSummary` - for each slot the owner it heard there (id and claim cycle), or that it heard
garbage there (a collision). Conflicts are then resolved by randomized trial and error, the
distributed colouring of Johansson ("Simple distributed Delta+1-coloring of graphs", IPL 1999),
with incumbency as priority. Per cycle, from what it heard:

1. *Listen, then pick* (a joiner): after ``listen_cycles`` cycles of listening the station picks
   uniformly at random (its explicit ``numpy.random.Generator``) among the slots free in its two-hop
   view: not used by a neighbour it heard within ``evict_after_cycles`` cycles, not reported used or
   collided by any of them. No free slot: it stays silent and tries again next cycle (``starved``).
2. *Conflict evidence* about the slot it held in the cycle a neighbour's summary describes (summaries
   are one cycle old: built at the end of cycle ``c``, broadcast in ``c + 1``):
   * a neighbour reports another **owner** of our slot (a station two hops away, heard cleanly):
     the lower priority re-picks; priority is the earlier claim, ties broken by a hash of the id
     (:func:`priority`);
   * a neighbour reports **garbage** in our slot (two senders in its range): the incumbent named in
     the report (the last clean owner it heard there within ``evict_after_cycles`` cycles) keeps
     the slot and every other claimant re-picks; with no incumbent known (two fresh claims), each
     claimant re-picks with probability ``backoff_p``;
   * **no acknowledgement**: neighbours are heard but none has reported hearing us cleanly in our
     slot for ``stubborn_cycles`` cycles in a row, or the garbage persists that long (two reporters
     naming different incumbents): re-pick with probability ``backoff_p``;
   * **alone**: a station that hears nobody for ``stubborn_cycles`` cycles may share its slot with a
     neighbour that hears nobody either (an isolated pair: neither is ever heard by the other); it
     keeps its slot but, with probability ``backoff_p``, skips one transmission and listens in its
     own slot (:attr:`SlotCore.listening`); hearing another owner there (or garbage), it re-picks
     whatever the priorities: the other cannot hear it in the shared slot, so only the listener can act.
3. *Outputs* for the next cycle: the slot it will transmit in (or None) and the summary it will
   broadcast there.

Memory is bounded: the peer table holds at most ``max_peers`` entries; a peer not heard for
``evict_after_cycles`` cycles is dropped, and a new id arriving at a full table evicts the least
recently heard entry if it is older than the current cycle, else the newcomer is not stored (a
flood of ids in one cycle cannot push out the neighbours already heard in it).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# SlotSummary.state codes
FREE, CLEAN, SOFT, GARBAGE = 0, 1, 2, 3


def reception_in_slot(kind: str, receiver_sends_there: bool, other_sender_in_reach: bool) -> tuple[bool, bool]:
    """What the radio of a receiver makes of one transmission in a slot other stations also hold
    (distributed assignment): ``(lost, garbage)``. A station transmitting in the slot hears nothing
    in it (half duplex; a range reply falls in its requester's own slot, so the requester listens
    there); a receiver in range of another sender in the slot decodes neither (the hidden terminal).
    A nav lost to another sender is energy heard and nothing decoded: ``garbage``, what the core's
    slot view records (:meth:`stations.core.StationCore.on_garbage`); a transmitting receiver hears
    no energy. The world side of both shells decides with it: the simulator from the cores' slots,
    the Zenoh station from the slots announced on the air."""
    deaf = kind != "range_rsp" and receiver_sends_there
    return deaf or other_sender_in_reach, not deaf and other_sender_in_reach and kind == "nav"


@dataclass(frozen=True)
class SlotConfig:
    """Parameters of the assignment. ``cycle_slots``: slots per TDMA cycle."""

    cycle_slots: int
    max_peers: int = 256
    evict_after_cycles: int = 3
    listen_cycles: int = 1
    stubborn_cycles: int = 3
    backoff_p: float = 0.5

    def __post_init__(self):
        if self.cycle_slots < 1 or self.max_peers < 1 or self.evict_after_cycles < 1:
            raise ValueError("cycle_slots, max_peers and evict_after_cycles must be >= 1")
        if not 0.0 < self.backoff_p <= 1.0:
            raise ValueError("backoff_p must be in (0, 1]")


@dataclass(frozen=True)
class SlotSummary:
    """A station's one-hop view of one cycle, what its next nav would carry (arrays of shape (C,)):
    ``state`` FREE / CLEAN (heard its owner this cycle) / SOFT (owner heard within the eviction
    window, not this cycle) / GARBAGE (energy, nothing decodable: a collision); ``owner`` the id heard
    there (for GARBAGE the last clean owner, the incumbent; 0 none) and ``since`` its claim cycle."""

    state: np.ndarray
    owner: np.ndarray
    since: np.ndarray

    def used(self) -> np.ndarray:
        """(C,) bool: slots this view holds in use (owned or collided)."""
        return self.state != FREE


@dataclass(frozen=True)
class Heard:
    """One clean reception of cycle ``c``: ``sender`` id, the ``slot`` it used, its claim cycle
    ``since`` and the :class:`SlotSummary` it carried (its view of cycle ``c - 1``; None: none yet)."""

    sender: int
    slot: int
    since: int
    summary: SlotSummary | None


@dataclass
class _Peer:
    last_cycle: int
    slot: int
    since: int
    summary: SlotSummary | None


def _mix64(x: int) -> int:
    """SplitMix64 finalizer of ``x``: a stable, well-spread hash of an id (Python's is neither)."""
    x = (x + 0x9E3779B97F4A7C15) & 0xFFFFFFFFFFFFFFFF
    x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & 0xFFFFFFFFFFFFFFFF
    x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
    return x ^ (x >> 31)


def priority(station_id: int, since_cycle: int) -> tuple[int, int]:
    """Priority key of a claim, lower wins: the earlier claim, ties by the id's hash."""
    return int(since_cycle), _mix64(int(station_id))


@dataclass
class SlotCore:
    """One station's slot assignment (sans-I/O; the caller owns time and the radio).

    Call :meth:`on_cycle` once at the end of every cycle with what the station received in it;
    :attr:`slot` is then the slot it holds next cycle (None: none), :attr:`listening` whether it
    skips its transmission there to listen, and :meth:`summary` the view it broadcasts."""

    station_id: int
    cfg: SlotConfig
    rng: np.random.Generator
    slot: int | None = None
    since: int = -1
    starved: int = 0  # cycles it wanted a slot and found none free
    repicks: int = 0
    listening: bool = False  # next cycle: hold the slot but listen in it instead of transmitting
    _peers: dict[int, _Peer] = field(default_factory=dict)
    _listened: int = 0
    _held: dict[int, int | None] = field(default_factory=dict)  # cycle -> slot transmitted in it (last 2)
    _unacked: int = 0
    _garbage_streak: int = 0
    _summary: SlotSummary | None = None

    # ------------------------------------------------------------------ inputs
    def on_cycle(self, cycle: int, heard: list[Heard], garbage_slots=()) -> int | None:
        """End of ``cycle``: ``heard`` (its clean receptions), ``garbage_slots`` (slots with energy and
        nothing decodable). Returns the slot for cycle ``cycle + 1`` (None: silent)."""
        listened_own = self.listening and self.slot is not None
        self._held[cycle] = None if self.listening else self.slot
        self._held.pop(cycle - 2, None)
        for h in heard:
            self._store(cycle, h)
        self._evict(cycle)
        garbage = np.zeros(self.cfg.cycle_slots, bool)
        garbage[[int(k) for k in garbage_slots if 0 <= int(k) < self.cfg.cycle_slots]] = True
        self._listened += 1
        old = self.slot
        if listened_own and self._own_slot_heard(heard, bool(garbage[old])):
            self.slot = None
        if self.slot is not None and self._lose(cycle, heard):
            self.slot = None
        self.repicks += int(old is not None and self.slot is None)
        self._summary = self._build_summary(cycle, garbage)
        self.listening = False
        if self.slot is None and self._listened >= self.cfg.listen_cycles:
            self._pick(cycle, garbage, avoid=old)
        elif self.slot is not None and not self._peers and self._unacked >= self.cfg.stubborn_cycles:
            self._unacked = 0
            self.listening = bool(self.rng.random() < self.cfg.backoff_p)
        return self.slot

    def _own_slot_heard(self, heard: list[Heard], garbage: bool) -> bool:
        """Listening in our own slot: give it up if another owner (or two: garbage) is there. Priority
        plays no part: the other owner cannot hear us in the slot we share (nor can anyone tell it, when
        we are its only common neighbour), so the listener is the one that can act."""
        return garbage or any(h.slot == self.slot for h in heard)

    def _store(self, cycle: int, h: Heard) -> None:
        if h.sender == self.station_id or not 0 <= h.slot < self.cfg.cycle_slots:
            return
        p = self._peers.get(h.sender)
        if p is None and len(self._peers) >= self.cfg.max_peers:
            oldest = min(self._peers, key=lambda k: self._peers[k].last_cycle)
            if self._peers[oldest].last_cycle >= cycle:
                return  # a full table of peers heard this cycle: the newcomer is not stored
            del self._peers[oldest]
        summary = h.summary if self._valid(h.summary) else None
        self._peers[h.sender] = _Peer(cycle, int(h.slot), int(h.since), summary)

    def _valid(self, s: SlotSummary | None) -> bool:
        """A summary of this cycle size (three arrays of ``C`` entries); anything else is ignored."""
        C = self.cfg.cycle_slots
        return s is not None and all(np.shape(a) == (C,) for a in (s.state, s.owner, s.since))

    def _evict(self, cycle: int) -> None:
        for k in [k for k, p in self._peers.items() if cycle - p.last_cycle >= self.cfg.evict_after_cycles]:
            del self._peers[k]

    # ------------------------------------------------------------------ views
    def _build_summary(self, cycle: int, garbage: np.ndarray) -> SlotSummary:
        """The one-hop view of ``cycle``: peers heard (CLEAN this cycle, SOFT within the window, the
        most recent claimant of a slot listed), garbage slots with their last clean owner, our own slot."""
        C = self.cfg.cycle_slots
        state, owner, since = np.zeros(C, np.int8), np.zeros(C, np.int64), np.full(C, -1, np.int64)
        for pid, p in sorted(self._peers.items(), key=lambda kv: kv[1].last_cycle):
            state[p.slot] = CLEAN if p.last_cycle == cycle else SOFT
            owner[p.slot], since[p.slot] = pid, p.since
        # garbage: the incumbent named only if heard cleanly before this cycle (a SOFT entry)
        owner[garbage & (state != SOFT)] = 0
        state[garbage] = GARBAGE
        if self.slot is not None:
            state[self.slot] = CLEAN
            owner[self.slot], since[self.slot] = self.station_id, self.since
        return SlotSummary(state=state, owner=owner, since=since)

    def summary(self) -> SlotSummary | None:
        """The one-hop view to broadcast next cycle (None before the first :meth:`on_cycle`)."""
        return self._summary

    def two_hop_used(self) -> np.ndarray:
        """(C,) bool: slots in use in the two-hop view (own one-hop view and the fresh peers' summaries)."""
        used = self._summary.used().copy() if self._summary is not None else np.zeros(self.cfg.cycle_slots, bool)
        for p in self._peers.values():
            if p.summary is not None:
                used |= p.summary.used()
        return used

    @property
    def peer_count(self) -> int:
        return len(self._peers)

    # ------------------------------------------------------------------ decisions
    def _evidence(self, cycle: int, heard: list[Heard]) -> tuple[bool, bool, bool, bool]:
        """(a better rival is known, garbage with another incumbent, garbage with none, acknowledged)
        about our slot from this cycle's summaries (which describe ``cycle - 1``)."""
        k, me, mine = self.slot, self.station_id, priority(self.station_id, self.since)
        better = other_inc = no_inc = acked = False
        for h in heard:
            s = h.summary
            if not self._valid(s) or h.sender == me:
                continue
            st, own = int(s.state[k]), int(s.owner[k])
            if st == GARBAGE:
                other_inc |= own not in (0, me)
                no_inc |= own == 0
            elif st == CLEAN and own == me:
                acked = True
            elif st in (CLEAN, SOFT) and own not in (0, me):
                better |= priority(own, int(s.since[k])) < mine
        return better, other_inc, no_inc, acked

    def _lose(self, cycle: int, heard: list[Heard]) -> bool:
        """Whether we give up our slot after ``cycle``'s evidence."""
        if self._held.get(cycle - 1) != self.slot:
            self._unacked = self._garbage_streak = 0
            return False  # the summaries heard now describe a cycle before our claim of this slot
        better, other_inc, no_inc, acked = self._evidence(cycle, heard)
        self._unacked = 0 if acked else self._unacked + 1
        self._garbage_streak = self._garbage_streak + 1 if (other_inc or no_inc) else 0
        if better or other_inc:
            return True
        coin = self.rng.random() < self.cfg.backoff_p
        if no_inc:
            return coin
        if (self._unacked >= self.cfg.stubborn_cycles and self._peers) or self._garbage_streak >= self.cfg.stubborn_cycles:
            self._unacked = 0
            return coin
        return False

    def _pick(self, cycle: int, garbage: np.ndarray, avoid: int | None = None) -> None:
        used = self.two_hop_used() | garbage
        if avoid is not None:
            used[avoid] = True  # the slot just given up
        free = np.flatnonzero(~used)
        if free.size == 0:
            self.starved += 1
            return
        self.slot = int(free[self.rng.integers(free.size)])
        self.since = cycle + 1
        self._unacked = self._garbage_streak = 0
