"""Plausibility before trust (issue 32): what a station core admits from a peer's message.

A signed message proves who sent it, not that its values are sane: a stolen station key can sign
anything the wire schema (``net/messages.py``) accepts. Before a value reaches a filter the core
checks it against physical bounds that come from the scenario (:class:`Bounds`):

* positions within the field's extent plus a margin (distance from station 1, the frame origin),
  variances below the square of that bound;
* ranges positive and below the field's diameter (and the radio range);
* clock corrections within the oscillator class (offset, fractional frequency, their variances),
  reference times and range times near the message's own transmit time;
* station ids: a sender is admitted while the number of peers is below the TDMA's slot count;
  an id named in a nav's ``ranges`` must have announced itself (we heard it), apart from a small
  budget of new ids per sender and cycle (a station that has just joined);
* protocol v2 (``poll``, ``reply``, a nav's ``poll``): member lists without repeats and within the peer
  bound, reply delays and the final's stamps within one slot;
* slot claims: a nav's slot must be the slot in which it was received (on our estimate of network
  time), and a sender may change its claimed slot only a few times per window.

A value outside its bounds is dropped and counted by reason (:attr:`Admission.dropped`), never fed
to a filter. Everything here is pure (no clock, no RNG, no I/O): the simulator and the station
process run exactly the same checks, and an offline replay of a journal reproduces them.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass

DAY_S = 86400.0  # fleet times are seconds since the start of the UTC day (stations/node.py)


@dataclass(frozen=True)
class Bounds:
    """Physical bounds of one field (see the module docstring); all finite and positive."""

    pos_m: float             # |position| in the network frame (distance from station 1)
    var_m2: float            # any position variance
    range_m: float           # a two-way range
    clock_offset_s: float    # |clock offset| against network time
    clock_freq: float        # |fractional frequency offset|
    time_window_s: float     # a reference / range time this far from the message's transmit time
    turnaround_s: float      # a responder's turnaround

    @classmethod
    def of(cls, cfg) -> "Bounds":
        """Bounds from a :class:`stations.core.StationConfig`: the field's radius (``field_radius_m``,
        0: unknown, then the radio range ``max_range_m``) plus ``field_margin_m``; the oscillator
        class (10 sigma of the offset at the epoch plus 10 sigma of the frequency over a day, and
        20 sigma of the frequency; never below 10 ms / 1 ppm, never a frequency of 1e-3 or more)."""
        radius = cfg.field_radius_m if cfg.field_radius_m > 0 else cfg.max_range_m
        pos = radius + cfg.field_margin_m
        cycle = cfg.tdma.cycle_s
        return cls(
            pos_m=pos,
            var_m2=(10.0 * pos) ** 2,
            range_m=min(cfg.max_range_m, 2.0 * pos),
            clock_offset_s=max(0.01, 10.0 * cfg.clock_offset_sigma_s + 10.0 * cfg.clock_freq_sigma * DAY_S),
            clock_freq=min(1e-3, max(1e-6, 20.0 * cfg.clock_freq_sigma)),
            time_window_s=(cfg.dead_after_cycles + 1) * cycle,
            turnaround_s=cfg.tdma.slot_s,
        )


def _vec_ok(v, bound: float) -> bool:
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) <= bound


def _cov_ok(c, bound: float) -> bool:
    for i in range(3):
        if not 0.0 <= c[i][i] <= bound:
            return False
    return True


class Admission:
    """One core's admission state: bounds, peer budget, slot-claim history, drop counts.

    ``max_peers`` bounds every per-peer structure of the core (peers, clocks of the network clock
    filter, slot claims); ``new_ids_per_cycle`` is how many not-yet-heard ids one sender may name in
    its ranges per cycle; a sender may change its claimed slot ``slot_changes`` times per
    ``slot_window_cycles`` cycles."""

    def __init__(self, bounds: Bounds, cycle_s: float, max_peers: int, new_ids_per_cycle: int = 2,
                 slot_changes: int = 3, slot_window_cycles: int = 20):
        self.b = bounds
        self.cycle_s = float(cycle_s)
        self.max_peers = int(max_peers)
        self.new_ids_per_cycle = int(new_ids_per_cycle)
        self.slot_changes = int(slot_changes)
        self.slot_window_s = slot_window_cycles * self.cycle_s
        self.ids: set[int] = set()     # every id admitted into the core's state (bounded by max_peers)
        self._new_ids: dict[int, tuple[int, int]] = {}   # sender -> (cycle, new ids named in it)
        self._claims: dict[int, tuple[int, deque]] = {}  # sender -> (claimed slot, times of changes)
        self.dropped: Counter[str] = Counter()

    def drop(self, reason: str) -> None:
        self.dropped[reason] += 1

    # ------------------------------------------------------------------ senders
    def admit_sender(self, src: int) -> bool:
        """A message's sender: admitted if known, or if there is room for one more peer."""
        if src in self.ids:
            return True
        if len(self.ids) >= self.max_peers:
            self.drop("peers_full")
            return False
        self.ids.add(src)
        return True

    def admit_named(self, src: int, peer: int, t_rx_s: float) -> bool:
        """An id named in ``src``'s ranges: one already admitted (heard announce itself, or named
        before), else within the sender's budget of new ids per cycle and the peer bound."""
        if peer in self.ids:
            return True
        cycle = int(t_rx_s // self.cycle_s)
        c, n = self._new_ids.get(src, (cycle, 0))
        if c != cycle:
            n = 0
        if n >= self.new_ids_per_cycle:
            self.drop("new_ids")
            return False
        if peer not in self.ids and len(self.ids) >= self.max_peers:
            self.drop("peers_full")
            return False
        self._new_ids[src] = (cycle, n + 1)
        self.ids.add(peer)
        return True

    # ------------------------------------------------------------------ values
    def station_fields(self, msg: dict, t_rx_s: float) -> str | None:
        """The reason a station message's own values are implausible, or None (plausible)."""
        b = self.b
        t_tx = msg.get("t_tx_s")
        if t_tx is not None and abs(t_tx - t_rx_s) > 2.0 * b.clock_offset_s + b.time_window_s:
            return "time"
        if "pos_m" in msg and not _vec_ok(msg["pos_m"], b.pos_m):
            return "pos"
        if "cov_m2" in msg and not _cov_ok(msg["cov_m2"], b.var_m2):
            return "cov"
        corr = msg.get("clock")
        if corr is not None and not self.clock_ok(corr, msg["t_tx_s"] if t_tx is not None else t_rx_s):
            return "clock"
        if msg["kind"] == "range_rsp":
            if not 0.0 <= msg["turnaround_s"] <= b.turnaround_s:
                return "turnaround"
            t2 = msg.get("t_rx_s")
            if t2 is not None and t_tx is not None and not 0.0 <= t_tx - t2 <= b.turnaround_s:
                return "turnaround"
        return self._poll_fields(msg, t_tx)

    def _poll_fields(self, msg: dict, t_tx: float | None) -> str | None:
        """Protocol v2's fields: a poll's member list (no id twice, at most one per peer: ``members``);
        a reply's delay ``T3 - T2`` within a slot (``turnaround``); a nav's final (``poll``): at most one
        receive stamp per peer, each and the poll's T1 within the slot before the nav's transmit time
        (T1 <= T4 <= T5 <= T1 + slot)."""
        kind, b = msg["kind"], self.b
        if kind == "poll":
            mem = msg["members"]
            if len(mem) > self.max_peers or len(set(mem)) != len(mem):
                return "members"
        elif kind == "reply":
            if not 0.0 <= msg["t_tx_s"] - msg["t_rx_s"] <= b.turnaround_s:
                return "turnaround"
        elif kind == "nav" and "poll" in msg:
            pf = msg["poll"]
            t1, rx = pf["t1"], pf["rx"]
            if not 0.0 <= t_tx - t1 <= b.turnaround_s or len(rx) > self.max_peers:
                return "poll"
            if len({p for p, _ in rx}) != len(rx) or not all(t1 <= t4 <= t_tx for _, t4 in rx):
                return "poll"
        return None

    def clock_ok(self, corr, t_tx_s: float) -> bool:
        """A clock correction ``[t_ref, offset, freq, P_tt, P_tf, P_ff]`` within the oscillator class."""
        b = self.b
        t_ref, off, f, ptt, ptf, pff = corr
        return (abs(t_ref - t_tx_s) <= b.time_window_s and abs(off) <= b.clock_offset_s
                and abs(f) <= b.clock_freq and ptt <= b.clock_offset_s ** 2 and pff <= b.clock_freq ** 2
                and abs(ptf) <= 1.01 * math.sqrt(ptt * pff) + 1e-30)

    def range_entry(self, r: list, t_tx_s: float) -> str | None:
        """The reason a nav's ``[peer, range_m, t_s(, dtheta_s)]`` entry is implausible, or None."""
        b = self.b
        if not 0.0 < r[1] <= b.range_m:
            return "range"
        if not -b.turnaround_s <= t_tx_s - r[2] <= b.time_window_s:
            return "time"
        if len(r) == 4 and abs(r[3]) > 2.0 * b.clock_offset_s:
            return "clock"
        return None

    # ------------------------------------------------------------------ slot claims
    def slot_claim(self, src: int, slot: int, in_slot: bool, t_rx_s: float) -> bool:
        """Is ``src``'s claim of ``slot`` (heard in a nav) to be believed? Only if the nav was received
        inside that slot (``in_slot``) and the sender has not changed its slot too often."""
        if not in_slot:
            self.drop("slot_time")
            return False
        prev = self._claims.get(src)
        if prev is None:
            self._claims[src] = (slot, deque())
            return True
        old, changes = prev
        if slot == old:
            return True
        while changes and t_rx_s - changes[0] > self.slot_window_s:
            changes.popleft()
        if len(changes) >= self.slot_changes:
            self.drop("slot_rate")
            return False
        changes.append(t_rx_s)
        self._claims[src] = (slot, changes)
        return True


def field_radius(pos_m, ids) -> float:
    """The field's extent for :class:`Bounds`: the largest true distance of a station from station 1
    (the network frame's origin; the first station if 1 is not deployed), m."""
    import numpy as np

    p = np.asarray(pos_m, float)
    origin = p[list(ids).index(1)] if 1 in ids else p[0]
    return float(np.max(np.linalg.norm(p - origin, axis=1))) if len(p) else 0.0
