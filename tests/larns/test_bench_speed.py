"""`larns bench speed`: the worlds it writes and the table it computes (the fleet runs are e2e elsewhere)."""

from __future__ import annotations

import math

import pytest

from larns.bench.speed import _STOPPED, summarize, world_file


def test_world_file_sets_seed_and_station_count(tmp_path):
    from net.scenario import load

    p = world_file("seed000", 7, 30, tmp_path)
    scn = load(p)
    assert scn.seed == 7 and len(scn.ids) == 30
    assert load(world_file("seed000", 8, None, tmp_path)).seed == 8
    with pytest.raises(ValueError, match="layout"):
        world_file("seed003", 1, 12, tmp_path)  # a fixed layout has no station count to set


def test_summary_ratios_and_counters():
    line = "[station 4] stopped: updates=59 err=0.12 m drops=0 late=1 host_late=3 lost=2 missed_slots=0 sync=0.3 ns"
    assert _STOPPED.search(line).groups() == ("4", "59", "3", "2", "0")
    c = {4: {"updates": 59, "host_late": 3, "lost": 2, "missed_slots": 0}}
    runs = [{"world": f"world{w}", "speed": s, "rc": 0, "rms_h_m": v, "counters": c}
            for w, s, v in ((1, 1.0, 0.3), (2, 1.0, 0.4), (1, 10.0, 0.3), (2, 10.0, 0.7))]
    rows = summarize(runs, {"world1": 0.3, "world2": 0.4}, [1.0, 10.0])
    assert rows[0]["ratio_speed1"] == 1.0 and rows[0]["within_20pct"]
    assert math.isclose(rows[1]["rms_h_m"], math.sqrt((0.3**2 + 0.7**2) / 2))
    assert math.isclose(rows[1]["ratio_sim"], rows[1]["rms_h_m"] / math.sqrt((0.3**2 + 0.4**2) / 2))
    assert not rows[1]["within_20pct"]
    assert rows[1]["lost"] == 4 and rows[1]["updates_min"] == 59
    # without a run at speed 1 the simulator alone is the reference (a slow host's field: --speeds 0.5)
    slow = [dict(r, speed=0.5) for r in runs[:2]]
    (row,) = summarize(slow, {"world1": 0.3, "world2": 0.4}, [0.5])
    assert row["ratio_speed1"] is None and row["within_20pct"]
    (row,) = summarize(slow, {"world1": 0.2, "world2": 0.3}, [0.5])
    assert not row["within_20pct"]
