"""Client/router topology: one `larns router` process, clients in separate processes on loopback.

Each client holds exactly one link (to the router), no peer links, and still hears every other
client's samples and liveliness tokens (the router routes them)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys

import pytest
from bus_member import SCRIPT as MEMBER

from net.bus import bus_argv, free_tcp_ports, make_config

pytestmark = pytest.mark.e2e


def test_clients_through_router():
    n = 4
    (port,) = free_tcp_ports(1)
    ep = f"tcp/127.0.0.1:{port}"
    # clients first: they wait for a router that comes up late
    procs = [subprocess.Popen([sys.executable, "-c", MEMBER, f"c{i}", str(n), "client", "-", ep], stdout=subprocess.PIPE, text=True)
             for i in range(n)]
    router = subprocess.Popen([sys.executable, "-m", "larns", "router", "--listen", ep, "-q"])
    try:
        outs = [json.loads(p.communicate(timeout=60)[0]) for p in procs]
    finally:
        router.send_signal(signal.SIGINT)
        rc = router.wait(15)
    names = [f"c{i}" for i in range(n)]
    for o in outs:
        assert o["got"] == names, o
        assert sorted(set(o["alive"])) == [f"test/alive/{x}" for x in names], o
        assert o["peers"] == 0 and o["routers"] == 1, o
    assert rc == 0  # SIGINT: clean exit


def test_client_and_router_config():
    with pytest.raises(ValueError, match="router endpoint"):
        make_config(mode="client")
    with pytest.raises(ValueError, match="mode"):
        make_config(mode="bogus")
    conf = make_config(connect=["tcp/127.0.0.1:2"], mode="client")
    assert json.loads(conf.get_json("mode")) == "client"
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/127.0.0.1:2"]
    conf = make_config(listen=["tcp/127.0.0.1:3"], mode="router")
    assert json.loads(conf.get_json("mode")) == "router"
    assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/127.0.0.1:3"]
    # launchers: a client gets --zenoh-mode client and no --listen; peer flags are unchanged
    assert bus_argv(["a"], ["r"], None, "client") == ["--zenoh-mode", "client", "--connect", "r"]
    assert bus_argv(["a"], ["b"]) == ["--listen", "a", "--connect", "b"]
