"""Security for the bus and the air messages (``--secure DIR``; docs/security.md).

Three layers, each stopping what the one below cannot:

1. **Links** (Zenoh, Rust): TLS with mutual authentication only, no tcp; every certificate is
   issued by the keystore's CA (``larns keys``). A process without credentials cannot connect.
2. **Access control** (Zenoh, Rust, enforced by *every* process on its own ingress, and by the
   router on each client's): subjects by certificate common name; station ``<id>`` may publish
   only its own keys ``larns/station/<id>/...`` (exactly those of ``net.messages.OWN_KEYS``: no
   invented sub-key), the aircraft and the vehicle likewise under ``larns/aircraft/<name>/`` and
   ``larns/vehicle/<name>/``, the recorder and monitor nothing; default deny. Peers do not relay for each other (Zenoh >= 1.9)
   and each enforces its own rules, so a peer that does not cannot speak for anyone else.
3. **Message signatures** (here): air and survey messages are relayed (router) and recorded, and
   TLS protects a link, not a message. Each sender signs ``key + envelope`` with its Ed25519 key;
   receivers (and ``larns replay --verify``) check it against the certificate of the signer the key
   names, and drop, counting by reason: ``unsigned``, ``unknown_signer``, ``signer_mismatch``,
   ``bad_signature``, ``replayed`` (sequence number and stamp not newer than the last accepted
   from that sender and kind) and ``stale`` (stamp too far from the receiver's clock).
4. **Floods** (here): a token bucket per key (a sender's nav, its requests to us, its replies to
   us) holds every sender to its TDMA-implied budget (:class:`RateLimiter`); copies of an accepted
   message are refused as replays before they spend it, and the budget is spent before the
   signature check (:class:`ReceiveGuard`).

Signed frame (the wire bytes; an unsigned envelope is plain msgpack)::

    0xC1 0x53 | u8 len | signer common name (ASCII) | 64-byte Ed25519 signature | envelope

``0xC1`` is never the first byte of a msgpack value, so a signed frame cannot be mistaken for an
envelope. The signature covers ``b"larns-sig-1\\0" + key + b"\\0" + envelope``: it binds the key
expression, so a signed nav cannot be re-published under another key.
"""

from __future__ import annotations

import json
import math
import time
from collections import Counter
from pathlib import Path
from typing import Any, Callable, Iterable

INDEX = "keystore.json"
MAGIC = b"\xc1\x53"
SIG_LEN = 64
SIG_CONTEXT = b"larns-sig-1\x00"


class KeystoreError(Exception):
    """A keystore or credential that cannot be used (missing files, wrong CA, unknown enclave)."""


def station_cn(sid: int) -> str:
    return f"station-{int(sid)}"


def aircraft_cn(name: str) -> str:
    return f"aircraft-{name}"


def vehicle_cn(name: str) -> str:
    return f"vehicle-{name}"


def sender_cn(key: str, src) -> str | None:
    """The enclave that may send a message with source ``src`` on ``key``: the key's role (station,
    aircraft, vehicle) with that source (None: no LARNS sender)."""
    role = str(key).split("/")[1] if str(key).count("/") >= 2 else ""
    if role == "station":
        return station_cn(src) if isinstance(src, int) and not isinstance(src, bool) else None
    if role in ("aircraft", "vehicle") and isinstance(src, str):
        return f"{role}-{src}"
    return None


# --------------------------------------------------------------------------- keystore (reading)

