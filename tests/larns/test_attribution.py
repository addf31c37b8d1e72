"""Offline tools verify (issue 32, item 5): a recording's messages are attributed by their key
and, with a keystore, by their signer; the rest is refused and reported by `larns info`. Real
MCAP files written by the recorder's sink, real signatures."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from net import messages as M
from net import security as S

PY = sys.executable
ROOT = Path(__file__).resolve().parents[2]


def _nav(src: int, seq: int, t: float) -> dict:
    return {"kind": "nav", "src": src, "seq": seq, "stamp_s": t, "cycle": int(t), "slot": src - 1,
            "t_tx_s": t, "pos_m": [1.0, 2.0, 3.0], "cov_m2": np.eye(3).tolist(), "n_updates": 3,
            "state": "surveying", "ranges": [[1, 100.0, t]], "members": [1, 2]}


@pytest.fixture()
def recording(tmp_path, monkeypatch):
    """Station 3 and 5 genuine; station 3 also publishes on its own key claiming src 5 (the
    issue's case: station 5 "in two places"), and with its own key on station 5's key (possible
    only through a compromised router or a forged file: only a signature check catches it)."""
    from larns.log.record import McapSink
    from net.keystore import init_keystore

    monkeypatch.setenv("LARNS_STATE_DIR", str(tmp_path / "state"))
    ks = tmp_path / "keys"
    init_keystore(ks, [3, 5], [])
    s3, s5 = S.Security(ks, "station-3"), S.Security(ks, "station-5")
    path = tmp_path / "r.mcap"
    sink = McapSink(path, epoch_unix_s=time.time(), foxglove=False)
    t0 = time.time_ns()
    for i in range(1, 11):
        for sec, sid in ((s3, 3), (s5, 5)):
            key = f"larns/station/{sid}/nav"
            sink.write(key, sec.seal(key, M.encode(_nav(sid, i, float(i)))), t0 + i * 10**9 + sid)
    for i in range(1, 5):   # station 3, own key, src 5
        key = "larns/station/3/nav"
        sink.write(key, s3.seal(key, M.encode(_nav(5, 100 + i, float(i)))), t0 + i * 10**9 + 7)
    for i in range(1, 3):   # station 3's signature on station 5's key, src 5
        key = "larns/station/5/nav"
        sink.write(key, s3.seal(key, M.encode(_nav(5, 200 + i, float(i)))), t0 + i * 10**9 + 8)
    key = "larns/station/5/nav"  # unsigned, on 5's key
    sink.write(key, M.encode(_nav(5, 300, 1.0)), t0 + 9)
    sink.finish()
    return path, ks


def test_attributed_by_key_then_by_signer(recording):
    from larns.analysis.summary import summarize

    path, ks = recording
    s = summarize([path])
    assert {(r["key"], r["src"], r["reason"], r["count"]) for r in s["refused"]} == \
        {("larns/station/3/nav", "5", "src_mismatch", 4)}
    assert s["stations"][3]["navs"] == 10
    assert s["stations"][5]["navs"] == 10 + 2 + 1        # without a keystore, the key is all we know
    v = summarize([path], keystore=S.Keystore(ks))
    assert v["verified"]
    assert {(r["key"], r["src"], r["reason"], r["count"]) for r in v["refused"]} == \
        {("larns/station/3/nav", "5", "src_mismatch", 4), ("larns/station/5/nav", "5", "signer_mismatch", 2),
         ("larns/station/5/nav", "5", "unsigned", 1)}
    assert v["stations"][3]["navs"] == 10 and v["stations"][5]["navs"] == 10
    assert v["loss"]["nav"]["duplicates"] == 0 and v["loss"]["nav"]["missing"] == 0


def test_larns_info_reports_refused_and_one_line_errors(recording, tmp_path):
    path, ks = recording
    p = subprocess.run([PY, "-m", "larns", "info", str(path), "--keystore", str(ks)],
                       capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert p.returncode == 0, p.stderr
    assert "Refused:           7 messages not attributed (by key and signer):" in p.stdout, p.stdout
    assert "larns/station/3/nav  src 5: src_mismatch x4" in p.stdout
    assert "larns/station/5/nav  src 5: signer_mismatch x2" in p.stdout
    j = subprocess.run([PY, "-m", "larns", "info", "--json", str(path)], capture_output=True, text=True,
                       timeout=60, cwd=ROOT)
    assert json.loads(j.stdout)["refused"] == [{"key": "larns/station/3/nav", "src": "5",
                                                 "reason": "src_mismatch", "count": 4}]
    bad = subprocess.run([PY, "-m", "larns", "info", str(path), "--keystore", str(tmp_path / "none")],
                         capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1 and "not a LARNS keystore" in bad.stderr


def test_revoked_signer_refused_offline(recording):
    """A key revoked after the fact: with the keystore's crl.pem its messages are refused offline."""
    from larns.analysis.summary import summarize
    from net.keystore import WritableKeystore

    path, ks = recording
    WritableKeystore(ks).revoke("station-5")
    v = summarize([path], keystore=S.Keystore(ks))
    reasons = {(r["key"], r["reason"]): r["count"] for r in v["refused"]}
    assert reasons[("larns/station/5/nav", "revoked")] == 10
    assert 5 not in v["stations"]


def test_journals_attributed_by_key(tmp_path):
    """`larns reestimate` groups journals by the key's station: an estimate on station 3's key
    claiming src 5 joins nobody's journal."""
    from larns.log.reader import Msg
    from larns.log.series import collect_journals

    def est(src, seq):
        return {"kind": "estimate", "src": src, "seq": seq, "stamp_s": 1.0, "t_s": 1.0, "pos_m": [0.0, 0.0, 0.0],
                "cov_m2": np.eye(3).tolist(), "n_updates": 1, "estimator": "dmap", "state": "surveying"}

    msgs = [Msg(topic="larns/station/3/estimate", data=M.encode(est(3, 1)), log_time=1, publish_time=1, sequence=1,
                encoding="msgpack", schema=""),
            Msg(topic="larns/station/3/estimate", data=M.encode(est(5, 2)), log_time=2, publish_time=2, sequence=2,
                encoding="msgpack", schema="")]
    j = collect_journals(msgs)
    assert sorted(j) == [3] and sorted(j[3].estimates) == [1]


def test_decoded_streams_attribute_by_key(recording):
    """The decoders every offline tool reads through (`decoded`, `decode_all`) drop a message
    whose src is not its key's publisher, and count it."""
    from collections import Counter

    from larns.log.reader import read_logs
    from larns.log.series import decode_all, decoded

    path, _ks = recording
    msgs = [m for lg in read_logs([path]) for m in lg.messages]
    invalid: Counter = Counter()
    got = [(m.topic, msg["src"]) for m, msg, _phy in decoded(msgs, invalid)]
    assert invalid["src_mismatch"] == 4
    assert ("larns/station/3/nav", 5) not in got and len(got) == 23
    none = [m.topic for m, msg in decode_all(msgs) if msg is None]
    assert none == ["larns/station/3/nav"] * 4
