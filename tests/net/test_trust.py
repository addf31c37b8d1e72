"""Keys as in trusted systems (issue 32, item 3; docs/security.md "Revocation, expiry, renewal"):
the CA-signed revocation list, expiry, renewal, one host's export of a keystore, certificates
fetched over real Zenoh, and the replay window across a receiver restart."""

from __future__ import annotations

import datetime as dt
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from net import security as S
from net import trust as T
from net.keystore import WritableKeystore, add_to_keystore, export_host, init_keystore, make_crl

PY = sys.executable
ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(autouse=True)
def _state_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("LARNS_STATE_DIR", str(tmp_path / "state"))


@pytest.fixture()
def ks(tmp_path) -> Path:
    root = tmp_path / "keys"
    init_keystore(root, [1, 2, 3, 5], ["ac1"], recorder=True)
    return root


def _nav(src: int, seq: int, t: float) -> dict:
    return {"kind": "nav", "src": src, "seq": seq, "stamp_s": t, "cycle": int(t), "slot": src - 1,
            "t_tx_s": t, "pos_m": [1.0, 2.0, 3.0], "cov_m2": np.eye(3).tolist(), "n_updates": 3,
            "state": "surveying", "ranges": [[1, 100.0, t]], "members": [1, 2]}


def _signed_nav(sec: S.Security, src: int, seq: int, t: float) -> tuple[str, bytes]:
    from net import messages as M

    key = f"larns/station/{src}/nav"
    return key, sec.seal(key, M.encode(_nav(src, seq, t)))


def _reason(fn) -> str:
    with pytest.raises(S.SecurityError) as e:
        fn()
    return e.value.reason


# --------------------------------------------------------------------------- revocation list

def test_revocation_list_signature_number_and_rollback(ks, tmp_path):
    """Only a list signed by the keystore's CA is taken; a newer number replaces an older one and
    an older one is ignored (nobody rolls a revocation back by re-sending an old list)."""
    w = WritableKeystore(ks)
    der1 = w.write_crl()                                       # number 1, nothing revoked
    store = T.TrustStore(w.ca_cert())
    assert store.add_crl(der1) and store.crl.number == 1 and not store.crl.serials
    serial = w.revoke("station-5")
    der2 = (ks / "crl.pem").read_bytes()
    assert store.add_crl(der2) and store.crl.number == 2 and serial in store.crl.serials
    assert not store.add_crl(der1)                             # rollback refused
    assert serial in store.crl.serials
    # tampered: one byte of the signed body changed
    raw = bytearray(T.RevocationList.parse(der2, w.ca_cert()).der)
    raw[-80] ^= 0x01
    with pytest.raises(T.TrustError) as e:
        store.add_crl(bytes(raw))
    assert e.value.reason == "bad_crl"
    # signed by another CA (same issuer name "LARNS CA"), even with a higher number
    other = WritableKeystore(init_keystore(tmp_path / "other", [5], []).root)
    ca_key, ca_cert = other._ca()
    _, forged = make_crl(ca_key, ca_cert, [], 99)
    with pytest.raises(T.TrustError, match="not signed by the keystore's CA"):
        store.add_crl(forged)
    assert store.crl.number == 2


def test_revoked_station_refused_and_reissued_accepted(ks):
    """Revoking station 5: its samples are refused as ``revoked`` already in ``parse`` (the access
    rule, before any budget), by a receiver that had cached its key; `keys add` issues a new key
    that is accepted; the old key's signatures stay ``revoked``."""
    old5 = S.Security(ks, "station-5")
    rx = S.Verifier(S.Keystore(ks), rescan_s=0.0)
    key, frame = _signed_nav(old5, 5, 1, 10.0)
    assert rx.open(key, frame)[0] == "station-5"                # cached now
    WritableKeystore(ks).revoke("station-5")
    assert not (ks / "station-5" / "key.pem").exists()
    rx._crl_next = -1.0                                          # (the file is re-read every rescan_s)
    assert _reason(lambda: rx.open(key, frame)) == "revoked"
    assert _reason(lambda: rx.parse(key, frame)) == "revoked"
    with pytest.raises(S.KeystoreError, match="no credentials"):
        S.Security(ks, "station-5")
    add_to_keystore(ks, stations=[5])
    new5 = S.Security(ks, "station-5")
    k2, f2 = _signed_nav(new5, 5, 2, 11.0)
    assert rx.open(k2, f2)[0] == "station-5"
    assert _reason(lambda: rx.verify(key, *S.split_signed(frame))) == "revoked"