class Keystore:
    """A keystore folder made by ``larns keys`` (layout in :mod:`larns.keys`)."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        idx = self.root / INDEX
        if not idx.is_file():
            raise KeystoreError(f"{self.root}: not a LARNS keystore (no {INDEX}; make one with "
                                f"`larns keys init {self.root} --stations 1-10`)")
        try:
            self.index = json.loads(idx.read_text())
        except (OSError, ValueError) as e:
            raise KeystoreError(f"{idx}: unreadable ({e})") from None
        if not (self.root / "ca.crt").is_file():
            raise KeystoreError(f"{self.root}: no ca.crt")

    @property
    def reserved(self) -> list[int]:
        return [int(i) for i in self.index.get("reserved", [])]

    @property
    def enclaves(self) -> dict[str, dict]:
        return dict(self.index.get("enclaves", {}))

    @property
    def aircraft(self) -> list[str]:
        return sorted(e["name"] for e in self.enclaves.values() if e.get("role") == "aircraft")

    @property
    def vehicles(self) -> list[str]:
        return sorted(e["name"] for e in self.enclaves.values() if e.get("role") == "vehicle")

    def path(self, cn: str, name: str) -> Path:
        return self.root / cn / name

    def ca_cert(self):
        from cryptography import x509

        return x509.load_pem_x509_certificate((self.root / "ca.crt").read_bytes())

    def check_enclave(self, cn: str) -> None:
        """Raise :class:`KeystoreError` unless ``cn`` has a key, a config and a certificate with
        common name ``cn`` issued by this keystore's CA, matching the key."""
        from cryptography.hazmat.primitives import serialization as ser

        for name in ("cert.pem", "key.pem", "zenoh.json5"):
            if not self.path(cn, name).is_file():
                raise KeystoreError(f"no credentials for {cn!r} in {self.root} (missing {cn}/{name}); "
                                    f"issue them with `larns keys add {self.root} ...`")
        cert = self.certificate(cn)
        try:
            key = ser.load_pem_private_key(self.path(cn, "key.pem").read_bytes(), password=None)
        except (OSError, ValueError, TypeError) as e:
            raise KeystoreError(f"{cn}: cannot load key.pem: {e}") from None
        raw = (ser.Encoding.Raw, ser.PublicFormat.Raw)
        if key.public_key().public_bytes(*raw) != cert.public_key().public_bytes(*raw):
            raise KeystoreError(f"{cn}: key.pem does not match cert.pem")

    def certificate(self, cn: str):
        """The CA-verified certificate of ``cn`` (raises :class:`KeystoreError`)."""
        from cryptography import x509
        from cryptography.x509.oid import NameOID

        p = self.path(cn, "cert.pem")
        try:
            cert = x509.load_pem_x509_certificate(p.read_bytes())
        except (OSError, ValueError) as e:
            raise KeystoreError(f"{cn}: cannot load cert.pem: {e}") from None
        got = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
        if not got or got[0].value != cn:
            raise KeystoreError(f"{p}: common name is not {cn!r}")
        try:
            cert.verify_directly_issued_by(self.ca_cert())
        except Exception as e:
            raise KeystoreError(f"{p}: not issued by {self.root}/ca.crt ({type(e).__name__})") from None
        self._check_current(p, cert)
        return cert

    def _check_current(self, p: Path, cert) -> None:
        """Raise :class:`KeystoreError` if ``cert`` is expired, not yet valid or revoked by the
        keystore's ``crl.pem`` (a process does not start on such credentials)."""
        from net.trust import CRL_FILE, RevocationList, TrustError

        now = time.time()
        nb, na = cert.not_valid_before_utc.timestamp(), cert.not_valid_after_utc.timestamp()
        if not nb <= now <= na:
            when = cert.not_valid_after_utc if now > na else cert.not_valid_before_utc
            raise KeystoreError(f"{p}: {'expired' if now > na else 'not valid before'} {when:%Y-%m-%d %H:%M} UTC "
                                f"(renew it with `larns keys renew {self.root} ...`)")
        crl = self.root / CRL_FILE
        if crl.is_file():
            try:
                rl = RevocationList.parse(crl.read_bytes(), self.ca_cert())
            except TrustError as e:
                raise KeystoreError(f"{crl}: {e}") from None
            if int(cert.serial_number) in rl.serials:
                raise KeystoreError(f"{p}: revoked by {crl} (issue new credentials with `larns keys add`)")

    def signer(self, cn: str) -> "Signer":
        from cryptography.hazmat.primitives import serialization as ser

        self.check_enclave(cn)
        return Signer(cn, ser.load_pem_private_key(self.path(cn, "key.pem").read_bytes(), password=None))


def load_keystore(root: str | Path, cn: str) -> Keystore:
    """The keystore with ``cn``'s credentials checked: what a ``--secure`` process calls first."""
    ks = Keystore(root)
    ks.check_enclave(cn)
    return ks


# --------------------------------------------------------------------------- Zenoh configuration

_ALL_MSGS = ["put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
             "liveliness_token", "declare_liveliness_subscriber", "liveliness_query"]
_OBSERVE = ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"]


def station_subscriptions(sid: int) -> list[str]:
    """What a station may subscribe to (docs/protocol.md): the navs of any tile (net/tiles.py: it
    subscribes to those within its radio reach) or of none (a replayed recording from before tiles),
    and the requests and replies addressed to it (protocol v2: every poll, the replies to its own)."""
    return ["larns/station/*/nav/**", f"larns/station/*/range/req/{sid}", f"larns/station/*/range/rsp/{sid}",
            "larns/station/*/poll", f"larns/station/*/reply/{sid}"]


