"""net/terrain.py: line of sight over a height grid (terrain, Earth bulge, Fresnel clearance) as net/radio.py
applies it to every link; the packaged hill scenario; terrain file errors through the real CLI."""

import itertools
import subprocess
import sys

import numpy as np
import pytest

from net.channel import AirChannel, Clock
from net.radio import RadioParams, horizon_m, link, reception_sigma_m
from net.scenario import ScenarioError, load
from net.terrain import EARTH_RADIUS_M, Terrain, clear, height_at

K = 4.0 / 3.0
LAMBDA_M = 299_792_458.0 / 1e9
# the pairs the hill masks (net/scenarios/hill.toml's description): those whose path crosses the hill
HILL_MASKED = {(1, 6), (1, 7), (1, 8), (2, 4), (2, 5), (2, 6), (3, 5), (3, 6), (3, 7), (4, 7), (4, 8), (5, 8)}


def ridge(height_m=100.0) -> Terrain:
    """A ridge along y: 0 m at x = -1000, ``height_m`` flat from x = 0 to 1000, 0 m at x = 2000 (any y in
    -20..20 km)."""
    row = [0.0, height_m, height_m, 0.0]
    return Terrain(origin_m=(-1000.0, -20_000.0), spacing_m=(1000.0, 20_000.0), heights_m=np.array([row, row, row]))


def flat(height_m=0.0) -> Terrain:
    return Terrain(origin_m=(-50_000.0, -50_000.0), spacing_m=(1000.0, 1000.0), heights_m=np.full((101, 101), height_m))


def test_bilinear_height_and_zero_outside_the_grid():
    t = ridge()
    assert height_at(t, [-1000.0, -500.0, 0.0, 500.0, 1500.0, 2000.0], 0.0).tolist() == [0, 50, 100, 100, 50, 0]
    assert height_at(t, [-1001.0, 2001.0, 0.0], [0.0, 0.0, 20_001.0]).tolist() == [0, 0, 0]


def test_a_ridge_blocks_below_its_top_plus_the_earth_bulge_and_not_above():
    """Antennas 10 km apart at equal heights across a 100 m ridge whose top starts at the midpoint: the path
    must clear 100 m + the bulge d1 d2 / (2 k R_E) = 5000^2 / (2 * 4/3 * 6371 km) = 1.4716 m there."""
    bulge_m = 5000.0**2 / (2 * K * EARTH_RADIUS_M)
    assert bulge_m == pytest.approx(1.4716, abs=1e-4)
    t = ridge()

    def los(z_m):
        return bool(clear([-5000.0, 0.0, z_m], [5000.0, 0.0, z_m], t, K, LAMBDA_M, 0.0))

    assert not los(50.0) and los(150.0)
    assert not los(100.0 + bulge_m - 0.05)
    assert los(100.0 + bulge_m + 0.05)
    # the antenna height counts: 95 m + 10 m antennas clear it
    assert bool(clear([-5000.0, 0.0, 95.0], [5000.0, 0.0, 95.0], t, K, LAMBDA_M, 10.0))
    # a Fresnel clearance of 0.6 needs 0.6 sqrt(lambda d1 d2 / d) = 0.6 * 27.4 m more at the midpoint
    r1_m = np.sqrt(LAMBDA_M * 5000.0 * 5000.0 / 10_000.0)
    tf = Terrain(t.origin_m, t.spacing_m, t.heights_m, fresnel_clearance=0.6)
    z = 100.0 + bulge_m + 0.6 * r1_m
    assert not bool(clear([-5000.0, 0.0, z - 0.05], [5000.0, 0.0, z - 0.05], tf, K, LAMBDA_M, 0.0))
    assert bool(clear([-5000.0, 0.0, z + 0.05], [5000.0, 0.0, z + 0.05], tf, K, LAMBDA_M, 0.0))


def test_the_earth_bulge_alone_ends_links_at_the_smooth_earth_horizon():
    """Over flat terrain at 0 m the bulge touches the path exactly at the horizon of the two antennas."""
    d_h = float(horizon_m(10.0, 10.0, K))
    for f, expect in ((0.99, True), (1.01, False)):
        a, b = np.array([-f * d_h / 2, 0.0, 0.0]), np.array([f * d_h / 2, 0.0, 0.0])
        assert bool(clear(a, b, flat(), K, LAMBDA_M, 10.0)) is expect, f


def test_flat_terrain_changes_no_link_and_bulk_equals_one_by_one():
    rng = np.random.default_rng(33)
    P = np.column_stack([rng.uniform(-40_000, 40_000, (40, 2)), rng.uniform(0, 300, 40)])
    plain = link(P[:, None, :], P[None, :, :], RadioParams())
    over = link(P[:, None, :], P[None, :, :], RadioParams(terrain=flat()))
    assert 0 < plain.exists.sum() < plain.exists.size  # some beyond the horizon, some not
    assert np.array_equal(plain.exists, over.exists)
    assert np.array_equal(plain.sigma_crlb_s, over.sigma_crlb_s)
    hilly = RadioParams(terrain=ridge(150.0))
    bulk = link(P[:, None, :], P[None, :, :], hilly).exists
    one = np.array([[bool(link(p, q, hilly).exists) for q in P] for p in P])
    assert np.array_equal(bulk, one)
    assert bulk.sum() < plain.exists.sum()  # the ridge masks some
    assert np.array_equal(bulk, bulk.T)


