"""larns scenario show: every value the emulator uses, incl. [site] (and stations on WGS84) and [radio]."""

import re

from larns.commands.scenario import format_scenario
from net.scenario import load


def test_show_prints_the_site_and_each_station_on_wgs84():
    text = format_scenario(load("seed000-geo"))
    assert re.search(r"^\[site\]\s+origin 48\.8566\d* deg, 2\.3522\d* deg, 35\.000 m \(WGS84\); azimuth of \+X 90 deg$",
                     text, re.M)
    rows = [ln.split() for ln in text.splitlines() if re.match(r"^\s+\d+\s", ln)]
    assert len(rows) == 10 and all(len(r) == 7 for r in rows)  # id x y z lat lon h
    assert all(48.8 < float(r[4]) < 48.9 and 2.3 < float(r[5]) < 2.4 for r in rows)
    assert "radio" not in text  # no [radio]: not shown, and not in the [channel] line


def test_show_prints_the_radio_without_its_frame_tie(tmp_path):
    path = tmp_path / "r.toml"
    path.write_text('name = "r"\nseed = 2\n[radio]\nantenna_height_m = 25.0\ntwo_ray = false\n')
    text = format_scenario(load(path))
    line = next(ln for ln in text.splitlines() if ln.startswith("[radio]"))
    assert "antenna_height_m 25" in line and "two_ray False" in line and "k_factor 1.33333" in line
    assert "up" not in line.split() and "origin_height_m" not in line
    assert "[site]" not in text
