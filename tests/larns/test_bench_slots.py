"""`larns bench slots` end to end, small: a sparse field that fits its cycle passes the bar, and a
cycle too short for the densest neighbourhood is reported as such (measured degree), not fudged."""

from __future__ import annotations

import json
import subprocess
import sys


def _run(tmp_path, *extra: str) -> tuple[subprocess.CompletedProcess, dict]:
    out = tmp_path / "slots.json"
    r = subprocess.run([sys.executable, "-m", "larns", "bench", "slots", "--stations", "40", "--trials", "1",
                        "--duration", "20", "--joiners", "2", "--png-dir", str(tmp_path), "--json", str(out),
                        *extra], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr[-2000:]
    return r, json.loads(out.read_text())


def test_bench_slots_sparse_field_passes_and_writes_json_and_png(tmp_path):
    r, res = _run(tmp_path, "--tx-power-dbm", "-5", "--cycle-slots", "20")
    t = res["trials"][0]
    assert t["graph"]["no_link_fraction"] > 0.5 and t["graph"]["hop_diameter"] >= 3  # multi-hop
    assert t["cycle_slots"] == 20 and t["converged_cycle"] is not None and t["conflict_pairs_end"] == 0
    assert t["slots_used"] <= 20 and abs(t["reuse"] - 40 / t["slots_used"]) < 1e-12
    assert all(c is not None and c <= 3 for c in t["joiner_hold_cycles"])
    assert res["bar"]["joiners_hold_within_3_cycles"] is True
    assert (tmp_path / "slots_field.png").stat().st_size > 0
    assert "conv_cyc" in r.stdout and "bar slots_le_40: PASS" in r.stdout


def test_bench_slots_reports_a_cycle_too_short_for_the_densest_neighbourhood(tmp_path):
    """Default radio (links to the 26 km horizon), 40 stations along a 100 km corridor: one station
    hears more than 10 others, so a 10-slot cycle cannot hold the layout."""
    r, res = _run(tmp_path, "--layout", "corridor", "--cycle-slots", "10")
    deg = res["summary"]["max_closed_1hop"]
    assert deg > 10
    t = res["trials"][0]
    assert t["unassigned_end"] > 0 or t["conflict_pairs_end"] > 0  # it does not converge, and says so
    assert t["converged_cycle"] is None and res["bar"]["converged_and_no_collisions_after_60s"] is False
    assert f"at least {deg} slots are needed" in r.stdout


SMALL_FIELD = """name = "slots-small"
seed = 3
[layout]
n = 16
joiners = 1
area_m = [9000.0, 7000.0, 10.0]
min_separation_m = 300.0
founders_within_m = 3000.0
[radio]
tx_power_dbm = -5.0
[tdma]
cycle_s = 0.24
slot_s = 0.01
assignment = "distributed"
cycle_slots = 12
[init]
sigma0_m = 10.0
"""


def test_bench_slots_on_a_scenario_runs_the_station_simulator(tmp_path):
    """--scenario: the same figures from the station simulator (the cores, their navs' summaries and
    the simulator's collisions), a late joiner included, beside the fixed plan's survey."""
    scn = tmp_path / "small.toml"
    scn.write_text(SMALL_FIELD)
    out = tmp_path / "slots.json"
    r = subprocess.run([sys.executable, "-m", "larns", "bench", "slots", "--scenario", str(scn), "--duration", "6",
                        "--compare-fixed", "--json", str(out)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads(out.read_text())
    t = res["trials"][0]
    assert t["plan"] == "distributed" and t["cycle_slots"] == 12 and t["conflict_pairs_end"] == 0
    assert t["converged_cycle"] is not None and t["unassigned_end"] == 0
    # 12 slots of 10 ms at the start of a 0.24 s cycle: times in cycles of the scenario's length
    assert t["cycle_s"] == 0.24 and abs(t["converged_s"] - 0.24 * t["converged_cycle"]) < 1e-9
    assert res["slot_s"] == 0.01 and "slot=10 ms" in r.stdout
    assert len(t["joiner_hold_cycles"]) == 1 and t["joiner_hold_cycles"][0] is not None
    assert res["fixed"]["plan"] == "fixed" and res["fixed"]["ranges"] > 0
    assert "fixed plan:" in r.stdout and "distributed plan:" in r.stdout
