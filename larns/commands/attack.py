"""`larns attack`: an adversary for testing a ``--secure`` fleet (docs/security.md). Loopback only.

    larns attack nocred  --connect tls/127.0.0.1:7447 --connect tcp/127.0.0.1:7447
    larns attack forge   --secure DIR --as 3 --victim 5 --connect ...     # a compromised station 3
    larns attack replay  --secure DIR --as 5 --delay 3 --connect ...      # stolen key of 5, old navs
    larns attack fuzz    --secure DIR --as 3 --count 10000 --connect ...  # malformed payloads
    larns attack flood   --secure DIR --as 9 --rate 20000 --connect ...   # one source, many msg/s
    larns attack all     --secure DIR --connect ... --duration 120        # the above, in turn, forever
    larns attack --as station-2 --mode all --secure DIR --connect ...     # an insider: station 2's key

Every attack is bounded in count and time and prints one JSON line of what it sent. What the
victims did with it shows in their drop counters (``larns station --report-json``: ``drops``).

* ``nocred``: a Zenoh session with no certificate (tcp and tls) trying to link and publish forged
  navs; it reports how many peers/routers it reached (0 expected).
* ``forge`` (credentials of station ``--as``): navs of the victim with the position shifted by 30 m
  and ranges lengthened by 25 m (the issue's attack) on the victim's key (refused by access control,
  in Rust), on its own key claiming to be the victim (``key`` / ``signer_mismatch``), unsigned
  (``unsigned``) and with a broken signature (``bad_signature``).
* ``replay`` (credentials of ``--as``, i.e. a stolen key): captures that station's real navs and
  publishes them again ``--delay`` seconds later (``replayed`` / ``stale``).
* ``fuzz``: random bytes, truncated and bit-flipped real envelopes, wrong types; signed with the
  attacker's valid key so that they reach the decoder (schema reasons) or unsigned (``unsigned``).
* ``flood``: as many navs and range requests per second as ``--rate`` on the attacker's own keys.

An insider (``--as station-N --mode M``, or ``larns attack insider``): a process holding station N's
valid credentials, loaded from ``--secure DIR`` as ``larns station --secure`` loads them, sending what
passes every transport check (larns/adversary/insider.py; docs/security.md "The insider kit"):

* ``ids``: navs naming 1,024 invented station ids in their ranges;
* ``slots``: navs sent inside other stations' slots, claiming them;
* ``absurd``: navs, range requests and replies with every field at its schema limits;
* ``replay``: station N's own signed navs put again ``--delay`` seconds later;
* ``flood``: fresh signed navs, requests and replies on every key of N at the receivers' budget;
* ``subkeys``: signed samples on invented sub-keys of N;
* ``all``: each in turn, ``--duration`` shared equally.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

ATTACK_NAMES = ("nocred", "forge", "replay", "fuzz", "flood", "insider")
INSIDER_MODES = ("ids", "slots", "absurd", "replay", "flood", "subkeys")  # larns.adversary.insider.MODES


def __getattr__(name: str):
    """The attacks' old home (``larns.commands.attack.forged_nav`` ...): now :mod:`larns.adversary.attacks`."""
    from larns.adversary import attacks

    try:
        return getattr(attacks, name)
    except AttributeError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None


