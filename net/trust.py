"""Trust in certificates over time (issue 32, docs/security.md "Revocation, expiry, renewal"):
the certificates a receiver accepts signatures from, their expiry, the CA-signed revocation list,
certificates fetched from the bus, and a replay window that survives a receiver's restart.

Pure parts (no sockets, no clocks of their own; times are passed in): :class:`RevocationList`,
:class:`TrustStore`, :class:`ReplayStore`'s merge rule. The bus side (:func:`attach_trust`) serves
this process's certificate and the newest revocation list on Zenoh queryables, answers nothing
else, and feeds what it fetches or receives into the :class:`TrustStore`.

Bus keys (unsigned: every payload is CA-signed DER, checked before use)::

    larns/trust/crl          the revocation list (put by `larns keys revoke --publish`; queryable)
    larns/trust/cert/<cn>    <cn>'s certificate (queryable, served by <cn> itself)
"""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import os
import threading
import time
from pathlib import Path
from typing import Any, Callable

CRL_FILE = "crl.pem"
CERTS_DIR = "certs"
TRUST_PREFIX = "larns/trust"
CRL_KEY = "larns/trust/crl"
MAX_CERTS_PER_CN = 4


def cert_key(cn: str) -> str:
    """Bus key of ``cn``'s certificate."""
    return f"{TRUST_PREFIX}/cert/{cn}"


class TrustError(ValueError):
    """A certificate or revocation list that is not acceptable; ``reason`` is a drop-counter tag."""

    def __init__(self, reason: str, detail: str = ""):
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason


def _load_cert(data: bytes):
    from cryptography import x509

    data = bytes(data)
    try:
        return x509.load_pem_x509_certificate(data) if data.lstrip().startswith(b"-----") \
            else x509.load_der_x509_certificate(data)
    except ValueError as e:
        raise TrustError("bad_cert", str(e)[:80]) from None


def common_name(cert) -> str | None:
    from cryptography.x509.oid import NameOID

    got = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    return str(got[0].value) if got else None


def validity_unix_s(cert) -> tuple[float, float]:
    """(not before, not after) of a certificate, Unix seconds."""
    return cert.not_valid_before_utc.timestamp(), cert.not_valid_after_utc.timestamp()


class RevocationList:
    """A CA-signed X.509 revocation list: the serial numbers revoked, its number (newer wins) and
    its DER bytes (what is put on the bus). :meth:`parse` checks the CA's signature."""

    def __init__(self, serials: frozenset[int], number: int, der: bytes):
        self.serials = serials
        self.number = number
        self.der = der

    @classmethod
    def parse(cls, data: bytes, ca_cert) -> "RevocationList":
        """The list in ``data`` (PEM or DER) if ``ca_cert``'s key signed it; :class:`TrustError`
        (``bad_crl``) otherwise."""
        from cryptography import x509

        data = bytes(data)
        try:
            crl = x509.load_pem_x509_crl(data) if data.lstrip().startswith(b"-----") \
                else x509.load_der_x509_crl(data)
        except ValueError as e:
            raise TrustError("bad_crl", f"unreadable ({str(e)[:60]})") from None
        if crl.issuer != ca_cert.subject or not crl.is_signature_valid(ca_cert.public_key()):
            raise TrustError("bad_crl", "not signed by the keystore's CA")
        try:
            number = int(crl.extensions.get_extension_for_class(x509.CRLNumber).value.crl_number)
        except x509.ExtensionNotFound:
            number = 0
        from cryptography.hazmat.primitives import serialization as ser

        return cls(frozenset(int(r.serial_number) for r in crl), number, crl.public_bytes(ser.Encoding.DER))


