"""MAC-level simulator of the distributed slot assignment (:mod:`stations.slots`) on a radio link graph.

Pure (no I/O, explicit generators) and synchronous in cycles: in every cycle each station holding a
slot transmits once in it, carrying its claim cycle and its :class:`stations.slots.SlotSummary` of
the previous cycle; a receiver in range of exactly one sender in a slot decodes it, a receiver in
range of two or more decodes none (garbage: a collision), a station does not receive in the slot
it transmits in (half duplex). Links are :func:`net.radio.link` of the scenario's radio (horizon and
link budget; symmetric here, all antennas ``antenna_height_m`` above flat ground). The station
processes run the same cores with ``[tdma] assignment = "distributed"`` (``stations/core.py``; the
in-process simulator ``stations/sim.py`` models the same collisions; docs/slots.md).

Figures (:class:`SimResult`): cycles until no two stations within two hops share a slot (and every
station holds one), slots used (max slot index + 1) against the densest neighbourhoods, the reuse
factor ``N / slots used``, collided transmissions (a transmission lost at one or more of its
neighbours by another sender in its slot) and a late joiner's cycles to hold a slot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from net.radio import RadioParams, link
from stations.slots import Heard, SlotConfig, SlotCore


# --------------------------------------------------------------------------- geometry and graphs
def field_positions(n: int, rng: np.random.Generator, width_m: float = 40e3, depth_m: float = 30e3) -> np.ndarray:
    """(n, 3) stations uniformly over a ``width_m`` x ``depth_m`` field at ground level (z = 0)."""
    return np.column_stack([rng.uniform(0.0, width_m, n), rng.uniform(0.0, depth_m, n), np.zeros(n)])


def corridor_positions(n: int, rng: np.random.Generator, length_m: float = 100e3,
                       halfwidth_m: float = 200.0) -> np.ndarray:
    """(n, 3) stations along a straight road of ``length_m``, within ``halfwidth_m`` of its axis."""
    return np.column_stack([rng.uniform(0.0, length_m, n), rng.uniform(-halfwidth_m, halfwidth_m, n), np.zeros(n)])


def link_graph(pos_m: np.ndarray, radio: RadioParams) -> np.ndarray:
    """(N, N) bool adjacency of positions ``pos_m`` (N, 3): the links :func:`net.radio.link` allows
    (both directions required), no self-loops."""
    p = np.asarray(pos_m, float)
    ex = link(p[:, None, :], p[None, :, :], radio).exists
    adj = ex & ex.T
    np.fill_diagonal(adj, False)
    return adj


def two_hop(adj: np.ndarray) -> np.ndarray:
    """(N, N) bool: pairs within two hops of ``adj`` (N, N), no self-loops."""
    a = adj.astype(np.int32)
    out = adj | ((a @ a) > 0)
    np.fill_diagonal(out, False)
    return out


@dataclass(frozen=True)
class GraphStats:
    """The densest neighbourhoods of a link graph: ``max_closed_1hop`` (a station and its
    neighbours: they are pairwise within two hops, so no cycle can be shorter; a lower bound on the
    slots), ``max_closed_2hop`` (a station and everybody within two hops; with that many slots a
    free slot always exists for everyone, the greedy bound), the fraction of pairs with no link,
    the hop diameter of the largest component and the number of components."""

    max_closed_1hop: int
    max_closed_2hop: int
    mean_degree: float
    no_link_fraction: float
    hop_diameter: int
    components: int


def graph_stats(adj: np.ndarray) -> GraphStats:
    n = len(adj)
    hops = _hops(adj)
    finite = hops[np.isfinite(hops)]
    pairs = max(n * (n - 1), 1)
    return GraphStats(max_closed_1hop=int(adj.sum(1).max(initial=0)) + 1,
                      max_closed_2hop=int(two_hop(adj).sum(1).max(initial=0)) + 1,
                      mean_degree=float(adj.sum(1).mean()) if n else 0.0,
                      no_link_fraction=float((~adj).sum() - n) / pairs,
                      hop_diameter=int(finite.max(initial=0)),
                      components=_components(hops))


def _hops(adj: np.ndarray) -> np.ndarray:
    """(N, N) hop counts by breadth-first frontier products (inf: not connected)."""
    n = len(adj)
    hops = np.full((n, n), np.inf)
    np.fill_diagonal(hops, 0.0)
    reach = np.eye(n, dtype=bool)
    frontier = reach.copy()
    a = adj.astype(np.int32)
    for h in range(1, n):
        frontier = ((frontier.astype(np.int32) @ a) > 0) & ~reach
        if not frontier.any():
            break
        hops[frontier] = h
        reach |= frontier
    return hops


def _components(hops: np.ndarray) -> int:
    seen = np.zeros(len(hops), bool)
    count = 0
    for i in range(len(hops)):
        if not seen[i]:
            seen |= np.isfinite(hops[i])
            count += 1
    return count


def conflicts(adj2: np.ndarray, slot: np.ndarray) -> int:
    """Pairs within two hops (``adj2`` (N, N)) that hold the same slot (``slot`` (N,), -1: none)."""
    s = np.asarray(slot)
    same = (s[:, None] == s[None, :]) & (s[:, None] >= 0)
    return int((same & adj2).sum()) // 2


# --------------------------------------------------------------------------- the MAC
@dataclass
class SimResult:
    """Per-cycle series (T,) and the final assignment: ``conflict_pairs`` (two-hop pairs sharing a
    slot), ``unassigned`` (stations on and holding no slot), ``collided_tx`` (transmissions lost at a
    neighbour to another sender), ``tx`` (transmissions), ``slot`` (T, N) each station's slot held
    (-1: none or off; a station listening in its own slot still holds it)."""

    conflict_pairs: np.ndarray
    unassigned: np.ndarray
    collided_tx: np.ndarray
    tx: np.ndarray
    slot: np.ndarray
    cores: list


def receptions(adj: np.ndarray, slot: np.ndarray, cycle_slots: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One cycle's air: ``slot`` (N,) each station's transmit slot (-1: silent). Returns the senders'
    count at each receiver and slot (N, C) (0 where the receiver transmits itself), the decoded
    sender index (N, C) (-1 where the count is not 1) and each transmission's collided flag (N,)."""
    n = len(slot)
    on = slot >= 0
    S = np.zeros((n, cycle_slots), np.int64)
    S[np.flatnonzero(on), slot[on]] = 1
    A = adj.astype(np.int64)
    count = A.T @ S
    count[S.astype(bool)] = 0  # half duplex
    who = A.T @ (S * (np.arange(n) + 1)[:, None]) - 1
    sender = np.where(count == 1, who, -1)
    garbage = (count >= 2).astype(np.int64)
    lost = A @ garbage  # (N, C): neighbours of each station with garbage in each slot
    collided = np.zeros(n, bool)
    collided[on] = lost[np.flatnonzero(on), slot[on]] > 0
    return count, sender, collided


