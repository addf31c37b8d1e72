"""Replay, offline re-estimation, info, report, recover and export on real recordings.

They read the session's shared fleet run (``fleet_run`` in tests/conftest.py: 5 station processes +
the aircraft + the vehicle + the fleet's recorder, over real Zenoh on loopback). A second recorder
(our own process) records the same run and is SIGKILLed before the end: its file has no
summary/footer and ends wherever the kill hit.
"""

from __future__ import annotations

import json
import math
import re
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from net import messages as M
from fleet_recording import ALGOS
from net.bus import free_tcp_ports

pytestmark = pytest.mark.e2e

PY = sys.executable


def larns(*args: str, timeout: float = 120, check: bool = True) -> subprocess.CompletedProcess:
    r = subprocess.run([PY, "-m", "larns", *args], capture_output=True, text=True, timeout=timeout)
    if check:
        assert r.returncode == 0, (args, r.stdout[-2000:], r.stderr[-3000:])
    return r


@pytest.fixture(scope="module")
def run(fleet_run):
    """(scenario path, clean recording, SIGKILLed recording) of the shared recorded fleet
    (tests/conftest.py ``fleet_run``)."""
    assert fleet_run.rc == 0, fleet_run.log[-3000:]
    return fleet_run.scn, fleet_run.rec, fleet_run.killed


# --------------------------------------------------------------------------- info

def test_info_counts_match_the_file(run):
    from mcap.reader import make_reader

    _, rec, _ = run
    s = json.loads(larns("info", str(rec), "--json").stdout)
    assert s["files"][0]["complete"]
    with open(rec, "rb") as f:
        summ = make_reader(f).get_summary()
    by_topic = {summ.channels[c].topic: n for c, n in summ.statistics.channel_message_counts.items()}
    # stream-read counts equal the indexed summary of the same file (an independent reader)
    assert {t: v["count"] for t, v in s["topics"].items()} == by_topic
    assert s["messages"] == summ.statistics.message_count
    assert sorted(map(int, s["stations"])) == [1, 2, 3, 4, 5]
    assert "ac1" in s["aircraft"] and s["aircraft"]["ac1"]["algos"] == sorted(ALGOS)
    assert all(v.get("journal") for v in s["stations"].values())
    for kind in ("nav", "estimate", "truth", "range_req", "range_rsp", "core_input", "ac_estimate"):
        assert s["loss"][kind]["received"] > 0, kind
    # the journal is sent with congestion control BLOCK: no holes
    assert s["loss"]["core_input"]["missing"] == 0
    assert 0.0 < s["duration_s"] < 60.0


PUBLISHER = textwrap.dedent("""
    import sys, time
    from net.bus import Bus
    from net import messages as M
    b = Bus(listen=[sys.argv[1]], connect=[sys.argv[2]])
    t0 = time.time()
    while not b.alive("larns/alive/recorder/*", 0.5) and time.time() - t0 < 20:
        time.sleep(0.1)
    time.sleep(0.5)
    for i in range(1, 61):
        if i in (10, 11, 40):      # never sent: the recorder must see 3 gaps
            continue
        m = {"kind": "truth", "src": 7, "seq": i, "stamp_s": 0.1 * i, "t_s": 0.1 * i, "pos_m": [1.0, 2.0, 3.0]}
        b.publish(M.key_for(m), M.encode(m))
        if i % 20 == 0:
            b.publish("larns/station/7/nav", b"not msgpack")
        time.sleep(0.01)
    time.sleep(0.5)
    b.close()
""")


