"""`larns keys`: a LARNS keystore (in the spirit of SROS2's: one certificate authority, one enclave
per process, security switched on by pointing a process at the keystore).

    larns keys init DIR --stations 1-10 --aircraft ac1 [--vehicle veh1] --recorder [--days 30]
    larns keys add DIR --station 11          # a hot-joiner, CA of DIR
    larns keys list DIR
    larns keys renew DIR --all [--days 30]   # new certificates for the same keys (before expiry)
    larns keys revoke DIR --station 5 [--publish --connect tls/HOST:PORT]   # CA-signed crl.pem
    larns keys export DIR OUT --enclave station-5   # what one host holds: its enclave, ca.crt,
                                                    # public certificates, crl.pem; never ca.key

Layout::

    DIR/keystore.json          index: reserved station ids, enclaves and their roles
    DIR/ca.crt                 the CA certificate (public: every process trusts it)
    DIR/ca.key                 the CA private key (0600; needed by `keys add` only - keep it offline)
    DIR/<cn>/cert.pem          the enclave's certificate, common name <cn>, signed by the CA
    DIR/<cn>/key.pem           the enclave's private key (0600)
    DIR/<cn>/zenoh.json5       its Zenoh security settings: TLS/mTLS links only and access control
    DIR/crl.pem                the revocation list, signed by the CA (after `keys revoke`)
    DIR/certs/<cn>.pem         public certificates of the other enclaves (in an exported host copy)

Certificates last ``--days`` (default 30): renew them with ``keys renew`` before they expire;
receivers refuse signatures by an expired or revoked certificate (``expired``, ``revoked``).

Common names: ``station-<id>``, ``aircraft-<name>``, ``vehicle-<name>``, ``recorder``, ``monitor`` (the launcher's
observer), ``router``, ``attacker-<n>`` is never issued. Keys are Ed25519 (RFC 8032): the same key
authenticates the process's TLS links and signs its air messages (:mod:`net.security`).

The access-control rules name every **reserved** station id (default 1..64, ``--reserve``), not only
the ones issued: processes started before ``keys add --station 11`` already know the subject
``station-11``, so a hot-joiner is accepted without restarting anyone.

This module is the argparse adapter: writing a keystore is :mod:`net.keystore`, checking recordings
:mod:`larns.analysis.verify` (both names also import from here, as before).
"""

from __future__ import annotations

import argparse
import json
import sys

import net.cli
from net.keystore import (DEFAULT_HOSTS, DEFAULT_RESERVE, VALID_DAYS, WritableKeystore,  # noqa: F401
                          add_to_keystore, init_keystore)
from net.security import Keystore, KeystoreError

from ..analysis.verify import verify_recording


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

def _enclave_names(a: argparse.Namespace, ks: Keystore) -> list[str]:
    """The common names picked by --station / --aircraft / --vehicle / --enclave / --all."""
    from net.security import aircraft_cn, station_cn, vehicle_cn

    if getattr(a, "all", False):
        return sorted(ks.enclaves)
    cns = [station_cn(i) for i in (parse_ids(a.station) if a.station else [])]
    cns += [aircraft_cn(n) for n in a.aircraft or []] + [vehicle_cn(n) for n in getattr(a, "vehicle", None) or []]
    cns += list(getattr(a, "enclave", None) or [])
    if not cns:
        raise ValueError("name what to act on: --station ID, --aircraft NAME, --vehicle NAME, --enclave CN"
                         + (" or --all" if hasattr(a, "all") else ""))
    return cns


def _cmd_renew(a: argparse.Namespace) -> int:
    try:
        ks = WritableKeystore(a.dir)
        for cn in _enclave_names(a, ks):
            until = ks.renew(cn, a.days)
            print(f"[keys] {cn}: renewed until {until:%Y-%m-%d %H:%M} UTC", file=sys.stderr)
    except (KeystoreError, ValueError) as e:
        print(f"larns keys renew: {e}", file=sys.stderr)
        return 2
    return 0


