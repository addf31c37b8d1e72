"""Checking the signatures in recordings against a keystore, as a live receiver would
(``larns replay --secure DIR``; :mod:`net.security`)."""

from __future__ import annotations

from net.security import Keystore, aircraft_cn, station_cn


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
