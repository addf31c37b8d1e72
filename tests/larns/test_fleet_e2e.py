"""End-to-end: real station processes over real Zenoh on loopback, recorder, MCAP read back.

The scenarios here are seed000's world (2 km x 2 km, 0.5 m ranging noise, 10 m coarse fix) with
fewer stations and wider TDMA slots (50 ms in a 0.5 s cycle), so that at ``--speed 5`` a slot
still lasts 10 ms of wall time: long enough for a Zenoh round trip on a loaded 2-core CI box.
Errors are computed from the MCAP file alone (estimate + truth topics) and compared with the
in-process simulator on the same scenario (the "accuracy class").
"""

from __future__ import annotations

import json
import math
import multiprocessing
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from larns.analysis.summary import mcap_station_summary
from net.bus import free_tcp_ports
from scenario_text import random_world

pytestmark = pytest.mark.e2e

SPEED = 5.0
PY = sys.executable


@pytest.fixture
def spawn(tmp_path):
    """``spawn(cmd, **popen_kw)`` -> Popen; whatever is still running at teardown is killed
    (a failing test never leaves stations or recorders behind)."""
    procs: list[subprocess.Popen] = []

    def _spawn(cmd, **kw):
        p = subprocess.Popen(cmd, **kw)
        procs.append(p)
        return p

    yield _spawn
    for p in procs:
        if p.poll() is None:
            p.kill()
            p.wait(10)
    # children of a killed `larns fleet` run in their own sessions: reap this test's stations
    # (their command line names a scenario file in this test's tmp_path)
    for pids in station_pids(str(tmp_path)).values():
        for pid in pids:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def write_scenario(tmp_path: Path, n: int, join_ids: list[int] | None = None, name: str = "e2e") -> Path:
    p = tmp_path / f"{name}.toml"
    p.write_text(random_world(name, n, join_ids or []))
    return p


def sim_stats(path: Path, t_s: float, ids: list[int], seeds: int = 4,
              stop_s: dict | None = None, start_s: dict | None = None) -> tuple[float, np.ndarray]:
    """In-process simulator on the same scenario over a few world seeds: (mean RMS final error of
    ``ids``, mean final sigma per station (root of the covariance trace))."""
    from net.scenario import load
    from stations.sim import Simulator

    scn = load(path)
    k = [scn.ids.index(i) for i in ids]
    rms, sig = [], []
    for seed in range(seeds):
        r = Simulator(scn, seed=seed, start_s=start_s, stop_s=stop_s).run(t_s, [t_s])
        e = np.linalg.norm(r.pos_m[-1, k] - r.truth_m[k], axis=-1)
        rms.append(np.sqrt(np.mean(e**2)))
        sig.append(np.sqrt(np.trace(r.cov_m2[-1, k], axis1=-2, axis2=-1)))
    return float(np.mean(rms)), np.mean(sig, axis=0)


class Background:
    """``fn(*args, **kw)`` in a forked process at the lowest CPU priority (nice 19), started while a
    fleet runs in real time: the reference simulation uses the idle CPU instead of adding its own
    seconds to the test, and the fleet's processes keep the CPU they need. ``get()`` the result."""

    def __init__(self, fn, *args, **kw):
        self._pool = multiprocessing.get_context("fork").Pool(1, initializer=os.nice, initargs=(19,))
        self._res = self._pool.apply_async(fn, args, kw)
        self._pool.close()

    def get(self, timeout: float = 300.0):
        try:
            return self._res.get(timeout)
        finally:
            self.close()

    def close(self) -> None:
        self._pool.terminate()
        self._pool.join()


def count_messages(path: Path) -> int:
    """Messages readable from a (possibly truncated, SIGKILLed) MCAP file by streaming."""
    from mcap.records import Message
    from mcap.stream_reader import StreamReader

    n = 0
    try:
        with open(path, "rb") as f:
            for rec in StreamReader(f).records:
                n += isinstance(rec, Message)
    except Exception:  # missing file or truncated tail
        pass
    return n