def access_control(ks: Keystore, me: str) -> dict:
    """Zenoh ``access_control`` section for process ``me``: what it accepts from each subject on
    its ingress (one subject per common name; default deny). Egress is allowed to every subject
    (ours to send); the peers' and the router's ingress rules limit what each may receive."""
    from net.messages import OWN_KEYS

    rules: list[dict] = []
    subjects: list[dict] = []
    policies: list[dict] = []

    def rule(rid: str, messages: list[str], keys: list[str], flows=("ingress",)) -> str:
        rules.append({"id": rid, "messages": list(messages), "flows": list(flows),
                      "permission": "allow", "key_exprs": list(keys)})
        return rid

    def subject(sid: str, cns: list[str], rule_ids: list[str]) -> None:
        subjects.append({"id": sid, "cert_common_names": cns})
        policies.append({"id": "p-" + sid, "rules": [*rule_ids, "trust-all"], "subjects": [sid]})

    everyone = rule("egress-all", _ALL_MSGS, ["larns/**"], flows=("egress",))
    # certificates and the revocation list (net/trust.py): CA-signed, so anyone may carry them
    rule("trust-all", ["put", "declare_subscriber", "query", "reply", "declare_queryable"],
                 ["larns/trust/**"])
    observe = rule("observe-all", _OBSERVE, ["larns/**"])
    for sid in ks.reserved:
        r_pub = rule(f"pub-station-{sid}", ["put"], [f"larns/station/{sid}/{k}" for k in OWN_KEYS["station"]])
        r_tok = rule(f"tok-station-{sid}", ["liveliness_token"], [f"larns/alive/station/{sid}"])
        r_sub = rule(f"sub-station-{sid}", ["declare_subscriber"], station_subscriptions(sid))
        subject(station_cn(sid), [station_cn(sid)], [everyone, r_pub, r_tok, r_sub])
    for role, names in (("aircraft", ks.aircraft), ("vehicle", ks.vehicles)):  # users: hear navs, speak for themselves
        for name in names:
            r_pub = rule(f"pub-{role}-{name}", ["put"], [f"larns/{role}/{name}/{k}" for k in OWN_KEYS[role]])
            r_tok = rule(f"tok-{role}-{name}", ["liveliness_token"], [f"larns/alive/{role}/{name}"])
            r_sub = rule(f"sub-{role}-{name}", ["declare_subscriber"], ["larns/station/*/nav/**"])
            subject(f"{role}-{name}", [f"{role}-{name}"], [everyone, r_pub, r_tok, r_sub])
    r_rtok = rule("tok-recorder", ["liveliness_token"], ["larns/alive/recorder/**"])
    subject("recorder", ["recorder"], [everyone, observe, r_rtok])
    subject("monitor", ["monitor"], [everyone, observe])
    # the router relays everyone's traffic; its own ingress rules held each client to its part
    r_router = rule("router-relay", _ALL_MSGS, ["larns/**"])
    subject("router", ["router"], [everyone, r_router])
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def tls_settings(ks: Keystore, cn: str) -> dict:
    root = ks.root.resolve()
    cert, key = str(root / cn / "cert.pem"), str(root / cn / "key.pem")
    return {"root_ca_certificate": str(root / "ca.crt"), "enable_mtls": True,
            "listen_certificate": cert, "listen_private_key": key,
            "connect_certificate": cert, "connect_private_key": key,
            "verify_name_on_connect": False}


def security_settings(ks: Keystore, cn: str) -> dict[str, Any]:
    """``{config path: value}`` to insert into a Zenoh config: TLS-only links with mTLS, access control."""
    return {"transport/link/protocols": ["tls"],
            "transport/link/tls": tls_settings(ks, cn),
            "access_control": access_control(ks, cn)}


def zenoh_security_json5(ks: Keystore, cn: str) -> str:
    """The enclave's Zenoh security settings as a JSON5 config file (endpoints and mode are given
    on the command line; ``--zenoh-config`` users can merge it into theirs)."""
    s = security_settings(ks, cn)
    conf = {"transport": {"link": {"protocols": s["transport/link/protocols"], "tls": s["transport/link/tls"]}},
            "access_control": s["access_control"]}
    return f"// LARNS enclave {cn}: TLS/mTLS links only + access control (generated by `larns keys`)\n" \
           + json.dumps(conf, indent=2) + "\n"


def load_enclave_settings(root: str | Path, cn: str) -> dict[str, Any]:
    """The ``{config path: value}`` settings from ``DIR/<cn>/zenoh.json5`` (JSON written by ``larns
    keys``), after checking the credentials. Raises :class:`KeystoreError` with a clear message."""
    ks = load_keystore(root, cn)
    text = ks.path(cn, "zenoh.json5").read_text()
    body = "\n".join(line for line in text.splitlines() if not line.lstrip().startswith("//"))
    try:
        conf = json.loads(body)
        acl = conf["access_control"]
        if not isinstance(acl, dict) or acl.get("default_permission") != "deny":
            raise ValueError("access_control must default to deny")
    except (ValueError, KeyError, TypeError) as e:
        raise KeystoreError(f"{ks.path(cn, 'zenoh.json5')}: not a LARNS enclave config ({e})") from None
    # file paths from where the keystore is now (a container may mount it elsewhere)
    return {"transport/link/protocols": ["tls"], "transport/link/tls": tls_settings(ks, cn),
            "access_control": acl}


def without_subjects(acl: dict, cns: Iterable[str]) -> dict:
    """Zenoh ``access_control`` ``acl`` without the subjects of common names ``cns`` (and their
    policies): under default deny, Zenoh then refuses everything those identities send."""
    gone = set(cns)
    subjects = [s for s in acl.get("subjects", []) if not set(s.get("cert_common_names", [])) <= gone]
    kept = {s["id"] for s in subjects}
    policies = [p for p in acl.get("policies", []) if set(p.get("subjects", [])) <= kept]
    return {**acl, "subjects": subjects, "policies": policies}


