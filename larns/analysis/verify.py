"""Checking the signatures in recordings against a keystore, as a live receiver would
(``larns replay --secure DIR``, ``larns info --keystore DIR``; :mod:`net.security`)."""

from __future__ import annotations

from net.security import Keystore, sender_cn


def signer_check(ks: Keystore):
    """``check(m, msg) -> reason or None`` for :meth:`larns.log.series.Recording.from_logs`: the
    recorded frame must carry a valid signature, by a certificate of the keystore's CA that was
    valid at the message's log time and is not revoked by the keystore's ``crl.pem``, of the
    sender the key and ``src`` name (certificates from ``<cn>/cert.pem`` or ``certs/<cn>.pem``).
    Reasons as a live receiver counts them (``unsigned``, ``signer_mismatch``, ``bad_signature``,
    ``unknown_signer``, ``revoked``, ``expired``)."""
    from net.security import SecurityError, Verifier

    at = [0.0]
    v = Verifier(ks, rescan_s=1e9, wall_s=lambda: at[0])

    def check(m, msg) -> str | None:
        at[0] = m.log_time * 1e-9
        try:
            signer, _env = v.open(m.topic, m.data)
        except SecurityError as e:
            return e.reason
        return None if signer == sender_cn(m.topic, msg["src"]) else "signer_mismatch"

    check.verifier = v
    return check


def verify_recording(ks: Keystore, paths, topics=None, exclude=None) -> dict:
    """Check every signed wire sample of MCAP recordings against the keystore: ``{"checked",
    "by_reason": {...}, "by_signer": {cn: n valid}}``. Samples are checked as a live receiver would
    (signature, signer named by the key, signer is the message's source, certificate valid at the
    sample's log time and not revoked); stamps are not checked against a clock (a recording is old
    by nature). Unsigned samples count as ``unsigned``."""
    from collections import Counter

    from net import messages as M
    from net.security import SecurityError, Verifier

    from ..log import read_logs
    from ..log.series import decode

    def read_messages(paths, topics, exclude):
        for lg in read_logs(list(paths), topics=topics, exclude=exclude, encodings=["msgpack"], sort=False):
            yield from lg.messages

    at = [0.0]
    v = Verifier(ks, rescan_s=1e9, wall_s=lambda: at[0])
    reasons: Counter = Counter()
    signers: Counter = Counter()
    n = 0
    for m in read_messages(paths, topics, exclude):
        if m.topic.startswith("larns/trust/"):
            continue
        n += 1
        at[0] = m.log_time * 1e-9
        try:
            signer, env = v.open(m.topic, m.data)
            msg, _ = decode(env)
            if signer != sender_cn(m.topic, msg["src"]):
                raise SecurityError("signer_mismatch", f"{signer} sent src {msg['src']}")
        except SecurityError as e:
            reasons[e.reason] += 1
            continue
        except M.MessageError as e:
            reasons[e.reason] += 1
            continue
        signers[signer] += 1
    return {"checked": n, "valid": sum(signers.values()), "by_reason": dict(reasons), "by_signer": dict(signers)}
