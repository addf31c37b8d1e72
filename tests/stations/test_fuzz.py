"""An insider's absurd messages through a station's whole receive path - the node's shell (channel
layer: the named sender's truth and clock) and the core (admission) - not only the core
(tests/stations/test_admission.py fuzzes the core alone). Found by `larns attack --as station-2
--mode absurd` against a live fleet: a range request stamped at 1e12 s had the channel read the
sender's emulated oscillator there, which draws its random walk up to that time - three stations
hung for good (issue 32)."""

from __future__ import annotations

import time

import numpy as np

from larns.adversary.insider import absurd_message, absurd_phy
from net import messages as M
from fake_bus import station_node


def make_node(net=None):
    return station_node(net)


def test_a_request_stamped_far_from_now_is_dropped_before_the_senders_clock_is_read():
    node, bus, scn = make_node()
    t = node.fleet_now()
    for k, (t_tx, t_phy) in enumerate([(1e12, t), (t, 1e12), (-1e12, t), (t + 120.0, t)]):
        m = {"kind": "range_req", "src": 3, "seq": k + 1, "stamp_s": t, "dst": 2, "cycle": 10, "slot": 2,
             "t_tx_s": t_tx}
        t0 = time.process_time()
        node._on_bytes(M.key_for(m), M.encode(m, {"pos_m": scn.true_pos(3).tolist(), "t_true_s": t_phy}))
        assert time.process_time() - t0 < 1.0
    assert node.drops.by_reason["time"] == 4 and not bus.rsps()
    clock = node.senders._clocks.get(3)
    assert clock is None or len(clock._x) < 10_000  # the sender's emulated oscillator was not drawn out there


def _absurd_through(node, scn, kinds: tuple[str, ...], rng: np.random.Generator, n: int = 3000) -> float:
    """``n`` absurd messages of ``kinds`` in turn from station 3 through station 2's node (its receive
    path; navs handed to the core as the node's batches do); returns the largest CPU seconds one took."""
    pos3 = scn.true_pos(3)
    worst = 0.0
    for k in range(n):
        t = node.fleet_now()
        kind = kinds[k % len(kinds)]
        m = absurd_message(rng, kind, 3, k + 1, t, dst=2, p_long=0.01)
        data = M.encode(m, absurd_phy(rng, t, pos3))
        t0 = time.process_time()
        node._on_bytes(M.key_for(m), data)
        if kind == "nav":  # navs reach the core in the node's batches
            node._nav_subs = []
            node._deliver(*M.decode(data))
        worst = max(worst, time.process_time() - t0)
    return worst


def test_fuzz_absurd_polls_replies_and_finals_through_a_poll_node():
    """Protocol v2: 3,000 wire-valid polls, replies and navs (finals among them) from station 3 with
    every field at its limits through station 2's node on the poll: none raises or costs more than
    1 s of CPU, the core records no error, its per-poller table of answered polls stays bounded."""
    from dataclasses import replace

    node, bus, scn = make_node()
    node.scn = replace(scn, tdma=replace(scn.tdma, ranging="poll"))
    node.start_core()  # (the core again, on the poll)
    assert node.core.poll
    worst = _absurd_through(node, scn, ("nav", "poll", "reply"), np.random.default_rng(31))
    assert worst < 1.0, worst
    assert node.stats["core_errors"] == 0
    core = node.core
    assert all(len(v) <= 2 for v in core._polled.values()) and len(core._polled) <= core.admission.max_peers
    assert sum(core.admission.dropped.values()) + node.drops.total > 1500


def test_fuzz_absurd_requests_replies_and_navs_through_the_node():
    """3,000 wire-valid messages from station 3 with every field at its limits (and 30 % of them with
    a ``phy`` at its limits too) through station 2's node: none raises, none costs more than 1 s
    of CPU, the core records no error, the sender's emulated clock stays bounded, and the core's
    state stays bounded (peers, clocks)."""
    node, bus, scn = make_node()
    worst = _absurd_through(node, scn, ("nav", "range_req", "range_rsp"), np.random.default_rng(32))
    # no message hangs the node (a claim drawing the sender's emulated clock out to 1e12 s would take
    # minutes); a typical message costs ~0.1 ms, so 1 s leaves room for a slow or loaded machine
    assert worst < 1.0, worst
    assert node.stats["core_errors"] == 0
    clock = node.senders._clocks.get(3)
    assert clock is None or len(clock._x) < 100_000
    core = node.core
    assert len(core.clk.index) <= core.admission.max_peers and len(core.peers) <= core.admission.max_peers
    assert sum(core.admission.dropped.values()) + node.drops.total > 1500
