"""The wire's spatial tiles (net/tiles.py, issue 33 item 5): the tile of a position, the tiles a
station subscribes to (a superset of every link the radio allows, far tiles left out), and on a real
Zenoh bus a station node that hears its neighbour's navs and nothing from outside its radio range."""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest

from net import messages as M
from net import radio as R
from net import scenario as S
from net import tiles as T


def test_tile_of_chunk_and_parse():
    assert T.tile_of([0.0, 0.0, 5.0], 1000.0) == (0, 0)
    assert T.tile_of([999.9, -0.1, 0.0], 1000.0) == (0, -1)
    assert T.tile_of([-1000.0, 2500.0, 0.0], 1000.0) == (-1, 2)
    assert T.tile_of([1e6, -1e6, 0.0], math.inf) == (0, 0)  # no radio: one tile
    for t in [(0, 0), (3, -1), (-12, 7)]:
        c = T.tile_chunk(t)
        assert not set(c) & set("*$?#/") and T.parse_tile(c) == t
    assert T.nav_key(7, (3, -1)) == "larns/station/7/nav/3_-1"
    assert T.parse_tile("nav") is None and T.parse_tile("3_") is None and T.parse_tile("1_2_3") is None


def test_tiles_within_against_brute_force():
    """A tile is in the set iff its closed square comes within the radius of the centre."""
    rng = np.random.default_rng(5)
    for _ in range(200):
        size = rng.uniform(100.0, 3000.0)
        c = rng.uniform(-5000.0, 5000.0, 2)
        r = rng.uniform(10.0, 8000.0)
        got = set(T.tiles_within(c, r, size))
        n = int(r / size) + 3
        i0, j0 = T.tile_of(c, size)
        for ix in range(i0 - n, i0 + n + 1):
            for iy in range(j0 - n, j0 + n + 1):
                dx = max(ix * size - c[0], 0.0, c[0] - (ix + 1) * size)
                dy = max(iy * size - c[1], 0.0, c[1] - (iy + 1) * size)
                assert ((ix, iy) in got) == (math.hypot(dx, dy) <= r)
        assert T.tile_of(c, size) in got


def _field(rng, n, width_m, tx_power_dbm, max_z_m, tile_m=None):
    """A random field of ``n`` stations (heights 0..max_z_m) with a weak radio."""
    radio = {"tx_power_dbm": float(tx_power_dbm)}
    if tile_m is not None:
        radio["tile_m"] = float(tile_m)
    pos = np.column_stack([rng.uniform(0, width_m, n), rng.uniform(0, 0.7 * width_m, n), rng.uniform(0, max_z_m, n)])
    raw = {"name": "tiles", "seed": 1, "stations": [{"id": i + 1, "pos_m": p.tolist()} for i, p in enumerate(pos)],
           "radio": radio}
    return S.from_dict(raw)


@pytest.mark.parametrize("tile_m", [None, 700.0, 5000.0])
def test_subscription_is_a_superset_of_every_radio_link(tile_m):
    """Random layouts (station heights 0-200 m, so the reach bound is not just the nominal one):
    every sender the radio lets a station hear publishes on a tile that station subscribes to, and
    no subscribed tile lies farther than the station's reach."""
    rng = np.random.default_rng(11)
    checked = far = 0
    for _ in range(6):
        scn = _field(rng, 30, 30000.0, float(rng.uniform(-10.0, 10.0)), 200.0, tile_m)
        til = T.Tiling.of(scn)
        pos = np.asarray(scn.pos_m, float)
        exists = R.link(pos[:, None, :], pos[None, :, :], scn.channel.radio).exists  # [tx, rx]
        for j in range(len(pos)):
            subs = set(til.subscription_tiles(pos[j]))
            reach = til.reach_m(pos[j])
            for i in range(len(pos)):
                if i != j and exists[i, j]:
                    assert til.tile(pos[i]) in subs, (i, j, np.linalg.norm(pos[i] - pos[j]), reach)
                    checked += 1
                elif til.tile(pos[i]) not in subs:
                    far += 1
            for ix, iy in subs:  # every subscribed tile touches the reach disc
                dx = max(ix * til.size_m - pos[j, 0], 0.0, pos[j, 0] - (ix + 1) * til.size_m)
                dy = max(iy * til.size_m - pos[j, 1], 0.0, pos[j, 1] - (iy + 1) * til.size_m)
                assert math.hypot(dx, dy) <= reach
    assert checked > 100 and far > 100  # links were checked, and far stations were left out


def test_superset_over_terrain_and_default_tile():
    """The packaged hill (terrain only removes links) and seed003-radio (mixed heights)."""
    for name in ("hill", "seed003-radio"):
        scn = S.load(name)
        til = T.Tiling.of(scn)
        assert til.size_m == T.default_tile_m(scn.channel.radio)
        pos = np.asarray(scn.pos_m, float)
        exists = R.link(pos[:, None, :], pos[None, :, :], scn.channel.radio).exists
        for j in range(len(pos)):
            subs = set(til.subscription_tiles(pos[j]))
            assert all(til.tile(pos[i]) in subs for i in range(len(pos)) if exists[i, j])


