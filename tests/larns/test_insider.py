"""`larns attack --as station-N` (larns/adversary/insider.py): each insider mode against a recording
fake bus on a fake clock - what it sends is wire-valid, within the per-key budget, aimed where the
mode says - and what a real station core does with it (issue 32 item 7). The real-Zenoh run is
`test_insider_modes_against_secure_stations` (e2e)."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
import pytest

from fake_bus import FakeBus
from larns.adversary import insider as I
from net import messages as M
from stations.core import StationConfig, StationCore
from stations.tdma import TdmaPlan

PLAN = TdmaPlan(1.0, 0.01)
EPOCH_WALL = 1000.0  # fake wall time of fleet time 0
ME = 2


class RawBus(FakeBus):
    """The fake bus with the raw put the insider's shell uses (replays go out as captured)."""

    def put_raw(self, key, data):
        self.sent.append((key, bytes(data)))


class FakeClock:
    def __init__(self, t0: float):
        self.t = t0

    def wall(self) -> float:
        return self.t

    def sleep(self, dt: float) -> None:
        self.t += dt


def _honest_nav(src: int, t: float, seq: int) -> bytes:
    m = {"kind": "nav", "src": src, "seq": seq, "stamp_s": t, "cycle": int(t), "slot": src - 1, "t_tx_s": t,
         "pos_m": [100.0 * src, 50.0, 0.0], "cov_m2": (np.eye(3) * 0.01).tolist(), "n_updates": 50,
         "state": "surveying", "ranges": [], "members": [1, 2, 3, 4, 5]}
    return M.encode(m, {"pos_m": m["pos_m"], "t_true_s": t})


def _insider(clock: FakeClock, victims=(1, 3, 4, 5), heard=(1, 2, 3, 4, 5)) -> I.Insider:
    ins = I.Insider(ME, np.random.default_rng(7), I.FieldClock(), victims=victims)
    for k, src in enumerate(heard):  # one cycle of the field's navs, delivered 1 ms late
        t = 10.0 + (src - 1) * 0.01 + 0.005
        ins.heard(M.station_key(src, "nav"), _honest_nav(src, t, 10 + k), EPOCH_WALL + t + 0.001)
    clock.t = EPOCH_WALL + 11.0
    return ins


def _drive(mode: str, seconds: float = 3.0, **kw):
    clock = FakeClock(0.0)
    ins = _insider(clock, **kw)
    bus = RawBus()
    res = I.run(bus, ins, [mode], seconds, wall=clock.wall, sleep=clock.sleep, period_s=0.001)
    sent = [(k, d, clock) for k, d in bus.sent]
    return ins, bus, res, sent


def _per_key_cycle(bus: RawBus, ins: I.Insider) -> Counter:
    """Samples per (key, cycle), the cycle read off each message's own stamp."""
    c: Counter = Counter()
    for k, d in bus.sent:
        c[(k, math.floor(M.decode(d)[0]["stamp_s"]))] += 1
    return c


def _core() -> StationCore:
    cfg = StationConfig(id=5, tdma=PLAN, known_ids=(1, 2, 3, 4), field_radius_m=2000.0,
                        clock_offset_sigma_s=1e-3, clock_freq_sigma=2e-6)
    return StationCore(cfg, np.array([100.0, 200.0, 10.0]), np.eye(3) * 100.0, start_s=0.0)


def test_as_accepts_station_n_and_n():
    assert I.parse_as("station-7") == 7 and I.parse_as("7") == 7
    for bad in ("station-x", "0", "70000", "aircraft-ac1"):
        with pytest.raises(ValueError):
            I.parse_as(bad)


def test_field_clock_is_read_off_the_navs():
    clock = FakeClock(0.0)
    ins = _insider(clock)
    # the fastest delivery (1 ms) sets the offset: field time = wall - epoch - 1 ms
    assert abs(ins.clock.now(EPOCH_WALL + 20.0) - (20.0 - 0.001)) < 1e-9
    assert ins.heard_ids == {1, 3, 4, 5}


def test_ids_mode_names_1024_invented_ids_and_a_core_stays_bounded():
    ins, bus, res, _ = _drive("ids")
    assert res[0]["sent"] == len(bus.sent) > 0
    assert max(_per_key_cycle(bus, ins).values()) <= ins.budget
    core = _core()
    for k, d in bus.sent:
        msg, phy = M.decode(d)  # wire-valid
        assert k == M.station_key(ME, "nav") and msg["src"] == ME
        ids = {e[0] for e in msg["ranges"]}
        assert len(ids) == M.MAX_LIST and min(ids) >= 100 and all(len(e) == 4 for e in msg["ranges"])
        core.on_message(msg, msg["stamp_s"] + 1e-6)
    # the core's clock filter and peers stay bounded (stations/admission.py), the ids are counted
    assert len(core.clk.index) <= core.admission.max_peers
    assert core.admission.dropped["new_ids"] > 1000


