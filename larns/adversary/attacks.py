"""The attacks behind `larns attack` (docs/security.md; what each one sends: the command's help,
`larns/commands/attack.py`), run against loopback endpoints. Every attack is bounded in count and
time and returns a dict of what it sent (the command prints it as one JSON line); what the victims
did with it shows in their drop counters."""


from __future__ import annotations

import argparse
import json
import time
from typing import Any

import numpy as np


def _bus(args: argparse.Namespace, cn: str | None):
    from net.bus import Bus

    sec = (args.secure, cn) if cn else None
    mode = "client" if args.zenoh_mode == "client" else "peer"
    return Bus(listen=[] if mode == "client" else ["tls/127.0.0.1:0" if sec else "tcp/127.0.0.1:0"],
               connect=args.connect or [], mode=mode, secure=sec)


def _wait_linked(bus, timeout_s: float) -> int:
    t0 = time.time()
    while time.time() - t0 < timeout_s:
        n = len(bus.peers()) + len(bus.routers())
        if n:
            return n
        time.sleep(0.2)
    return 0


def _fleet_t(args: argparse.Namespace) -> float:
    from stations.node import default_epoch

    epoch = default_epoch() if args.epoch is None else args.epoch
    return (time.time() - epoch) * args.speed


def forged_nav(src: int, seq: int, t_s: float, pos_m, shift_m: float = 30.0, lengthen_m: float = 25.0,
               ranges=None) -> dict:
    """A nav claiming to be ``src``: position shifted, ranges lengthened (the issue's attack)."""
    p = np.asarray(pos_m, float) + np.array([shift_m, 0.0, 0.0])
    # entries [peer, range_m, t_s] or, with two-way time transfer, [peer, range_m, t_s, dtheta_s]
    rs = [[int(e[0]), float(e[1]) + lengthen_m, *map(float, e[2:])] for e in (ranges or [])]
    return {"kind": "nav", "src": int(src), "seq": int(seq), "stamp_s": float(t_s), "cycle": int(t_s),
            "slot": int(src) - 1, "t_tx_s": float(t_s), "pos_m": p.tolist(),
            "cov_m2": (np.eye(3) * 0.01).tolist(), "n_updates": 100, "state": "surveying",
            "ranges": rs, "members": []}


# --------------------------------------------------------------------------- attacks

def attack_nocred(args) -> dict:
    from net import messages as M

    out: dict[str, Any] = {"attack": "nocred"}
    for proto in ("tcp", "tls"):
        eps = [proto + e[3:] for e in (args.connect or [])]
        from net.bus import Bus

        # (no certificate: it can only listen on tcp; it dials the victims over tcp and over tls, as
        # a peer: a client would block in open until a router accepts it, i.e. forever)
        b = Bus(listen=["tcp/127.0.0.1:0"], connect=eps)
        linked = _wait_linked(b, args.link_wait)
        sent = 0
        for i in range(50):
            m = forged_nav(args.victim, 10**6 + i, _fleet_t(args), [0.0, 0.0, 0.0])
            b.publish(M.key_for(m), M.encode(m, {"pos_m": [0.0, 0.0, 0.0], "t_true_s": _fleet_t(args)}))
            sent += 1
            time.sleep(0.01)
        out[proto] = {"links": linked, "sent": sent}
        b.close()
    return out