def cmd_attack(args: argparse.Namespace) -> int:
    if not all(e.split("/", 1)[-1].startswith(("127.", "localhost", "[::1]")) for e in args.connect or []):
        print("larns attack: loopback endpoints only", file=sys.stderr)
        return 2
    if args.attack is None and args.mode is None:
        print("larns attack: name an attack, or run an insider with --as station-N --mode MODE", file=sys.stderr)
        return 2
    if args.mode is not None and args.attack not in (None, "insider"):
        print(f"larns attack {args.attack}: --mode is for the insider (--as station-N --mode MODE)", file=sys.stderr)
        return 2
    if args.attack is None or args.attack == "insider":
        args.attack, args.mode = "insider", args.mode or "all"
    try:
        args.victims = [int(v) for v in args.victims.split(",")] if args.victims else (
            [] if args.attack == "insider" else [1, 2, 3, 4, 5, 6, 7, 8, 10])
    except ValueError:
        print(f"larns attack: --victims: expected station ids like 1,2,5, got {args.victims!r}", file=sys.stderr)
        return 2
    if args.attack != "all" and args.attack != "nocred" and not args.secure:
        print(f"larns attack {args.attack}: needs --secure DIR (the credentials it abuses)", file=sys.stderr)
        return 2
    try:
        from larns.adversary.attacks import ATTACKS, attack_all

        if args.attack == "all":
            attack_all(args)
        elif args.attack == "insider":
            from larns.adversary.insider import attack_insider

            attack_insider(args)
        else:
            print(json.dumps(ATTACKS[args.attack](args)), flush=True)
    except Exception:  # an open Zenoh session would keep the process alive: report and leave
        import traceback

        traceback.print_exc()
        sys.stderr.flush()
        os._exit(1)
    return 0


def _station(text: str) -> int:
    from larns.adversary.insider import parse_as

    try:
        return parse_as(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def register(sub) -> None:
    from .helptext import Formatter, examples

    p = sub.add_parser("attack", help="adversary for a --secure fleet (loopback only; docs/security.md)",
                       description=__doc__, formatter_class=Formatter,
                       epilog=examples(
                           "larns attack forge --secure runs/keys --as 3 --victim 5 --connect tls/127.0.0.1:7447",
                           "larns attack all --secure runs/keys --connect tls/127.0.0.1:7447 --duration 120",
                           "larns attack --as station-2 --mode all --secure runs/keys --connect tls/127.0.0.1:7447 "
                           "--duration 60",
                           "larns attack --as station-2 --mode slots --secure runs/keys --connect tls/127.0.0.1:7447",
                       ))
    p.add_argument("attack", nargs="?", choices=[*ATTACK_NAMES, "all"], default=None,
                   help="the attack to run (all: each outsider attack in turn; none with --mode: the insider)")
    p.add_argument("--secure", default=None, metavar="DIR", help="keystore whose credentials are abused")
    p.add_argument("--as", dest="as_id", type=_station, default=3, metavar="station-N",
                   help="station whose credentials are used: station-N or N (default 3)")
    p.add_argument("--mode", choices=[*INSIDER_MODES, "all"], default=None,
                   help="insider mode (all: each in turn; implies the insider attack)")
    p.add_argument("--budget", type=int, default=4, help="insider: samples per key and cycle (default 4, the "
                   "receivers' per-key budget)")
    p.add_argument("--victim", type=int, default=5, help="station impersonated (default 5)")
    p.add_argument("--victims", default=None, help="flood: stations sent range requests (default all but 9)")
    p.add_argument("--connect", action="append", default=None, metavar="ENDPOINT",
                   help="endpoint of the fleet to attack (repeatable; loopback only)")
    p.add_argument("--zenoh-mode", choices=("peer", "client"), default="peer",
                   help="peer, or client of the router given with --connect")
    p.add_argument("--duration", type=float, default=10.0, help="seconds (default 10)")
    p.add_argument("--period", type=float, default=0.3, help="forge: seconds between rounds; fuzz: between payloads")
    p.add_argument("--delay", type=float, default=1.0, help="replay (and insider replay): seconds between "
                   "capture and replay")
    p.add_argument("--count", type=int, default=10000, help="fuzz: payloads (default 10000)")
    p.add_argument("--rate", type=float, default=20000.0, help="flood: messages per second (default 20000)")
    p.add_argument("--seed", type=int, default=15, help="fuzz and insider: random seed")
    p.add_argument("--epoch", type=float, default=None, help="fleet epoch (stamps of forged messages)")
    p.add_argument("--speed", type=float, default=1.0, help="the fleet's speed factor")
    p.add_argument("--link-wait", type=float, default=5.0, help="seconds to wait for a link")
    p.set_defaults(func=cmd_attack)

