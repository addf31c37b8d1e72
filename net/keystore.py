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

from .security import INDEX, Keystore, KeystoreError, aircraft_cn, station_cn, zenoh_security_json5

DEFAULT_RESERVE = 64
VALID_DAYS = 3650
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
