"""Security (issue 15, docs/security.md): keystore, signatures, receive guards, and adversaries
against real processes over real TLS on loopback.

The process tests are bounded in count and time (each < ~40 s); the long fleet bars are in the
docs' commands, not here."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from net import messages as M
from net import security as S
from net.bus import free_tcp_ports

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def ks(tmp_path_factory) -> Path:
    from net.keystore import init_keystore

    root = tmp_path_factory.mktemp("ks") / "keys"
    init_keystore(root, list(range(1, 11)), ["ac1"], recorder=True)
    return root


def _nav(src: int, seq: int, t: float) -> dict:
    return {"kind": "nav", "src": src, "seq": seq, "stamp_s": t, "cycle": int(t), "slot": src - 1,
            "t_tx_s": t, "pos_m": [1.0, 2.0, 3.0], "cov_m2": np.eye(3).tolist(), "n_updates": 3,
            "state": "surveying", "ranges": [[1, 100.0, t]], "members": [1, 2]}


# --------------------------------------------------------------------------- keystore

def test_keystore_layout_and_checks(ks, tmp_path):
    from net.keystore import add_to_keystore, init_keystore

    k = S.Keystore(ks)
    assert {"router", "monitor", "recorder", "aircraft-ac1"} <= set(k.enclaves)
    assert all(f"station-{i}" in k.enclaves for i in range(1, 11))
    assert 11 in k.reserved and 64 in k.reserved
    for cn in ("station-3", "router", "aircraft-ac1"):
        k.check_enclave(cn)
        assert oct((ks / cn / "key.pem").stat().st_mode & 0o777) == "0o600"
    acl = S.load_enclave_settings(ks, "station-3")["access_control"]
    assert acl["default_permission"] == "deny"
    rules = {r["id"]: r for r in acl["rules"]}
    assert "larns/station/5/nav" in rules["pub-station-5"]["key_exprs"]
    assert rules["pub-station-5"]["messages"] == ["put"]
    with pytest.raises(S.KeystoreError, match="station-11"):
        k.check_enclave("station-11")
    _, new = add_to_keystore(ks, stations=[11])
    assert new == ["station-11"]
    S.Keystore(ks).check_enclave("station-11")
    # a certificate from another CA is refused
    other = init_keystore(tmp_path / "other", [5], [])
    (tmp_path / "mixed").mkdir()
    import shutil

    shutil.copytree(ks, tmp_path / "mixed", dirs_exist_ok=True)
    shutil.copy(other.root / "station-5" / "cert.pem", tmp_path / "mixed" / "station-5" / "cert.pem")
    with pytest.raises(S.KeystoreError, match="not issued by"):
        S.Keystore(tmp_path / "mixed").check_enclave("station-5")
    with pytest.raises(S.KeystoreError, match="not a LARNS keystore"):
        S.Keystore(tmp_path / "nothing")


def test_cli_missing_credentials_exit_nonzero(ks, tmp_path):
    for cmd in (["station", "--id", "3", "--secure", str(tmp_path / "none"), "--duration", "1"],
                ["station", "--id", "12", "--scenario", "seed000", "--secure", str(ks), "--duration", "1"],
                ["record", "-o", str(tmp_path / "x.mcap"), "--secure", str(tmp_path / "none"), "--duration", "1"],
                ["router", "--secure", str(tmp_path / "none"), "--duration", "1"]):
        p = subprocess.run([sys.executable, "-m", "larns", *cmd], capture_output=True, text=True, timeout=60)
        assert p.returncode == 2, (cmd, p.stderr)
        assert "keystore" in p.stderr or "credentials" in p.stderr, p.stderr
        assert "Traceback" not in p.stderr
    assert not (tmp_path / "x.mcap").exists()


# --------------------------------------------------------------------------- signatures and guards

def test_signature_roundtrip_and_reasons(ks):
    s3 = S.Security(ks, "station-3")
    s5 = S.Security(ks, "station-5")
    env = M.encode(_nav(3, 1, 10.0), {"pos_m": [0.0, 0.0, 0.0], "t_true_s": 10.0})
    key = "larns/station/3/nav"
    frame = s3.seal(key, env)
    assert frame[:1] == M.SIGNED_MARK and frame.endswith(env)
    assert M.decode(frame)[0]["src"] == 3  # offline tools read signed frames
    assert M.peek_stamp(frame) == 10.0
    v = S.Verifier(S.Keystore(ks))
    assert v.open(key, frame) == ("station-3", env)

    def reason(k, data):
        with pytest.raises(S.SecurityError) as e:
            v.open(k, data)
        return e.value.reason

    assert reason(key, env) == "unsigned"
    assert reason("larns/station/5/nav", frame) == "signer_mismatch"        # moved to another key
    assert reason(key, s5.seal(key, env)) == "signer_mismatch"              # 5 signing as 3
    bad = bytearray(frame)
    bad[-1] ^= 1
    assert reason(key, bytes(bad)) == "bad_signature"                       # tampered envelope
    assert reason(key, frame[:20]) == "bad_frame"
    forged = S.MAGIC + bytes([9]) + b"station-3" + bytes(64) + env
    assert reason(key, forged) == "bad_signature"
    k40 = "larns/station/40/nav"  # reserved id, no certificate issued
    sig40 = S.MAGIC + bytes([10]) + b"station-40" + bytes(64) + env
    assert reason(k40, sig40) == "unknown_signer"


def test_receive_guard_replay_stale_rate(ks):
    s3 = S.Security(ks, "station-3")
    now = [100.0]
    rx = S.Security(ks, "station-5").station_guard(1.0, lambda: now[0])
    key = "larns/station/3/nav"

    def frame(seq, t):
        return s3.seal(key, M.encode(_nav(3, seq, t), {"pos_m": [0.0, 0.0, 0.0], "t_true_s": t}))

    def why(data):
        with pytest.raises(M.MessageError) as e:
            rx.decode(key, data)
        return e.value.reason

    f1 = frame(1, 100.0)
    assert rx.decode(key, f1)[0]["seq"] == 1
    assert why(f1) == "replayed"
    now[0] = 101.0
    assert rx.decode(key, frame(2, 101.0))[0]["seq"] == 2
    assert why(frame(1, 100.0)) == "replayed"
    assert rx.decode(key, frame(1, 101.5))[0]["seq"] == 1      # a restarted sender: seq from 1, newer stamp
    assert why(frame(9, 30.0)) == "stale"
    now[0] = 200.0
    assert why(f1) == "stale"                                   # an old recording played again
    # budget per key: 4 per cycle, burst 8. Junk and copies of an accepted message are refused
    # before they spend it (a flooder re-sending one signed frame cannot starve its sender)
    now[0] = 300.0
    first = frame(30, 300.0)
    assert rx.decode(key, first)[0]["seq"] == 30
    assert {why(first) for _ in range(50)} == {"replayed"}
    assert {why(b"junk") for _ in range(20)} == {"unsigned"}
    out = []
    for i in range(10):
        try:
            out.append(rx.decode(key, frame(31 + i, 300.0))[0]["seq"])
        except M.MessageError as e:
            out.append(e.reason)
    assert out == list(range(31, 38)) + ["rate"] * 3, out
    # the budget is the key's: the same sender's requests to us still pass
    req = "larns/station/3/range/req/5"
    assert rx.decode(req, s3.seal(req, M.encode(_nav(3, 99, 300.0))))[0]["seq"] == 99
    # its own samples (local delivery, however late) are decoded, never counted
    s5 = S.Security(ks, "station-5")
    own = s5.seal("larns/station/5/nav", M.encode(_nav(5, 1, 1.0), {"pos_m": [0.0, 0.0, 0.0], "t_true_s": 1.0}))
    assert rx.decode("larns/station/5/nav", own)[0]["src"] == 5


def test_rate_limiter_refills():
    lim = S.RateLimiter(4.0, 8.0)
    assert sum(lim.allow("a", 0.0) for _ in range(20)) == 8
    assert sum(lim.allow("a", 1.0) for _ in range(20)) == 4        # 4 per second
    assert sum(lim.allow("b", 1.0) for _ in range(20)) == 8        # per source
    assert lim.throttled["a"] == 28


def test_signature_cost_is_measured(ks):
    """Per-message cost (docs/security.md). Not a timing assertion: a sanity bound only."""
    import timeit

    s = S.Security(ks, "station-3")
    env = M.encode(_nav(3, 1, 1.0), {"pos_m": [0.0, 0.0, 0.0], "t_true_s": 1.0})
    fr = s.seal("larns/station/3/nav", env)
    v = S.Verifier(S.Keystore(ks))
    t_sign = min(timeit.repeat(lambda: s.seal("larns/station/3/nav", env), number=200, repeat=3)) / 200
    t_ver = min(timeit.repeat(lambda: v.open("larns/station/3/nav", fr), number=200, repeat=3)) / 200
    assert t_sign < 5e-3 and t_ver < 5e-3, (t_sign, t_ver)


# --------------------------------------------------------------------------- real processes

PY = sys.executable


def _station(ks, sid, ports, epoch, duration, seeds, env=None, extra=()):
    cmd = [PY, "-m", "larns", "station", "--id", str(sid), "--scenario", "seed000", "--epoch", repr(epoch),
           "--duration", repr(duration), "--quiet", "--report-json", "--secure", str(ks),
           "--listen", f"tcp/127.0.0.1:{ports[sid]}", *extra]
    for s in seeds:
        if s != sid:
            cmd += ["--connect", f"tcp/127.0.0.1:{ports[s]}"]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, **(env or {})})


def _attack(ks, name, ports, seeds, *args, epoch=None):
    cmd = [PY, "-m", "larns", "attack", name, "--link-wait", "8", *args]
    if ks:
        cmd += ["--secure", str(ks)]
    if epoch is not None:
        cmd += ["--epoch", repr(epoch)]
    for s in seeds:
        cmd += ["--connect", f"tcp/127.0.0.1:{ports[s]}" if name == "nocred" else f"tls/127.0.0.1:{ports[s]}"]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _report(p, timeout=90) -> dict:
    out, err = p.communicate(timeout=timeout)
    assert p.returncode == 0, err[-2000:]
    assert "Traceback" not in err, err[-2000:]
    return json.loads(out.strip().splitlines()[-1])


_WATCH = """
import json, sys, time
from net.bus import Bus
from net import messages as M
b = Bus(listen=["tls/127.0.0.1:0"], connect=sys.argv[3:], secure=(sys.argv[1], "monitor"))
seqs = []
b.subscribe("larns/station/5/nav/**", lambda k, d: seqs.append(M.decode(d)[0]["seq"]))
time.sleep(float(sys.argv[2]))
print(json.dumps({"navs": len(seqs), "forged": sum(1 for s in seqs if s >= 10**6)}))
b.close()
"""


@pytest.mark.e2e
@pytest.mark.timeout(180)
def test_adversaries_against_secure_stations(ks):
    """Four secure stations (1, 2, 3, 5) for 22 s with three attackers: no credentials, station 3's
    credentials forging station 5 (its key, its own key, unsigned, bad signature), and station 5's
    stolen key replaying 5's navs. A watcher with the monitor's credentials sees only genuine navs on
    larns/station/5/nav; the stations count every attack by reason; nothing crashes."""
    ids = [1, 2, 3, 5]
    ports = dict(zip(ids, free_tcp_ports(len(ids))))
    epoch = time.time() + 6.0
    dur = 22.0
    procs = {s: _station(ks, s, ports, epoch, dur, [1, 2]) for s in ids}
    watch = subprocess.Popen([PY, "-c", _WATCH, str(ks), str(dur + 4), *[f"tls/127.0.0.1:{ports[s]}" for s in ids]],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    time.sleep(8.0)
    atk = [_attack(None, "nocred", ports, [1, 5], "--duration", "3"),
           _attack(ks, "forge", ports, [1, 2, 5], "--as", "3", "--victim", "5", "--duration", "10",
                   epoch=epoch),
           _attack(ks, "replay", ports, [1, 2], "--as", "5", "--delay", "1", "--duration", "10", epoch=epoch)]
    res = [_report(a) for a in atk]
    reps = {s: _report(p) for s, p in procs.items()}
    w = _report(watch)
    assert res[0]["tcp"]["links"] == 0 and res[0]["tls"]["links"] == 0        # no credentials: no link
    assert res[1]["sent"]["victim_key"] > 10 and res[2]["sent"] > 3
    assert w["navs"] >= 10 and w["forged"] == 0                              # 3 cannot speak as 5
    for s in (1, 2, 5):
        r = reps[s]["drops"]["by_reason"]
        assert r.get("unsigned", 0) > 0 and r.get("bad_signature", 0) > 0, (s, r)
        assert r.get("signer_mismatch", 0) > 0, (s, r)
        if s != 5:  # (station 5 ignores samples of its own, replayed or not)
            assert r.get("replayed", 0) + r.get("stale", 0) > 0, (s, r)
    for s in (2, 3, 5):  # (station 1 is the origin: no updates)
        assert reps[s]["n_updates"] > 5, reps[s]
        assert reps[s]["err_m"] < 20.0, reps[s]   # the forged navs (30 m shift) never reached a core


@pytest.mark.e2e
@pytest.mark.timeout(180)
def test_fuzz_from_credentialed_process_all_counted(ks):
    """10,000 malformed payloads, each validly signed by station 3, at station 5 with its budgets
    off (LARNS_RATE_LIMITS=off, so that every payload reaches the decoder): the station survives
    and counts every one by reason."""
    ports = dict(zip([3, 5], free_tcp_ports(2)))
    epoch = time.time() + 3.0
    st = _station(ks, 5, ports, epoch, 40.0, [], env={"LARNS_RATE_LIMITS": "off"})
    time.sleep(3.0)
    a = _attack(ks, "fuzz", ports, [5], "--as", "3", "--count", "10000", "--period", "0", "--duration", "60")
    res = _report(a, timeout=120)
    time.sleep(8.0)  # the station reads navs in one batch per cycle: let it work through the backlog
    st.send_signal(signal.SIGINT)
    rep = _report(st)
    assert res["sent"] == 10000
    # every payload is counted by reason, or (a bit flip that leaves a valid nav) delivered as a
    # nav; seen: 9,999-10,002 drops (the one or two above 10,000 are not explained yet; one below,
    # 9,998 drops + 1 nav, on a machine loaded by other jobs: the sender's Zenoh put is best effort)
    got = rep["drops"]["total"] + rep["rx"].get("nav", 0)
    assert 9995 <= got <= 10005 and rep["drops"]["total"] >= 9990, (rep["drops"], rep["rx"])
    assert len(rep["drops"]["by_reason"]) >= 4, rep["drops"]


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.timeout(300)
def test_flood_from_station_9_leaves_other_slots_intact(ks):
    """Stations 1-5 and 9 for 40 s; from ~11 s to ~31 s a second process with station 9's
    credentials floods navs and range requests at 20,000 msg/s. Every other station completes
    >= 95 % of its own exchanges (a reply in time to its request, with any peer) from the flood's
    start to the run's last cycles, and counts what reached Python of the flood by reason."""
    ids = [1, 2, 3, 4, 5, 9]
    ports = dict(zip(ids, free_tcp_ports(len(ids))))
    epoch = time.time() + 6.0
    procs = {s: _station(ks, s, ports, epoch, 40.0, [1, 2]) for s in ids}
    time.sleep(6.0 + 10.0)
    a = _attack(ks, "flood", ports, ids, "--as", "9", "--rate", "20000", "--duration", "20",
                "--victims", "1,2,3,4,5")
    res = _report(a, timeout=120)
    reps = {s: _report(p) for s, p in procs.items()}
    assert res["rate_per_s"] >= 15000, res
    for s in (1, 2, 3, 4, 5):
        r = reps[s]
        ex = [e for e in r["exchanges"] if 10.0 <= e[0] <= 36.0]
        done = sum(1 for e in ex if e[2]) / max(1, len(ex))
        assert len(ex) >= 20 and done >= 0.95, (s, done, len(ex), r["drops"])
        by = r["drops"]["by_reason"]
        print(f"station {s}: {done:.3f} of {len(ex)} exchanges, drops {by}")
        assert by.get("rate", 0) + by.get("replayed", 0) + by.get("stale", 0) > 0, (s, r["drops"])


