"""larns/bench/aircraft.py: ``larns bench aircraft --quick`` (a short run without the sweep) writes the
RMSE, PCRB, height, sample and speed keys of every filter and its figures."""

from __future__ import annotations

import json

import numpy as np
import pytest


def test_bench_aircraft_quick_smoke(tmp_path):
    from larns.cli import main

    js = tmp_path / "b.json"
    rc = main(["bench", "aircraft", "--quick", "--trials", "2", "--duration", "2", "--warmup", "1",
               "--no-sweep", "--json", str(js), "--png-dir", str(tmp_path)])
    assert rc == 0
    out = json.loads(js.read_text())
    assert set(out["rmse_m"]["hover"]) == {"lsq-pr", "lsq-tdoa", "ekf-pr", "ekf-tdoa", "ukf-pr", "ukf-tdoa"}
    assert set(out["rmse_m"]["hover"]["ukf-pr"]) == {"100", "1000"}
    assert set(out["pcrb_m"]["turn"]) == {"ekf-pr", "ekf-tdoa", "ukf-pr", "ukf-tdoa"}
    assert out["height_m"]["hover"]["1000"] == pytest.approx(1000 * np.tan(np.radians(3)))
    assert out["samples"]["hover"]["1000"] > 0
    assert out["speed"]["max_rel_state_diff"] < 1e-9
    lc = out["speed"]["live_core"]  # the live core at seed001's 100 broadcasts/s: every algorithm published
    assert lc["broadcasts_per_s"] == pytest.approx(100.0) and set(lc["each_pct_of_core"]) == set(lc["algos"])
    assert lc["messages_per_s"] > 3 * lc["broadcasts_per_s"] and 0 < lc["all_pct_of_core"] < 400
    assert (tmp_path / "aircraft_fig4_hover.png").stat().st_size > 1000