def station_pids(tag: str) -> dict[int, list[int]]:
    """Station processes whose command line mentions ``tag`` (the scenario path): id -> pids."""
    out = subprocess.run(["ps", "-ww", "-eo", "pid=,args="], capture_output=True, text=True).stdout
    ids: dict[int, list[int]] = {}
    for line in out.splitlines():
        pid, _, args = line.strip().partition(" ")
        a = args.split()
        if "stations" in a and "-m" in a and tag in args and "--id" in a:
            ids.setdefault(int(a[a.index("--id") + 1]), []).append(int(pid))
    return ids


def assert_accuracy_class(summary: dict, ids: list[int], sim: tuple[float, np.ndarray]) -> float:
    """Same accuracy class as the simulator: as much information (sigma within 2x the simulator's),
    consistent with it (each error within 4 sigma), and an RMS error of the same order."""
    ref_rms, ref_sig = sim
    errs = np.array([summary[i]["err_m"] for i in ids])
    sig = np.array([summary[i]["sigma_m"] for i in ids])
    rms = float(np.sqrt(np.mean(errs**2)))
    assert np.all(sig <= 2.0 * ref_sig + 0.2), (sig, ref_sig)
    assert np.all(errs <= 4.0 * sig + 0.5), (errs, sig)
    assert rms <= 3.0 * ref_rms + 2.0, (rms, ref_rms, errs)
    return rms