def simulate(pos_m: np.ndarray, radio: RadioParams, cfg: SlotConfig, cycles: int, rng: np.random.Generator,
             start_cycle: np.ndarray | None = None) -> SimResult:
    """Run ``cycles`` cycles of the stations at ``pos_m`` (N, 3); station ``i`` powers on at cycle
    ``start_cycle[i]`` (default all at 0: a cold start of the whole field). Station ids are
    ``1..N``; each core draws from its own generator spawned from ``rng``."""
    adj = link_graph(pos_m, radio)
    return simulate_graph(adj, cfg, cycles, rng, start_cycle)


def simulate_graph(adj: np.ndarray, cfg: SlotConfig, cycles: int, rng: np.random.Generator,
                   start_cycle: np.ndarray | None = None) -> SimResult:
    """:func:`simulate` on a given adjacency ``adj`` (N, N) bool (symmetric, no self-loops)."""
    n = len(adj)
    start = np.zeros(n, int) if start_cycle is None else np.asarray(start_cycle, int)
    cores = [SlotCore(i + 1, cfg, g) for i, g in enumerate(rng.spawn(n))]
    out = SimResult(conflict_pairs=np.zeros(cycles, int), unassigned=np.zeros(cycles, int),
                    collided_tx=np.zeros(cycles, int), tx=np.zeros(cycles, int),
                    slot=np.full((cycles, n), -1), cores=cores)
    on_before, adj_on, adj2 = None, adj, adj
    for c in range(cycles):
        on = start <= c
        if on_before is None or (on != on_before).any():  # the graph of the stations powered on
            on_before, adj_on = on, adj & on[None, :] & on[:, None]
            adj2 = two_hop(adj_on)
        slot = np.array([cores[i].slot if on[i] and cores[i].slot is not None else -1 for i in range(n)])
        tx = np.array([-1 if cores[i].listening else slot[i] for i in range(n)])
        count, sender, collided = receptions(adj_on, tx, cfg.cycle_slots)
        out.slot[c], out.tx[c] = slot, int((tx >= 0).sum())
        out.collided_tx[c] = int(collided.sum())
        out.conflict_pairs[c] = conflicts(adj2, slot)
        out.unassigned[c] = int((on & (slot < 0)).sum())
        # what each transmission carries: its claim cycle and the summary built at the end of c - 1
        sent = [(cores[i].since, cores[i].summary()) if tx[i] >= 0 else None for i in range(n)]
        for r in np.flatnonzero(on):
            heard = [Heard(int(j) + 1, int(k), *sent[j]) for k, j in zip(*_decoded(sender[r]))]
            cores[r].on_cycle(c, heard, np.flatnonzero(count[r] >= 2))
    return out


def _decoded(sender_row: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(slots, sender indices) decoded by one receiver, from its row (C,) of the sender matrix."""
    ks = np.flatnonzero(sender_row >= 0)
    return ks, sender_row[ks]


def converged_cycle(res: SimResult, after: int = 0) -> int | None:
    """First cycle ``>= after`` from which every later cycle has no conflicting pair and no station
    without a slot (None: not by the end)."""
    bad = (res.conflict_pairs > 0) | (res.unassigned > 0)
    bad[:after] = True
    idx = np.flatnonzero(bad)
    first = int(idx[-1]) + 1 if idx.size else 0
    return first if first < len(bad) else None


def hold_cycle(res: SimResult, station: int, start: int, adj2: np.ndarray) -> int | None:
    """Cycles from power-on (its first cycle counts 1) until station index ``station`` transmits in
    the slot it keeps to the end of the run with no station within two hops sharing it (None: never)."""
    s = res.slot[:, station]
    T = len(s)
    ok = np.zeros(T, bool)
    for c in range(start, T):
        others = res.slot[c, adj2[station]]
        ok[c] = s[c] >= 0 and not np.any(others == s[c]) and s[c] == s[-1]
    bad = np.flatnonzero(~ok[start:])
    first = start + (int(bad[-1]) + 1 if bad.size else 0)
    return first - start + 1 if first < T else None