class TrustStore:
    """The certificates a receiver may accept signatures from, as of the time given.

    A certificate enters only if the CA issued it to the common name it names; it is *usable* at
    ``now_unix_s`` if not expired, not before its start and not revoked by the newest revocation
    list seen (:meth:`add_crl`: a list with a higher number replaces the old one; an older one is
    ignored, so nobody can roll a revocation back by re-sending an old list). Several certificates
    per common name may be held (a renewed or re-issued one beside the old)."""

    def __init__(self, ca_cert):
        self.ca_cert = ca_cert
        self.crl: RevocationList | None = None
        self._certs: dict[str, dict[bytes, tuple[Any, Any, float, float, int]]] = {}

    # ---------------------------------------------------------------- updates
    def add_cert(self, data_or_cert, cn: str | None = None) -> str:
        """Add a CA-issued certificate (PEM/DER bytes or a loaded one); returns its common name.
        Raises :class:`TrustError` (``bad_cert``: not from our CA, or not named ``cn``)."""
        cert = data_or_cert if hasattr(data_or_cert, "serial_number") else _load_cert(data_or_cert)
        name = common_name(cert)
        if name is None or (cn is not None and name != cn):
            raise TrustError("bad_cert", f"common name {name!r}, expected {cn!r}")
        try:
            cert.verify_directly_issued_by(self.ca_cert)
        except Exception as e:  # noqa: BLE001 - any failure means: not ours
            raise TrustError("bad_cert", f"{name}: not issued by the CA ({type(e).__name__})") from None
        from cryptography.hazmat.primitives import serialization as ser

        fp = hashlib.sha256(cert.public_bytes(ser.Encoding.DER)).digest()
        held = self._certs.setdefault(name, {})
        if fp not in held:
            if len(held) >= MAX_CERTS_PER_CN:  # keep the ones that last longest
                del held[min(held, key=lambda k: held[k][3])]
            nb, na = validity_unix_s(cert)
            held[fp] = (cert, cert.public_key(), nb, na, int(cert.serial_number))
        return name

    def add_crl(self, data: bytes) -> bool:
        """Take a revocation list if the CA signed it and it is newer than ours; True if taken."""
        crl = RevocationList.parse(data, self.ca_cert)
        if self.crl is not None and crl.number <= self.crl.number:
            return False
        self.crl = crl
        return True

    # ---------------------------------------------------------------- queries
    def revoked(self, serial: int) -> bool:
        return self.crl is not None and int(serial) in self.crl.serials

    def keys(self, cn: str, now_unix_s: float) -> list:
        """Public keys of ``cn``'s usable certificates."""
        return [pk for _c, pk, nb, na, serial in self._certs.get(cn, {}).values()
                if nb <= now_unix_s <= na and not self.revoked(serial)]

    def status(self, cn: str, now_unix_s: float) -> str:
        """``ok`` (a usable certificate), ``revoked`` (every one held is revoked), ``expired``
        (some not revoked, none valid now) or ``unknown_signer`` (none held)."""
        held = list(self._certs.get(cn, {}).values())
        if not held:
            return "unknown_signer"
        if self.keys(cn, now_unix_s):
            return "ok"
        if all(self.revoked(serial) for *_x, serial in held):
            return "revoked"
        return "expired"

    def unusable_keys(self, cn: str) -> list[tuple[str, Any]]:
        """``(reason, public key)`` of ``cn``'s revoked certificates (to name a refusal precisely)."""
        return [("revoked", pk) for _c, pk, _nb, _na, serial in self._certs.get(cn, {}).values()
                if self.revoked(serial)]

    def certificate_der(self, cn: str, now_unix_s: float) -> bytes | None:
        """DER of ``cn``'s longest-lasting usable certificate (what this process serves)."""
        from cryptography.hazmat.primitives import serialization as ser

        best = None
        for cert, _pk, nb, na, serial in self._certs.get(cn, {}).values():
            if nb <= now_unix_s <= na and not self.revoked(serial) and (best is None or na > best[1]):
                best = (cert, na)
        return None if best is None else best[0].public_bytes(ser.Encoding.DER)


# --------------------------------------------------------------------------- replay state

class ReplayStore:
    """Where a receiver keeps the newest ``(stamp_s, seq)`` it accepted per (signer, kind), so a
    restarted receiver still refuses what it accepted before (issue 32). A JSON file, written
    atomically at most every ``every_s`` seconds of ``clock`` and on :meth:`flush`."""

    def __init__(self, path: str | Path, every_s: float = 1.0, clock: Callable[[], float] = time.monotonic):
        self.path = Path(path)
        self.every_s = float(every_s)
        self.clock = clock
        self._next = -float("inf")
        self._lock = threading.Lock()

    def load(self) -> dict[tuple[str, str], tuple[float, int]]:
        try:
            raw = json.loads(self.path.read_text())
            return {(str(s), str(k)): (float(v[0]), int(v[1])) for s, k, *v in raw["last"]}
        except (OSError, ValueError, KeyError, TypeError, IndexError):
            return {}

    def maybe_save(self, last: dict[tuple[str, str], tuple[float, int]]) -> None:
        if self.clock() >= self._next:
            self.flush(last)

    def flush(self, last: dict[tuple[str, str], tuple[float, int]]) -> None:
        self._next = self.clock() + self.every_s
        body = json.dumps({"last": [[s, k, st, q] for (s, k), (st, q) in sorted(dict(last).items())]})
        with self._lock:
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                tmp = self.path.with_name(f"{self.path.name}.{os.getpid()}.tmp")
                tmp.write_text(body)
                os.replace(tmp, self.path)
            except OSError:
                pass  # a read-only place: the guard still works, it just forgets on restart