def _cmd_revoke(a: argparse.Namespace) -> int:
    try:
        ks = WritableKeystore(a.dir)
        cns = _enclave_names(a, ks)
        for cn in cns:
            serial = ks.revoke(cn)
            print(f"[keys] {cn}: certificate {serial:x} revoked ({ks.root}/crl.pem, "
                  f"number {ks.index['crl_number']})", file=sys.stderr)
        ks.write_configs()
    except (KeystoreError, ValueError) as e:
        print(f"larns keys revoke: {e}", file=sys.stderr)
        return 2
    if a.publish:
        return _publish_crl(a, ks)
    return 0


def _publish_crl(a: argparse.Namespace, ks) -> int:
    """Put ``crl.pem`` on the bus as the ``monitor`` enclave (every secure process takes it)."""
    import time

    from net.bus import Bus
    from net.trust import CRL_FILE, RevocationList, publish_crl

    if not a.connect:
        print("larns keys revoke --publish: give the field's address with --connect tls/HOST:PORT", file=sys.stderr)
        return 2
    der = RevocationList.parse((ks.root / CRL_FILE).read_bytes(), ks.ca_cert()).der
    try:
        bus = Bus(listen=[], connect=a.connect, mode="client" if a.client else "peer", secure=(str(ks.root), "monitor"))
    except KeystoreError as e:
        print(f"larns keys revoke --publish: {e}", file=sys.stderr)
        return 2
    t_end = time.monotonic() + a.link_wait
    while time.monotonic() < t_end and len(bus.peers()) + len(bus.routers()) < len(a.connect):
        time.sleep(0.1)
    for _ in range(3):   # a few times, a second apart: a peer still linking gets one of them
        publish_crl(bus, der)
        time.sleep(1.0)
    bus.close()
    print(f"[keys] revocation list published on the bus ({', '.join(a.connect)})", file=sys.stderr)
    net.cli.EXIT_AT_ONCE = True  # nothing left to do: no Zenoh thread may meet the interpreter's finalization
    return 0


def _cmd_export(a: argparse.Namespace) -> int:
    from net.keystore import export_host

    try:
        files = export_host(a.dir, a.out, list(a.enclave))
    except (KeystoreError, OSError) as e:
        print(f"larns keys export: {e}", file=sys.stderr)
        return 2
    print(f"[keys] {a.out}: {', '.join(a.enclave)} + {len(files) - 3 * len(a.enclave)} public files", file=sys.stderr)
    return 0


def _cmd_init(a: argparse.Namespace) -> int:
    try:
        ks = init_keystore(a.dir, parse_ids(a.stations), a.aircraft or [], recorder=a.recorder,
                           reserve=parse_ids(a.reserve) if a.reserve else None,
                           hosts=a.host or None, force=a.force, valid_days=a.days, vehicles=a.vehicle or [])
    except (KeystoreError, ValueError) as e:
        print(f"larns keys: {e}", file=sys.stderr)
        return 2
    print(f"[keys] keystore {ks.root}: CA + {len(ks.enclaves)} enclaves "
          f"({', '.join(sorted(ks.enclaves))}); station ids reserved {ks.reserved[0]}..{ks.reserved[-1]}",
          file=sys.stderr)
    return 0


def _cmd_add(a: argparse.Namespace) -> int:
    try:
        ks, new = add_to_keystore(a.dir, parse_ids(a.station) if a.station else [], a.aircraft or [],
                                  recorder=a.recorder, vehicles=a.vehicle or [])
    except (KeystoreError, ValueError) as e:
        print(f"larns keys: {e}", file=sys.stderr)
        return 2
    print(f"[keys] {ks.root}: issued {', '.join(new) if new else 'nothing new'}", file=sys.stderr)
    return 0


def _cmd_list(a: argparse.Namespace) -> int:
    try:
        ks = Keystore(a.dir)
    except KeystoreError as e:
        print(f"larns keys: {e}", file=sys.stderr)
        return 2
    for cn, e in sorted(ks.enclaves.items()):
        try:
            ks.check_enclave(cn)
            ok = "ok"
        except KeystoreError as err:
            ok = f"BAD: {err}"
        print(f"{cn:>20}  {e['role']:>9}  {ok}")
    return 0


