"""`larns report` and `larns info` for a navigation engineer (issue 34 item 6): strict JSON, topics in
natural order and grouped, the 60 s sync columns of a short run, and the report's navigation figures
(plan map with ellipses, horizontal / vertical errors against their own sigma, NEES with its band,
the CRLB on the convergence figure, one TDMA cycle) on the session's real fleet recording
(``fleet_run`` in tests/conftest.py: 5 station processes + the aircraft + a vehicle, 30 fleet s)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

PY = sys.executable


def strict_loads(s: str):
    """``json.loads`` that refuses ``NaN``, ``Infinity`` and ``-Infinity`` (RFC 8259)."""
    def refuse(c):
        raise ValueError(f"not JSON: {c}")

    return json.loads(s, parse_constant=refuse)


def larns(*args: str, timeout: float = 180) -> subprocess.CompletedProcess:
    r = subprocess.run([PY, "-m", "larns", *args], capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, r.stderr[-3000:]
    return r


@pytest.fixture(scope="module")
def rec(fleet_run) -> Path:
    assert fleet_run.rc == 0, fleet_run.log[-3000:]
    return fleet_run.rec


@pytest.fixture(scope="module")
def report(rec, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("report")
    larns("report", str(rec), "-o", str(out))
    return out


# --------------------------------------------------------------------------- strict JSON

def test_strict_parser_refuses_bare_nan():
    with pytest.raises(ValueError):
        strict_loads('{"a": NaN}')


def test_dumps_strict_writes_null_for_non_finite_numbers():
    from larns.analysis.summary import dumps_strict

    s = dumps_strict({1: np.float64("nan"), "a": np.array([1.5, np.inf, -np.inf]), "b": (np.int64(3), np.bool_(True)),
                      "c": float("nan"), "d": Path("x")})
    assert strict_loads(s) == {"1": None, "a": [1.5, None, None], "b": [3, True], "c": None, "d": "x"}


def test_report_json_and_info_json_are_strict(report, rec):
    res = strict_loads((report / "report.json").read_text())
    assert res["stations"]["1"]["inside_3sigma"] is None  # the origin: NaN before, null now
    s = strict_loads(larns("info", "--json", str(rec)).stdout)
    assert s["messages"] > 1000


# --------------------------------------------------------------------------- larns info

def test_topics_in_natural_order_and_grouped():
    from larns.analysis.summary import natural_key, topic_group
    from larns.commands.info import topic_lines

    keys = ["larns/station/10/nav", "larns/station/2/nav", "larns/station/1/nav", "larns/foxglove/station/10",
            "larns/foxglove/station/9", "larns/aircraft/ac1/truth", "larns/vehicle/veh1/estimate", "larns/alive/x"]
    assert sorted(keys[:3], key=natural_key) == ["larns/station/1/nav", "larns/station/2/nav", "larns/station/10/nav"]
    assert [topic_group(k) for k in keys] == ["stations"] * 3 + ["other"] * 2 + ["aircraft", "vehicle", "other"]
    t = {"count": 1, "rate_hz": 0.0, "encoding": "msgpack", "kinds": {"nav": 1}}
    lines = topic_lines({k: t for k in keys})
    names = [ln.split()[0] for ln in lines[1:]]
    assert names == ["stations:", "larns/station/1/nav", "larns/station/2/nav", "larns/station/10/nav",
                     "aircraft:", "larns/aircraft/ac1/truth", "vehicle:", "larns/vehicle/veh1/estimate",
                     "other:", "larns/alive/x", "larns/foxglove/station/9", "larns/foxglove/station/10"]
    assert lines[0].split()[:2] == ["Topics:", "8"]


def test_info_on_the_fleet_recording_groups_topics_and_says_the_run_is_short(rec):
    txt = larns("info", str(rec)).stdout
    assert "nan" not in txt.lower().split()
    lines = txt.splitlines()
    heads = [ln.strip() for ln in lines if ln.strip() in ("stations:", "aircraft:", "vehicle:", "other:")]
    assert heads == ["stations:", "aircraft:", "vehicle:", "other:"]
    i = lines.index("  stations:")
    j = lines.index("  aircraft:")
    st = [ln.split()[0] for ln in lines[i + 1:j]]
    assert st and all(k.startswith("larns/station/") for k in st)
    from larns.analysis.summary import natural_key

    assert st == sorted(st, key=natural_key)
    # 30 fleet s: every station row's 60 s columns say so
    rows = [ln for ln in lines if ln.split()[:1] and ln.split()[0] in {"1", "2", "3", "4", "5"}]
    assert len(rows) == 5 and all(ln.endswith("run shorter than 60 s") for ln in rows), rows


def test_sync_columns_print_numbers_after_60_s():
    from larns.commands.info import station_lines

    s = {"stations": {1: {"state": "frame", "sync_ns": 0.1, "sync_t_s": 90.0, "sync_rms_ns_after_60s": 0.5,
                          "sync_max_ns_after_60s": 1.25},
                      2: {"state": "surveying", "sync_ns": 0.2, "sync_t_s": 59.4},
                      3: {"state": "surveying", "sigma_m": math.nan}}}
    r1, r2, r3 = station_lines(s)[2:5]
    assert r1.split()[-2:] == ["0.50", "1.25"]
    assert r2.endswith("run shorter than 60 s")
    assert "nan" not in r3 and r3.split()[-2:] == ["-", "-"]


# --------------------------------------------------------------------------- the report's figures

FIGURES = ("station_map.png", "station_errors.png", "station_nees.png", "survey_convergence.png", "tdma_timeline.png",
           "network.png", "aircraft_errors.png", "aircraft_sigma.png", "aircraft_track.png", "vehicle_errors.png")


def test_report_writes_every_figure(report):
    res = strict_loads((report / "report.json").read_text())
    for f in FIGURES:
        assert (report / f).stat().st_size > 5000, f
        assert f in res["figures"], f
    md = (report / "report.md").read_text()
    assert all(f"]({f})" in md for f in FIGURES)


def test_report_numbers_hold_together(rec, report):
    from larns.log.series import load

    res = strict_loads((report / "report.json").read_text())
    c = res["convergence"]
    # the centralized CRLB for the ranges the navs list: positive and of the errors' order
    assert c["final_crlb_horizontal_rms_m"] > 0
    assert 0.2 < c["final_rms_over_crlb"] < 10, c
    # NEES on the coordinates each estimate carries (positive variance; in the founders' frame
    # station 2 has x, 3 has x y, 4 and 5 all three: 9 dof), summed over the surveying stations 2-5
    final_cov = {sid: np.asarray(s.track()["cov_m2"][-1]) for sid, s in load([rec]).stations.items()}
    carried = {sid: np.diag(P) > 0 for sid, P in final_cov.items()}
    ne = c["nees"]
    assert ne["dof"] == sum(int(carried[k].sum()) for k in (2, 3, 4, 5)) >= 9
    assert ne["probability"] == 0.95 and ne["band"][0] < 1 < ne["band"][1]
    # horizontal and vertical against their own sigma; no vertical where z is not carried
    st = res["stations"]
    for k in (2, 3, 4, 5):
        assert ("final_ev_m" in st[str(k)]) == bool(carried[k][2]), k
        assert st[str(k)]["final_sigma_h_m"] > 0
    for k in (4, 5):
        assert st[str(k)]["final_sigma_v_m"] > 0
    m = res["station_map"]
    assert m["sigma"] == 2 and abs(m["probability"] - 0.8647) < 1e-3 and m["magnification"] >= 1
    assert (m["stations"]["1"]["inside"] is None) == (not carried[1][:2].any())
    assert m["stations"]["4"]["semi_major_m"] > 0
    # every aircraft algorithm of the run
    assert set(res["aircraft_sigma"]["ac1"]) == {"ukf-pr", "ekf-tdoa", "lsq-pr"}
    assert set(res["aircraft_track"]["ac1"]) == {"ukf-pr", "ekf-tdoa", "lsq-pr"}


def test_tdma_cycle_on_network_time_puts_each_request_in_its_slot(rec, report):
    """The one-cycle plot places each request at its stamp less the station's clock error: each must
    fall inside the initiator's own slot (the raw stamps are on each station's own oscillator)."""
    from larns.log.series import load
    from larns.viz.report import _network_time, extract

    res = strict_loads((report / "report.json").read_text())
    t = res["tdma"]
    assert t["cycle_s"] == 0.25 and t["slot_s"] == 0.05 and t["slots_drawn"] == 5
    d = extract(load([rec]))
    c0 = t["cycle_shown"]
    shown = [r for r in d["reqs"] if r[4] == c0]
    assert len(shown) >= 4
    for stamp, src, _dst, _seq, _c in shown:
        x = _network_time(d, src, stamp) - c0 * t["cycle_s"]
        slot = d["slots"][src]
        assert slot * t["slot_s"] - 1e-6 <= x < (slot + 1) * t["slot_s"], (src, x)  # (requests go at the slot start)


# --------------------------------------------------------------------------- the pure parts

def test_ellipse_and_nees_of_known_covariances():
    from larns.analysis.consistency import ellipse, ellipse_probability, nees_band, nees_free

    ax, ang = ellipse(np.array([[4.0, 0.0], [0.0, 1.0]]), k=2.0)
    assert np.allclose(ax, [4.0, 2.0]) and abs(math.sin(ang)) < 1e-12
    ax, ang = ellipse(np.array([[1.0, 0.0], [0.0, 9.0]]), k=1.0)
    assert np.allclose(ax, [3.0, 1.0]) and abs(abs(ang) - math.pi / 2) < 1e-12
    assert abs(ellipse_probability(2.0) - (1 - math.exp(-2))) < 1e-15
    tr = {"t_s": np.array([0.0, 1.0]), "pos_m": np.array([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]]),
          "cov_m2": np.array([np.diag([1.0, 4.0, 9.0]), np.diag([1.0, 0.0, 1.0])])}
    q = nees_free(tr, np.zeros(3), np.array([True, True, True]))
    assert q[0] == pytest.approx(3.0) and math.isnan(q[1])  # a singular P: NaN
    q2 = nees_free(tr, np.zeros(3), np.array([True, False, False]))
    assert q2 == pytest.approx([1.0, 0.0])
    q3 = nees_free(tr, np.zeros(3))  # each estimate's own axes: the second carries x and z
    assert q3 == pytest.approx([3.0, 0.0])
    lo, hi = nees_band(np.array([3.0, 0.0]))
    assert lo[0] < 1 < hi[0] and math.isnan(lo[1])


def test_survey_crlb_curve_matches_the_bench_bound():
    """The report's CRLB is ``nav.crlb.survey_crlb`` (the bench's) of the counts up to each time."""
    from larns.analysis.consistency import crlb_horizontal_rms, range_events, survey_crlb_curve
    from nav.crlb import survey_crlb
    from nav.geometry import frame_free_mask

    X = np.array([[0, 0, 0], [1000, 0, 0], [400, 900, 0], [700, 300, 40], [200, 500, -30]], float)
    navs = {1: [{"ranges": [[2, 1000.0, 1.0], [3, 985.0, 2.0]]}],
            2: [{"ranges": [[4, 1.0, 1.5]]}, {"ranges": [[4, 1.0, 1.5]]}],  # a nav recorded twice
            4: [{"ranges": [[5, 1.0, 3.0], [1, 1.0, 3.5], [3, 1.0, 4.0]]}],
            5: [{"ranges": [[3, 1.0, 5.0], [2, 1.0, 5.5], [9, 1.0, 5.6]]}]}  # 9: not a station here
    ev = range_events(navs)
    assert len(ev) == 9 and np.all(np.diff(ev[:, 0]) >= 0)
    free = frame_free_mask(5)
    s0 = np.array([np.inf, 10.0, 10.0, 10.0, 10.0])
    grid = np.array([0.5, 3.0, 10.0])
    b = survey_crlb_curve([1, 2, 3, 4, 5], X, ev, grid, 0.5, free, s0)
    counts = np.zeros((5, 5))
    for _, i, j in ev:
        if j <= 5:
            counts[int(i) - 1, int(j) - 1] += 1
    assert np.allclose(b[2], survey_crlb(X, counts, 0.5, free, s0))
    assert np.allclose(b[0], survey_crlb(X, np.zeros((5, 5)), 0.5, free, s0))  # the prior alone
    h = crlb_horizontal_rms(b, [1, 2, 3, 4])
    assert h[0] > h[1] > h[2] > 0


def test_survey_crlb_curve_counts_the_polls_finals_as_the_bench_does():
    """With the poll the bound takes 4/3 of a range per exchange closed by its final
    (``nav.crlb.poll_exchange_counts``): the pollers' reply rows from their navs, the finals from the
    members' journals (a poller's nav whose final lists the member's reply as heard)."""
    from types import SimpleNamespace

    from larns.analysis.consistency import final_events, range_events, survey_crlb_curve
    from nav.crlb import poll_exchange_counts, survey_crlb
    from nav.geometry import frame_free_mask

    X = np.array([[0, 0, 0], [1000, 0, 0], [400, 900, 0], [700, 300, 40]], float)
    nav1 = {"kind": "nav", "src": 1, "ranges": [[2, 1000.0, 1.0], [3, 985.0, 1.0], [4, 760.0, 1.0]],
            "poll": {"seq": 0, "t1": 0.99, "rx": [[2, 0.991], [3, 0.992], [4, 0.993]]}}
    nav2 = {"kind": "nav", "src": 2, "ranges": [[1, 1000.0, 2.0], [3, 1.0, 2.0]],
            "poll": {"seq": 0, "t1": 1.99, "rx": [[1, 1.991], [3, 1.992]]}}  # station 4's reply not heard
    ev = range_events({1: [nav1], 2: [nav2]})
    journals = {2: SimpleNamespace(inputs={0: (None, [["m", 1.01, nav1], ["t", 1.5]])}),
                3: SimpleNamespace(inputs={0: (None, [["m", 1.01, nav1]]), 1: (None, [["m", 2.01, nav2]])}),
                4: SimpleNamespace(inputs={0: (None, [["m", 2.01, nav2]])}),  # heard, but not in nav2's rx
                1: SimpleNamespace(inputs={})}  # station 1 missed station 2's final
    fin = final_events(journals)
    assert fin.tolist() == [[1.01, 2, 1], [1.01, 3, 1], [2.01, 3, 2]]
    free, s0 = frame_free_mask(4), np.array([np.inf, 10.0, 10.0, 10.0])
    b = survey_crlb_curve([1, 2, 3, 4], X, ev, np.array([1.5, 3.0]), 0.5, free, s0, fin)
    replies, finals = np.zeros((4, 4)), np.zeros((4, 4))
    for _, i, j in ev:
        replies[int(i) - 1, int(j) - 1] += 1
    for _, m, p in fin:
        finals[int(m) - 1, int(p) - 1] += 1
    assert np.allclose(b[1], survey_crlb(X, poll_exchange_counts(replies, finals), 0.5, free, s0))
    early = np.zeros((4, 4))
    early[0, 1:] = 1
    early[1, 0] = early[2, 0] = 1 / 3
    assert np.allclose(b[0], survey_crlb(X, early, 0.5, free, s0))
    assert np.trace(b[1][1]) < np.trace(survey_crlb_curve([1, 2, 3, 4], X, ev, np.array([3.0]), 0.5, free, s0)[0][1])


