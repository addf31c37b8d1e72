"""`larns keys`: a LARNS keystore (in the spirit of SROS2's: one certificate authority, one enclave
per process, security switched on by pointing a process at the keystore).

    larns keys init DIR --stations 1-10 --aircraft ac1 --recorder
    larns keys add DIR --station 11          # a hot-joiner, CA of DIR
    larns keys list DIR

Layout::

    DIR/keystore.json          index: reserved station ids, enclaves and their roles
    DIR/ca.crt                 the CA certificate (public: every process trusts it)
    DIR/ca.key                 the CA private key (0600; needed by `keys add` only - keep it offline)
    DIR/<cn>/cert.pem          the enclave's certificate, common name <cn>, signed by the CA
    DIR/<cn>/key.pem           the enclave's private key (0600)
    DIR/<cn>/zenoh.json5       its Zenoh security settings: TLS/mTLS links only and access control

Common names: ``station-<id>``, ``aircraft-<name>``, ``recorder``, ``monitor`` (the launcher's
observer), ``router``, ``attacker-<n>`` is never issued. Keys are Ed25519 (RFC 8032): the same key
authenticates the process's TLS links and signs its air messages (:mod:`net.security`).

The access-control rules name every **reserved** station id (default 1..64, ``--reserve``), not only
the ones issued: processes started before ``keys add --station 11`` already know the subject
``station-11``, so a hot-joiner is accepted without restarting anyone.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import sys
from pathlib import Path

from net.security import INDEX, Keystore, KeystoreError, aircraft_cn, station_cn, zenoh_security_json5

DEFAULT_RESERVE = 64
VALID_DAYS = 3650
DEFAULT_HOSTS = ["localhost", "127.0.0.1"]


def parse_ids(spec: str) -> list[int]:
    """``"1-10,12"`` -> [1, ..., 10, 12]."""
    out: list[int] = []
    for part in str(spec).split(","):
        part = part.strip()
        if not part:
            continue
        a, _, b = part.partition("-")
        lo, hi = int(a), int(b or a)
        if not 1 <= lo <= hi <= 65535:
            raise ValueError(f"bad station id range {part!r} (ids are 1..65535)")
        out.extend(range(lo, hi + 1))
    return sorted(set(out))


# --------------------------------------------------------------------------- certificates

def _write_private(path: Path, data: bytes) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def _new_key():
    from cryptography.hazmat.primitives.asymmetric import ed25519

    return ed25519.Ed25519PrivateKey.generate()


def _pem_key(key) -> bytes:
    from cryptography.hazmat.primitives import serialization as ser

    return key.private_bytes(ser.Encoding.PEM, ser.PrivateFormat.PKCS8, ser.NoEncryption())


def _make_ca(name: str):
    from cryptography import x509
    from cryptography.x509.oid import NameOID

    key = _new_key()
    subj = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name),
                      x509.NameAttribute(NameOID.ORGANIZATION_NAME, "LARNS")])
    now = dt.datetime.now(dt.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(subj).issuer_name(subj).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5)).not_valid_after(now + dt.timedelta(days=VALID_DAYS))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                         content_commitment=False, key_encipherment=False,
                                         data_encipherment=False, key_agreement=False,
                                         encipher_only=False, decipher_only=False), critical=True)
            .sign(key, None))
    return key, cert


def _issue(ca_key, ca_cert, cn: str, hosts: list[str]):
    import ipaddress

    from cryptography import x509
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    key = _new_key()
    now = dt.datetime.now(dt.timezone.utc)
    sans: list = []
    for h in hosts:
        try:
            sans.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            sans.append(x509.DNSName(h))
    cert = (x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn),
                                     x509.NameAttribute(NameOID.ORGANIZATION_NAME, "LARNS")]))
            .issuer_name(ca_cert.subject).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5)).not_valid_after(now + dt.timedelta(days=VALID_DAYS))
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                  ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
            .add_extension(x509.SubjectAlternativeName(sans), critical=False)
            .sign(ca_key, None))
    return key, cert


# --------------------------------------------------------------------------- keystore (writing)

class WritableKeystore(Keystore):
    """:class:`net.security.Keystore` plus issuing with the CA key."""

    def _save_index(self) -> None:
        (self.root / INDEX).write_text(json.dumps(self.index, indent=2, sort_keys=True) + "\n")

    def _ca(self):
        from cryptography.hazmat.primitives import serialization as ser

        kp = self.root / "ca.key"
        if not kp.is_file():
            raise KeystoreError(f"{self.root}: no ca.key (the CA's private key is needed to issue "
                                f"credentials; run `keys add` where the CA key is kept)")
        return ser.load_pem_private_key(kp.read_bytes(), password=None), self.ca_cert()

    def issue(self, cn: str, role: str, hosts: list[str] | None = None, **meta) -> bool:
        """Issue ``cn`` (role station/aircraft/recorder/monitor/router) unless it exists. True if new."""
        from cryptography.hazmat.primitives import serialization as ser

        if cn in self.index.setdefault("enclaves", {}) and self.path(cn, "cert.pem").is_file():
            return False
        ca_key, ca_cert = self._ca()
        hosts = list(dict.fromkeys([*(hosts or []), *self.index.get("hosts", DEFAULT_HOSTS)]))
        key, cert = _issue(ca_key, ca_cert, cn, hosts)
        d = self.root / cn
        d.mkdir(parents=True, exist_ok=True)
        _write_private(d / "key.pem", _pem_key(key))
        (d / "cert.pem").write_bytes(cert.public_bytes(ser.Encoding.PEM))
        self.index["enclaves"][cn] = {"role": role, **meta}
        self._save_index()
        return True

    def write_configs(self) -> None:
        """(Re)write every enclave's zenoh.json5 (access control names every known subject)."""
        for cn in self.enclaves:
            (self.root / cn / "zenoh.json5").write_text(zenoh_security_json5(self, cn))