def test_slots_mode_claims_victims_slots_inside_those_slots():
    ins, bus, res, _ = _drive("slots", seconds=8.0)
    assert res[0]["sent"] == len(bus.sent) == 8  # one victim per cycle, in turn
    core = _core()
    claimed = set()
    for k, d in bus.sent:
        msg, _ = M.decode(d)
        t = msg["stamp_s"]
        cyc, slot = PLAN.locate(t)
        assert msg["slot"] == slot != ME - 1 and msg["cycle"] == cyc  # sent inside the slot it claims
        assert msg["slot"] + 1 in (1, 3, 4, 5)
        claimed.add(msg["slot"])
        core.on_message(msg, t + 1e-4)
    assert claimed == {0, 2, 3, 4}
    assert max(_per_key_cycle(bus, ins).values()) <= ins.budget
    # the core believed a few claims at most, then rate-limited them
    assert core.admission.dropped["slot_rate"] > 0


def test_absurd_mode_sends_every_field_at_its_limits_and_the_core_survives():
    ins, bus, res, _ = _drive("absurd", seconds=3.0)
    kinds = Counter()
    at_limit = Counter()
    core = _core()
    for k, d in bus.sent:
        msg, phy = M.decode(d)  # every one wire-valid: it meets the plausibility checks, not the schema
        kinds[msg["kind"]] += 1
        assert M.key_for(msg) == k and msg["src"] == ME
        for f in ("pos_m", "t_tx_s", "turnaround_s", "clock"):
            v = np.abs(np.asarray(msg.get(f, 0.0), float))
            if np.any(v == M.MAX_ABS):
                at_limit[f] += 1
        if msg["kind"] == "nav" and any(e[1] == M.MAX_ABS for e in msg["ranges"]):
            at_limit["ranges"] += 1
        core.on_message(msg, msg["stamp_s"] + 1e-6)  # no exception may escape
    assert set(kinds) == {"nav", "range_req", "range_rsp", "poll", "reply"}  # (both protocols)
    assert all(at_limit[f] > 0 for f in ("pos_m", "t_tx_s", "turnaround_s", "clock", "ranges")), at_limit
    assert max(_per_key_cycle(bus, ins).values()) <= ins.budget
    assert sum(core.admission.dropped.values()) > 0.5 * kinds["nav"]
    assert len(core.clk.index) <= core.admission.max_peers


def test_replay_mode_puts_the_real_stations_own_signed_bytes_again_after_the_delay():
    clock = FakeClock(0.0)
    ins = _insider(clock)
    bus = RawBus()
    own = [_honest_nav(ME, 11.0 + k, 100 + k) for k in range(3)]
    other = _honest_nav(3, 11.02, 200)

    def deliver(dt):  # the real station 2 and station 3 go on while the insider replays
        clock.sleep(dt)
        t = clock.t - EPOCH_WALL
        for k, d in enumerate(own):
            if abs(t - (11.0 + k + 0.5)) < dt / 2:
                ins.heard(M.station_key(ME, "nav"), d, clock.t)
                ins.heard(M.station_key(3, "nav"), other, clock.t)

    I.run(bus, ins, ["replay"], 5.0, wall=clock.wall, sleep=deliver, period_s=0.01)
    assert [d for _, d in bus.sent] == own  # exactly its own, byte for byte, in order
    assert all(k == M.station_key(ME, "nav") for k, _ in bus.sent)
    assert ins.sent["replay"] == 3


def test_flood_mode_fills_every_key_to_the_budget_with_fresh_messages():
    ins, bus, res, _ = _drive("flood", seconds=3.0)
    per = _per_key_cycle(bus, ins)
    keys = {k for k, _ in per}
    assert M.station_key(ME, "nav") in keys
    assert {M.station_key(ME, "range", "req", v) for v in (1, 3, 4, 5)} <= keys
    assert {M.station_key(ME, "range", "rsp", v) for v in (1, 3, 4, 5)} <= keys
    assert max(per.values()) == ins.budget  # to the budget, not beyond
    seqs = defaultdict(list)
    for k, d in bus.sent:
        m = M.decode(d)[0]
        seqs[k].append((m["stamp_s"], m["seq"]))
    assert all(s == sorted(s) and len(set(s)) == len(s) for s in seqs.values())  # fresh: never a copy


def test_subkeys_mode_invents_keys_no_receiver_subscribes():
    ins, bus, res, _ = _drive("subkeys", seconds=1.0)
    keys = [k for k, _ in bus.sent]
    assert len(set(keys)) == len(keys) > 100
    for k in keys:
        role, sid, rest = M.parse_key(k)
        assert role == "station" and sid == ME
        assert rest not in (["nav"], ["estimate"], ["truth"], ["init"], ["input"], ["integrity"])
        assert rest[:2] not in (["range", "req"], ["range", "rsp"])