def test_info_counts_match_what_was_published(tmp_path):
    out = tmp_path / "pub.mcap"
    p_rec, p_pub = free_tcp_ports(2)
    rec = subprocess.Popen([PY, "-m", "larns", "record", "-o", str(out), "-q", "--listen", f"tcp/127.0.0.1:{p_rec}"])
    try:
        pub = subprocess.run([PY, "-c", PUBLISHER, f"tcp/127.0.0.1:{p_pub}", f"tcp/127.0.0.1:{p_rec}"], timeout=60)
        assert pub.returncode == 0
    finally:
        rec.send_signal(signal.SIGINT)
        assert rec.wait(timeout=20) == 0
    s = json.loads(larns("info", str(out), "--json").stdout)
    assert s["topics"]["larns/station/7/truth"]["count"] == 57
    assert s["topics"]["larns/station/7/nav"]["count"] == 2  # i = 20, 60 (40 skipped)
    assert s["invalid"] == {"msgpack": 2}
    assert s["loss"]["truth"] == {"senders": 1, "received": 57, "missing": 3, "duplicates": 0, "reordered": 0,
                                  "leading": 0, "loss_pct": pytest.approx(5.0)}
    txt = larns("info", str(out)).stdout
    assert "larns/station/7/truth" in txt and "complete" in txt


# --------------------------------------------------------------------------- offline

def _estimates(path: Path) -> dict[int, dict[int, dict]]:
    from larns.log import read_log
    from larns.log.series import decode_all

    out: dict[int, dict[int, dict]] = {}
    for _m, msg in decode_all(read_log(path).messages):
        if msg is not None and msg["kind"] == "estimate":
            out.setdefault(msg["src"], {})[msg["seq"]] = msg
    return out


def test_offline_reestimation_is_bit_exact(run, tmp_path):
    _, rec, _ = run
    out = tmp_path / "offline.mcap"
    r = larns("replay", str(rec), "--offline", "--check", "-o", str(out), "--json", "-q")
    res = json.loads(r.stdout.strip().splitlines()[-1])
    assert sorted(map(int, res["stations"])) == [1, 2, 3, 4, 5]
    recorded = _estimates(rec)
    for sid, st in res["stations"].items():
        sid = int(sid)
        assert st["error"] is None and st["missing_from"] is None, st
        assert st["bit_exact"] and st["compared"] == len(recorded[sid]) > 10, st
    # the written file holds the re-estimated estimates: identical core fields, every recorded one present
    replayed = _estimates(out)
    for sid, rec_est in recorded.items():
        for seq, m in rec_est.items():
            o = replayed[sid][seq]
            for k in ("t_s", "pos_m", "cov_m2", "n_updates", "estimator", "state"):
                assert o[k] == m[k], (sid, seq, k)
    # another survey estimator on the same inputs: same number of estimates, different values
    ukf = tmp_path / "ukf.mcap"
    r2 = larns("replay", str(rec), "--offline", "--estimator", "seed-ukf", "--json", "-q", "-o", str(ukf))
    res2 = json.loads(r2.stdout.strip().splitlines()[-1])
    for sid, st in res2["stations"].items():
        assert st["estimator"] == "seed-ukf" and st["estimates"] == res["stations"][sid]["estimates"]
    assert not all(st["bit_exact"] for sid, st in res2["stations"].items() if sid not in ("1", 1))
    # the written file: estimates and the regenerated Foxglove view come from the other estimator
    est2 = _estimates(ukf)
    assert all(m["estimator"] == "seed-ukf" for per in est2.values() for m in per.values())
    view = [json.loads(d) for _, _, d in _json_channels(ukf)["larns/foxglove/station/3"]]
    assert view and all(v["estimator"] == "seed-ukf" for v in view)


def _offline_json(*args: str, check: bool = True) -> tuple[dict, subprocess.CompletedProcess]:
    r = larns("reestimate", *args, "--json", check=check)  # the table, then the JSON line
    return json.loads(r.stdout.strip().splitlines()[-1]), r