@pytest.fixture(scope="module")
def fleet7(tmp_path_factory):
    """One `larns fleet` run shared by the two tests below: six stations from the start and a
    seventh (marked ``join`` in the scenario) hot-joining at 20 fleet s, 60 fleet s at speed 5,
    recorded, with the JSON report. Yields what the tests read; stations left over are killed."""
    d = tmp_path_factory.mktemp("fleet7")
    scn = write_scenario(d, 7, join_ids=[7])
    out, js = d / "run.mcap", d / "fleet.json"
    dur, t_join = 60.0, 20.0
    # reference: the simulator with the joiner starting at the same fleet time (while the fleet runs)
    sim = Background(sim_stats, scn, dur, [2, 3, 4, 5, 6], start_s={7: t_join})
    fleet = subprocess.Popen([PY, "-m", "larns", "fleet", "--scenario", str(scn), "--duration", str(dur),
                              "--speed", str(SPEED), "--record", str(out), "--no-table", "--json", str(js),
                              "--join-time", str(t_join)],
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        # ps shows one process per station (the joiner's from its join time on)
        seen: dict[int, list[int]] = {}
        t0 = time.time()
        while time.time() - t0 < 40 and len(seen) < 7 and fleet.poll() is None:
            seen = station_pids(str(scn))
            time.sleep(0.5)
        log, _ = fleet.communicate(timeout=120)
        left = station_pids(str(scn))
        yield {"scn": scn, "out": out, "js": js, "dur": dur, "t_join": t_join, "seen": seen, "log": log,
               "rc": fleet.returncode, "left": left, "sim": sim.get()}
    finally:
        sim.close()
        if fleet.poll() is None:
            fleet.kill()
            fleet.wait(10)
        for pids in station_pids(str(scn)).values():
            for pid in pids:
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass


def test_fleet_six_stations_converge_from_mcap(fleet7):
    f = fleet7
    assert sorted(f["seen"]) == [1, 2, 3, 4, 5, 6, 7] and all(len(p) == 1 for p in f["seen"].values()), f["seen"]
    assert f["rc"] == 0, f["log"]
    rep = json.loads(f["js"].read_text())
    assert all(v == 0 for v in rep["exit_codes"].values()), rep["exit_codes"]
    assert f["left"] == {}

    summary = mcap_station_summary(f["out"])
    assert sorted(summary) == [1, 2, 3, 4, 5, 6, 7]
    for sid, s in summary.items():
        if sid not in (1, 7):  # station 1 is the fixed origin: nothing to update
            assert s["n_updates"][-1] >= 30, (sid, s["n_updates"][-1])   # >= 1 range per cycle, 120 cycles
        if sid != 7:
            assert len(s["t_s"]) >= 60  # one estimate per cycle, published while running
        assert np.all(np.diff(s["n_updates"]) >= 0)
    sim = f["sim"]  # the simulator with the joiner starting at the same fleet time
    rms = assert_accuracy_class(summary, [2, 3, 4, 5, 6], sim)
    print(f"networked RMS {rms:.2f} m vs simulator {sim[0]:.2f} m")
    # every kind of traffic is in the file
    from mcap.reader import make_reader

    from net import messages as M
    with open(f["out"], "rb") as fh:
        topics = {c.topic for c in make_reader(fh).get_summary().channels.values()}
    for sid in range(1, 8):
        assert {f"larns/station/{sid}/estimate", f"larns/station/{sid}/truth"} <= topics
        assert any(M.is_nav_key(t) and t.startswith(f"larns/station/{sid}/nav/") for t in topics)  # with its tile
    assert any("/range/req/" in t for t in topics) and any("/range/rsp/" in t for t in topics)


def test_hot_join_converges_without_disturbing(fleet7):
    f = fleet7
    assert f["rc"] == 0, f["log"]
    t_join = f["t_join"]
    summary = mcap_station_summary(f["out"])
    assert sorted(summary) == [1, 2, 3, 4, 5, 6, 7]
    j = summary[7]
    # the joiner's first estimate comes after the join time (fleet clock, epoch from the file)
    from larns.log.series import load

    rec = load([f["out"]])
    navs7 = [ns for ns, _ in rec.stations[7].nav]
    members_with_7 = sum(1 for sid, st in rec.stations.items() if sid != 7 for _, n in st.nav if 7 in n["members"])
    fleet_t, speed = rec.timebase.fleet_s, rec.timebase.speed
    assert fleet_t(j["log_time_ns"][0]) >= t_join - 0.1
    assert navs7 and members_with_7 > 0          # it took a slot and others added it to their rotation
    assert j["state"] == "surveying"
    # converged: consistent with its covariance, and tighter than the coarse fix it started from
    assert j["err_m"] <= 3.0 * j["sigma_m"] + 0.5, (j["err_m"], j["sigma_m"])
    assert j["sigma_m"] < math.sqrt(3) * 10.0 * 0.6
    # existing stations move by < 1 sigma (per axis) across the join: last estimate before the joiner's
    # first nav vs the first estimate 2 cycles later
    t7 = navs7[0]
    for sid in range(2, 7):
        s = summary[sid]
        before = np.searchsorted(s["log_time_ns"], t7) - 1
        after = np.searchsorted(s["log_time_ns"], t7 + int(2 * 0.5 / speed * 1e9))
        assert before >= 0 and after < len(s["log_time_ns"])
        d = np.abs(s["pos_m"][after] - s["pos_m"][before])
        sig = np.sqrt(np.diag(s["cov_m2"][before]))
        assert np.all(d <= sig + 1e-6), (sid, d, sig)


FUZZ = textwrap.dedent("""
    import json, sys, time
    import numpy as np
    from net.bus import Bus
    from net import messages as M
    seed_ep, n_total, ids = sys.argv[1], int(sys.argv[2]), json.loads(sys.argv[3])
    b = Bus(connect=[seed_ep])
    t0 = time.time()
    while len(b.alive("larns/alive/station/*", 0.5)) < len(ids) and time.time() - t0 < 30:
        time.sleep(0.2)
    time.sleep(0.5)
    rng = np.random.default_rng(7)
    good = M.encode({"kind": "nav", "src": 2, "seq": 1, "stamp_s": 1.0, "cycle": 1, "slot": 1, "t_tx_s": 1.0,
                     "pos_m": [1, 2, 3], "cov_m2": np.eye(3), "n_updates": 1, "state": "surveying",
                     "ranges": [], "members": [1]}, {"pos_m": [0, 0, 0], "t_true_s": 1.0})
    truth = M.encode({"kind": "truth", "src": 3, "seq": 1, "stamp_s": 0.0, "t_s": 0.0, "pos_m": [0, 0, 0]})
    expect = {i: 0 for i in ids}
    sent = 0
    while sent < n_total:
        r = rng.random()
        k = int(rng.choice(ids))
        if r < 0.4:      # random bytes
            data = rng.integers(0, 256, int(rng.integers(0, 300)), dtype=np.uint8).tobytes()
        elif r < 0.8:    # bit flips of a valid nav
            b2 = bytearray(good)
            for j in rng.integers(0, len(b2), int(rng.integers(1, 5))):
                b2[j] = int(rng.integers(0, 256))
            data = bytes(b2)
        elif r < 0.9:    # valid, but a kind stations never accept (no phy)
            data = truth
        else:            # valid nav from station 2 on another station's key: spoof, rejected
            data = good
            k = int(rng.choice([i for i in ids if i != 2]))
        if r < 0.8:
            try:
                M.decode(data)
                continue  # still a valid message: not malformed, skip it
            except M.MessageError:
                pass
        if r >= 0.8 or rng.random() < 0.5:
            key, targets = f"larns/station/{k}/nav", ids
        else:
            dst = int(rng.choice(ids))
            key = f"larns/station/{k}/range/{'req' if rng.random() < 0.5 else 'rsp'}/{dst}"
            targets = [dst]
        b.publish(key, data, block=True)  # count what was sent: no drops at the sender
        for t in targets:
            expect[t] += 1
        sent += 1
        if sent % 50 == 0:
            time.sleep(0.01)
    time.sleep(0.5)
    print(json.dumps({"sent": sent, "expect": expect}))
    b.close()
""")


def test_kill_station_and_recorder_and_fuzz(tmp_path, spawn):
    """SIGKILL a non-frame station and (separately) one of two recorders while a fuzzer publishes
    thousands of malformed payloads on station keys: every other station keeps updating, stays
    alive, converges, and its drop counter accounts for the payloads it rejected."""
    scn = write_scenario(tmp_path, 6, name="kill")
    dur = 60.0
    ids = [1, 2, 3, 4, 5, 6]
    ports = free_tcp_ports(8)
    eps = [f"tcp/127.0.0.1:{p}" for p in ports]
    seeds = eps[:2]
    epoch = time.time() + 8.0
    common = ["--scenario", str(scn), "--speed", str(SPEED), "--epoch", repr(epoch)]
    procs: dict[str, subprocess.Popen] = {}
    for name, ep, out in (("recA", eps[6], tmp_path / "a.mcap"), ("recB", eps[7], tmp_path / "b.mcap")):
        procs[name] = spawn([PY, "-m", "larns", "record", "-o", str(out), "-q", "--listen", ep,
                                        *sum((["--connect", s] for s in seeds), []), "--epoch", repr(epoch),
                                        "--speed", str(SPEED), "--flush", "0.5"])
    for i, sid in enumerate(ids):
        procs[f"st{sid}"] = spawn(
            [PY, "-m", "stations", "--id", str(sid), *common, "--duration", str(dur), "--quiet",
             "--report-json", "--listen", eps[i], *sum((["--connect", s] for s in seeds if s != eps[i]), [])],
            stdout=subprocess.PIPE, text=True)
    fuzz = spawn([PY, "-c", FUZZ, seeds[0], "3000", json.dumps(ids)], stdout=subprocess.PIPE, text=True)
    # reference: the simulator with the same station dying at the same fleet time (while the fleet runs)
    sim = Background(sim_stats, scn, dur, [2, 3, 4, 5], stop_s={6: 25.0})

    def wait_fleet(t):
        time.sleep(max(0.0, epoch + t / SPEED - time.time()))

    wait_fleet(15.0)
    t_w = time.time()  # (on a loaded box, make sure recorder A flushed a chunk before killing it)
    a_mcap = tmp_path / "a.mcap"
    while count_messages(a_mcap) == 0 and time.time() - t_w < 30:
        time.sleep(0.2)
    assert count_messages(a_mcap) > 0, ("recorder A recorded nothing", procs["recA"].poll())
    procs["recA"].send_signal(signal.SIGKILL)
    wait_fleet(25.0)
    procs["st6"].send_signal(signal.SIGKILL)
    t_kill_ns = time.time_ns()
    fz_out, _ = fuzz.communicate(timeout=120)
    fz = json.loads(fz_out.strip().splitlines()[-1])
    reports = {}
    for sid in ids[:-1]:
        o, _ = procs[f"st{sid}"].communicate(timeout=120)
        assert procs[f"st{sid}"].returncode == 0
        reports[sid] = json.loads(o.strip().splitlines()[-1])
    procs["recB"].send_signal(signal.SIGINT)
    assert procs["recB"].wait(30) == 0
    procs["st6"].wait(5)
    procs["recA"].wait(5)

    assert fz["sent"] == 3000
    summary = mcap_station_summary(tmp_path / "b.mcap")
    for sid in ids[:-1]:
        s = summary[sid]
        # keeps updating after the kills
        k = np.searchsorted(s["log_time_ns"], t_kill_ns)
        if sid != 1:  # station 1 is the fixed origin: no updates to make
            assert s["n_updates"][-1] - s["n_updates"][k] >= 10, (sid, s["n_updates"][k], s["n_updates"][-1])
        remaining_ns = (epoch + dur / SPEED) * 1e9 - t_kill_ns
        assert remaining_ns > 2e9  # the kill happened well before the end
        assert s["log_time_ns"][-1] > t_kill_ns + 0.6 * remaining_ns
        # every payload sent to it was rejected and counted
        drops = reports[sid]["drops"]["total"]
        assert 0.9 * fz["expect"][str(sid)] <= drops <= fz["expect"][str(sid)], (sid, drops, fz["expect"], {k: v for k, v in reports[sid].items() if k in ("drops", "rx", "slots")})
    # reference: the simulator with the same station dying at the same fleet time
    assert_accuracy_class(summary, [2, 3, 4, 5], sim.get())
    # the killed recorder's file is still readable up to its last flushed chunk
    assert count_messages(tmp_path / "a.mcap") > 0


def test_sigterm_clean_exit(tmp_path, spawn):
    """SIGTERM: a station withdraws its liveliness token and exits 0 with its report; the recorder
    finishes an indexed MCAP file."""
    scn = write_scenario(tmp_path, 4, name="term")
    p1, p2, p3 = free_tcp_ports(3)
    epoch = time.time() + 2.0
    st = [spawn([PY, "-m", "stations", "--id", str(i), "--scenario", str(scn), "--epoch", repr(epoch),
                            "--speed", "5", "--quiet", "--report-json", "--listen", f"tcp/127.0.0.1:{p}",
                            "--connect", f"tcp/127.0.0.1:{p1}"], stdout=subprocess.PIPE, text=True)
          for i, p in ((1, p1), (2, p2))]
    out = tmp_path / "t.mcap"
    rec = spawn([PY, "-m", "larns", "record", "-o", str(out), "-q", "--listen", f"tcp/127.0.0.1:{p3}",
                            "--connect", f"tcp/127.0.0.1:{p1}", "--flush", "0.5"])
    time.sleep(max(0.0, epoch + 3.0 - time.time()))
    t0 = time.time()  # on a loaded box: wait until the stations are up and publishing
    while (not out.exists() or out.stat().st_size < 4096) and time.time() - t0 < 30:
        time.sleep(0.2)
    for p in (*st, rec):
        p.send_signal(signal.SIGTERM)
    for p in st:
        o, _ = p.communicate(timeout=20)
        assert p.returncode == 0
        rep = json.loads(o.strip().splitlines()[-1])
        assert rep["slots"] >= 3
    assert rec.wait(20) == 0
    from mcap.reader import make_reader
    with open(out, "rb") as f:
        summ = make_reader(f).get_summary()
    assert summ is not None and summ.statistics.message_count > 0


def test_fleet_ctrl_c_stops_everything(tmp_path, spawn):
    """`larns fleet` without a duration runs until Ctrl-C (SIGINT): then every child is gone and the
    recording is a valid indexed MCAP."""
    scn = write_scenario(tmp_path, 4, name="ctrlc")
    out = tmp_path / "c.mcap"
    fleet = spawn([PY, "-m", "larns", "fleet", "--scenario", str(scn), "--duration", "0", "--speed",
                              str(SPEED), "--record", str(out), "--no-table"],
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    t0 = time.time()
    while len(station_pids(str(scn))) < 4 and time.time() - t0 < 30:
        time.sleep(0.3)
    while (not out.exists() or out.stat().st_size < 4096) and time.time() - t0 < 40:
        time.sleep(0.3)
    fleet.send_signal(signal.SIGINT)
    log, _ = fleet.communicate(timeout=60)
    assert fleet.returncode == 130, log
    assert station_pids(str(scn)) == {}
    from mcap.reader import make_reader
    with open(out, "rb") as f:
        summ = make_reader(f).get_summary()
    assert summ.statistics.message_count > 0
    assert any(c.topic == "larns/station/4/estimate" for c in summ.channels.values())