def test_all_modes_in_turn_share_the_duration():
    clock = FakeClock(0.0)
    ins = _insider(clock)
    bus = RawBus()
    for k in range(3):
        ins.captured.append((clock.t, M.station_key(ME, "nav"), _honest_nav(ME, 11.0 + k, 300 + k)))
    res = I.run(bus, ins, I.MODES, 12.0, wall=clock.wall, sleep=clock.sleep, period_s=0.001)
    assert [r["mode"] for r in res] == list(I.MODES)
    assert all(abs(r["seconds"] - 2.0) < 0.01 for r in res)
    assert all(r["sent"] > 0 for r in res if r["mode"] != "replay")  # (replay: only what is heard from then on)


def test_cli_refuses_an_insider_without_credentials_or_a_bad_as(capsys):
    import argparse

    from larns.commands import attack as cmd

    p = argparse.ArgumentParser()
    cmd.register(p.add_subparsers())
    a = p.parse_args(["attack", "--as", "station-2", "--mode", "ids", "--connect", "tls/127.0.0.1:7447"])
    assert a.as_id == 2
    assert cmd.cmd_attack(a) == 2 and "--secure" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        p.parse_args(["attack", "--as", "aircraft-ac1", "--mode", "ids"])
    assert cmd.cmd_attack(p.parse_args(["attack", "--connect", "tls/127.0.0.1:1"])) == 2
    assert cmd.cmd_attack(p.parse_args(["attack", "forge", "--mode", "ids"])) == 2


# --------------------------------------------------------------------------- real Zenoh

PY = sys.executable
ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.e2e
@pytest.mark.slow  # (~55 s: four secure stations for 36 s)
@pytest.mark.timeout(180)
def test_insider_modes_against_secure_stations(tmp_path):
    """Secure stations 1, 2, 3, 5 (real processes, real Zenoh, TLS) and `larns attack --as station-2
    --mode all` for 18 s: every mode sends, every sample reaches the stations signed (their transport
    checks pass it), the stations refuse what is implausible (counted by reason) and keep
    surveying; nothing crashes."""
    from net.bus import free_tcp_ports
    from net.keystore import init_keystore

    ks = tmp_path / "keys"
    init_keystore(ks, [1, 2, 3, 5], [], recorder=False)
    env = {**os.environ, "LARNS_STATE_DIR": str(tmp_path / "state")}
    ids = [1, 2, 3, 5]
    ports = dict(zip(ids, free_tcp_ports(len(ids))))
    epoch = time.time() + 5.0
    dur = 36.0
    procs = {}
    for s in ids:
        cmd = [PY, "-m", "larns", "station", "--id", str(s), "--scenario", "seed000", "--epoch", repr(epoch),
               "--duration", repr(dur), "--quiet", "--report-json", "--secure", str(ks),
               "--listen", f"tls/127.0.0.1:{ports[s]}"]
        cmd += [a for o in ids if o < s for a in ("--connect", f"tls/127.0.0.1:{ports[o]}")]
        procs[s] = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)
    time.sleep(5.0 + 10.0)  # the field surveys first
    atk = subprocess.Popen([PY, "-m", "larns", "attack", "--as", "station-2", "--mode", "all", "--secure", str(ks),
                            "--duration", "18", "--link-wait", "8", "--epoch", repr(epoch),
                            *[a for s in (1, 3, 5) for a in ("--connect", f"tls/127.0.0.1:{ports[s]}")]],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)
    out, err = atk.communicate(timeout=90)
    assert atk.returncode == 0 and "Traceback" not in err, err[-2000:]
    lines = [json.loads(x) for x in out.strip().splitlines()]
    assert [r["mode"] for r in lines] == list(I.MODES)
    assert all(r["links"] > 0 and r["sent"] > 0 for r in lines), lines
    reps = {}
    for s, p in procs.items():
        o, e = p.communicate(timeout=90)
        assert p.returncode == 0 and "Traceback" not in e, e[-2000:]
        reps[s] = json.loads(o.strip().splitlines()[-1])
    for s in (1, 3, 5):
        r = reps[s]
        imp = r["implausible"]
        assert imp.get("new_ids", 0) > 0 and imp.get("pos", 0) + imp.get("time", 0) + imp.get("clock", 0) > 0, (s, imp)
        assert r["core_errors"] == 0, (s, r)
        by = r["drops"]["by_reason"]
        assert by.get("replayed", 0) + by.get("stale", 0) > 0, (s, by)  # the replays
    for s in (3, 5):  # (accuracy under attack: the 10-station fleet bar, tests/larns/test_insider_fleet.py)
        assert reps[s]["n_updates"] > 20, reps[s]