def apply_security(conf, root: str | Path, cn: str, guard: list[dict] | None = None,
                   revoked: Iterable[str] = ()) -> None:
    """Insert ``cn``'s security settings into a ``zenoh.Config``, turn its endpoints to tls/, and
    add the Zenoh ingress flood guard ``guard`` (:func:`flood_guard`) unless it is a client; the
    common names ``revoked`` lose their access rules (:func:`without_subjects`)."""
    for key, value in load_enclave_settings(root, cn).items():
        if key == "access_control" and revoked:
            value = without_subjects(value, revoked)
        conf.insert_json5(key, json.dumps(value))
    if guard and json.loads(conf.get_json("mode")) != "client":
        conf.insert_json5("downsampling", json.dumps(guard))
    for which in ("listen/endpoints", "connect/endpoints"):
        try:
            eps = json.loads(conf.get_json(which))
        except Exception:
            continue
        if isinstance(eps, list) and eps:
            conf.insert_json5(which, json.dumps([secure_endpoint(e) for e in eps if isinstance(e, str)]))


def secure_endpoint(ep: str) -> str:
    """``tcp/HOST:PORT`` -> ``tls/HOST:PORT`` (secure processes speak TLS only)."""
    return "tls/" + ep[4:] if ep.startswith("tcp/") else ep


# --------------------------------------------------------------------------- flood guard (Zenoh)

def rate_limits_on() -> bool:
    """``LARNS_RATE_LIMITS=off`` switches the flood guard and the per-key budgets off (tests
    that must see every hostile payload reach the decoder; debugging). On by default."""
    import os

    return os.environ.get("LARNS_RATE_LIMITS", "on").lower() not in ("off", "0", "no", "false")


def flood_guard(cycle_s: float, slot_s: float, speed: float = 1.0, ids=(), me: int | None = None,
                pair_ids=(), nav_keys: dict | None = None) -> list[dict]:
    """Zenoh ``downsampling`` for a peer's or the router's ingress. Zenoh keeps one state per rule
    *and per link*, and peers link directly to each other (a client only to its router), so on a
    peer and on the router each rule caps one remote process. A LARNS station sends each of these
    keys at most once per cycle (an addressed reply once per requesting slot; protocol v2: a poll per
    cycle, a reply to each poller per cycle); the caps leave 4x headroom and
    drop the rest in Rust, before any Python runs. Not for clients: their one link carries
    everyone's traffic (the router caps it per client).

    The installed Zenoh (1.10) matches a rule only on its exact key (a rule with a ``*`` inside
    did not match our keys in our experiment), so the rules are spelled out for each station id in
    ``ids``: a station ``me`` caps what it subscribes to (nav, requests and replies addressed to it);
    the router (``me`` None) caps every id's nav, estimate, truth and init, and the requests and
    replies between the ids in ``pair_ids``. The journal (``.../input``, sent in bursts of chunks)
    and the aircraft's keys are not capped here (the receivers' :class:`RateLimiter` counts them).
    ``nav_keys`` ``{id: key}``: each station's nav key with its tile (net/tiles.py
    ``station_nav_keys``), capped beside the tile-less ``larns/station/<id>/nav`` (both are allowed)."""
    if not rate_limits_on():
        return []
    per_cycle = 4.0 * speed / cycle_s       # Hz, wall: 4 per cycle
    per_slot = 2.0 * speed / slot_s         # Hz, wall: 2 per slot
    rules: list[dict] = []

    def navs(k) -> list[str]:  # a station's nav key with its tile, and the tile-less one (both allowed)
        return [x for x in ((nav_keys or {}).get(k), f"larns/station/{k}/nav") if x is not None]

    for k in ids:
        if me is not None:
            if k == me:
                continue
            rules += [{"key_expr": x, "freq": per_cycle} for x in navs(k)]
            rules += [{"key_expr": f"larns/station/{k}/{x}", "freq": per_cycle}
                      for x in (f"range/req/{me}", f"range/rsp/{me}", "poll", f"reply/{me}")]
        else:
            rules += [{"key_expr": x, "freq": per_cycle} for x in navs(k)]
            rules += [{"key_expr": f"larns/station/{k}/{x}", "freq": per_cycle}
                      for x in ("estimate", "truth", "init", "poll")]
    if me is None:
        for k in pair_ids:
            for j in pair_ids:
                if j != k:
                    rules += [{"key_expr": f"larns/station/{k}/range/req/{j}", "freq": per_cycle},
                              {"key_expr": f"larns/station/{k}/range/rsp/{j}", "freq": per_slot},
                              {"key_expr": f"larns/station/{k}/reply/{j}", "freq": per_cycle}]
    if not rules:
        return []
    return [{"id": "larns-flood-guard", "flows": ["ingress"], "messages": ["put"], "rules": rules}]


# --------------------------------------------------------------------------- signatures

def _message_error():
    from net.messages import MessageError  # (net.messages imports this module lazily)

    return MessageError


class SecurityError(ValueError):
    """A message refused by the security layer; ``reason`` is the drop counter's tag. Raised to
    receivers as a :class:`net.messages.MessageError` (see :func:`refused`)."""

    def __init__(self, reason: str, detail: str = ""):
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason


def refused(reason: str, detail: str = "") -> Exception:
    """A :class:`net.messages.MessageError` with a security ``reason`` (what receivers count)."""
    return _message_error()(reason, detail)