def test_the_hill_masks_the_pairs_across_it_and_the_aircraft_sees_all():
    scn = load("hill")
    radio = scn.channel.radio
    assert radio.terrain is not None and radio.terrain.shape == (33, 33)
    ex = link(scn.pos_m[:, None, :], scn.pos_m[None, :, :], radio).exists
    masked = {(a, b) for (i, a), (j, b) in itertools.combinations(enumerate(scn.ids), 2) if not ex[i, j]}
    assert masked == HILL_MASKED
    # without the terrain every pair is within the horizon and the budget
    assert link(scn.pos_m[:, None, :], scn.pos_m[None, :, :], RadioParams().in_frame(np.eye(3), np.zeros(3))).exists.sum() == 64
    R, t = radio.terrain.R, radio.terrain.t_m

    def net(p_phys):
        return (np.asarray(p_phys, float) - t) @ R.T

    for r_m, ang in itertools.product((3000.0, 7000.0), np.radians(np.arange(0, 360, 30))):  # at 1000 m
        ac = net([r_m * np.cos(ang), r_m * np.sin(ang), 1000.0])  # 3 km: the scenario's circle
        assert all(reception_sigma_m(p, ac, radio, 0.9) is not None for p in scn.pos_m)
    # a vehicle 2 m up west of the ring: station 7 (east, behind the hill) and 6, 8 are hidden, the rest heard
    veh = net([-6500.0, 0.0, 2.0])
    heard = {sid for sid, p in zip(scn.ids, scn.pos_m) if reception_sigma_m(p, veh, radio, 0.9) is not None}
    assert heard == {1, 2, 3, 4, 5}
    # the same vehicle over the hill's top sees every station
    top = net([0.0, 0.0, 300.0])
    assert all(reception_sigma_m(p, top, radio, 0.9) is not None for p in scn.pos_m)


def test_the_channel_drops_what_the_terrain_masks():
    scn = load("hill")
    air = AirChannel(scn.channel, np.random.default_rng(0), (scn.seed, 1))
    i = {sid: k for k, sid in enumerate(scn.ids)}
    assert air.arrival_local_s(scn.pos_m[i[7]], 1.0, scn.pos_m[i[1]], Clock(), tx_id=7) is None
    assert air.arrival_local_s(scn.pos_m[i[2]], 1.0, scn.pos_m[i[1]], Clock(), tx_id=2) is not None


def test_the_simulator_ranges_only_over_the_links_the_terrain_allows():
    from stations.sim import Simulator

    scn = load("hill")
    r = Simulator(scn).run(20.0, [20.0])
    L = r.link_counts[-1] + r.link_counts[-1].T
    for (i, a), (j, b) in itertools.combinations(enumerate(r.ids), 2):
        if (a, b) in HILL_MASKED:
            assert L[i, j] == 0, (a, b, L[i, j])
        else:
            assert L[i, j] > 0, (a, b)


def _validate(tmp_path, radio: str, grid: str | None = None):
    if grid is not None:
        (tmp_path / "g.terrain").write_text(grid)
    st = "".join(f"[[stations]]\nid = {i + 1}\npos_m = {p}\n"
                 for i, p in enumerate([[0, 0, 0], [1000, 0, 0], [0, 1000, 0], [500, 500, 30]]))
    path = tmp_path / "t.toml"
    path.write_text(f'name = "t"\n[radio]\n{radio}\n{st}')
    return subprocess.run([sys.executable, "-m", "larns", "scenario", "validate", str(path)], capture_output=True,
                          text=True, timeout=60)


GOOD = "origin_m = [0.0, 0.0]\nspacing_m = 500.0\nheights_m = [[0, 0], [0, 1]]\n"


@pytest.mark.parametrize("radio, grid, message", [
    ('terrain = "missing.terrain"', None, r"\[radio\] terrain: cannot read .*missing.terrain: .*\(expected a terrain grid"),
    ('terrain = "g.terrain"', "heights_m = [[0, 1], [2]]\norigin_m = [0, 0]\nspacing_m = 1.0\n",
     r"\[radio\] terrain: .*g.terrain: heights_m: rows of lengths \[1, 2\] \(expected"),
    ('terrain = "g.terrain"', "origin_m = [0, 0\n", r"\[radio\] terrain: .*g.terrain: not TOML"),
    ('terrain = "g.terrain"', GOOD.replace("500.0", "-1"), r"g.terrain: spacing_m: got -1 \(expected"),
    ('terrain = 3', None, r"\[radio\] terrain: got 3 \(expected the path"),
    ("fresnel_clearance = 0.6", None, r"\[radio\] fresnel_clearance: without \[radio\] terrain"),
])
def test_a_bad_terrain_is_one_line_and_exit_2(tmp_path, radio, grid, message):
    p = _validate(tmp_path, radio, grid)
    assert p.returncode == 2, p.stdout + p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
    assert lines[0].startswith(str(tmp_path / "t.toml") + ": "), lines[0]
    import re
    assert re.search(message, lines[0]), lines[0]


def test_a_good_terrain_file_beside_the_scenario_loads(tmp_path):
    p = _validate(tmp_path, 'terrain = "g.terrain"\nfresnel_clearance = 0.6', GOOD)
    assert p.returncode == 0, p.stderr
    scn = load(tmp_path / "t.toml")
    assert scn.channel.radio.terrain.fresnel_clearance == 0.6
    with pytest.raises(ScenarioError, match="fresnel_clearance: got -1"):
        load(tmp_path / "t.toml", radio={"fresnel_clearance": -1})