def attack_forge(args) -> dict:
    from net import messages as M
    from net.security import MAGIC

    me = int(args.as_id)
    b = _bus(args, f"station-{me}")
    linked = _wait_linked(b, args.link_wait)
    victim_pos: dict = {}

    def grab(key, data):
        try:
            msg, phy = M.decode(data)
        except M.MessageError:
            return
        if msg["src"] == args.victim and msg["kind"] == "nav":
            victim_pos["msg"], victim_pos["phy"], victim_pos["wall"] = msg, phy, time.time()

    b.subscribe("larns/station/*/nav/**", grab)
    t_end = time.time() + args.duration
    sent = {"victim_key": 0, "own_key_as_victim": 0, "unsigned": 0, "bad_signature": 0}
    seq = 10**6
    while time.time() < t_end:
        v = victim_pos.get("msg")
        pos = v["pos_m"] if v else [500.0, 500.0, 0.0]
        phy = victim_pos.get("phy") or {"pos_m": pos, "t_true_s": _fleet_t(args)}
        # the field's clock read off the victim's last nav (an attacker need not know the epoch), so
        # the forgeries are fresh and meet the signature check rather than the staleness test
        t_now = v["stamp_s"] + (time.time() - victim_pos["wall"]) * args.speed if v else _fleet_t(args)
        phy = {"pos_m": phy["pos_m"], "t_true_s": t_now}
        seq += 1
        m = forged_nav(args.victim, seq, t_now, pos, ranges=v["ranges"] if v else None)
        env = M.encode(m, phy)
        b.publish(M.key_for(m), env)                          # victim's key: access control
        sent["victim_key"] += 1
        # one variant per round on our own key (the receivers' flood guard lets one per 1/4 cycle in)
        variant = seq % 3
        if variant == 0:
            b.publish(f"larns/station/{me}/nav", env)         # own key, src = victim
            sent["own_key_as_victim"] += 1
        elif variant == 1:
            b.session.put(f"larns/station/{me}/nav", env)     # unsigned (raw, past Bus.publish)
            sent["unsigned"] += 1
        else:
            m2 = dict(m, src=me, slot=me - 1)
            good = b.security.seal(f"larns/station/{me}/nav", M.encode(m2, phy))
            n = good[2]
            bad = good[:3 + n] + bytes(64) + good[3 + n + 64:]
            assert bad[:2] == MAGIC
            b.session.put(f"larns/station/{me}/nav", bad)     # broken signature
            sent["bad_signature"] += 1
        time.sleep(args.period)
    b.close()
    return {"attack": "forge", "as": me, "victim": args.victim, "links": linked, "sent": sent}


def attack_replay(args) -> dict:
    me = int(args.as_id)
    b = _bus(args, f"station-{me}")
    linked = _wait_linked(b, args.link_wait)
    captured: list = []
    b.subscribe(f"larns/station/{me}/nav/**", lambda k, d: captured.append((time.time(), k, d)))
    t_end = time.time() + args.duration
    sent = 0
    while time.time() < t_end:
        now = time.time()
        while captured and now - captured[0][0] >= args.delay:
            _, k, d = captured.pop(0)
            b.session.put(k, d)  # the original signed bytes, again
            sent += 1
        time.sleep(0.05)
    b.close()
    return {"attack": "replay", "as": me, "links": linked, "delay_s": args.delay, "sent": sent}


def fuzz_payloads(rng: np.random.Generator, base: bytes, n: int) -> list[bytes]:
    """``n`` malformed payloads: random bytes, truncations, bit flips, type swaps of ``base``."""
    import msgpack

    env = msgpack.unpackb(base, raw=False)
    out: list[bytes] = []
    for i in range(n):
        k = i % 6
        if k == 0:
            out.append(rng.bytes(int(rng.integers(0, 200))))
        elif k == 1:
            out.append(base[: int(rng.integers(0, len(base)))])
        elif k == 2:
            b = bytearray(base)
            for _ in range(int(rng.integers(1, 8))):
                j = int(rng.integers(0, len(b)))
                b[j] ^= 1 << int(rng.integers(0, 8))
            out.append(bytes(b))
        elif k == 3:
            m = dict(env["msg"])
            f = list(m)[int(rng.integers(0, len(m)))]
            m[f] = [None, "x" * 70, -1, 1e300, [1, 2], {"a": 1}, float("nan"), True][int(rng.integers(0, 8))]
            out.append(msgpack.packb({**env, "msg": m}, use_bin_type=True))
        elif k == 4:
            out.append(msgpack.packb({**env, "v": int(rng.integers(2, 9))}, use_bin_type=True))
        else:
            out.append(msgpack.packb([env, 1], use_bin_type=True))
    return out