def test_offline_aircraft_reflown_bit_for_bit_and_other_algorithms(run, tmp_path):
    """The aircraft's journal re-flies every recorded estimate of every recorded algorithm bit for bit
    (no scenario, no seeds); another algorithm runs on the same measurements and both accuracies are
    printed; ``--check`` covers the aircraft and the vehicle."""
    _, rec, _ = run
    out = tmp_path / "ac.mcap"
    res, r = _offline_json(str(rec), "--check", "--algo", "ekf-pr", "--algo", "ukf-tdoa", "-o", str(out))
    ac = res["aircraft"]["ac1"]
    assert set(ac) == set(ALGOS) | {"ekf-pr", "ukf-tdoa"}
    recorded = _ac_estimates(rec)
    for algo in ALGOS:
        d = ac[algo]
        assert d["error"] is None and d["missing_from"] is None and d["stopped"] is None, d
        # 100 %: every recorded estimate re-flown, every field identical
        assert d["recorded"] == len(recorded[algo]) > 0 and d["compared"] == d["recorded"], d
        assert d["equal"] == d["compared"] and d["bit_exact"], d
        # the same estimates (the re-flight may hold a last one the recorder missed) and their accuracy
        assert d["rerun"]["samples"] >= d["recorded_accuracy"]["samples"] > 0, d
        assert math.isfinite(d["rerun"]["rms_err_m"]) and math.isfinite(d["recorded_accuracy"]["rms_err_m"]), d
    assert sum(ac[a]["compared"] for a in ALGOS) > 50
    for algo in ("ekf-pr", "ukf-tdoa"):  # not recorded: accuracy only, beside the recorded filters'
        d = ac[algo]
        assert d["error"] is None and d["recorded"] == 0 and d["compared"] == 0 and d["n"] > 0, d
        assert d["rerun"]["samples"] > 0 and math.isfinite(d["rerun"]["rms_err_m"]), d
        assert 0.0 < d["rerun"]["mean_sigma_m"] < 1e4 and d["invalid"] == 0, d
    assert res["vehicles"]["veh1"]["bit_exact"], res["vehicles"]
    txt = r.stdout
    assert re.search(r"aircraft ac1 ukf-pr: \d+ estimates re-flown from \d+ journal inputs; vs the (\d+) recorded: "
                     r"\1/\1 identical; accuracy \(second half\) re-run [\d.]+/[\d.]+, recorded [\d.]+/[\d.]+", txt), txt
    assert re.search(r"aircraft ac1 ekf-pr: \d+ estimates re-flown .*re-run [\d.]+/[\d.]+, recorded -", txt), txt
    # the written recording holds the re-flown estimates: the recorded ones identical, the others new
    est = _ac_estimates(out)
    for algo in ALGOS:
        by_seq = {m["seq"]: m for m in est[algo]}
        assert len(by_seq) == ac[algo]["n"] and all(by_seq[m["seq"]] == m for m in recorded[algo]), algo
    assert len(est["ekf-pr"]) == ac["ekf-pr"]["n"] and len(est["ukf-tdoa"]) == ac["ukf-tdoa"]["n"]
    # a station survey estimator other than the recorded one: accuracy beside the recorded, no mismatch
    res2, r2 = _offline_json(str(rec), "--estimator", "seed-ukf", "--check")
    for sid, st in res2["stations"].items():
        assert not st["same_estimator"] and st["rerun"]["samples"] > 3 and st["recorded_accuracy"]["samples"] > 3, st
    txt2 = r2.stdout
    assert "first mismatch" not in txt2 and "recorded: dmap" in txt2, txt2