def split_signed(data: bytes) -> tuple[str, bytes, bytes] | None:
    """``(signer, signature, envelope)`` of a signed frame; None if ``data`` is not one. Raises
    :class:`SecurityError` ("bad_frame") on a truncated or garbled frame."""
    if data[:2] != MAGIC:
        return None
    if len(data) < 3:
        raise SecurityError("bad_frame", "truncated")
    n = data[2]
    end = 3 + n + SIG_LEN
    if n == 0 or len(data) <= end:
        raise SecurityError("bad_frame", "truncated")
    try:
        signer = bytes(data[3:3 + n]).decode("ascii")
    except UnicodeDecodeError:
        raise SecurityError("bad_frame", "signer not ASCII") from None
    return signer, bytes(data[3 + n:end]), bytes(data[end:])


def strip_signature(data: bytes) -> bytes:
    """The envelope inside a signed frame (not verified: for offline tools); ``data`` otherwise."""
    try:
        parts = split_signed(data)
    except SecurityError:
        return data
    return data if parts is None else parts[2]


def _signed_bytes(key: str, envelope: bytes) -> bytes:
    return SIG_CONTEXT + key.encode() + b"\x00" + envelope


class Signer:
    """Signs envelopes with one enclave's Ed25519 key."""

    def __init__(self, cn: str, private_key):
        self.cn = cn
        self._key = private_key
        self._head = MAGIC + bytes([len(cn)]) + cn.encode("ascii")

    def seal(self, key: str, envelope: bytes) -> bytes:
        return self._head + self._key.sign(_signed_bytes(key, envelope)) + envelope


def expected_signer(key: str) -> str | None:
    """The only common name allowed to sign samples on ``key`` (None: not a LARNS key)."""
    parts = str(key).split("/")
    if len(parts) < 3 or parts[0] != "larns":
        return None
    if parts[1] == "station":
        return f"station-{parts[2]}" if parts[2].isdigit() else None
    if parts[1] in ("aircraft", "vehicle"):
        return f"{parts[1]}-{parts[2]}"
    return None