def test_router_access_rules_follow_the_revocation_list(ks):
    """What the router reopens its session with (larns/commands/router.py ``RevocationWatch``): the
    names whose every certificate is revoked, read from the keystore's files; their access rules
    removed (subject and policy), everyone else's kept; a re-issued certificate gives them back."""
    rx = S.Verifier(S.Keystore(ks), rescan_s=0.0)
    names = ["station-1", "station-3", "station-5", "aircraft-ac1", "recorder", "station-9"]
    assert rx.revoked_among(names) == frozenset()
    WritableKeystore(ks).revoke("station-5")
    assert rx.revoked_among(names) == {"station-5"}             # (station-9: never issued, not revoked)
    acl = S.access_control(S.Keystore(ks), "router")
    cut = S.without_subjects(acl, {"station-5"})
    cns = {cn for sub in cut["subjects"] for cn in sub["cert_common_names"]}
    assert "station-5" not in cns and {"station-1", "station-3", "router"} <= cns
    assert len(cut["subjects"]) == len(acl["subjects"]) - 1 == len(cut["policies"])
    assert cut["rules"] == acl["rules"] and cut["default_permission"] == "deny"
    add_to_keystore(ks, stations=[5])
    assert rx.revoked_among(names) == frozenset()                # a new certificate: usable again


