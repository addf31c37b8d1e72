"""Station node receive/transmit path without Zenoh: a fake bus records what the node publishes.

Checks the I/O shell around the core: strict decode + drop counter, key/source consistency,
phy stripped and turned into a local rx timestamp by the air channel, out-of-slot exchanges dropped by the core,
duplicates filtered, wire loss applied, outputs stamped with the true transmit time.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np
import pytest

from nav.geometry import SPEED_OF_LIGHT_M_S
from net import messages as M
from net import scenario as S
from stations.node import NodeOptions, StationNode, default_epoch
from fake_bus import FakeBus


SPEED = 0.01  # a 10 ms slot lasts 1 s of wall time: the test is far from any slot boundary


def make_node(net=None, station_id=2):
    scn = S.load("seed000", layout={"n": 4})
    if net is not None:
        scn = replace(scn, net=net)
    bus = FakeBus()
    # fleet time 10.0 + 0.1 slot right now
    epoch = time.time() - (10.0 + 0.001) / SPEED
    node = StationNode(scn, NodeOptions(station_id=station_id, speed=SPEED, epoch_unix_s=epoch, quiet=True), bus)
    node.start_core()
    bus.sent.clear()
    return node, bus, scn


def local_of(scn, src, t_true):
    """What station ``src``'s own clock reads at true time ``t_true`` (the stamp a real sender puts in
    ``t_tx_s``; the receiving channel takes the true transmit time from it, issue 32)."""
    from stations.sim import station_clock

    return station_clock(scn, src).to_local(t_true)


def req_from(scn, src, dst, seq, t_true):
    m = {"kind": "range_req", "src": src, "seq": seq, "stamp_s": t_true, "dst": dst, "cycle": 10,
         "slot": 0, "t_tx_s": local_of(scn, src, t_true)}
    return M.key_for(m), M.encode(m, {"pos_m": scn.true_pos(src), "t_true_s": t_true})


def test_request_answered_with_true_timing():
    node, bus, scn = make_node()
    t_tx = node.fleet_now()
    node._on_bytes(*req_from(scn, 3, 2, 1, t_tx))
    rsps = bus.of_kind("range_rsp")
    assert len(rsps) == 1
    key, msg, phy = rsps[0]
    assert key == "larns/station/2/range/rsp/3" and msg["dst"] == 3 and msg["req_seq"] == 1
    # true reply time = true tx + time of flight + turnaround (clocks are ideal in seed000), noise ~ ns
    tof = np.linalg.norm(scn.true_pos(3) - scn.true_pos(2)) / SPEED_OF_LIGHT_M_S
    assert phy["t_true_s"] == pytest.approx(t_tx + tof + scn.channel.turnaround_s, abs=20e-9)
    assert phy["pos_m"] == pytest.approx(scn.true_pos(2).tolist())
    # the same request again (a wire duplicate) is filtered
    node._on_bytes(*req_from(scn, 3, 2, 1, t_tx))
    assert len(bus.of_kind("range_rsp")) == 1 and node.stats["duplicates"] == 1
    assert node.drops.total == 0


def req_in_slot(scn, src, dst, seq, t_true, cycle, slot):
    m = {"kind": "range_req", "src": src, "seq": seq, "stamp_s": t_true, "dst": dst, "cycle": cycle,
         "slot": slot, "t_tx_s": local_of(scn, src, t_true)}
    return M.key_for(m), M.encode(m, {"pos_m": scn.true_pos(src), "t_true_s": t_true})


def test_host_late_request_is_answered_on_its_physical_time_and_out_of_slot_is_dropped_by_the_core():
    node, bus, scn = make_node()
    # sent in the previous slot, delivered now (host latency ~ 1 s of wall time): the physics holds,
    # the core answers as if on time (the reply carries the physical stamps)
    t_prev_slot = (math.floor(node.fleet_now() / scn.tdma.slot_s) - 1) * scn.tdma.slot_s + 1e-4
    cyc, slot = divmod(round((t_prev_slot - 1e-4) / scn.tdma.slot_s), scn.tdma.slots_per_cycle)
    node._on_bytes(*req_in_slot(scn, 3, 2, 5, t_prev_slot, cyc, slot))
    rsps = bus.of_kind("range_rsp")
    assert len(rsps) == 1 and node.stats["core_late"] == 0
    assert rsps[0][2]["t_true_s"] == pytest.approx(t_prev_slot + scn.channel.turnaround_s, abs=2e-5)
    # a request whose physical time lies outside the slot it claims: the core (its own clock) drops it
    node._on_bytes(*req_in_slot(scn, 3, 2, 6, t_prev_slot, cyc - 1, slot))
    assert len(bus.of_kind("range_rsp")) == 1 and node.core.counters["late"] == 1 and node.stats["core_late"] == 1


def test_malformed_spoofed_and_wrong_kind_are_counted_not_fatal():
    node, bus, scn = make_node()
    t = node.fleet_now()
    node._on_bytes("larns/station/3/nav", b"\x93garbage")
    node._on_bytes("larns/station/3/nav", b"")
    key, data = req_from(scn, 3, 2, 1, t)
    node._on_bytes("larns/station/4/range/req/2", data)           # src 3 on station 4's key
    node._on_bytes("larns/station/3/range/req/4", data)           # addressed elsewhere
    truth = {"kind": "truth", "src": 3, "seq": 1, "stamp_s": t, "t_s": t, "pos_m": [0, 0, 0]}
    node._on_bytes("larns/station/3/nav", M.encode(truth))        # not an air message
    m, _ = M.decode(data)
    node._on_bytes(key, M.encode(m))                              # air message without phy
    assert node.drops.total == 6
    assert node.drops.by_reason["msgpack"] == 2 and node.drops.by_reason["key"] == 2
    assert node.drops.by_reason["kind"] == 2
    assert not bus.of_kind("range_rsp")
    # still fully functional
    node._on_bytes(*req_from(scn, 3, 2, 2, t))
    assert len(bus.of_kind("range_rsp")) == 1


def test_wire_loss_applies():
    node, bus, scn = make_node(net=S.NetFaults(loss_prob=1.0))
    node._on_bytes(*req_from(scn, 3, 2, 1, node.fleet_now()))
    assert not bus.of_kind("range_rsp") and node.stats["rx_range_req"] == 0


def test_wire_delay_holds_message_back():
    node, bus, scn = make_node(net=S.NetFaults(delay_s=0.002))  # 0.2 s of wall time at SPEED
    node._on_bytes(*req_from(scn, 3, 2, 1, node.fleet_now()))
    assert not bus.of_kind("range_rsp") and len(node._pending) == 1
    time.sleep(0.25)
    node._on_bytes("larns/station/3/nav", b"junk")  # any activity delivers what is due
    assert len(bus.of_kind("range_rsp")) == 1


def test_timer_sends_request_with_phy_and_estimate_with_truth():
    node, bus, scn = make_node(station_id=3)
    dl = node.core.next_deadline()
    node._send(node.core.on_timer(dl))
    reqs = bus.of_kind("range_req")
    assert len(reqs) == 1
    _, msg, phy = reqs[0]
    assert phy["t_true_s"] == pytest.approx(node.clock.to_true(msg["t_tx_s"]))
    node._send(node.core.on_timer(node.core.next_deadline()))  # the nav + estimate
    assert bus.of_kind("nav") and bus.of_kind("estimate")
    (_, tr, _), = bus.of_kind("truth")
    assert tr["pos_m"] == pytest.approx(scn.true_pos(3).tolist())
    (_, est, _), = bus.of_kind("estimate")
    assert est["slot"] == node.core.slot and est["dropped"] == 0


def test_default_epoch_is_day_start():
    assert default_epoch(86400 * 3 + 5000.0) == 86400 * 3


def _make_due(node, t_local_s):
    """Shift the node's epoch so that local time ``t_local_s`` was 1 ms of wall time ago."""
    node.epoch = time.time() - 0.001 - node.clock.to_true(t_local_s) / node.speed


def test_navs_are_drained_before_the_own_nav_not_at_the_request():
    node, bus, _ = make_node(station_id=3)
    assert not node._drain_due(node.fleet_now())  # no nav subscription: nothing to drain
    node._nav_subs = [object()]
    node._last_drain = time.time()
    req_dl = node.core.next_deadline()
    assert node._is_slot_start(req_dl)
    _make_due(node, req_dl)
    assert not node._drain_due(node.fleet_now())  # the request goes out without a batch in front
    node._fire_timers()
    nav_dl = node.core.next_deadline()
    assert not node._is_slot_start(nav_dl) and nav_dl > req_dl
    assert not node._drain_due(node.fleet_now())  # the nav is not due yet
    _make_due(node, nav_dl)
    assert node._drain_due(node.fleet_now())  # the batch goes right before the own nav
    # fallback: a station that somehow has no due nav still drains every 1.5 cycles
    node._fire_timers()
    node._last_drain = time.time() - 1.6 * node.cycle_s / node.speed
    assert node._drain_due(node.fleet_now())