def init_keystore(root: str | Path, stations: list[int], aircraft: list[str] = (), recorder: bool = True,
                  reserve: list[int] | None = None, hosts: list[str] | None = None,
                  force: bool = False) -> Keystore:
    """Create a keystore: CA, router, monitor (and recorder), one enclave per station and aircraft."""
    from cryptography.hazmat.primitives import serialization as ser

    root = Path(root)
    if (root / INDEX).exists() and not force:
        raise KeystoreError(f"{root} already holds a keystore (use `larns keys add`, or --force)")
    root.mkdir(parents=True, exist_ok=True)
    ca_key, ca_cert = _make_ca("LARNS CA")
    _write_private(root / "ca.key", _pem_key(ca_key))
    (root / "ca.crt").write_bytes(ca_cert.public_bytes(ser.Encoding.PEM))
    reserved = sorted(set(reserve or range(1, max(DEFAULT_RESERVE, max(stations, default=0)) + 1)) | set(stations))
    (root / INDEX).write_text(json.dumps({"version": 1, "reserved": reserved, "enclaves": {},
                                          "hosts": list(hosts or DEFAULT_HOSTS)}))
    ks = WritableKeystore(root)
    ks.issue("router", "router")
    ks.issue("monitor", "monitor")
    if recorder:
        ks.issue("recorder", "recorder")
    for sid in stations:
        ks.issue(station_cn(sid), "station", id=int(sid))
    for name in aircraft:
        ks.issue(aircraft_cn(name), "aircraft", name=name)
    ks.write_configs()
    return ks


def add_to_keystore(root: str | Path, stations: list[int] = (), aircraft: list[str] = (),
                    recorder: bool = False) -> tuple[Keystore, list[str]]:
    ks = WritableKeystore(root)
    new: list[str] = []
    for sid in stations:
        if sid not in ks.reserved:
            print(f"[keys] warning: station {sid} is not among the reserved ids; processes started "
                  f"before now will refuse it until restarted", file=sys.stderr)
            ks.index["reserved"] = sorted(set(ks.reserved) | {int(sid)})
        if ks.issue(station_cn(sid), "station", id=int(sid)):
            new.append(station_cn(sid))
    for name in aircraft:
        if ks.issue(aircraft_cn(name), "aircraft", name=name):
            new.append(aircraft_cn(name))
    if recorder and ks.issue("recorder", "recorder"):
        new.append("recorder")
    ks.write_configs()
    return ks, new


# --------------------------------------------------------------------------- recordings

def verify_recording(ks: Keystore, paths, topics=None, exclude=None) -> dict:
    """Check every signed wire sample of MCAP recordings against the keystore: ``{"checked",
    "by_reason": {...}, "by_signer": {cn: n valid}}``. Samples are checked as a live receiver would
    (signature, signer named by the key, signer is the message's source); time is not checked
    (a recording is old by nature). Unsigned samples count as ``unsigned``."""
    from collections import Counter

    from net import messages as M
    from net.security import SecurityError, Verifier

    from ..log import read_logs
    from ..log.series import decode

    def read_messages(paths, topics, exclude):
        for lg in read_logs(list(paths), topics=topics, exclude=exclude, encodings=["msgpack"], sort=False):
            yield from lg.messages

    v = Verifier(ks, rescan_s=1e9)
    reasons: Counter = Counter()
    signers: Counter = Counter()
    n = 0
    for m in read_messages(paths, topics, exclude):
        n += 1
        try:
            signer, env = v.open(m.topic, m.data)
            msg, _ = decode(env)
            src = msg["src"]
            if signer != (aircraft_cn(src) if isinstance(src, str) else station_cn(src)):
                raise SecurityError("signer_mismatch", f"{signer} sent src {src}")
        except SecurityError as e:
            reasons[e.reason] += 1
            continue
        except M.MessageError as e:
            reasons[e.reason] += 1
            continue
        signers[signer] += 1
    return {"checked": n, "valid": sum(signers.values()), "by_reason": dict(reasons), "by_signer": dict(signers)}