def test_offline_aircraft_up_to_a_deliberate_hole_and_check_fails_on_a_mismatch(run, tmp_path):
    """One aircraft journal message removed: the re-flight is exact up to it and says where it
    stopped; one recorded estimate altered: ``--check`` exits 3 and names it."""
    _, rec, _ = run
    from larns.log import LogWriter, read_log

    lg = read_log(rec)
    inputs = [m for m in lg.messages if m.topic == "larns/aircraft/ac1/input"]
    assert len(inputs) >= 3
    hole = len(inputs) // 2
    gap = tmp_path / "gap.mcap"
    with LogWriter(gap, lg.metadata) as w:
        for m in lg.messages:
            if m.topic == "larns/aircraft/ac1/input" and M.decode(m.data)[0]["seq"] == hole:
                continue
            w.write(m.topic, m.data, m.log_time, m.publish_time)
    res, rg = _offline_json(str(gap), "--check")  # exact as far as it went: --check passes
    t_hole = M.decode(inputs[hole - 1].data)[0]["stamp_s"]
    for algo in ALGOS:
        d = res["aircraft"]["ac1"][algo]
        assert d["missing_from"] == hole and d["inputs"] == hole - 1, d
        assert d["compared"] <= d["recorded"] and d["equal"] == d["compared"], d
        assert d["stopped_at_s"] is not None and d["stopped_at_s"] <= t_hole, (d, t_hole)
    per = res["aircraft"]["ac1"]
    assert 0 < sum(per[a]["compared"] for a in ALGOS) < sum(per[a]["recorded"] for a in ALGOS), per
    txt = rg.stdout
    assert f"journal hole at input {hole}: stopped there (t = " in txt, txt
    # one recorded estimate altered by a millimetre: not bit for bit, --check fails and says which
    bad = tmp_path / "bad.mcap"
    altered = None
    with LogWriter(bad, lg.metadata) as w:
        for m in lg.messages:
            data = m.data
            if altered is None and m.topic == f"larns/aircraft/ac1/estimate/{ALGOS[0]}":
                msg = M.decode(data)[0]
                if msg["seq"] > 10:
                    msg["pos_m"] = [msg["pos_m"][0] + 1e-3] + msg["pos_m"][1:]
                    data, altered = M.encode(msg), msg["seq"]
            w.write(m.topic, data, m.log_time, m.publish_time)
    res3, r3 = _offline_json(str(bad), "--check", check=False)
    assert r3.returncode == 3, r3.stderr[-2000:]
    d = res3["aircraft"]["ac1"][ALGOS[0]]
    assert d["equal"] == d["compared"] - 1, d
    assert f"aircraft ac1 {ALGOS[0]}: {d['equal']}/{d['compared']} identical" in r3.stderr


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["ins-ekf", "triad"])
def test_inertial_aircraft_live_run_reflown_bit_for_bit(algo, tmp_path):
    """A short live fleet (seed003-text over Zenoh, the recorder) with the inertial or the triad
    aircraft: ``larns reestimate --check`` re-flies 100 % of its recorded estimates bit for bit
    (~40-70 s each)."""
    src = (Path(__file__).parents[2] / "net" / "scenarios" / "seed003-text.toml").read_text()
    if algo == "triad":
        src = re.sub(r'^algos = \["ins-ekf"\].*$', 'algos = ["triad"]\nsatellites = 2', src, flags=re.M)
        src = re.sub(r"^imu = .*\n", "", src, flags=re.M)
    scn = tmp_path / f"{algo}.toml"
    scn.write_text(src)
    rec = tmp_path / "run.mcap"
    # the INS starts from the broadcasts alone at ~35 s (docs/ins.md), the triad after its 10 s window
    dur = "50" if algo == "ins-ekf" else "25"
    r = larns("fleet", "--scenario", str(scn), "--duration", dur, "--aircraft", "--record", str(rec), "--no-table",
              timeout=300)
    res, _ = _offline_json(str(rec), "--check")
    d = res["aircraft"]["ac1"][algo]
    assert d["error"] is None and d["missing_from"] is None and d["stopped"] is None, d
    assert d["recorded"] == d["compared"] == d["equal"] > 10, (d, r.stderr[-2000:])


def _ac_estimates(path: Path) -> dict[str, list[dict]]:
    from larns.log import read_log

    out: dict[str, list[dict]] = {}
    for m in read_log(path).messages:
        if m.encoding == "msgpack" and m.topic.startswith("larns/aircraft/ac1/estimate/"):
            msg = M.decode(m.data)[0]
            out.setdefault(msg["algo"], []).append(msg)
    return {a: sorted(v, key=lambda x: x["seq"]) for a, v in out.items()}


# --------------------------------------------------------------------------- live replay