def test_network_figure_keeps_negative_latencies(tmp_path):
    """Latency stamps are on the sender's emulated clock: negative values are drawn and counted, not
    clamped to a floor."""
    from larns.viz.report import fig_network

    info = {"loss": {"range_req": {"loss_pct": 0.0}, "nav": {"loss_pct": 1.0}}}
    out = fig_network(info, {"latency_ms": {"range_req": [-1.2, -0.01, 0.5, 3.0], "nav": [2.0, 40.0]}},
                      tmp_path / "network.png")
    assert out == {"negative_latency": {"nav": 0, "range_req": 2}}
    assert (tmp_path / "network.png").stat().st_size > 5000


def test_aircraft_line_of_a_run_shorter_than_30_s():
    from larns.commands.info import aircraft_line

    r = {"n": 53, "first_t_s": 16.7, "t_10m_s": 18.5, "t_3m_s": None, "final_eh_m": 1.96, "final_sigma_h_m": 1.74,
         "statuses": {"tracking": 14}}
    line = aircraft_line("ac1", "ekf-tdoa", r)
    assert "nan" not in line and "run shorter than 30 s" in line
    line = aircraft_line("ac1", "ekf-tdoa", {**r, "max_eh_window_m": 1.5, "nees_mean": 2.25})
    assert "max from 30 s 1.50 m, NEES 2.25" in line
