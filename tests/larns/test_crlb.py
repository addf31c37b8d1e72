"""larns/commands/crlb.py: ``larns crlb`` on seed003 writes its JSON summary (horizontal bound below
the vertical inside the field) and its map."""

from __future__ import annotations

import json


def test_crlb_command_smoke(tmp_path, capsys):
    from larns.cli import main

    png, js = tmp_path / "c.png", tmp_path / "c.json"
    assert main(["crlb", "--scenario", "seed003", "--step", "5000", "--png", str(png), "--json", str(js)]) == 0
    out = json.loads(js.read_text())
    inside = out["summary"][0]
    assert inside["band_km"] == [0, 0] and inside["horiz_median_m"] < inside["vert_median_m"]
    assert png.stat().st_size > 1000
