"""aircraft/node.py: the aircraft node's receive path without Zenoh (a recording fake bus) - garbage
and mismatched keys are counted and dropped, valid navs give schema-valid truth and estimates."""

from __future__ import annotations

import time

import numpy as np

from net.scenario import load


def test_aircraft_node_shell_drops_garbage_and_publishes_valid_messages():
    """The node's receive path without Zenoh (a recording fake bus): malformed bytes and mismatched
    keys are counted and dropped; valid navs yield schema-valid truth and estimates; phy never leaks."""
    from aircraft.node import AircraftNode, AircraftOptions
    from net import messages as M

    class FakeBus:
        def __init__(self):
            self.sent = []

        def publish(self, key, data, block=False):
            self.sent.append((key, data))

    scn = load("seed003", clock={"model": "perfect"})  # hand-made navs stamped on true time
    bus = FakeBus()
    # the fleet's epoch now: the channel takes only transmissions within a minute of the node's time
    node = AircraftNode(scn, AircraftOptions(algos=("ukf-pr", "lsq-pr"), duration_s=60.0,
                                             epoch_unix_s=time.time()), bus)
    node._ingest("larns/station/2/nav", b"\xc1garbage")
    nav = {"kind": "nav", "src": 2, "seq": 1, "stamp_s": 0.1, "cycle": 0, "slot": 1, "t_tx_s": 0.1,
           "pos_m": scn.pos_m[1], "cov_m2": np.eye(3), "n_updates": 3, "state": "surveying", "ranges": [],
           "members": [1, 3]}
    node._ingest("larns/station/3/nav", M.encode(nav, {"pos_m": scn.pos_m[1], "t_true_s": 0.1}))  # key != src
    assert node.drops.total == 2 and not bus.sent
    seq = 0
    for c in range(12):
        for j, sid in enumerate(scn.ids):
            seq += 1
            t = c * scn.tdma.cycle_s + j * scn.tdma.slot_s
            m = dict(nav, src=sid, seq=seq, stamp_s=t, t_tx_s=t, pos_m=scn.pos_m[j], cycle=c, slot=j,
                     cov_m2=np.eye(3) * (0.0 if sid == 1 else 0.04))
            node._ingest(f"larns/station/{sid}/nav", M.encode(m, {"pos_m": scn.pos_m[j], "t_true_s": t}))
    assert node.drops.total == 2
    kinds = {}
    for key, data in bus.sent:
        msg, phy = M.decode(data)
        assert phy is None and key == M.key_for(msg)
        kinds.setdefault(msg["kind"], []).append(msg)
    assert len(kinds["ac_truth"]) == 12 * len(scn.ids)
    algos = {m["algo"] for m in kinds["ac_estimate"]}
    assert algos == {"ukf-pr", "lsq-pr"}
    rep = node.report()
    assert rep["estimates"]["ukf-pr"]["err_m"] < 50.0, rep


def test_aircraft_node_drains_navs_from_a_ring_buffer_in_order():
    """With a bus that has ring buffers the node reads the navs in batches (once per TDMA cycle) and
    hands every one to the core in arrival order: one ``ac_truth`` per nav, sequence as sent."""
    from aircraft.node import AircraftNode, AircraftOptions
    from net import messages as M

    scn = load("seed003", clock={"model": "perfect"})
    waiting = []

    class RingBus:
        def __init__(self):
            self.sent, self.rings = [], []

        def publish(self, key, data, block=False):
            self.sent.append((key, data))

        def subscribe_ring(self, keyexpr, capacity=8192):
            self.rings.append(keyexpr)
            return "ring"

        def drain(self, sub, max_n=100_000):
            out = waiting[:max_n]
            del waiting[:len(out)]
            return out

        def declare_token(self, key):
            return None

    bus = RingBus()
    node = AircraftNode(scn, AircraftOptions(algos=("lsq-pr",), duration_s=0.6, epoch_unix_s=time.time(),
                                             quiet=True), bus)
    seq = 0
    for c in range(6):
        for j, sid in enumerate(scn.ids):
            seq += 1
            t = c * scn.tdma.cycle_s + j * scn.tdma.slot_s
            m = {"kind": "nav", "src": sid, "seq": seq, "stamp_s": t, "cycle": c, "slot": j, "t_tx_s": t,
                 "pos_m": scn.pos_m[j], "cov_m2": np.eye(3) * 0.04, "n_updates": 3, "state": "surveying",
                 "ranges": [], "members": [1, 3]}
            waiting.append((f"larns/station/{sid}/nav", M.encode(m, {"pos_m": scn.pos_m[j], "t_true_s": t})))
    node.run()
    assert bus.rings == ["larns/station/*/nav/**"] and not waiting
    truths = [M.decode(d)[0] for _, d in bus.sent if M.decode(d)[0]["kind"] == "ac_truth"]
    assert len(truths) == 6 * len(scn.ids) and node.drops.total == 0
    assert [m["t_s"] for m in truths] == sorted(m["t_s"] for m in truths)