def test_without_radio_or_with_tiles_off_everything(monkeypatch):
    scn = S.load("seed000")
    til = T.Tiling.of(scn)
    assert til.nav_key(4, scn.true_pos(4)) == "larns/station/4/nav/0_0"
    assert til.nav_subscriptions(scn.true_pos(4)) == [T.ALL_NAVS]
    radio_scn = _field(np.random.default_rng(2), 5, 30000.0, -5.0, 0.0)
    subs = T.Tiling.of(radio_scn).nav_subscriptions(radio_scn.pos_m[0])
    assert T.UNTILED_NAVS in subs and len(subs) > 2  # the tiles in reach + recordings from before tiles
    monkeypatch.setenv("LARNS_NAV_TILES", "off")
    assert T.Tiling.of(radio_scn).nav_subscriptions(radio_scn.pos_m[0]) == [T.ALL_NAVS]


def test_tile_m_key_is_checked_and_not_journaled():
    scn = _field(np.random.default_rng(3), 5, 1000.0, 0.0, 0.0, tile_m=1234.0)
    assert T.Tiling.of(scn).size_m == 1234.0
    assert "tile_m" not in R.radio_dict(scn.channel.radio)  # the cores' config: unchanged by tiles
    with pytest.raises(S.ScenarioError, match="tile_m"):
        _field(np.random.default_rng(3), 5, 1000.0, 0.0, 0.0, tile_m=0.0)


def test_nav_keys_of_the_wire():
    assert M.is_nav_key("larns/station/3/nav/2_-1") and M.is_nav_key("larns/station/3/nav")
    assert not M.is_nav_key("larns/station/3/estimate") and not M.is_nav_key("larns/station/3/range/req/2")
    assert not M.is_nav_key("larns/aircraft/ac1/nav")


def _line_scenario():
    """Stations 1-3 within 2 km of each other, 4 and 5 at 40 km: a -5 dBm radio reaches ~3 km."""
    pos = [[0.0, 0.0, 0.0], [1500.0, 0.0, 0.0], [0.0, 1500.0, 0.0], [40000.0, 0.0, 0.0], [40000.0, 1500.0, 0.0]]
    return S.from_dict({"name": "line", "seed": 1, "radio": {"tx_power_dbm": -5.0},
                        "stations": [{"id": i + 1, "pos_m": p} for i, p in enumerate(pos)]})


@pytest.mark.e2e
@pytest.mark.timeout(60)
def test_station_node_on_zenoh_hears_neighbours_only():
    """Station 1's node on a real Zenoh bus: a peer publishes navs of station 2 (1.5 km away) and of
    stations 4 and 5 (40 km, beyond the radio's reach) on their tiled keys, and a nav on the
    tile-less key of a recording from before tiles; the node's bus delivers station 2's and the
    tile-less one, nothing of 4's or 5's."""
    from net.bus import Bus, free_tcp_ports
    from stations.node import NodeOptions, StationNode

    scn = _line_scenario()
    til = T.Tiling.of(scn)
    assert not R.link(scn.true_pos(4), scn.true_pos(1), scn.channel.radio).exists
    assert til.tile(scn.true_pos(4)) not in til.subscription_tiles(scn.true_pos(1))
    (port,) = free_tcp_ports(1)
    got: list[str] = []
    with Bus(listen=[f"tcp/127.0.0.1:{port}"]) as b1, Bus(connect=[f"tcp/127.0.0.1:{port}"]) as b2:
        node = StationNode(scn, NodeOptions(station_id=1, speed=1.0, epoch_unix_s=time.time(), run_s=5.0,
                                            quiet=True, journal=False), b1)
        ingest = node._ingest
        node._ingest = lambda wall, key, data: (got.append(key), ingest(wall, key, data))
        th = threading.Thread(target=node.run, daemon=True)
        th.start()
        keys = {sid: til.nav_key(sid, scn.true_pos(sid)) for sid in (2, 4, 5)}
        time.sleep(0.5)
        for _ in range(25):  # the node drains its navs once per 1 s cycle
            for k in [*keys.values(), "larns/station/4/nav"]:
                b2.publish(k, b"not a nav")
            time.sleep(0.1)
        th.join(20.0)
        assert not th.is_alive()
    assert keys[2] in got                                  # the neighbour's tile
    assert "larns/station/4/nav" in got                    # a replayed recording from before tiles
    assert not [k for k in got if k in (keys[4], keys[5])]  # nothing from beyond the radio's reach
    assert node.report()["bus_rx"] == len(got)
