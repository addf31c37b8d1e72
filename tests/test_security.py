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

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def ks(tmp_path_factory) -> Path:
    from larns.keys import init_keystore

    root = tmp_path_factory.mktemp("ks") / "keys"
    init_keystore(root, list(range(1, 11)), ["ac1"], recorder=True)
    return root


def _nav(src: int, seq: int, t: float) -> dict:
    return {"kind": "nav", "src": src, "seq": seq, "stamp_s": t, "cycle": int(t), "slot": src - 1,
            "t_tx_s": t, "pos_m": [1.0, 2.0, 3.0], "cov_m2": np.eye(3).tolist(), "n_updates": 3,
            "state": "surveying", "ranges": [[1, 100.0, t]], "members": [1, 2]}


# --------------------------------------------------------------------------- keystore

def test_keystore_layout_and_checks(ks, tmp_path):
    from larns.keys import add_to_keystore, init_keystore

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
    assert rules["pub-station-5"]["key_exprs"] == ["larns/station/5/**"]
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
    assert why(frame(9, 90.0)) == "stale"
    now[0] = 200.0
    assert why(f1) == "stale"                                   # an old recording played again
    # budget: 4 per cycle, burst 8; the 9th message at once is throttled before any decoding
    out = []
    for i in range(12):
        try:
            rx.decode("larns/station/7/nav", b"junk")
            out.append("ok")
        except M.MessageError as e:
            out.append(e.reason)
    assert out[:8] == ["unsigned"] * 8 and out[8:] == ["rate"] * 4


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
