"""A bus that records what a node publishes (the station node tests drive the node without Zenoh)."""

from __future__ import annotations

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
