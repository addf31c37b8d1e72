"""Distributed slot assignment (stations/slots.py) and its MAC simulator (stations/slotsim.py), issue 33
item 4: after convergence no two stations within two hops share a slot (random geometries), a joiner
holds a slot within 3 cycles, the peer table stays bounded under a flood of ids, incumbency wins."""

from __future__ import annotations

import numpy as np
import pytest

from net.radio import RadioParams
from stations.slots import CLEAN, FREE, GARBAGE, Heard, SlotConfig, SlotCore, SlotSummary, priority
from stations.slotsim import (converged_cycle, field_positions, graph_stats, hold_cycle, link_graph, simulate_graph,
                              two_hop)

GRAPHS = 20
CYCLES = 120


def _clashes(adj: np.ndarray, slot: np.ndarray) -> list[tuple[int, int]]:
    """Pairs (i, j) within two hops holding the same slot, by brute force on the adjacency (N, N):
    independent of stations.slotsim's matrix products."""
    n = len(adj)
    nbrs = [set(np.flatnonzero(adj[i])) for i in range(n)]
    out = []
    for i in range(n):
        near = set(nbrs[i])
        for j in nbrs[i]:
            near |= nbrs[j]
        out += [(i, j) for j in near if j > i and slot[i] >= 0 and slot[i] == slot[j]]
    return out


def _random_graph(k: int) -> np.ndarray:
    """Graph k of the property test: 20-60 stations over 10-30 km at 0-10 dBm (multi-hop)."""
    rng = np.random.default_rng(1000 + k)
    n = int(rng.integers(20, 61))
    side_m = float(rng.uniform(10e3, 30e3))
    pos = field_positions(n, rng, side_m, side_m * float(rng.uniform(0.5, 1.0)))
    return link_graph(pos, RadioParams(tx_power_dbm=float(rng.uniform(0.0, 10.0))))


def _run_property(k: int) -> tuple[np.ndarray, np.ndarray, object]:
    adj = _random_graph(k)
    cfg = SlotConfig(graph_stats(adj).max_closed_2hop)  # the cycle sized for the densest 2-hop neighbourhood
    res = simulate_graph(adj, cfg, CYCLES, np.random.default_rng(k))
    return adj, res.slot[-1], res


@pytest.mark.parametrize("k", range(GRAPHS))
def test_after_convergence_no_two_stations_within_two_hops_share_a_slot(k):
    adj, slot, res = _run_property(k)
    assert graph_stats(adj).hop_diameter >= 2  # multi-hop: not everybody hears everybody
    assert converged_cycle(res) is not None, "not converged"
    assert (slot >= 0).all(), "a station holds no slot"
    assert _clashes(adj, slot) == []
    assert res.collided_tx[converged_cycle(res):].sum() == 0


def test_the_property_check_catches_a_broken_assignment(monkeypatch):
    """With collision resolution switched off (a station never gives its slot up) the same check finds
    stations within two hops sharing a slot: the property test can fail."""
    monkeypatch.setattr(SlotCore, "_lose", lambda self, cycle, heard: False)
    found = [k for k in range(GRAPHS) if _clashes(*_run_property(k)[:2])]
    assert len(found) >= GRAPHS // 2


def test_the_simulator_counts_a_planted_two_hop_clash():
    """A path 0 - 1 - 2 with 0 and 2 in the same slot: station 1 decodes neither (garbage), both
    transmissions collided, one conflicting pair."""
    from stations.slotsim import conflicts, receptions

    adj = np.zeros((3, 3), bool)
    adj[0, 1] = adj[1, 0] = adj[1, 2] = adj[2, 1] = True
    slot = np.array([0, 1, 0])
    count, sender, collided = receptions(adj, slot, 3)
    assert count[1, 0] == 2 and sender[1, 0] == -1 and collided.tolist() == [True, False, True]
    assert sender[0, 1] == 1 and sender[2, 1] == 1  # station 1 is heard by both in slot 1
    assert conflicts(two_hop(adj), slot) == 1 and _clashes(adj, slot) == [(0, 2)]


