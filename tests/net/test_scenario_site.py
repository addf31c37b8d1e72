"""Scenarios on the Earth: ``[site]``, stations as latitude/longitude/height or a GeoJSON file, and the
packaged twin ``seed000-geo`` (seed000's stations on the map, same world seed)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from nav.site import Site
from net.scenario import ScenarioError, from_dict, load

ORIGIN = [48.8566, 2.3522, 35.0]
PHYS = np.array([[0.0, 0.0, 0.0], [900.0, 100.0, 10.0], [300.0, 800.0, -5.0], [500.0, 400.0, 60.0],
                 [1200.0, 700.0, 20.0]])


def _geo(site: Site, phys=PHYS) -> list[dict]:
    lat, lon, h = site.frame_to_geodetic(phys)
    return [{"id": i + 1, "lat_deg": float(lat[i]), "lon_deg": float(lon[i]), "h_m": float(h[i])}
            for i in range(len(phys))]


def test_the_geo_twin_reproduces_seed000_positions():
    a, g = load("seed000"), load("seed000-geo")
    assert a.ids == g.ids and a.seed == g.seed
    assert np.max(np.abs(a.pos_m - g.pos_m)) < 1e-3
    assert a.site is None and g.site is not None and g.site.origin == tuple(ORIGIN)
    # the site's network tie puts the network frame back where the stations are on the map
    st = sorted(g.raw["stations"], key=lambda s: s["id"])
    lat, lon, h = g.site.net_to_geodetic(g.pos_m)
    back = g.site.geodetic_to_frame(lat, lon, h)
    assert np.max(np.abs(back - np.array([s["pos_m"] for s in st]))) < 1e-3


@pytest.mark.parametrize("azimuth_deg", [90.0, 0.0, 213.0])
def test_lat_lon_stations_equal_their_local_twin(azimuth_deg):
    site = Site(*ORIGIN, azimuth_deg=azimuth_deg)
    local = from_dict({"stations": [{"id": i + 1, "pos_m": list(p)} for i, p in enumerate(PHYS)]})
    geo = from_dict({"site": {"origin": ORIGIN, "azimuth_deg": azimuth_deg}, "stations": _geo(site)})
    assert np.max(np.abs(local.pos_m - geo.pos_m)) < 1e-3
    assert geo.site.azimuth_deg == azimuth_deg
    # the raw document downstream readers use (vehicle/aircraft fields) holds physical pos_m
    assert all("pos_m" in s and "lat_deg" not in s for s in geo.raw["stations"])


def test_random_layout_with_a_site():
    scn = load("seed000", site={"origin": ORIGIN, "azimuth_deg": 30.0})
    base = load("seed000")
    assert np.array_equal(scn.pos_m, base.pos_m) and scn.site.azimuth_deg == 30.0
    lat, lon, _ = scn.site.net_to_geodetic(scn.pos_m)
    assert np.all(np.abs(lat - ORIGIN[0]) < 0.03) and np.all(np.abs(lon - ORIGIN[1]) < 0.04)


def test_origin_defaults_to_station_1():
    site = Site(*ORIGIN)
    geo = _geo(site, PHYS + [100.0, 200.0, 3.0])
    scn = from_dict({"stations": geo})
    assert scn.site.origin == (geo[0]["lat_deg"], geo[0]["lon_deg"], geo[0]["h_m"])


def _feature(e: dict) -> dict:
    return {"type": "Feature", "geometry": {"type": "Point", "coordinates": [e["lon_deg"], e["lat_deg"], e["h_m"]]},
            "properties": {"id": e["id"], "name": f"S{e['id']}"}}


def test_stations_from_geojson(tmp_path):
    site = Site(*ORIGIN)
    (tmp_path / "st.geojson").write_text(json.dumps({"type": "FeatureCollection",
                                                     "features": [_feature(e) for e in _geo(site)]}))
    f = tmp_path / "geo.toml"
    f.write_text(f'name = "g"\nseed = 3\n[site]\norigin = {ORIGIN}\nstations_geojson = "st.geojson"\n')
    scn = load(f)
    local = from_dict({"stations": [{"id": i + 1, "pos_m": list(p)} for i, p in enumerate(PHYS)]})
    assert np.max(np.abs(scn.pos_m - local.pos_m)) < 1e-3 and scn.ids == [1, 2, 3, 4, 5]
    # from another working directory: the file is relative to the scenario
    r = subprocess.run([sys.executable, "-m", "larns", "scenario", "validate", str(f)], capture_output=True,
                       text=True, cwd="/")
    assert r.returncode == 0, r.stderr


GOOD = {"site": {"origin": ORIGIN}}
BAD = [
    ({"site": {"origin": [48.0, 2.0]}}, "[site] origin", "[lat_deg, lon_deg, h_m]"),
    ({"site": {"origin": [95.0, 2.0, 0.0]}}, "[site] origin[0]", "-90..90"),
    ({"site": {"origin": [45.0, 200.0, 0.0]}}, "[site] origin[1]", "-180..180"),
    ({"site": {"origin": ORIGIN, "azimuth": 3.0}}, "[site] azimuth", "azimuth_deg"),
    ({"site": {"origin": ORIGIN, "azimuth_deg": "east"}}, "[site] azimuth_deg", "finite number"),
    ({"site": {"azimuth_deg": 10.0}}, "[site] origin", "missing"),
    ({"site": {"origin": ORIGIN, "stations_geojson": 3}}, "[site] stations_geojson", "GeoJSON"),
    ({"site": {"origin": ORIGIN, "stations_geojson": "nope.geojson"}}, "[site] stations_geojson", "readable"),
    ({"site": {"origin": ORIGIN, "stations_geojson": "x.geojson"}, "stations": [{"id": 1, "pos_m": [0, 0, 0]}]},
     "[site] stations_geojson", "one of them"),
    ({"stations": [{"id": 1, "lat_deg": 10.0}]}, "stations[0].lon_deg", "missing"),
    ({"stations": [{"id": 1, "lat_deg": 100.0, "lon_deg": 0.0}]}, "stations[0].lat_deg", "-90..90"),
    ({"stations": [{"id": 1, "lat_deg": 10.0, "lon_deg": 0.0, "pos_m": [0, 0, 0]}]}, "stations[0].pos_m",
     "one of them"),
    ({"stations": [{"id": 1, "lat_deg": 10.0, "lon_deg": 0.0, "h": 3.0}]}, "stations[0].h", "h_m"),
    ({"stations": [{"id": 1, "lat_deg": 10.0, "lon_deg": 0.0}, {"id": 2, "pos_m": [0, 0, 0]}]}, "[site] origin",
     "mix"),
]


@pytest.mark.parametrize("raw,where,expected", BAD)
def test_bad_site_entries_name_their_key(raw, where, expected):
    with pytest.raises(ScenarioError) as e:
        from_dict(raw)
    msg = e.value.message
    assert msg.startswith(where + ":") and expected in msg and "(expected" in msg, msg


@pytest.mark.parametrize("content,where", [
    ("not json", "not JSON"),
    (json.dumps({"type": "Feature"}), "not a FeatureCollection"),
    (json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "geometry": {"type": "LineString", "coordinates": [[0, 0], [1, 1]]}, "properties": {"id": 1}}]}),
     "features[0].geometry"),
    (json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "geometry": {"type": "Point", "coordinates": [2.0, 48.0]}, "properties": {}}]}),
     "features[0].properties.id"),
    (json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "geometry": {"type": "Point", "coordinates": [2.0, 148.0]}, "properties": {"id": 1}}]}),
     "features[0].coordinates[1]"),
])
def test_bad_geojson_is_one_line_exit_2(tmp_path, content, where, capsys):
    from larns.cli import main

    (tmp_path / "st.geojson").write_text(content)
    f = tmp_path / "bad.toml"
    f.write_text(f'[site]\norigin = {ORIGIN}\nstations_geojson = "st.geojson"\n')
    assert main(["scenario", "validate", str(f)]) == 2  # in process (the real process: the test below)
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith(f"{f}: [site] stations_geojson: ") and where in lines[0] and "(expected" in lines[0]


def test_bad_site_through_the_cli_is_one_line(tmp_path):
    f = tmp_path / "bad.toml"
    f.write_text('[site]\norigin = [48.0, 2.0]\n')
    r = subprocess.run([sys.executable, "-m", "larns", "scenario", "validate", str(f)], capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.strip() == (f"{f}: [site] origin: got [48.0, 2.0] (expected "
                                                      "[lat_deg, lon_deg, h_m])")


def test_the_geo_twin_surveys_like_seed000():
    """The same world seed on the same stations (given on the map): the in-process simulator's survey
    errors of seed000-geo are seed000's (dmap, 12 s; measured: within 1 um)."""
    from stations.sim import Simulator

    times = np.array([5.0, 12.0])
    runs = [Simulator(load(name), estimator="dmap").run(12.0, times) for name in ("seed000", "seed000-geo")]
    err = [r.pos_m - r.truth_m for r in runs]
    assert np.array_equal(runs[0].link_counts, runs[1].link_counts)
    assert np.all(np.isfinite(err[0][-1])) and np.max(np.abs(err[0][-1])) > 0.01  # a survey that has errors
    assert np.max(np.abs(err[0] - err[1])) < 1e-3
