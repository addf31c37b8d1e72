"""Issue 32 in the station process: the channel owns physics (a sender's ``phy`` cannot shorten a
range), the delivery loop survives a core exception, the wire-delay queue is bounded."""

from __future__ import annotations

import numpy as np

from net import messages as M
from net import scenario as S
from stations import node as N
from stations.sim import station_clock
from fake_bus import station_node


def make_node(net=None):
    return station_node(net)


def request(scn, t_true, seq=1, phy_t=None, phy_pos=None):
    """Station 3's range request to 2, stamped by its own clock; ``phy_*`` what it claims physically."""
    m = {"kind": "range_req", "src": 3, "seq": seq, "stamp_s": t_true, "dst": 2, "cycle": 10, "slot": 0,
         "t_tx_s": station_clock(scn, 3).to_local(t_true)}
    phy = {"pos_m": scn.true_pos(3) if phy_pos is None else phy_pos, "t_true_s": t_true if phy_t is None else phy_t}
    return M.key_for(m), M.encode(m, phy)


def test_a_phy_block_claiming_an_earlier_signal_or_another_place_does_not_shorten_the_range():
    honest, bus_h, scn = make_node()
    liar, bus_l, _ = make_node()
    t = honest.fleet_now()
    honest._on_bytes(*request(scn, t))
    # the same transmission, its phy claiming 1 us earlier (300 m shorter) from right next to station 2
    liar._on_bytes(*request(scn, t, phy_t=t - 1e-6, phy_pos=scn.true_pos(2) + 1.0))
    (h,), (lie,) = bus_h.rsps(), bus_l.rsps()
    assert abs(lie["t_rx_s"] - h["t_rx_s"]) < 1e-12  # the same reception time on station 2's clock (0.3 mm)
    # a claimed later transmission (a delay) is physically possible: the signal arrives later
    late, bus_d, _ = make_node()
    late._on_bytes(*request(scn, t, phy_t=t + 1e-6))
    (d,) = bus_d.rsps()
    assert d["t_rx_s"] - h["t_rx_s"] > 0.9e-6


def test_the_delivery_loop_survives_core_exceptions():
    node, bus, scn = make_node()
    real = node.core.on_message

    def boom(msg, t):
        raise ZeroDivisionError("float division by zero")

    node.core.on_message = boom
    for seq in range(1, 4):
        node._on_bytes(*request(scn, node.fleet_now(), seq=seq))
    assert node.stats["core_errors"] == 3 and node.drops.by_reason["core"] == 3
    assert node.drops.lines_logged == 1  # logged at a limited rate
    node.core.on_message = real
    node._on_bytes(*request(scn, node.fleet_now(), seq=9))
    assert len(bus.rsps()) == 1


def test_the_timer_loop_survives_a_core_exception(monkeypatch):
    node, bus, scn = make_node()
    monkeypatch.setattr(node.core, "next_deadline", lambda: node.clock.to_local(node.fleet_now()) - 1e-3)
    monkeypatch.setattr(node.core, "on_timer", lambda t: 1 / 0)
    node._fire_timers()
    assert node.stats["core_errors"] == 1


def test_messages_held_by_wire_delays_are_bounded(monkeypatch):
    monkeypatch.setattr(N, "PENDING_MAX", 5)
    node, bus, scn = make_node(net=S.NetFaults(delay_s=10.0))
    t = node.fleet_now()
    for seq in range(1, 9):
        node._on_bytes(*request(scn, t, seq=seq))
    assert len(node._pending) == 5 and node.drops.by_reason["pending_full"] == 3
    assert sorted(e[2]["seq"] for e in node._pending) == [4, 5, 6, 7, 8]
    assert np.isfinite(node._pending[0][0])
