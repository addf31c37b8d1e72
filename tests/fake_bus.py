"""A bus that records what a node publishes (the station node tests drive the node without Zenoh)."""

from __future__ import annotations

import time
from dataclasses import replace

from net import messages as M


class FakeBus:
    def __init__(self):
        self.sent: list[tuple[str, bytes]] = []

    def publish(self, key, data):
        self.sent.append((key, data))

    def subscribe(self, keyexpr, cb):
        return None

    def declare_token(self, key):
        return None

    def of_kind(self, kind):
        """(key, msg, phy) of every published message of ``kind``."""
        return [(k, *M.decode(d)) for k, d in self.sent if M.decode(d)[0]["kind"] == kind]

    def rsps(self):
        """Every published range reply."""
        return [M.decode(d)[0] for k, d in self.sent if "/range/rsp/" in k]


NODE_SPEED = 0.01


def station_node(net=None):
    """Station 2 of a 4-station seed000 world on a :class:`FakeBus`, its core started at fleet time
    10 s and run at speed 0.01 (``net``: wire faults). Returns ``(node, bus, scenario)``."""
    from net import scenario as S
    from stations import node as N

    scn = S.load("seed000", layout={"n": 4})
    if net is not None:
        scn = replace(scn, net=net)
    bus = FakeBus()
    epoch = time.time() - (10.0 + 0.001) / NODE_SPEED
    node = N.StationNode(scn, N.NodeOptions(station_id=2, speed=NODE_SPEED, epoch_unix_s=epoch, quiet=True), bus)
    node.start_core()
    bus.sent.clear()
    return node, bus, scn