def _summary(C: int, used: dict[int, tuple[int, int, int]]) -> SlotSummary:
    """A summary of ``C`` slots: ``used`` slot -> (state, owner, since)."""
    state, owner, since = np.zeros(C, np.int8), np.zeros(C, np.int64), np.full(C, -1, np.int64)
    for k, (st, o, s) in used.items():
        state[k], owner[k], since[k] = st, o, s
    return SlotSummary(state, owner, since)


@pytest.mark.parametrize("seed", range(10))
def test_a_joiner_picks_only_a_slot_free_in_its_two_hop_view(seed):
    """Neighbour 7 in slot 0 reports station 9 in slot 1 (two hops away) and garbage in slot 2; the
    joiner hears garbage in slot 4 itself: of 6 slots, 3 and 5 are free, picked after one cycle."""
    core = SlotCore(1, SlotConfig(6), np.random.default_rng(seed))
    s7 = _summary(6, {0: (CLEAN, 7, 0), 1: (CLEAN, 9, 0), 2: (GARBAGE, 0, -1)})
    assert core.on_cycle(10, [Heard(7, 0, 0, s7)], garbage_slots=[4]) in (3, 5)
    assert core.since == 11
    assert set(np.flatnonzero(~core.two_hop_used())) <= {3, 5}


def test_a_joiner_finds_no_slot_in_a_full_view_and_waits():
    core = SlotCore(1, SlotConfig(2), np.random.default_rng(0))
    s7 = _summary(2, {0: (CLEAN, 7, 0), 1: (CLEAN, 9, 0)})
    assert core.on_cycle(3, [Heard(7, 0, 0, s7)]) is None and core.starved == 1


def test_a_late_joiner_holds_a_slot_within_three_cycles_in_a_sparse_field():
    rng = np.random.default_rng(7)
    pos = field_positions(61, rng, 30e3, 20e3)
    adj = link_graph(pos, RadioParams(tx_power_dbm=0.0))
    assert graph_stats(adj[:60, :60]).no_link_fraction > 0.8  # sparse
    start = np.r_[np.zeros(60, int), 60]
    C = graph_stats(adj).max_closed_2hop
    res = simulate_graph(adj, SlotConfig(C), 80, rng, start)
    assert converged_cycle(res) is not None
    held = hold_cycle(res, 60, 60, two_hop(adj))
    assert held is not None and held <= 3
    assert _clashes(adj, res.slot[-1]) == []


def test_the_incumbent_keeps_its_slot_and_the_newer_claim_repicks():
    """Both transmitted in slot 0 in cycles 20 and 21; a common neighbour reports garbage there with
    station 1 (claim of cycle 5) as the last clean owner: 1 keeps, 2 (claim of cycle 20) moves."""
    C = 4
    report = _summary(C, {0: (GARBAGE, 1, 5), 3: (CLEAN, 3, 0)})
    cores = {}
    for sid, since in ((1, 5), (2, 20)):
        c = SlotCore(sid, SlotConfig(C), np.random.default_rng(sid), slot=0, since=since)
        c._listened = 5
        c.on_cycle(20, [])
        cores[sid] = c.on_cycle(21, [Heard(3, 3, 0, report)])
    assert cores[1] == 0
    assert cores[2] not in (None, 0, 3)


def test_a_named_earlier_owner_two_hops_away_wins_and_ties_break_by_the_id_hash():
    C = 3
    for me, rival, my_since, rival_since in ((5, 6, 10, 4), (5, 6, 10, 10)):
        c = SlotCore(me, SlotConfig(C), np.random.default_rng(0), slot=0, since=my_since)
        c._listened = 5
        c.on_cycle(11, [])
        s = _summary(C, {0: (CLEAN, rival, rival_since), 1: (CLEAN, 9, 0)})
        after = c.on_cycle(12, [Heard(9, 1, 0, s)])
        lose = priority(rival, rival_since) < priority(me, my_since)
        assert (after != 0) == lose
    assert priority(6, 4) < priority(5, 10)