def replay_state_path(ca_der: bytes, cn: str) -> Path:
    """Default file of ``cn``'s replay state: ``$LARNS_STATE_DIR`` (else the user's cache folder,
    else the temp folder), one file per CA and receiver, so two keystores never share one."""
    import tempfile

    base = os.environ.get("LARNS_STATE_DIR")
    if not base:
        cache = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        base = os.path.join(cache, "larns") if os.access(os.path.dirname(cache) or "/", os.W_OK) \
            else os.path.join(tempfile.gettempdir(), "larns-state")
    tag = hashlib.sha256(ca_der).hexdigest()[:16]
    return Path(base) / f"replay-{tag}-{cn}.json"


def prune_replay_states(folder: str | Path, max_age_s: float = 7 * 86400.0) -> int:
    """Remove replay histories not written for ``max_age_s`` (keystores long gone: every test run
    makes a new CA). Returns how many were removed."""
    n = 0
    cutoff = time.time() - max_age_s
    try:
        for p in Path(folder).glob("replay-*.json"):
            try:
                if p.stat().st_mtime < cutoff:
                    p.unlink()
                    n += 1
            except OSError:
                continue
    except OSError:
        pass
    return n


# --------------------------------------------------------------------------- on the bus

def attach_trust(bus, store: TrustStore, cn: str, on_change: Callable[[], None] | None = None,
                 now_unix_s: Callable[[], float] = time.time, pull_every_s: float = 10.0) -> dict:
    """Serve ``cn``'s certificate and the newest revocation list on Zenoh queryables, take
    revocation lists put on :data:`CRL_KEY`, and ask the others for theirs every ``pull_every_s``
    (a list put while this process was still linking reaches it that way). Returns
    ``{"fetch": fn(cn)}``: fetch a signer's certificate from the bus (asynchronous; the reply
    lands in ``store``). ``on_change`` runs after a newer list was taken."""
    session = bus.session

    def take_crl(data: bytes) -> None:
        try:
            if store.add_crl(data) and on_change is not None:
                on_change()
        except TrustError:
            pass  # not our CA's, or unreadable: ignored (counted nowhere: it changes nothing)

    def serve_cert(query) -> None:
        der = store.certificate_der(cn, now_unix_s())
        if der is not None:
            query.reply(cert_key(cn), der)

    def serve_crl(query) -> None:
        if store.crl is not None:
            query.reply(CRL_KEY, store.crl.der)

    def on_reply(reply) -> None:
        ok = getattr(reply, "ok", None)
        if ok is None:
            return
        key, data = str(ok.key_expr), ok.payload.to_bytes()
        if key == CRL_KEY:
            take_crl(data)
            return
        try:
            store.add_cert(data, key.rsplit("/", 1)[-1])
        except TrustError:
            pass

    keep = [session.declare_queryable(cert_key(cn), serve_cert),
            session.declare_queryable(CRL_KEY, serve_crl),
            session.declare_subscriber(CRL_KEY, lambda s: take_crl(s.payload.to_bytes()))]

    def pull() -> None:  # the newest list any process holds (a put missed while linking)
        while not getattr(bus, "closed", False):
            try:
                session.get(CRL_KEY, on_reply, timeout=5.0)
            except Exception:  # noqa: BLE001 - the session is closing
                return
            time.sleep(pull_every_s)

    threading.Thread(target=pull, name="larns-trust-pull", daemon=True).start()

    def fetch(signer: str) -> None:
        try:
            session.get(cert_key(signer), on_reply, timeout=5.0)
        except Exception:  # noqa: BLE001 - a closing session: the next unknown sample retries
            pass

    return {"fetch": fetch, "keep": keep}


def publish_crl(bus, der: bytes) -> None:
    """Put a revocation list on the bus (every receiver that holds an older one takes it)."""
    bus.session.put(CRL_KEY, bytes(der))


def utc_now() -> dt.datetime:
    return dt.datetime.now(dt.timezone.utc)
