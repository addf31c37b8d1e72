"""Zenoh bus: real peer sessions in separate processes on loopback, gossip full mesh, no multicast."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest
from bus_member import SCRIPT as MEMBER

from net.bus import bus_argv, free_tcp_ports, make_config

pytestmark = pytest.mark.e2e


def test_gossip_full_mesh_from_one_seed():
    """Four peers, all given only peer 0 as seed: each hears every other (no relaying in
    Zenoh >= 1.9, so this needs direct links discovered by gossip)."""
    n = 4
    ports = free_tcp_ports(n)
    seed = f"tcp/127.0.0.1:{ports[0]}"
    procs = [subprocess.Popen([sys.executable, "-c", MEMBER, f"p{i}", str(n), "peer", f"tcp/127.0.0.1:{ports[i]}", seed],
                              stdout=subprocess.PIPE, text=True) for i in range(n)]
    outs = [json.loads(p.communicate(timeout=40)[0]) for p in procs]
    names = [f"p{i}" for i in range(n)]
    for o in outs:
        assert o["got"] == names, o
        assert len(o["alive"]) >= n - 1
    # the non-seed peers are linked to everyone directly
    assert max(o["peers"] for o in outs) == n - 1


def test_config_defaults():
    conf = make_config(["tcp/127.0.0.1:1"], ["tcp/127.0.0.1:2"])
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    assert json.loads(conf.get_json("scouting/gossip/enabled")) is True
    assert json.loads(conf.get_json("transport/shared_memory/enabled")) is False
    assert json.loads(conf.get_json("mode")) == "peer"
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/127.0.0.1:2"]
    assert bus_argv(["a"], ["b", "c"], "f") == ["--listen", "a", "--connect", "b", "--connect", "c",
                                                "--zenoh-config", "f"]


def test_config_file_pass_through(tmp_path):
    f = tmp_path / "z.json5"
    f.write_text('{ mode: "peer", scouting: { multicast: { enabled: false } }, '
                 'connect: { endpoints: ["tcp/10.0.0.1:7447"] } }')
    conf = make_config(config_file=str(f))
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/10.0.0.1:7447"]
    conf = make_config(connect=["tcp/127.0.0.1:9"], config_file=str(f))
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/127.0.0.1:9"]


RING = textwrap.dedent("""
    import json, sys, time
    from net.bus import Bus
    role, ep = sys.argv[1], sys.argv[2]
    if role == "sub":
        b = Bus(listen=[ep])
        sub = b.subscribe_ring("ring/**", 100)
        b.declare_token("ring/alive/sub")
        t0 = time.time()
        while not b.alive("ring/done/*", 0.5) and time.time() - t0 < 30:
            time.sleep(0.1)
        time.sleep(0.3)
        got = b.drain(sub)
        print(json.dumps({"n": len(got), "first": got[0][1].decode() if got else None,
                          "last": got[-1][1].decode() if got else None, "key": got[0][0] if got else None,
                          "again": len(b.drain(sub))}))
        b.close()
    else:
        b = Bus(connect=[ep])
        t0 = time.time()
        while not b.alive("ring/alive/*", 0.5) and time.time() - t0 < 20:
            time.sleep(0.1)
        time.sleep(0.3)
        for i in range(150):
            b.publish("ring/x", str(i).encode(), block=True)
        time.sleep(0.3)
        b.declare_token("ring/done/pub")
        t0 = time.time()  # stay until the subscriber has drained and left (its token goes away)
        while b.alive("ring/alive/*", 0.5) and time.time() - t0 < 20:
            time.sleep(0.1)
        b.close()
""")


def test_ring_subscription_keeps_newest():
    """Ring-buffer subscription (used for nav broadcasts): no callback per sample, drained in
    order, oldest dropped beyond the capacity."""
    (port,) = free_tcp_ports(1)
    ep = f"tcp/127.0.0.1:{port}"
    sub = subprocess.Popen([sys.executable, "-c", RING, "sub", ep], stdout=subprocess.PIPE, text=True)
    pub = subprocess.run([sys.executable, "-c", RING, "pub", ep], timeout=40)
    assert pub.returncode == 0
    out = json.loads(sub.communicate(timeout=40)[0])
    assert out == {"n": 100, "first": "50", "last": "149", "key": "ring/x", "again": 0}


_LEAN_CHECK = r"""
import os, sys, time
from net.bus import Bus, free_tcp_ports
port = free_tcp_ports(1)[0]
a = Bus(listen=[f"tcp/127.0.0.1:{port}"])
b = Bus(connect=[f"tcp/127.0.0.1:{port}"], listen=["tcp/127.0.0.1:0"])
got = []
a.subscribe("larns/t", lambda k, d: got.append(d))
for _ in range(100):
    b.publish("larns/t", b"x")
    time.sleep(0.02)
    if got:
        break