def test_expired_certificate_refused_and_renewed(ks):
    """A certificate that expired in 2001 is refused (the process does not start: one line; its
    signatures: ``expired``); `keys renew` re-issues it for the same key and it is accepted again."""
    w = WritableKeystore(ks)
    s3 = S.Security(ks, "station-3")                              # before: valid
    key, frame = _signed_nav(s3, 3, 1, 10.0)
    from cryptography.hazmat.primitives import serialization as ser

    k3 = ser.load_pem_private_key((ks / "station-3" / "key.pem").read_bytes(), None)
    w._write_cert("station-3", k3, days=365, not_before=dt.datetime(2000, 1, 1, tzinfo=dt.timezone.utc))
    with pytest.raises(S.KeystoreError, match=r"expired 2000-12-31 .*larns keys renew"):
        S.Keystore(ks).check_enclave("station-3")
    rx = S.Verifier(S.Keystore(ks), rescan_s=0.0)
    assert _reason(lambda: rx.open(key, frame)) == "expired"
    p = subprocess.run([PY, "-m", "larns", "station", "--id", "3", "--scenario", "seed000", "--secure", str(ks),
                        "--duration", "1"], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert p.returncode == 2 and "expired" in p.stderr and "Traceback" not in p.stderr, p.stderr
    until = w.renew("station-3", days=2)
    assert dt.timedelta(days=1.9) < until - dt.datetime.now(dt.timezone.utc) < dt.timedelta(days=2.1)
    rx2 = S.Verifier(S.Keystore(ks), rescan_s=0.0)
    assert rx2.open(key, frame)[0] == "station-3"                # same key: old signatures still verify
    # the default lifetime is short
    cert = S.Keystore(ks).certificate("station-1")
    assert cert.not_valid_after_utc - cert.not_valid_before_utc < dt.timedelta(days=31)


def test_keys_cli_revoke_renew_export_one_line_errors(ks, tmp_path):
    def keys(*a):
        return subprocess.run([PY, "-m", "larns", "keys", *a], capture_output=True, text=True, timeout=60, cwd=ROOT)

    r = keys("revoke", str(ks), "--station", "2")
    assert r.returncode == 0 and (ks / "crl.pem").is_file(), r.stderr
    r = keys("revoke", str(ks), "--station", "2")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "no enclave 'station-2'" in r.stderr
    r = keys("renew", str(ks))
    assert r.returncode == 2 and "--station" in r.stderr and "Traceback" not in r.stderr
    r = keys("renew", str(ks), "--all", "--days", "3")
    assert r.returncode == 0 and "station-5: renewed until" in r.stderr, r.stderr
    r = keys("export", str(ks), str(tmp_path / "host"), "--enclave", "station-9")
    assert r.returncode == 2 and "station-9" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    r = keys("export", str(ks), str(tmp_path / "host"), "--enclave", "station-3")
    assert r.returncode == 0, r.stderr


def test_host_export_holds_only_its_own_key_and_verifies_everyone(ks, tmp_path):
    """One host's export: its enclave, ca.crt, the public certificates, crl.pem - no ca.key, no
    other key.pem - and a verifier on it checks every peer; a stale enclave is removed on re-export."""
    host = tmp_path / "host3"
    export_host(ks, host, ["station-3"])
    (host / "station-5").mkdir()
    (host / "station-5" / "key.pem").write_text("left over")
    WritableKeystore(ks).revoke("station-1")
    export_host(ks, host, ["station-3"])
    files = sorted(p.relative_to(host).as_posix() for p in host.rglob("*") if p.is_file())
    assert "ca.key" not in files and "crl.pem" in files
    assert [f for f in files if f.endswith("key.pem")] == ["station-3/key.pem"]
    assert "certs/station-5.pem" in files and "certs/station-1.pem" not in files
    s3 = S.Security(host, "station-3")
    s5 = S.Security(ks, "station-5")
    key, frame = _signed_nav(s5, 5, 1, 10.0)
    assert s3.verifier.open(key, frame)[0] == "station-5"
    assert s3.verifier.trust.crl is not None and s3.verifier.trust.crl.number == 1


# --------------------------------------------------------------------------- replay window

def test_replay_window_survives_a_receiver_restart(ks):
    """A receiver that accepted station 3's navs up to seq 20, then restarted, still refuses a
    replay of seq 10 (its history was saved); a receiver with no history of the sender accepts
    only a recent first message (the narrow window), not one 30 s old."""
    from net.messages import MessageError

    s3 = S.Security(ks, "station-3")
    now = [100.0]
    rx = S.Security(ks, "station-5")
    g = rx.station_guard(1.0, lambda: now[0])
    frames = {q: _signed_nav(s3, 3, q, 80.0 + q) for q in range(1, 21)}
    for q in range(1, 21):
        now[0] = 80.0 + q
        g.decode(*frames[q])
    rx.close()                                                  # (also saved as it grows)
    # restart: a new process, the same keystore and state folder
    rx2 = S.Security(ks, "station-5")
    g2 = rx2.station_guard(1.0, lambda: now[0])
    with pytest.raises(MessageError) as e:
        g2.decode(*frames[10])
    assert e.value.reason == "replayed"
    with pytest.raises(MessageError) as e:
        g2.decode(*frames[20])
    assert e.value.reason == "replayed"
    now[0] = 101.5
    assert g2.decode(*_signed_nav(s3, 3, 21, 101.0))[0]["seq"] == 21
    # a receiver that never heard station 3: a 30 s old nav (inside the 60 s window) is stale
    import os

    os.environ["LARNS_STATE_DIR"] = os.environ["LARNS_STATE_DIR"] + "-other"
    g3 = S.Security(ks, "station-1").station_guard(1.0, lambda: now[0])
    with pytest.raises(MessageError) as e:
        g3.decode(*frames[1])                                   # stamp 81 at 101.5: 20.5 s old
    assert e.value.reason == "stale"
    assert g3.decode(*frames[20])[0]["seq"] == 20               # 1.5 s old: taken; order from now on
    with pytest.raises(MessageError) as e:
        g3.decode(*frames[19])
    assert e.value.reason == "replayed"


def test_replay_history_from_another_epoch_is_forgotten(tmp_path):
    """A state file whose stamps lie beyond the receiver's clock (an earlier fleet epoch) does not
    block the new run."""
    store = T.ReplayStore(tmp_path / "r.json")
    store.flush({("station-3", "nav"): (500.0, 400)})
    g = S.ReplayGuard(60.0, 10.0, T.ReplayStore(tmp_path / "r.json"))
    g.check("station-3", {"kind": "nav", "stamp_s": 3.0, "seq": 1}, 3.5)
    g2 = S.ReplayGuard(60.0, 10.0, T.ReplayStore(tmp_path / "r.json"))
    g2._last[("station-3", "nav")] = (3.0, 1)
    with pytest.raises(S.SecurityError):
        g2.check("station-3", {"kind": "nav", "stamp_s": 3.0, "seq": 1}, 4.0)


# --------------------------------------------------------------------------- over real Zenoh

@pytest.mark.e2e
def test_certificate_fetched_over_zenoh_by_a_host_with_only_its_own_credentials(ks, tmp_path):
    """Two processes, each with only its own enclave + ca.crt (no certs/ folder): the receiver
    fetches the signer's certificate from the bus and then verifies its navs (before: `DROP
    unknown_signer`)."""
    from net.bus import Bus, free_tcp_ports

    hosts = {}
    for cn in ("station-3", "station-5"):
        hosts[cn] = tmp_path / cn
        export_host(ks, hosts[cn], [cn])
        import shutil

        shutil.rmtree(hosts[cn] / "certs")
    p3, p5 = free_tcp_ports(2)
    b5 = Bus(listen=[f"tcp/127.0.0.1:{p5}"], secure=(str(hosts["station-5"]), "station-5"))
    b3 = Bus(listen=[f"tcp/127.0.0.1:{p3}"], connect=[f"tcp/127.0.0.1:{p5}"],
             secure=(str(hosts["station-3"]), "station-3"))
    try:
        v3 = b3.security.verifier
        v3.rescan_s = 0.2
        key, frame = _signed_nav(b5.security, 5, 1, 10.0)
        reasons = []
        t_end = time.time() + 15.0
        while time.time() < t_end:
            try:
                assert v3.open(key, frame)[0] == "station-5"
                break
            except S.SecurityError as e:
                reasons.append(e.reason)
                time.sleep(0.3)
        else:
            pytest.fail(f"station-5's certificate never arrived: {reasons[-3:]}")
        assert set(reasons) <= {"unknown_signer"}
    finally:
        b3.close()
        b5.close()


def test_old_replay_histories_are_pruned(tmp_path):
    import os

    old, new = tmp_path / "replay-a-station-1-0.json", tmp_path / "replay-b-station-1-0.json"
    for p in (old, new):
        p.write_text("{}")
    os.utime(old, (time.time() - 8 * 86400, time.time() - 8 * 86400))
    assert T.prune_replay_states(tmp_path) == 1
    assert not old.exists() and new.exists()


def test_process_refuses_to_start_on_revoked_credentials(ks, tmp_path):
    """A host that still holds station 5's enclave, once the new crl.pem reaches it: station 5
    does not start there (one line, exit 2)."""
    import shutil

    host = tmp_path / "host5"
    export_host(ks, host, ["station-5"])
    WritableKeystore(ks).revoke("station-5")
    shutil.copy(ks / "crl.pem", host / "crl.pem")
    with pytest.raises(S.KeystoreError, match="revoked by"):
        S.Keystore(host).check_enclave("station-5")
    p = subprocess.run([PY, "-m", "larns", "station", "--id", "5", "--scenario", "seed000", "--secure", str(host),
                        "--duration", "1"], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert p.returncode == 2 and "revoked by" in p.stderr and "Traceback" not in p.stderr, p.stderr
    assert len(p.stderr.strip().splitlines()) == 1, p.stderr


def test_keys_init_add_list_bad_input_exit_2(ks, tmp_path):
    for args in (["init", str(ks), "--stations", "1-3"], ["add", str(tmp_path / "none"), "--station", "4"],
                 ["list", str(tmp_path / "none")], ["init", str(tmp_path / "x"), "--stations", "0-3"]):
        p = subprocess.run([PY, "-m", "larns", "keys", *args], capture_output=True, text=True, timeout=60, cwd=ROOT)
        assert p.returncode == 2 and len(p.stderr.strip().splitlines()) == 1, (args, p.stderr)
        assert "Traceback" not in p.stderr