def test_recording_keeps_signatures_and_replay_verifies(ks, tmp_path):
    """The recorder keeps signed frames as they are; `larns replay --secure DIR` checks them
    (exit 1 and counts by reason when one was tampered with or unsigned)."""
    from larns.analysis.verify import verify_recording
    from larns.log.record import McapSink

    s3 = S.Security(ks, "station-3")
    key = "larns/station/3/nav"
    sink = McapSink(tmp_path / "r.mcap", epoch_unix_s=0.0, foxglove=False)
    good = [s3.seal(key, M.encode(_nav(3, i, float(i)), {"pos_m": [0.0, 0.0, 0.0], "t_true_s": float(i)}))
            for i in range(1, 6)]
    t0 = time.time_ns()                                    # (certificates are checked at the log time)
    for i, f in enumerate(good):
        sink.write(key, f, t0 + i * 1000)
    bad = bytearray(good[0])
    bad[-3] ^= 0x40
    sink.write(key, bytes(bad), t0 + 9000)
    sink.write(key, M.encode(_nav(3, 9, 9.0)), t0 + 9500)
    sink.write("larns/station/5/nav", good[1], t0 + 9900)  # moved to another key
    sink.finish()
    res = verify_recording(S.Keystore(ks), [tmp_path / "r.mcap"])
    assert res["checked"] == 8 and res["by_signer"] == {"station-3": 5}
    assert res["by_reason"] == {"bad_signature": 1, "unsigned": 1, "signer_mismatch": 1}
    p = subprocess.run([PY, "-m", "larns", "replay", "--secure", str(ks), str(tmp_path / "r.mcap")],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 1 and '"valid": 5' in p.stdout, p.stderr


def test_vehicle_enclave_speaks_only_for_itself(tmp_path):
    """A ground vehicle has its own enclave (``vehicle-<name>``): access rules for its keys, and its
    signed messages verify only on its own keys (recorder / replay check; live receivers likewise)."""
    from larns.analysis.verify import verify_recording
    from larns.log.record import McapSink
    from net.keystore import add_to_keystore, init_keystore

    root = tmp_path / "keys"
    init_keystore(root, [1, 2], ["ac1"], vehicles=["veh1"])
    k = S.Keystore(root)
    assert k.vehicles == ["veh1"] and k.aircraft == ["ac1"]
    k.check_enclave("vehicle-veh1")
    acl = S.load_enclave_settings(root, "station-1")["access_control"]
    rules = {r["id"]: r for r in acl["rules"]}
    assert rules["pub-vehicle-veh1"]["key_exprs"] == [f"larns/vehicle/veh1/{k}" for k in ("estimate", "truth", "init", "input")]
    assert rules["tok-vehicle-veh1"]["key_exprs"] == ["larns/alive/vehicle/veh1"]
    assert rules["sub-vehicle-veh1"]["key_exprs"] == ["larns/station/*/nav/**"]
    assert {"id": "vehicle-veh1", "cert_common_names": ["vehicle-veh1"]} in acl["subjects"]
    assert add_to_keystore(root, vehicles=["veh2"])[1] == ["vehicle-veh2"]
    assert S.sender_cn("larns/vehicle/veh1/estimate", "veh1") == "vehicle-veh1"
    assert S.sender_cn("larns/aircraft/ac1/estimate", "ac1") == "aircraft-ac1"
    assert S.sender_cn("larns/station/3/nav", 3) == "station-3"
    assert S.sender_cn("larns/station/3/nav", "3") is None and S.sender_cn("larns/vehicle/veh1/x", 1) is None
    assert S.expected_signer("larns/vehicle/veh1/estimate") == "vehicle-veh1"
    veh = S.Security(root, "vehicle-veh1")
    est = {"kind": "veh_estimate", "src": "veh1", "seq": 1, "stamp_s": 1.0, "t_s": 1.0, "pos_m": [1.0, 2.0, 3.0],
           "cov_m2": np.eye(3).tolist(), "vel_m_s": [0.0, 0.0, 0.0], "algo": "ekf", "n_updates": 1}
    mine, theirs = "larns/vehicle/veh1/estimate", "larns/aircraft/veh1/estimate"
    sink = McapSink(tmp_path / "v.mcap", epoch_unix_s=0.0, foxglove=False)
    t0 = time.time_ns()
    sink.write(mine, veh.seal(mine, M.encode(est)), t0)
    sink.write(theirs, veh.seal(theirs, M.encode(est)), t0 + 1000)  # its key on an aircraft's topic
    sink.finish()
    res = verify_recording(S.Keystore(root), [tmp_path / "v.mcap"])
    assert res["by_signer"] == {"vehicle-veh1": 1} and res["by_reason"] == {"signer_mismatch": 1}, res


def test_access_rules_name_exactly_the_keys_each_sender_publishes(ks):
    """Every message kind's key (``key_for``) is allowed to its own sender and to nobody else, and
    invented sub-keys (the insider's ``subkeys``) are allowed to nobody."""
    from larns.log.keyexpr import keyexpr_match as _matches
    from net.keystore import add_to_keystore

    add_to_keystore(ks, vehicles=["veh1"])
    acl = S.load_enclave_settings(ks, "station-3")["access_control"]
    rules = {r["id"]: r["key_exprs"] for r in acl["rules"] if r["id"].startswith("pub-")}
    assert all("**" not in k for keys in rules.values() for k in keys), rules
    senders = {"station": 7, "aircraft": "ac1", "vehicle": "veh1"}
    for kind in M.SCHEMAS:
        role = "aircraft" if kind.startswith("ac_") else "vehicle" if kind.startswith("veh_") else "station"
        try:
            key = M.key_for({"kind": kind, "src": senders[role], "dst": 4, "algo": "ukf-pr"})
        except M.MessageError:
            continue  # not published by a sender (no key)
        allowed = [rid for rid, keys in rules.items() if any(_matches(p, key) for p in keys)]
        assert allowed == [f"pub-{role}-{senders[role]}"], (kind, key, allowed)
    for key in ("larns/station/7/x/1", "larns/station/7/nav/extra/2", "larns/aircraft/ac1/estimate/a/b",
                "larns/vehicle/veh1/x", "larns/station/7"):
        assert not any(_matches(p, key) for keys in rules.values() for p in keys), key
