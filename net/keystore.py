"""Writing a LARNS keystore: the certificate authority, one Ed25519 key and certificate per
enclave, the index and every enclave's Zenoh security settings (``larns keys`` is the command;
reading and checking a keystore is :class:`net.security.Keystore`; layout in docs/security.md and
:mod:`larns.commands.keys`)."""

from __future__ import annotations

import datetime as dt
import json
import os
import sys
from pathlib import Path

from .security import INDEX, Keystore, KeystoreError, aircraft_cn, station_cn, vehicle_cn, zenoh_security_json5

DEFAULT_RESERVE = 64
VALID_DAYS = 30        # an enclave's certificate: short on purpose (`larns keys renew` re-issues it)
CA_VALID_DAYS = 3650   # the CA's own certificate (its key stays with the key service, offline)
DEFAULT_HOSTS = ["localhost", "127.0.0.1"]


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


def _make_ca(name: str, days: float = CA_VALID_DAYS):
    from cryptography import x509
    from cryptography.x509.oid import NameOID

    key = _new_key()
    subj = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name),
                      x509.NameAttribute(NameOID.ORGANIZATION_NAME, "LARNS")])
    now = dt.datetime.now(dt.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(subj).issuer_name(subj).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5)).not_valid_after(now + dt.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                         content_commitment=False, key_encipherment=False,
                                         data_encipherment=False, key_agreement=False,
                                         encipher_only=False, decipher_only=False), critical=True)
            .sign(key, None))
    return key, cert


def _issue(ca_key, ca_cert, cn: str, hosts: list[str], days: float = VALID_DAYS, key=None,
           not_before: dt.datetime | None = None):
    import ipaddress

    from cryptography import x509
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    key = key or _new_key()
    now = not_before or dt.datetime.now(dt.timezone.utc)
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
            .not_valid_before(now - dt.timedelta(minutes=5)).not_valid_after(now + dt.timedelta(days=days))
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

    @property
    def valid_days(self) -> float:
        return float(self.index.get("valid_days", VALID_DAYS))

    def issue(self, cn: str, role: str, hosts: list[str] | None = None, **meta) -> bool:
        """Issue ``cn`` (role station/aircraft/vehicle/recorder/monitor/router) unless it exists. True if new."""
        if cn in self.index.setdefault("enclaves", {}) and self.path(cn, "cert.pem").is_file():
            return False
        self._write_cert(cn, None, hosts=hosts)
        self.index["enclaves"][cn] = {"role": role, **meta}
        self._save_index()
        return True

    def _write_cert(self, cn: str, key, days: float | None = None, not_before: dt.datetime | None = None,
                    hosts: list[str] | None = None):
        """Issue a certificate for ``cn`` (a new key unless ``key``) and write the enclave's files."""
        from cryptography.hazmat.primitives import serialization as ser

        ca_key, ca_cert = self._ca()
        hosts = list(dict.fromkeys([*(hosts or []), *self.index.get("hosts", DEFAULT_HOSTS)]))
        key, cert = _issue(ca_key, ca_cert, cn, hosts, self.valid_days if days is None else days, key, not_before)
        d = self.root / cn
        d.mkdir(parents=True, exist_ok=True)
        _write_private(d / "key.pem", _pem_key(key))
        (d / "cert.pem").write_bytes(cert.public_bytes(ser.Encoding.PEM))
        return cert

    def renew(self, cn: str, days: float | None = None) -> dt.datetime:
        """A new certificate for ``cn``'s key (same key, new validity); returns its expiry. Running
        receivers take it from the file or the bus; the process itself signs on as before."""
        from cryptography.hazmat.primitives import serialization as ser

        if cn not in self.enclaves or not self.path(cn, "key.pem").is_file():
            raise KeystoreError(f"{self.root}: no enclave {cn!r} to renew (see `larns keys list {self.root}`)")
        key = ser.load_pem_private_key(self.path(cn, "key.pem").read_bytes(), password=None)
        return self._write_cert(cn, key, days).not_valid_after_utc

    def revoke(self, cn: str) -> int:
        """Revoke ``cn``'s current certificate: its serial goes on the CA-signed revocation list
        (``crl.pem``, a higher number than before), its key is deleted and its certificate moved to
        ``revoked/<cn>-<serial>.pem``, so `larns keys add` can issue it anew (a new key). Returns
        the serial revoked."""
        from cryptography import x509

        p = self.path(cn, "cert.pem")
        if cn not in self.enclaves or not p.is_file():
            raise KeystoreError(f"{self.root}: no enclave {cn!r} to revoke (see `larns keys list {self.root}`)")
        serial = int(x509.load_pem_x509_certificate(p.read_bytes()).serial_number)
        revoked = self.index.setdefault("revoked", [])
        revoked.append({"cn": cn, "serial": str(serial), "at": dt.datetime.now(dt.timezone.utc).isoformat()})
        self.write_crl()
        kept = self.root / "revoked"          # the public part, kept: offline tools name the reason
        kept.mkdir(exist_ok=True)
        p.replace(kept / f"{cn}-{serial:x}.pem")
        for name in ("key.pem", "zenoh.json5"):
            self.path(cn, name).unlink(missing_ok=True)
        del self.index["enclaves"][cn]
        self._save_index()
        return serial

    def write_crl(self) -> bytes:
        """(Re)write ``crl.pem``: every serial in the index's ``revoked``, signed by the CA, with a
        number one above the last one written. Returns its DER (what goes on the bus)."""
        from net.trust import CRL_FILE

        ca_key, ca_cert = self._ca()
        number = int(self.index.get("crl_number", 0)) + 1
        pem, der = make_crl(ca_key, ca_cert, [(int(r["serial"]), r["at"]) for r in self.index.get("revoked", [])],
                            number)
        (self.root / CRL_FILE).write_bytes(pem)
        self.index["crl_number"] = number
        self._save_index()
        return der

    def write_configs(self) -> None:
        """(Re)write every enclave's zenoh.json5 (access control names every known subject)."""
        for cn in self.enclaves:
            (self.root / cn / "zenoh.json5").write_text(zenoh_security_json5(self, cn))


