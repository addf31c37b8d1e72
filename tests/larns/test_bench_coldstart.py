"""`larns bench cold-start` on the session's shared recorded fleet (tests/conftest.py ``fleet_run``)."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest

from larns.bench import coldstart as cs

pytestmark = pytest.mark.e2e


@pytest.fixture(scope="module")
def flight(fleet_run):
    assert fleet_run.rc == 0, fleet_run.log[-3000:]
    (a,) = cs.load_journals(str(fleet_run.rec))
    entries, hole, _n = a.contiguous()
    assert hole is None
    return a, entries


def test_a_start_at_the_first_broadcast_is_the_live_navigator(flight):
    """Re-flown from the journal's first broadcast with the rules as recorded, a single algorithm
    publishes exactly the estimates the live process published (the estimators of one core are
    independent): the bench's starts are the live receiver, switched on later."""
    a, entries = flight
    # the earliest reception, not the first entry: the journal is in the order the navigator consumed
    # the broadcasts, and a fleet's first ones can arrive out of order (one CI run: 0.105 s, then 0.005 s)
    t_first = min(e[1] for e in entries if e[0] == "m")
    mine = cs.refly(a.init, a.name, entries, "ukf-pr", t_first, {})
    live = [m for _lt, m in a.estimates["ukf-pr"]]
    assert len(live) > 10
    # every recorded estimate is re-flown identically (the recorder may have missed one; the
    # journal has no hole); an estimate is named by its time and its rank among those of that time
    by_key = {(e["t_s"], k): e for k, e in _ranked(mine)}
    assert len(by_key) >= len(live)
    for k, y in _ranked(live):
        x = by_key[(y["t_s"], k)]
        assert x["pos_m"] == list(y["pos_m"]) and x["cov_m2"] == [list(r) for r in y["cov_m2"]], y["t_s"]


def _ranked(ests):
    seen: dict[float, int] = {}
    for e in ests:
        seen[e["t_s"]] = k = seen.get(e["t_s"], -1) + 1
        yield k, e


def test_a_later_start_sees_only_what_came_after_it(flight):
    a, entries = flight
    t_first = next(e[1] for e in entries if e[0] == "m")
    later = cs.refly(a.init, a.name, entries, "ekf-pr", t_first + 10.0, {})
    assert later and later[0]["t_s"] >= t_first + 10.0
    # without rule 5 a filter may start sooner, never later
    loose = cs.refly(a.init, a.name, entries, "ekf-pr", t_first + 10.0, cs.RULES["survey"])
    assert loose and loose[0]["t_s"] <= later[0]["t_s"]


def test_score_of_a_start():
    truth = lambda t: [0.0, 0.0, 100.0]  # noqa: E731
    ests = [{"t_s": 1.0, "pos_m": [12.0, 0.0, 100.0], "cov_m2": [[4.0, 0, 0], [0, 4.0, 0], [0, 0, 4.0]]},
            {"t_s": 2.0, "pos_m": [1.0, 0.0, 100.0], "cov_m2": [[4.0, 0, 0], [0, 4.0, 0], [0, 0, 4.0]]},
            {"t_s": 3.0, "pos_m": [0.0, 2.0, 100.0], "cov_m2": [[4.0, 0, 0], [0, 4.0, 0], [0, 0, 4.0]]}]
    s = cs.score(ests, truth, 0.5)
    assert s["n"] == 3 and s["first_s"] == 0.5 and s["settled_s"] == 1.5
    assert s["err_m"] == 2.0 and math.isclose(s["nees"], 1.0) and math.isclose(s["sigma_m"], math.sqrt(12.0))
    assert math.isnan(cs.score(ests[:1], truth, 0.5)["settled_s"])
    assert cs.score([], truth, 0.0)["n"] == 0
    rows = [cs.score(ests, truth, 0.5), cs.score(ests[:1], truth, 0.5), cs.score([], truth, 0.0)]
    summ = cs.summarize(rows, bad_m=5.0)
    assert (summ["starts"], summ["no_estimate"], summ["bad"], summ["never_settled"]) == (3, 1, 2, 2)
    assert summ["overconfident"] == 1  # 12 m off with sigma 3.5 m: beyond 3 sigma + 1 m


def test_cli_table_json_png(fleet_run, tmp_path):
    out, png = tmp_path / "cold.json", tmp_path / "cold.png"
    r = subprocess.run([sys.executable, "-m", "larns", "bench", "cold-start", str(fleet_run.rec), "--starts", "3",
                        "--span", "10", "--algo", "ekf-pr", "--without", "survey,floor", "--json", str(out),
                        "--png", str(png)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "without survey,floor" in r.stdout and "ekf-pr" in r.stdout
    doc = json.loads(out.read_text())
    assert set(doc["summary"]) == {"rules", "without survey,floor"}
    assert [row["offset_s"] for row in doc["rows"]["rules"]["ekf-pr"]] == [0.0, 5.0, 10.0]
    assert all(row["n"] > 0 for row in doc["rows"]["rules"]["ekf-pr"])
    assert png.stat().st_size > 10_000


def test_cli_bad_input(tmp_path):
    r = subprocess.run([sys.executable, "-m", "larns", "bench", "cold-start", "x.mcap", "--without", "bogus"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "unknown rule 'bogus'" in r.stderr
    r = subprocess.run([sys.executable, "-m", "larns", "bench", "cold-start", str(tmp_path / "nope.mcap")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "no such file" in r.stderr and "Traceback" not in r.stderr
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file" * 100)
    r = subprocess.run([sys.executable, "-m", "larns", "bench", "cold-start", str(junk)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "not an MCAP file" in r.stderr and "Traceback" not in r.stderr
