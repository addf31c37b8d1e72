"""`larns bench sync`: the NEES band of correlated stations, and a short run end to end."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from larns.bench.survey import chi2_band
from larns.bench.sync import correlated_band


def test_correlated_band_reduces_to_chi_square_and_widens_with_common_mode():
    T, n = 50, 9
    lo, hi = correlated_band(np.ones((T, 1, n)))
    ref = chi2_band(1, T * n)
    assert abs(lo[0] - ref[0]) < 0.01 and abs(hi[0] - ref[1]) < 0.01
    common = np.zeros((T, 1, n))
    common[:, :, 0] = n  # all stations share one error: the trial is one chi2(1) draw, n times over
    lo_c, hi_c = correlated_band(common)
    ref_c = chi2_band(1, T)
    assert abs(lo_c[0] - ref_c[0]) < 0.02 and abs(hi_c[0] - ref_c[1]) < 0.02
    assert hi_c[0] > hi[0] + 0.2


def test_bench_sync_short_run(tmp_path):
    out = tmp_path / "sync.json"
    r = subprocess.run([sys.executable, "-m", "larns", "bench", "sync", "--trials", "2", "--duration", "6",
                        "--jobs", "1", "--png-dir", "", "--json", str(out)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads(out.read_text())
    assert res["times_s"] == [2.0, 5.0]
    for key in ("sync_rms_ns", "sync_crlb_rms_ns", "nees_mean"):
        assert len(res[key]) == 2 and all(np.isfinite(res[key]))
    band = res["nees_band_95_correlated"]
    assert all(b[0] < 1.0 < b[1] for b in band)
    # two trials of nine stations sharing network time: wider than nine independent stations would be
    assert band[1][1] > res["nees_band_95"][1]
    assert "band_lo" in r.stdout


def test_bench_sync_trial_maximum_and_departure_step():
    """One 70 s trial with station 1 silent from 30 s: the per-trial largest error from 60 s on is the
    largest |error| of the stations alive there, and the departure's step of network time is reported
    (small: the survivors renormalize without a step)."""
    from larns.bench.sync import _trial, summarize

    res_t = _trial(("seed000", "tcxo", 0.5, 10, 5, 70.0, {1: 30.0}, {}))
    assert set(res_t["steps_s"]) == {1} and res_t["steps_s"][1] < 0.3e-9
    times = np.arange(1.0, 70.0 + 1e-9, 1.0)
    res = summarize([res_t], times, [30.0, 60.0], {"clock": "tcxo", "sigma_d_m": 0.5, "stations": 10,
                                                    "scenario": "seed000"})
    e = np.abs(res_t["err_s"][times >= 60.0]) * 1e9
    assert np.isnan(e[:, 0]).all() and np.isfinite(e[:, 1:]).all()  # station 1 gone, the others measured
    assert res["sync_trial_max_ns"] == [np.nanmax(e)]
    # the stations' definitions of network time, on the true clocks: apart by far less than the sync error
    assert len(res["sync_spread_ns"]) == 2 and 0.0 < res["sync_spread_ns"][1] < 0.5
    assert 0.0 < res["sync_trial_max_ns"][0] < 3.0
    assert res["departure_step_ns"] == {"1": res_t["steps_s"][1] * 1e9}
    assert "trial_max_from_60s_le_2ns_in_99pct" in res["bar"] and "departure_steps_le_0.3ns" in res["bar"]


def test_bench_sync_late_founder_cell():
    """Station 1 powers on 5 s after the others (``--late-founder 5``), one 40 s trial: before it the
    bench measures nine stations (station 1's error is NaN), after it ten; the stations' definitions of
    network time agree within the 2 ns bar from 35 s (the steering of docs/sync.md; since the multi-hop
    rules the nine take the founder's definition, whose descends from the founders', before them the
    founder took theirs; before either rule 114-711 us)."""
    from larns.bench.sync import _trial, summarize

    res_t = _trial(("seed000", "tcxo", 0.5, 10, 2, 40.0, {}, {1: 5.0}))
    times = np.arange(1.0, 40.0 + 1e-9, 1.0)
    err = res_t["err_s"]
    assert np.isnan(err[times < 5.0, 0]).all() and np.isfinite(err[times >= 6.0, 0]).all()
    res = summarize([res_t], times, [30.0, 40.0], {"clock": "tcxo", "sigma_d_m": 0.5, "stations": 10,
                                                    "scenario": "seed000", "late_founder_s": 5.0})
    assert res["bar"]["late_founder_spread_le_2ns_from_30s_after"], res["sync_spread_ns"]
    assert res["sync_spread_ns"][1] < 2.0


def test_the_bound_filter_errors_match_the_bound():
    """crlb_offset_var with an rng feeds the centralized filter exchanges of clocks drawn from its own
    model: its variance is the same as without values (it does not depend on them), and its errors
    are those of an efficient estimator: NEES of the ensemble offsets about 1 over one 60 s trial of
    ten stations (seeded; 500 samples of 9 effectively independent components, tolerance 0.25), and
    the reference station's error against the ensemble is no longer zero."""
    from larns.bench.sync import crlb_offset_var
    from net.scenario import load
    from stations.sim import Simulator

    scn = load("seed000", seed=3, channel={"sigma_d_m": 0.5}, layout={"n": 10}, clock={"model": "tcxo"})
    sim = Simulator(scn)
    times = np.arange(1.0, 60.0 + 1e-9, 1.0)
    r = sim.run(60.0, times)
    var0, none = crlb_offset_var(scn, sim.exchange_log, r.ids, times)
    var, err = crlb_offset_var(scn, sim.exchange_log, r.ids, times, rng=np.random.default_rng(5))
    assert none is None and np.allclose(var, var0, rtol=1e-9, atol=0.0)
    late = times >= 10.0
    nees = np.mean(err[late] ** 2 / var[late])
    assert abs(nees - 1.0) < 0.25, nees
    assert np.all(np.abs(err[late, 0]) > 0.0)


def test_bench_sync_bound_draws():
    """--bound-draws: the bound's own filter drawn again on one world's exchanges; its largest errors
    from 60 s on are those of an efficient estimator at the bound (about 0.5 ns RMS here: a few ns at most),
    and the share at most 2 ns comes with its binomial interval."""
    from larns.bench.sync import bound_draws

    bd = bound_draws(("seed000", "tcxo", 0.5, 10, 1, 70.0, {}, {}), 6, 1)
    assert bd["n"] == 6 and bd["world_seed"] == 1
    assert 0.3 < bd["median_ns"] < 3.0 and bd["median_ns"] <= bd["max_ns"] < 5.0
    ok = bd["trial_max_le_2ns"]
    assert 0.0 <= ok <= 1.0 and abs(bd["ci95"] - 1.96 * np.sqrt(ok * (1 - ok) / 6)) < 1e-12