class Verifier:
    """Checks signed frames against CA-issued certificates that are usable now (not expired, not
    revoked: :class:`net.trust.TrustStore`). A signer's certificate is looked for in the keystore
    (``<cn>/cert.pem``, else the public ``certs/<cn>.pem``) and, once :meth:`set_fetch` is given
    a way, fetched from the bus; an unknown signer is looked up again at most every ``rescan_s``
    (a hot-joiner's certificate issued after we started, `larns keys add`). The keystore's
    revocation list (``crl.pem``) is re-read when it changes (checked at most every ``rescan_s``);
    one that arrives on the bus (:func:`net.trust.attach_trust`) counts from the next sample."""

    def __init__(self, ks: Keystore, rescan_s: float = 2.0, clock: Callable[[], float] = time.monotonic,
                 wall_s: Callable[[], float] = time.time):
        from net.trust import TrustStore

        self.ks = ks
        self.rescan_s = rescan_s
        self.clock = clock
        self.wall_s = wall_s
        self.trust = TrustStore(ks.ca_cert())
        self._fetch: Callable[[str], None] | None = None
        self._missing: dict[str, float] = {}
        self._crl_seen: tuple | None = None
        self._crl_next = -math.inf
        self._crl_file()

    def set_fetch(self, fetch: Callable[[str], None] | None) -> None:
        """``fetch(cn)``: ask the bus for ``cn``'s certificate (asynchronous)."""
        self._fetch = fetch

    def _crl_file(self) -> None:
        from net.trust import CRL_FILE, TrustError

        self._crl_next = self.clock() + self.rescan_s
        p = self.ks.root / CRL_FILE
        try:
            st = p.stat()
        except OSError:
            return
        if (st.st_mtime_ns, st.st_size) == self._crl_seen:
            return
        self._crl_seen = (st.st_mtime_ns, st.st_size)
        try:
            self.trust.add_crl(p.read_bytes())
        except (OSError, TrustError):
            pass

    def _look_up(self, cn: str) -> None:
        now = self.clock()
        if now - self._missing.get(cn, -math.inf) < self.rescan_s:
            return
        self._missing[cn] = now
        self._crl_file()
        self.load_certs(cn)
        if self._fetch is not None:
            self._fetch(cn)

    def load_certs(self, cn: str) -> None:
        """Take ``cn``'s certificates from the keystore's files (its enclave, ``certs/``, ``revoked/``)."""
        from net.trust import CERTS_DIR, TrustError

        for p in (self.ks.path(cn, "cert.pem"), self.ks.root / CERTS_DIR / f"{cn}.pem",
                  *sorted((self.ks.root / "revoked").glob(f"{cn}-*.pem"))):
            try:
                self.trust.add_cert(p.read_bytes(), cn)
            except (OSError, TrustError):
                continue

    def revoked_among(self, cns: Iterable[str], load: bool = True) -> frozenset[str]:
        """The common names among ``cns`` whose every certificate held is revoked by the newest
        list (the keystore's ``crl.pem`` re-read if due, or one taken from the bus); the
        certificates of a name not held yet or revoked are read from the keystore's files again (at
        most every ``rescan_s``: a re-issued one makes the name usable again) if ``load``."""
        if self.clock() >= self._crl_next:
            self._crl_file()
        if self.trust.crl is None:
            return frozenset()
        now, out = self.wall_s(), set()
        for cn in cns:
            if load and self.trust.status(cn, now) in ("unknown_signer", "revoked"):
                t = self.clock()
                if t - self._missing.get(cn, -math.inf) >= self.rescan_s:
                    self._missing[cn] = t
                    self.load_certs(cn)
            if self.trust.status(cn, now) == "revoked":
                out.add(cn)
        return frozenset(out)

    def public_keys(self, cn: str) -> list:
        """Public keys of ``cn``'s certificates usable now (looked up if there is none)."""
        if self.clock() >= self._crl_next:
            self._crl_file()
        keys = self.trust.keys(cn, self.wall_s())
        if not keys:
            self._look_up(cn)
            keys = self.trust.keys(cn, self.wall_s())
        return keys

    def public_key(self, cn: str):
        keys = self.public_keys(cn)
        return keys[0] if keys else None

    def parse(self, key: str, data: bytes) -> tuple[str, bytes, bytes]:
        """``(signer, signature, envelope)`` of a frame on ``key`` whose signer may sign on ``key``
        and is not revoked; the signature is not checked yet (:meth:`verify`). Raises
        :class:`SecurityError`."""
        parts = split_signed(data)
        if parts is None:
            raise SecurityError("unsigned", key)
        signer, sig, env = parts
        want = expected_signer(key)
        if want is None or signer != want:
            raise SecurityError("signer_mismatch", f"{signer} on {key}")
        if not signer.replace("-", "").replace("_", "").isalnum() or len(signer) > 64:
            raise SecurityError("unknown_signer", signer[:64])
        if self.trust.status(signer, self.wall_s()) == "revoked":  # access rule: a revoked signer
            self._look_up(signer)                                   # is refused before its budget
            if self.trust.status(signer, self.wall_s()) == "revoked":  # (unless re-issued since)
                raise SecurityError("revoked", signer)
        return signer, sig, env

    def verify(self, key: str, signer: str, sig: bytes, env: bytes) -> None:
        """Check ``sig`` over ``key`` and ``env`` against ``signer``'s usable certificates
        (~50 us); a signature by a revoked key is refused as ``revoked``, a signer with no usable
        certificate as ``unknown_signer``, ``expired`` or ``revoked``."""
        from cryptography.exceptions import InvalidSignature

        data = _signed_bytes(key, env)
        keys = self.public_keys(signer)
        for pk in keys:
            try:
                pk.verify(sig, data)
                return
            except InvalidSignature:
                continue
        if not keys:
            st = self.trust.status(signer, self.wall_s())
            raise SecurityError("unknown_signer" if st == "ok" else st, signer)
        for reason, pk in self.trust.unusable_keys(signer):
            try:
                pk.verify(sig, data)
            except InvalidSignature:
                continue
            raise SecurityError(reason, f"{signer} on {key}")
        raise SecurityError("bad_signature", f"{signer} on {key}")

    def open(self, key: str, data: bytes) -> tuple[str, bytes]:
        """``(signer, envelope)`` of a valid frame on ``key``; raises :class:`SecurityError`."""
        signer, sig, env = self.parse(key, data)
        self.verify(key, signer, sig, env)
        return signer, env


class ReplayGuard:
    """Per (signer, kind): accept a message only if ``(stamp_s, seq)`` is newer than the last one
    accepted (a restarted sender's sequence restarts, its stamps do not), and only if its stamp is
    within ``window_s`` of the receiver's fleet time (an old recording replayed is stale).

    A sender this receiver holds no history of gets the narrower ``fresh_window_s``: a message
    replayed to a receiver that never heard the original must be that recent. With ``store``
    (:class:`net.trust.ReplayStore`) the history survives a restart of the receiver: it is loaded
    at start and saved as it grows; entries newer than the receiver's clock allows (a file from
    another fleet epoch) are forgotten at the first message."""

    def __init__(self, window_s: float, fresh_window_s: float | None = None, store=None):
        self.window_s = float(window_s)
        self.fresh_window_s = self.window_s if fresh_window_s is None else min(float(fresh_window_s), self.window_s)
        self.store = store
        self._last: dict[tuple[str, str], tuple[float, int]] = store.load() if store is not None else {}
        self._purge = bool(self._last)

    def peek(self, signer: str, msg: dict, now_s: float) -> None:
        """Raise ``stale`` or ``replayed`` as :meth:`check` would, without recording anything (a
        copy is refused before it costs a signature check or its sender's budget)."""
        stamp, seq = float(msg["stamp_s"]), int(msg["seq"])
        if self._purge:  # loaded history from another epoch would refuse the new one's stamps
            self._purge = False
            self._last = {k: v for k, v in self._last.items() if v[0] <= now_s + self.fresh_window_s}
        if abs(stamp - now_s) > self.window_s:
            raise SecurityError("stale", f"{signer} {msg['kind']} stamp {stamp:.3f} s at {now_s:.3f} s")
        last = self._last.get((signer, msg["kind"]))
        if last is None and abs(stamp - now_s) > self.fresh_window_s:
            raise SecurityError("stale", f"{signer} {msg['kind']} first stamp {stamp:.3f} s at {now_s:.3f} s")
        if last is not None and (stamp, seq) <= last:
            raise SecurityError("replayed", f"{signer} {msg['kind']} seq {seq}")

    def record(self, signer: str, msg: dict) -> None:
        """Remember an accepted (verified) message as its sender's newest."""
        self._last[(signer, msg["kind"])] = (float(msg["stamp_s"]), int(msg["seq"]))
        if self.store is not None:
            self.store.maybe_save(self._last)

    def flush(self) -> None:
        """Save the history now (a receiver that stops)."""
        if self.store is not None:
            self.store.flush(self._last)

    def check(self, signer: str, msg: dict, now_s: float) -> None:
        self.peek(signer, msg, now_s)
        self.record(signer, msg)