def test_the_peer_table_stays_bounded_under_a_flood_of_hostile_ids():
    cfg = SlotConfig(8, max_peers=16, evict_after_cycles=3)
    core = SlotCore(1, cfg, np.random.default_rng(0))
    rng = np.random.default_rng(1)
    big = _summary(8, {k: (CLEAN, 10_000 + k, 0) for k in range(8)})
    for cycle in range(5):
        heard = [Heard(2, 0, 0, None)]  # the one genuine neighbour, heard first every cycle
        heard += [Heard(int(i), int(rng.integers(8)), 0, big) for i in rng.integers(3, 2**31, 5000)]
        core.on_cycle(cycle, heard)
        assert core.peer_count <= 16
        assert 2 in core._peers  # the flood did not push out the neighbour heard in the same cycle
    # malformed input is ignored, not stored: slots out of range, summaries of another cycle size
    ragged = SlotSummary(np.zeros(8, np.int8), np.zeros(2, np.int64), np.zeros(8, np.int64))
    core.on_cycle(5, [Heard(3, 99, 0, None), Heard(4, 1, 0, _summary(5, {})), Heard(5, 2, 0, ragged)])
    assert 3 not in core._peers and core._peers[4].summary is None and core._peers[5].summary is None
    core.slot, core.since = 2, 6  # a holder reads the ragged summary's slot 2 without an IndexError
    core.on_cycle(6, [])
    core.on_cycle(7, [Heard(5, 2, 0, ragged)])
    for cycle in range(8, 8 + cfg.evict_after_cycles):
        core.on_cycle(cycle, [])
    assert core.peer_count == 0  # nobody heard for evict_after_cycles cycles: all evicted


def test_summary_marks_own_slot_peers_and_garbage():
    core = SlotCore(1, SlotConfig(5), np.random.default_rng(0), slot=4, since=2)
    core._listened = 3
    core.on_cycle(3, [Heard(2, 0, 1, None)], garbage_slots=[1])
    s = core.summary()
    assert s.state.tolist() == [CLEAN, GARBAGE, FREE, FREE, CLEAN]
    assert s.owner[0] == 2 and s.owner[4] == 1 and s.owner[1] == 0


def test_config_rejects_nonsense():
    with pytest.raises(ValueError):
        SlotConfig(0)
    with pytest.raises(ValueError):
        SlotConfig(4, backoff_p=0.0)


def test_an_isolated_pair_sharing_a_slot_is_found_by_listening_in_it():
    """Two stations that hear only each other: in the same slot neither is ever heard, and nobody else
    can report it; the one that hears nobody listens in its own slot now and then and resolves it.
    Over 20 seeds of a 2-slot cycle some start in the same slot (the case is exercised); all end apart."""
    adj = np.array([[False, True], [True, False]])
    clashed = 0
    for seed in range(20):
        res = simulate_graph(adj, SlotConfig(2), 60, np.random.default_rng(seed))
        clashed += int(res.conflict_pairs[1] > 0)
        assert res.conflict_pairs[-20:].sum() == 0 and (res.slot[-1] >= 0).all()
    assert clashed >= 3


def test_a_listener_that_hears_another_owner_in_its_slot_gives_it_up():
    """Even with the earlier claim: the other owner cannot hear it in the shared slot."""
    for rival_since in (8, 0):
        core = SlotCore(1, SlotConfig(3), np.random.default_rng(0), slot=0, since=2, listening=True)
        core._listened = 5
        assert core.on_cycle(10, [Heard(5, 0, rival_since, None)]) not in (None, 0)
    core = SlotCore(1, SlotConfig(3), np.random.default_rng(0), slot=0, since=2, listening=True)
    core._listened = 5
    assert core.on_cycle(10, [], garbage_slots=[0]) not in (None, 0)  # two others there
    core = SlotCore(1, SlotConfig(3), np.random.default_rng(0), slot=0, since=2, listening=True)
    core._listened = 5
    assert core.on_cycle(10, [Heard(5, 1, 0, None)]) == 0  # nobody else in slot 0: keep it