def cmd_verify_recordings(keystore: str, paths, topics=None, exclude=None) -> int:
    """``larns replay --secure DIR run.mcap``: verify instead of publishing (exit 1 if any sample fails)."""
    try:
        ks = Keystore(keystore)
    except KeystoreError as e:
        print(f"larns replay --secure: {e}", file=sys.stderr)
        return 2
    res = verify_recording(ks, paths, topics, exclude)
    print(json.dumps(res, indent=1, sort_keys=True))
    bad = sum(res["by_reason"].values())
    print(f"[verify] {res['valid']} of {res['checked']} samples signed by their own sender; {bad} refused "
          f"{res['by_reason'] or ''}", file=sys.stderr)
    return 1 if bad else 0


# --------------------------------------------------------------------------- command line

def _cmd_init(a: argparse.Namespace) -> int:
    try:
        ks = init_keystore(a.dir, parse_ids(a.stations), a.aircraft or [], recorder=a.recorder,
                           reserve=parse_ids(a.reserve) if a.reserve else None,
                           hosts=a.host or None, force=a.force)
    except (KeystoreError, ValueError) as e:
        print(f"larns keys: {e}", file=sys.stderr)
        return 1
    print(f"[keys] keystore {ks.root}: CA + {len(ks.enclaves)} enclaves "
          f"({', '.join(sorted(ks.enclaves))}); station ids reserved {ks.reserved[0]}..{ks.reserved[-1]}",
          file=sys.stderr)
    return 0


def _cmd_add(a: argparse.Namespace) -> int:
    try:
        ks, new = add_to_keystore(a.dir, parse_ids(a.station) if a.station else [], a.aircraft or [],
                                  recorder=a.recorder)
    except (KeystoreError, ValueError) as e:
        print(f"larns keys: {e}", file=sys.stderr)
        return 1
    print(f"[keys] {ks.root}: issued {', '.join(new) if new else 'nothing new'}", file=sys.stderr)
    return 0


def _cmd_list(a: argparse.Namespace) -> int:
    try:
        ks = Keystore(a.dir)
    except KeystoreError as e:
        print(f"larns keys: {e}", file=sys.stderr)
        return 1
    for cn, e in sorted(ks.enclaves.items()):
        try:
            ks.check_enclave(cn)
            ok = "ok"
        except KeystoreError as err:
            ok = f"BAD: {err}"
        print(f"{cn:>20}  {e['role']:>9}  {ok}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("keys", help="keystore for --secure: CA, per-process certificates, Zenoh access control",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ks = p.add_subparsers(dest="keys_cmd", required=True, metavar="ACTION")
    i = ks.add_parser("init", help="create a keystore (CA + enclaves)")
    i.add_argument("dir")
    i.add_argument("--stations", default="1-10", help="station ids to issue, e.g. 1-10 (default 1-10)")
    i.add_argument("--aircraft", action="append", metavar="NAME", help="aircraft name (repeatable)")
    i.add_argument("--recorder", action="store_true", default=True, help="issue the recorder (default)")
    i.add_argument("--no-recorder", dest="recorder", action="store_false")
    i.add_argument("--reserve", default=None,
                   help="station ids named in the access-control rules (hot-joiners must be among them; "
                        f"default 1..max({DEFAULT_RESERVE}, largest id))")
    i.add_argument("--host", action="append", metavar="NAME",
                   help="host name / address put in every certificate (repeatable; default localhost, "
                        "127.0.0.1; add the compose service names for containers)")
    i.add_argument("--force", action="store_true", help="overwrite an existing keystore")
    i.set_defaults(func=_cmd_init)
    a = ks.add_parser("add", help="issue more enclaves with the keystore's CA (e.g. a hot-joiner)")
    a.add_argument("dir")
    a.add_argument("--station", default=None, help="station id(s), e.g. 11 or 11-12")
    a.add_argument("--aircraft", action="append", metavar="NAME")
    a.add_argument("--recorder", action="store_true")
    a.set_defaults(func=_cmd_add)
    ls = ks.add_parser("list", help="enclaves and whether their credentials check out")
    ls.add_argument("dir")
    ls.set_defaults(func=_cmd_list)