def init_keystore(root: str | Path, stations: list[int], aircraft: list[str] = (), recorder: bool = True,
                  reserve: list[int] | None = None, hosts: list[str] | None = None,
                  force: bool = False, valid_days: float = VALID_DAYS, vehicles: list[str] = ()) -> Keystore:
    """Create a keystore: CA, router, monitor (and recorder), one enclave per station, aircraft and
    vehicle."""
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
                                          "hosts": list(hosts or DEFAULT_HOSTS), "valid_days": float(valid_days)}))
    ks = WritableKeystore(root)
    ks.issue("router", "router")
    ks.issue("monitor", "monitor")
    if recorder:
        ks.issue("recorder", "recorder")
    for sid in stations:
        ks.issue(station_cn(sid), "station", id=int(sid))
    for name in aircraft:
        ks.issue(aircraft_cn(name), "aircraft", name=name)
    for name in vehicles:
        ks.issue(vehicle_cn(name), "vehicle", name=name)
    ks.write_configs()
    return ks


def add_to_keystore(root: str | Path, stations: list[int] = (), aircraft: list[str] = (),
                    recorder: bool = False, vehicles: list[str] = ()) -> tuple[Keystore, list[str]]:
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
    for name in vehicles:
        if ks.issue(vehicle_cn(name), "vehicle", name=name):
            new.append(vehicle_cn(name))
    if recorder and ks.issue("recorder", "recorder"):
        new.append("recorder")
    ks.write_configs()
    return ks, new


# --------------------------------------------------------------------------- revocation, hosts

def make_crl(ca_key, ca_cert, revoked: list[tuple[int, str]], number: int, next_days: float = 7.0) -> tuple[bytes, bytes]:
    """A revocation list signed by the CA: ``(PEM, DER)``; ``revoked`` is ``[(serial, ISO time)]``."""
    from cryptography import x509
    from cryptography.hazmat.primitives import serialization as ser

    now = dt.datetime.now(dt.timezone.utc)
    b = (x509.CertificateRevocationListBuilder().issuer_name(ca_cert.subject)
         .last_update(now - dt.timedelta(minutes=5)).next_update(now + dt.timedelta(days=next_days))
         .add_extension(x509.CRLNumber(int(number)), critical=False))
    for serial, at in revoked:
        b = b.add_revoked_certificate(x509.RevokedCertificateBuilder().serial_number(int(serial))
                                      .revocation_date(dt.datetime.fromisoformat(at)).build())
    crl = b.sign(ca_key, None)
    return crl.public_bytes(ser.Encoding.PEM), crl.public_bytes(ser.Encoding.DER)


def export_host(root: str | Path, out: str | Path, cns: list[str]) -> list[str]:
    """What one host needs, and nothing more: ``ca.crt``, ``keystore.json``, ``crl.pem`` (if any),
    every enclave's *public* certificate in ``certs/<cn>.pem``, and the enclaves ``cns`` in full
    (key, certificate, Zenoh settings). Never ``ca.key``. Files in ``out`` that are not part of
    this export are removed (a revoked enclave's old files). Returns the files written."""
    import shutil

    from net.trust import CERTS_DIR, CRL_FILE

    ks = Keystore(root)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for cn in cns:
        ks.check_enclave(cn)
    want: dict[str, Path] = {"ca.crt": ks.root / "ca.crt", INDEX: ks.root / INDEX}
    if (ks.root / CRL_FILE).is_file():
        want[CRL_FILE] = ks.root / CRL_FILE
    for cn in ks.enclaves:
        if ks.path(cn, "cert.pem").is_file():
            want[f"{CERTS_DIR}/{cn}.pem"] = ks.path(cn, "cert.pem")
    for cn in cns:
        for name in ("cert.pem", "key.pem", "zenoh.json5"):
            want[f"{cn}/{name}"] = ks.path(cn, name)
    for p in sorted(out.rglob("*"), reverse=True):  # stale files and folders first
        rel = p.relative_to(out).as_posix()
        if p.is_file() and rel not in want:
            p.unlink()
        elif p.is_dir() and not any(w.startswith(rel + "/") for w in want):
            shutil.rmtree(p, ignore_errors=True)
    for rel, src in want.items():
        dst = out / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        if rel.endswith("key.pem"):
            _write_private(dst, src.read_bytes())
        else:
            dst.write_bytes(src.read_bytes())
    return sorted(want)