class RateLimiter:
    """Token buckets per source (a key, or a sender): ``rate`` messages per second, ``burst`` at
    most at once. ``allow(source, now_s)`` is O(1) and runs before any decoding, so a flood costs a
    dict lookup.

    Time: with ``clock`` (e.g. :func:`monotonic_fleet_clock`) the buckets refill on that clock and
    ``now_s`` is ignored; without, on the ``now_s`` given. Either way time never runs backwards for
    a bucket: a step back (a wall clock set back 30 s) refills nothing and blocks nothing."""

    def __init__(self, rate_per_s: float, burst: float, max_sources: int = 4096,
                 clock: Callable[[], float] | None = None):
        self.rate = float(rate_per_s)
        self.burst = float(burst)
        self.max_sources = max_sources
        self.clock = clock
        self._b: dict[Any, list[float]] = {}
        self.throttled: Counter = Counter()

    def allow(self, source: Any, now_s: float | None = None) -> bool:
        if self.clock is not None or now_s is None:
            now_s = (self.clock or time.monotonic)()
        b = self._b.get(source)
        if b is None:
            if len(self._b) >= self.max_sources:
                self._b.clear()  # bounded memory under a flood of fake sources
            b = self._b[source] = [self.burst, now_s]
        tokens = min(self.burst, b[0] + max(now_s - b[1], 0.0) * self.rate)
        b[1] = now_s
        if tokens < 1.0:
            b[0] = tokens
            self.throttled[source] += 1
            return False
        b[0] = tokens - 1.0
        return True


def monotonic_fleet_clock(speed: float = 1.0) -> Callable[[], float]:
    """Seconds at fleet rate (``speed`` fleet seconds per wall second) from the monotonic clock: what
    a receiver's rate limiter runs on (a wall-clock step changes fleet time, not this)."""
    speed = float(speed)
    return lambda: time.monotonic() * speed


STALE_S = 60.0  # fleet seconds: a stamp further than this from the receiver's clock is stale
FRESH_S = 10.0  # fleet seconds (or 5 cycles): the same for a sender the receiver has no history of
RECORDER_BUDGET = (200.0, 400.0)  # per source: messages per wall second, burst


def source_of(key: str) -> str:
    """``larns/station/7/nav`` -> ``station/7`` (the publisher, authenticated by access control)."""
    parts = str(key).split("/", 3)
    return "/".join(parts[1:3]) if len(parts) >= 3 else str(key)[:64]


class ReceiveGuard:
    """What a ``--secure`` receiver runs on every sample, cheapest test first: frame and signer
    allowed on the key -> strict decode -> signer is the message's source -> replay/staleness
    (checked, not yet recorded) -> budget of the key -> signature -> replay recorded.

    A copy of an accepted message (what a flooder re-sends cheapest) is refused as ``replayed``
    or ``stale`` before it spends anyone's budget, and the budgets are per key (a station's nav,
    its requests to us, its replies to us), so a flood on one key leaves the sender's other keys
    alone. :meth:`decode` returns ``(msg, phy)`` like :func:`net.messages.decode` and raises its
    :class:`~net.messages.MessageError` with the reason (``rate``, ``unsigned``, ``bad_frame``,
    ``bad_signature``, ``unknown_signer``, ``signer_mismatch``, ``replayed``, ``stale``, or a
    schema reason)."""

    def __init__(self, verifier: Verifier | None, limiter: RateLimiter | None, replay: ReplayGuard | None,
                 now_s: Callable[[], float], own_source: str | None = None):
        from net.messages import decode

        self.own_source = own_source  # our own samples (local delivery): decoded, never counted
        self.verifier = verifier
        self.limiter = limiter
        self.replay = replay
        self.now_s = now_s
        self._decode = decode

    def decode(self, key: str, data: bytes) -> tuple[dict, dict | None]:
        if self.own_source is not None and source_of(key) == self.own_source:
            return self._decode(data)
        now = self.now_s()
        if self.verifier is None:
            if self.limiter is not None and not self.limiter.allow(key, now):
                raise refused("rate", key)
            return self._decode(data)
        try:
            signer, sig, env = self.verifier.parse(key, bytes(data))
        except SecurityError as e:
            raise refused(e.reason, str(e)) from None
        msg, phy = self._decode(env)
        src = msg["src"]
        if signer != sender_cn(key, src):
            raise refused("signer_mismatch", f"{signer} sent src {src}")
        try:
            if self.replay is not None:
                self.replay.peek(signer, msg, now)
            if self.limiter is not None and not self.limiter.allow(key, now):
                raise SecurityError("rate", key)
            self.verifier.verify(key, signer, sig, env)
        except SecurityError as e:
            raise refused(e.reason, str(e)) from None
        if self.replay is not None:
            self.replay.record(signer, msg)
        return msg, phy