def attack_fuzz(args) -> dict:
    from net import messages as M

    me = int(args.as_id)
    b = _bus(args, f"station-{me}")
    linked = _wait_linked(b, args.link_wait)
    time.sleep(1.0)  # subscriptions propagate
    rng = np.random.default_rng(args.seed)
    m = forged_nav(me, 1, _fleet_t(args), [0.0, 0.0, 0.0])
    base = M.encode(m, {"pos_m": [0.0, 0.0, 0.0], "t_true_s": 0.0})
    key = f"larns/station/{me}/nav"
    sent = 0
    t0 = time.time()
    for p in fuzz_payloads(rng, base, args.count):
        b.publish(key, p, block=True)  # signed with our valid key: reaches the decoder
        sent += 1
        if args.period:
            time.sleep(args.period)
        if time.time() - t0 > args.duration:
            break
    time.sleep(1.0)
    b.close()
    return {"attack": "fuzz", "as": me, "links": linked, "sent": sent, "key": key}


def attack_flood(args) -> dict:
    from net import messages as M

    me = int(args.as_id)
    b = _bus(args, f"station-{me}")
    linked = _wait_linked(b, args.link_wait)
    time.sleep(1.0)
    m = forged_nav(me, 1, _fleet_t(args), [0.0, 0.0, 0.0])
    sess = b.session
    keys = [f"larns/station/{me}/nav"] + [f"larns/station/{me}/range/req/{k}" for k in args.victims]
    pubs = [sess.declare_publisher(k) for k in keys]
    # pre-signed payloads (a flood need not be valid: the point is the volume)
    payloads = [b.security.seal(k, M.encode(m, {"pos_m": [0.0, 0.0, 0.0], "t_true_s": 0.0})) for k in keys]
    sent = 0
    t0 = time.time()
    t_end = t0 + args.duration
    next_t = t0
    batch = max(1, int(args.rate / 1000))
    while True:
        now = time.time()
        if now >= t_end:
            break
        if now < next_t:
            time.sleep(min(next_t - now, 0.001))
            continue
        for _ in range(batch):
            i = sent % len(pubs)
            pubs[i].put(payloads[i])
            sent += 1
        next_t += batch / args.rate
    dt = time.time() - t0
    b.close()
    return {"attack": "flood", "as": me, "links": linked, "sent": sent, "seconds": dt, "rate_per_s": sent / dt}


def attack_insider(args) -> list[dict]:
    """An insider with ``--as``'s credentials (larns/adversary/insider.py)."""
    from larns.adversary.insider import attack_insider as run_insider

    return run_insider(args)


ATTACKS = {"nocred": attack_nocred, "forge": attack_forge, "replay": attack_replay, "fuzz": attack_fuzz,
           "flood": attack_flood, "insider": attack_insider}


def attack_all(args) -> list[dict]:
    """Each attack in turn for a share of ``--duration`` (the 120 s secure-fleet bar)."""
    t_end = time.time() + args.duration
    out = []
    plan = [("nocred", 0.1), ("forge", 0.25), ("replay", 0.25), ("fuzz", 0.2), ("flood", 0.2)]
    for name, share in plan:
        left = t_end - time.time()
        if left <= 1:
            break
        a = argparse.Namespace(**vars(args))
        a.duration = max(1.0, min(left, share * args.duration))
        if name == "fuzz":
            a.period = a.duration / max(1, a.count)
        if name == "replay":
            a.as_id = args.victim
        if name == "nocred":
            a.link_wait = min(args.link_wait, 2.0)
        r = ATTACKS[name](a)
        print(json.dumps(r), flush=True)
        out.append(r)
    return out