names = sorted({open(f"/proc/self/task/{t}/comm").read().strip().split("-")[0]
                for t in os.listdir("/proc/self/task")})
print(bool(got), "ZENOH_RUNTIME" in os.environ, ",".join(names))
a.close(); b.close()
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_lean_runtime_one_worker_and_not_inherited():
    """Station-side sessions run Zenoh on one worker (no rx/tx/net/acc pools) and do not leak the
    setting into the environment that spawned processes (a router) inherit."""
    env = {k: v for k, v in os.environ.items() if k != "ZENOH_RUNTIME"}
    out = subprocess.run([sys.executable, "-c", _LEAN_CHECK], capture_output=True, text=True,
                         timeout=60, env=env).stdout.split()
    assert out[:2] == ["True", "False"], out
    pools = set(out[2].split(","))
    assert "app" in pools and not pools & {"rx", "tx", "net", "acc"}, pools


def test_a_message_over_the_size_bound_is_refused_by_zenoh():
    """Zenoh reassembles a message split over batches before any of our code sees it; our sessions
    cap that at ``MAX_ZENOH_MESSAGE_BYTES`` (Zenoh's default 1 GiB would let a stolen key make every
    receiver hold that much). Real sessions: 100 kB (two batches) arrives, 200 kB and 10 MB do not,
    the link survives and the next small message arrives."""
    import time

    from net.bus import MAX_ZENOH_MESSAGE_BYTES, Bus

    port = free_tcp_ports(1)[0]
    got = []
    with Bus(listen=[f"tcp/127.0.0.1:{port}"]) as a, Bus(connect=[f"tcp/127.0.0.1:{port}"]) as b:
        a.subscribe("larns/test/**", lambda k, d: got.append(len(d)))
        t0 = time.time()
        while not b.peers() and time.time() - t0 < 10:
            time.sleep(0.05)
        time.sleep(0.5)
        for n in (100_000, 200_000, 10_000_000, 10):
            b.publish("larns/test/x", b"x" * n, block=True)
            time.sleep(0.3)
        t0 = time.time()
        while 10 not in got and time.time() - t0 < 5:
            time.sleep(0.05)
    assert MAX_ZENOH_MESSAGE_BYTES < 200_000
    assert got == [100_000, 10], got


def test_a_reader_that_stops_reading_costs_one_drop_wait_not_one_per_message():
    """Air messages go out with congestion control DROP after waiting up to ``WAIT_BEFORE_DROP_US``
    for room (net/bus.py). A subscriber that stops reading (a stalled or hostile process) must not
    hold every publish that long: Zenoh waits once, then drops at once while the link stays full.
    Real sessions: 20 000 puts of 2 kB to a subscriber whose callback never returns."""
    import threading
    import time

    from net.bus import WAIT_BEFORE_DROP_US, Bus

    port = free_tcp_ports(1)[0]
    stall = threading.Event()
    with Bus(listen=[f"tcp/127.0.0.1:{port}"]) as a, Bus(connect=[f"tcp/127.0.0.1:{port}"]) as b:
        a.subscribe("larns/test/**", lambda k, d: stall.wait(30.0))
        t0 = time.time()
        while not b.peers() and time.time() - t0 < 10:
            time.sleep(0.05)
        time.sleep(0.5)
        t0 = time.monotonic()
        for _ in range(20_000):
            b.publish("larns/test/x", b"x" * 2048)
        took_s = time.monotonic() - t0
        stall.set()
    # one wait per congestion episode: 20 000 waits would take 1000 s
    assert took_s < 200 * WAIT_BEFORE_DROP_US * 1e-6, took_s
