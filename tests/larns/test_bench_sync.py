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