def test_replay_into_a_live_aircraft(run, tmp_path):
    scn, rec, _ = run
    p_ac, p_rp = free_tcp_ports(2)
    ac = subprocess.Popen([PY, "-m", "larns", "aircraft", "--scenario", str(scn), "--algo", "ekf-pr",
                           # --duration bounds the aircraft's precomputed track (horizon), see the report
                           "--epoch", repr(time.time()), "--duration", "120", "--report-json", "-q",
                           "--listen", f"tcp/127.0.0.1:{p_ac}"],
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        r = larns("replay", str(rec), "--topics", "larns/station/*/nav/**", "--rate", "2", "--delay", "0.5",
                  "--wait-for", "larns/alive/aircraft/*", "--json", "-q",
                  "--listen", f"tcp/127.0.0.1:{p_rp}", "--connect", f"tcp/127.0.0.1:{p_ac}")
    finally:
        time.sleep(0.5)
        ac.send_signal(signal.SIGINT)
        out, err = ac.communicate(timeout=30)
    assert ac.returncode == 0, err[-2000:]
    st = json.loads(r.stdout.strip().splitlines()[-1])
    n_nav = sum(1 for m in _wire(rec) if M.is_nav_key(m.topic))
    assert st["published"] == n_nav
    rep = json.loads(out.strip().splitlines()[-1])
    # the aircraft measured (nearly) every replayed broadcast and its EKF converged on them
    assert rep["measurements"] >= 0.9 * n_nav, (rep, n_nav)
    assert rep["estimates"]["ekf-pr"]["n_updates"] > 20
    assert rep["estimates"]["ekf-pr"]["err_m"] < 50.0, rep


def _wire(path: Path):
    from larns.log import read_log

    return [m for m in read_log(path).messages if m.encoding == "msgpack"]


# --------------------------------------------------------------------------- crash safety

def test_killed_recording_info_report_replay_recover(run, tmp_path):
    from mcap.reader import make_reader

    from larns.log import read_log

    _, _, killed = run
    lg = read_log(killed)
    assert not lg.complete and lg.error  # no footer: SIGKILL
    assert len(lg.messages) > 200
    with open(killed, "rb") as f:  # the indexed reader alone cannot open it
        with pytest.raises(Exception):
            make_reader(f).get_summary()
            list(make_reader(f).iter_messages())
    s = json.loads(larns("info", str(killed), "--json").stdout)
    assert not s["files"][0]["complete"] and s["messages"] == len(lg.messages)
    rep = tmp_path / "report"
    larns("report", str(killed), "-o", str(rep))
    for f in ("station_errors.png", "survey_convergence.png", "survey_histograms.png", "tdma_timeline.png",
              "network.png", "aircraft_errors.png", "report.md", "report.json"):
        assert (rep / f).stat().st_size > 1000, f
    md = (rep / "report.md").read_text()
    assert "INCOMPLETE" in md and "station_errors.png" in md
    res = json.loads((rep / "report.json").read_text())
    assert set(map(int, res["stations"])) == {1, 2, 3, 4, 5}
    # live replay of what is there (a short window, fast)
    (port,) = free_tcp_ports(1)
    st = json.loads(larns("replay", str(killed), "--until", "1.0", "--rate", "5", "--delay", "0", "--json", "-q",
                          "--listen", f"tcp/127.0.0.1:{port}").stdout.strip().splitlines()[-1])
    t0 = min(m.log_time for m in lg.messages)
    assert st["published"] == sum(1 for m in lg.messages if m.encoding == "msgpack" and m.log_time <= t0 + 1e9)
    # offline replay of what is there: still bit exact up to the damage
    r = json.loads(larns("replay", str(killed), "--offline", "--json", "-q").stdout.strip().splitlines()[-1])
    assert all(st["bit_exact"] for st in r["stations"].values()), r
    # recover: a clean indexed file with exactly the readable messages
    fixed = tmp_path / "fixed.mcap"
    larns("recover", str(killed), "-o", str(fixed))
    with open(fixed, "rb") as f:
        rd = make_reader(f)
        summ = rd.get_summary()
        assert summ is not None and summ.statistics.message_count == len(lg.messages)
        got = [(ch.topic, m.log_time, m.data) for _s, ch, m in rd.iter_messages(log_time_order=True)]
    want = [(m.topic, m.log_time, m.data) for m in lg.messages]
    assert sorted(got) == sorted(want)
    assert read_log(fixed).complete


# --------------------------------------------------------------------------- Foxglove

def _json_channels(path: Path) -> dict[str, list]:
    from larns.log import read_log

    lg = read_log(path)
    schemas = {name: json.loads(data) for name, enc, data in lg.schemas.values() if enc == "jsonschema"}
    out: dict[str, list] = {}
    for m in lg.messages:
        if m.encoding == "json":
            out.setdefault(m.topic, []).append((m.schema, schemas[m.schema], m.data))
    return out


def _no_nan(s: str):
    raise ValueError(f"non-finite number {s} in JSON")


def test_foxglove_channels_from_recorder_and_export(run, tmp_path):
    import jsonschema

    _, rec, _ = run
    got = _json_channels(rec)  # written live by the recorder
    assert {"larns/foxglove/tf", "larns/foxglove/scene", "larns/foxglove/aircraft/ac1/ukf-pr"} <= set(got)
    assert {f"larns/foxglove/station/{i}" for i in range(1, 6)} <= set(got)
    names = set()
    validators: dict[str, jsonschema.Draft7Validator] = {}
    for topic, rows in got.items():
        for name, schema, data in rows:
            names.add(name)
            if name not in validators:
                jsonschema.Draft7Validator.check_schema(schema)
                validators[name] = jsonschema.Draft7Validator(schema)
            doc = json.loads(data, parse_constant=_no_nan)  # rejects NaN / Infinity
            validators[name].validate(doc)
    assert {"foxglove.FrameTransform", "foxglove.SceneUpdate", "larns.StationEstimate",
            "larns.AircraftEstimate"} <= names
    # errors are plottable numbers: the survey converges (station 2's last error below its first, or
    # below sigma_d = 0.5 m where its first record already came after convergence: station 2 has
    # one free coordinate and may converge before the recorder's first sample) and is consistent
    st2 = [json.loads(d) for _, _, d in got["larns/foxglove/station/2"]]
    assert all("err_m" in r for r in st2[1:])
    assert st2[-1]["err_m"] < max(st2[0]["err_m"], 0.5) and st2[-1]["err_m"] < 3 * st2[-1]["sigma_m"] + 0.5
    # an old log without the view: export adds the same channels
    bare = tmp_path / "bare.mcap"
    from larns.log import LogWriter, read_log

    lg = read_log(rec)
    with LogWriter(bare, lg.metadata) as w:
        for m in lg.messages:
            if m.encoding == "msgpack":
                w.write(m.topic, m.data, m.log_time, m.publish_time)
    out = tmp_path / "fox.mcap"
    larns("export", str(bare), "-o", str(out))
    exp = _json_channels(out)
    assert {t: len(v) for t, v in exp.items()} == {t: len(v) for t, v in got.items()}
    layout = json.loads((Path(__file__).parents[2] / "docs" / "foxglove-layout.json").read_text())
    text = json.dumps(layout)
    assert "larns/foxglove/scene" in text and "larns/foxglove/station/" in text


def test_start_paused_keyboard_on_a_terminal(run):
    """--start-paused with a terminal on stdin: nothing plays until a key; 's' steps one message, 'q' quits."""
    import os
    import pty

    _, rec, _ = run
    master, slave = pty.openpty()
    (port,) = free_tcp_ports(1)
    p = subprocess.Popen([PY, "-m", "larns", "replay", str(rec), "--start-paused", "--delay", "0", "--json",
                          "--listen", f"tcp/127.0.0.1:{port}"],
                         stdin=slave, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    os.close(slave)
    import threading

    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(p.stderr.readline, "")), daemon=True)
    reader.start()
    try:
        t0 = time.time()  # ready: it says it is paused (after loading the log and opening the bus)
        while not any("[replay] paused" in ln for ln in lines) and p.poll() is None and time.time() - t0 < 30:
            time.sleep(0.1)
        time.sleep(1.5)  # paused: at rate 1 the 6 s log would have published a quarter of its messages
        assert p.poll() is None
        os.write(master, b"s")
        time.sleep(0.3)
        os.write(master, b"s")
        time.sleep(0.3)
        os.write(master, b"q")
        out = p.stdout.read()
        p.wait(timeout=30)
        reader.join(10)
        err = "".join(lines)
    finally:
        os.close(master)
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0, err[-2000:]
    st = json.loads(out.strip().splitlines()[-1])
    assert st["published"] == 2, (st, err[-1000:])
    assert "paused" in err