def register(sub) -> None:
    from .helptext import Formatter, examples

    p = sub.add_parser("keys", help="keystore for --secure: CA, per-process certificates, Zenoh access control",
                       description=__doc__, formatter_class=Formatter,
                       epilog=examples(
                           "larns keys init runs/keys --stations 1-10 --aircraft ac1",
                           "larns keys add runs/keys --station 11",
                           "larns keys list runs/keys",
                           "larns keys revoke runs/keys --station 5 --publish --connect tls/127.0.0.1:7447",
                           "larns keys export runs/keys runs/host5 --enclave station-5",
                       ))
    ks = p.add_subparsers(dest="keys_cmd", required=True, metavar="ACTION",
                          help="init, add, list, renew, revoke or export")
    i = ks.add_parser("init", help="create a keystore (CA + enclaves)")
    i.add_argument("dir")
    i.add_argument("--stations", default="1-10", help="station ids to issue, e.g. 1-10 (default 1-10)")
    i.add_argument("--aircraft", action="append", metavar="NAME", help="aircraft name (repeatable)")
    i.add_argument("--vehicle", action="append", metavar="NAME", help="ground vehicle name (repeatable)")
    i.add_argument("--recorder", action="store_true", default=True, help="issue the recorder (default)")
    i.add_argument("--no-recorder", dest="recorder", action="store_false")
    i.add_argument("--reserve", default=None,
                   help="station ids named in the access-control rules (hot-joiners must be among them; "
                        f"default 1..max({DEFAULT_RESERVE}, largest id))")
    i.add_argument("--host", action="append", metavar="NAME",
                   help="host name / address put in every certificate (repeatable; default localhost, "
                        "127.0.0.1; add the compose service names for containers)")
    i.add_argument("--force", action="store_true", help="overwrite an existing keystore")
    i.add_argument("--days", type=float, default=VALID_DAYS,
                   help=f"lifetime of the enclaves' certificates, days (default {VALID_DAYS}; `keys renew`)")
    i.set_defaults(func=_cmd_init)
    a = ks.add_parser("add", help="issue more enclaves with the keystore's CA (e.g. a hot-joiner)")
    a.add_argument("dir")
    a.add_argument("--station", default=None, help="station id(s), e.g. 11 or 11-12")
    a.add_argument("--aircraft", action="append", metavar="NAME")
    a.add_argument("--vehicle", action="append", metavar="NAME")
    a.add_argument("--recorder", action="store_true")
    a.set_defaults(func=_cmd_add)
    ls = ks.add_parser("list", help="enclaves and whether their credentials check out")
    ls.add_argument("dir")
    ls.set_defaults(func=_cmd_list)
    r = ks.add_parser("renew", help="new certificates for the same keys (before they expire)")
    r.add_argument("dir")
    r.add_argument("--station", default=None, help="station id(s), e.g. 5 or 1-10")
    r.add_argument("--aircraft", action="append", metavar="NAME")
    r.add_argument("--vehicle", action="append", metavar="NAME")
    r.add_argument("--enclave", action="append", metavar="CN", help="common name, e.g. recorder")
    r.add_argument("--all", action="store_true", help="every enclave")
    r.add_argument("--days", type=float, default=None, help="lifetime, days (default: the keystore's)")
    r.set_defaults(func=_cmd_renew)
    v = ks.add_parser("revoke", help="revoke enclaves: CA-signed crl.pem; --publish puts it on the bus")
    v.add_argument("dir")
    v.add_argument("--station", default=None, help="station id(s), e.g. 5")
    v.add_argument("--aircraft", action="append", metavar="NAME")
    v.add_argument("--vehicle", action="append", metavar="NAME")
    v.add_argument("--enclave", action="append", metavar="CN")
    v.add_argument("--publish", action="store_true", help="put the list on the bus (as the monitor enclave)")
    v.add_argument("--connect", action="append", metavar="ENDPOINT", help="tls/HOST:PORT of the field (repeatable)")
    v.add_argument("--client", action="store_true", help="connect as a Zenoh client (router topology)")
    v.add_argument("--link-wait", type=float, default=10.0,
                   help="seconds to wait at most for a link to every --connect before publishing (default 10)")
    v.set_defaults(func=_cmd_revoke)
    x = ks.add_parser("export", help="one host's part of a keystore: its enclave(s), ca.crt, public certificates")
    x.add_argument("dir")
    x.add_argument("out")
    x.add_argument("--enclave", action="append", required=True, metavar="CN", help="e.g. station-5 (repeatable)")
    x.set_defaults(func=_cmd_export)
