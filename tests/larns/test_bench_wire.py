"""`larns bench wire` without fleets: its fields, what their geometry predicts, and the station line it
parses (the fleets themselves: docs/fleet.md, "The wire per station process")."""

from __future__ import annotations

from larns.bench import wire as W


def test_fields_of_the_same_density_and_their_prediction(tmp_path):
    geo = {}
    for n in (20, 40):
        p = tmp_path / f"wire-{n}.toml"
        p.write_text(W.field_toml(n, 1000.0, -7.0, None))
        geo[n] = W.geometry(p)
        assert geo[n]["stations"] == n
    # the same radio and tiles; the senders on a station's tiles grow far less than the field
    assert geo[20]["tile_m"] == geo[40]["tile_m"]
    assert geo[40]["senders_on_tiles_mean"] / geo[20]["senders_on_tiles_mean"] < 1.3
    assert 5.0 < geo[20]["neighbours_mean"] < geo[20]["senders_on_tiles_mean"] < 20


def test_the_station_line_it_reads():
    line = ("[station 12] stopped: updates=29 err=11.12 m drops=0 late=0 host_late=0 lost=1 missed_slots=0 "
            "sync=0.00 ns range delay ms p50=0.7 p90=2.0 p99=3.7 bus_rx=521 in 29.1 s")
    m = W._BUS.search(line)
    assert m is not None and (m[1], m[2], m[3]) == ("12", "521", "29.1")