# --------------------------------------------------------------------------- per-process bundle

class Security:
    """A ``--secure`` process's credentials: signer, verifier, receive guards. ``None`` everywhere
    it is used means an insecure process."""

    def __init__(self, root: str | Path, cn: str):
        self.root = str(root)
        self.cn = cn
        self.ks = load_keystore(root, cn)
        self.signer = self.ks.signer(cn)
        self.verifier = Verifier(self.ks)
        self.verifier.trust.add_cert(self.ks.certificate(cn))  # ours, served on the bus
        self._replay: list[ReplayGuard] = []
        self._guarded = False
        self._trust_bus: dict | None = None

    @property
    def verifies(self) -> bool:
        """Whether this process made a receive guard (which loads signers' certificates on its own
        thread): then a revocation watch must only read the trust store."""
        return self._guarded

    def attach(self, bus) -> None:
        """On a running bus: serve our certificate and the newest revocation list, take lists put
        on the bus, fetch unknown signers' certificates (:func:`net.trust.attach_trust`)."""
        from net.trust import attach_trust

        self._trust_bus = attach_trust(bus, self.verifier.trust, self.cn)
        self.verifier.set_fetch(self._trust_bus["fetch"])

    def close(self) -> None:
        """Save the receive guards' replay history (also saved as it grows)."""
        for g in self._replay:
            g.flush()

    def replay_guard(self, window_s: float, fresh_window_s: float | None = None) -> ReplayGuard:
        """A replay guard whose history survives a restart (:func:`net.trust.replay_state_path`)."""
        from cryptography.hazmat.primitives import serialization as ser

        from net.trust import ReplayStore, replay_state_path

        path = replay_state_path(self.ks.ca_cert().public_bytes(ser.Encoding.DER), f"{self.cn}-{len(self._replay)}")
        if not self._replay:
            from net.trust import prune_replay_states

            prune_replay_states(path.parent)
        g = ReplayGuard(window_s, fresh_window_s, ReplayStore(path))
        self._replay.append(g)
        return g

    def seal(self, key: str, data: bytes) -> bytes:
        return self.signer.seal(key, data)

    def guard(self, now_s: Callable[[], float], rate_per_s: float | None, burst: float,
              window_s: float | None, speed: float | None = None, cycle_s: float = 1.0,
              fresh_cycles: float = 5.0) -> ReceiveGuard:
        """A receive guard; ``now_s`` is the receiver's fleet clock (stamps are fleet seconds). With
        ``speed`` the rate limiter runs on the monotonic clock at fleet rate
        (:func:`monotonic_fleet_clock`), else on ``now_s`` (never backwards either way)."""
        self._guarded = True
        on = rate_limits_on()
        own = "/".join(self.cn.split("-", 1)) if "-" in self.cn else None  # station-5 -> station/5
        clock = None if speed is None else monotonic_fleet_clock(speed)
        return ReceiveGuard(self.verifier, RateLimiter(rate_per_s, burst, clock=clock) if rate_per_s and on else None,
                            self.replay_guard(window_s, max(FRESH_S, fresh_cycles * cycle_s)) if window_s else None,
                            now_s, own)

    def station_guard(self, cycle_s: float, now_s: Callable[[], float], speed: float | None = None) -> ReceiveGuard:
        """A station hears from each peer at most a nav, a request and a reply per cycle (protocol v2: a
        nav, a poll and its reply to our poll): budget 4
        per cycle, burst 8; stamps more than :data:`STALE_S` (or 20 cycles) away from our fleet
        clock are stale. The window is wide on purpose: replays inside it are caught by the
        ``(stamp, seq)`` order, and a nav delivered seconds late on a loaded machine (speed 5: a
        second of wall time is 5 fleet seconds) is still one the core would use."""
        return self.guard(now_s, 4.0 / cycle_s, 8.0, max(STALE_S, 20.0 * cycle_s), speed, cycle_s)

    def aircraft_guard(self, cycle_s: float, now_s: Callable[[], float], speed: float | None = None) -> ReceiveGuard:
        """The aircraft hears one nav per station and cycle: budget 2 per cycle, burst 4."""
        return self.guard(now_s, 2.0 / cycle_s, 4.0, max(STALE_S, 20.0 * cycle_s), speed, cycle_s)
