"""An insider: a process holding one station's valid credentials (`larns attack --as station-N`).

The outsider attacks (``attacks.py``) test what the transport refuses. An insider passes every
transport check - its samples are signed by a key the CA issued, on keys its access rules allow -,
so what it says meets the receivers' plausibility checks (``stations/admission.py``,
``aircraft/navigator/plausible.py``, the vehicle navigator's) and integrity tests. Modes:

* ``ids``: navs whose ``ranges`` name up to 1,024 invented station ids (4-element entries, each a new
  clock for a naive clock filter), plausible ranges and times;
* ``slots``: navs sent *inside other stations' slots* claiming those slots (a lower id wins a
  collision), one victim per cycle in turn;
* ``absurd``: navs, range requests and range replies with every field at its schema limits
  (``net/messages.py``: numbers at +-1e12, 0 or -1, ids at 65,535, lists of 1,024 entries, clock
  frequency -1, non-positive-definite covariances); the stamp fresh so they pass the replay guard;
* ``replay``: the real station N's own signed navs, range requests and replies captured and put
  again ``delay_s`` later (the original bytes);
* ``flood``: fresh signed navs, range requests and replies on every key of N at the receivers'
  per-key budget (4 per cycle, paced over the cycle as the Zenoh flood guard passes them), copies of
  N's latest real nav with new stamps and sequence numbers;
* ``subkeys``: signed samples on invented sub-keys of N (``larns/station/N/x/<i>``, ...): refused by
  the exact access rules, never a recorder channel.

:class:`Insider` is the sans-I/O part (messages in: what it hears; time in; samples out), driven by
:func:`run` over any bus with ``publish`` / ``subscribe`` (``net.bus.Bus`` or a test's fake).
"""

from __future__ import annotations

import math
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from net import messages as M

MODES = ("ids", "slots", "absurd", "replay", "flood", "subkeys")

LIMIT = M.MAX_ABS
# numbers at the schema's limits and its edges (every one passes `net.messages.decode`)
EXTREMES = (LIMIT, -LIMIT, 0.0, -1.0, 1.0, 5e-324, -5e-324, 1e-300, LIMIT / 3.0, -LIMIT / 7.0)
NONNEG = (LIMIT, 0.0, 5e-324, 1e-300, 1.0, LIMIT / 3.0)
IDS = (1, 2, M.MAX_ID, M.MAX_ID - 1, 64, 65)


def parse_as(text: str | int) -> int:
    """``station-3`` or ``3`` -> 3 (``larns attack --as``)."""
    s = str(text).strip()
    if s.startswith("station-"):
        s = s[len("station-"):]
    try:
        n = int(s)
    except ValueError:
        raise ValueError(f"--as: expected station-N or N, got {text!r}") from None
    if not 1 <= n <= M.MAX_ID:
        raise ValueError(f"--as: station id {n} outside 1..{M.MAX_ID}")
    return n


# --------------------------------------------------------------------------- absurd messages

def _pick(rng: np.random.Generator, pool) -> Any:
    return pool[int(rng.random() * len(pool))]


def _vec(rng: np.random.Generator) -> list[float]:
    return [float(_pick(rng, EXTREMES)) for _ in range(3)]


def _cov(rng: np.random.Generator) -> list[list[float]]:
    """A 3x3 with variances at their limits and any off-diagonals (often not positive definite)."""
    c = [[float(_pick(rng, EXTREMES)) for _ in range(3)] for _ in range(3)]
    for i in range(3):
        c[i][i] = float(_pick(rng, NONNEG))
    return c


def _clock(rng: np.random.Generator, t_s: float) -> list[float]:
    """``[t_ref, offset, freq, P_tt, P_tf, P_ff]`` at limits (a frequency of -1 among them)."""
    return [float(_pick(rng, (t_s, *EXTREMES))), float(_pick(rng, EXTREMES)), float(_pick(rng, (-1.0, *EXTREMES))),
            float(_pick(rng, NONNEG)), float(_pick(rng, EXTREMES)), float(_pick(rng, NONNEG))]


def _n_list(rng: np.random.Generator, p_long: float = 0.1) -> int:
    """A list length: mostly short, at the schema's limit (1,024) with probability ``p_long``."""
    return M.MAX_LIST if rng.random() < p_long else int(rng.choice((0, 1, 4, 64)))


def absurd_message(rng: np.random.Generator, kind: str, src: int, seq: int, stamp_s: float,
                   dst: int | None = None, p_long: float = 0.1) -> dict:
    """One ``kind`` message from ``src`` with every field at its schema limits (valid on the wire).
    ``stamp_s`` is kept (fresh: it must pass the receivers' replay guard to test what lies behind);
    a nav's ``ranges`` and ``members`` hold 1,024 entries with probability ``p_long``."""
    base = {"kind": kind, "src": int(src), "seq": int(seq), "stamp_s": float(stamp_s)}
    t = float(_pick(rng, (stamp_s, *EXTREMES)))
    if kind == "nav":
        n = _n_list(rng, p_long)
        ids = _ids(rng, n, None)
        rs = rng.choice(NONNEG, n).tolist()
        ts = rng.choice((stamp_s, *EXTREMES), n).tolist()
        dth = rng.choice(EXTREMES, n).tolist()
        four = (rng.random(n) < 0.7).tolist()
        ranges = [[i, r, tt, d] if f else [i, r, tt] for i, r, tt, d, f in zip(ids, rs, ts, dth, four)]
        m = dict(base, cycle=int(_pick(rng, (0, M.MAX_SEQ, int(stamp_s)))), slot=int(_pick(rng, (0, src - 1, M.MAX_ID))),
                 t_tx_s=t, pos_m=_vec(rng), cov_m2=_cov(rng), n_updates=int(_pick(rng, (0, 1, M.MAX_SEQ))),
                 state=str(_pick(rng, M.STATES)), ranges=ranges,
                 members=rng.integers(1, M.MAX_ID + 1, _n_list(rng, p_long)).tolist())
        if rng.random() < 0.8:
            m["clock"] = _clock(rng, stamp_s)
        if rng.random() < 0.3:  # a final (protocol v2)
            rx = _ids(rng, _n_list(rng, p_long), None)
            m["poll"] = {"seq": int(_pick(rng, (0, 1, M.MAX_SEQ))), "t1": float(_pick(rng, (stamp_s, *EXTREMES))),
                         "rx": [[i, float(_pick(rng, (stamp_s, *EXTREMES)))] for i in rx]}
        return m
    if kind == "range_req":
        return dict(base, dst=int(dst or 1), cycle=int(_pick(rng, (0, M.MAX_SEQ, int(stamp_s)))),
                    slot=int(_pick(rng, (0, src - 1, M.MAX_ID))), t_tx_s=t)
    if kind == "range_rsp":
        m = dict(base, dst=int(dst or 1), req_seq=int(_pick(rng, (0, 1, M.MAX_SEQ))),
                 turnaround_s=float(_pick(rng, EXTREMES)), pos_m=_vec(rng), cov_m2=_cov(rng),
                 n_updates=int(_pick(rng, (0, M.MAX_SEQ))), state=str(_pick(rng, M.STATES)))
        for k in ("t_tx_s", "t_rx_s"):
            if rng.random() < 0.8:
                m[k] = float(_pick(rng, (stamp_s, *EXTREMES)))
        if rng.random() < 0.8:
            m["clock"] = _clock(rng, stamp_s)
        return m
    if kind == "poll":
        return dict(base, cycle=int(_pick(rng, (0, M.MAX_SEQ, int(stamp_s)))), slot=int(_pick(rng, (0, src - 1, M.MAX_ID))),
                    t_tx_s=t, members=_ids(rng, _n_list(rng, p_long), dst))
    if kind == "reply":
        m = dict(base, dst=int(dst or 1), poll_seq=int(_pick(rng, (0, 1, M.MAX_SEQ))),
                 t_rx_s=float(_pick(rng, (stamp_s, *EXTREMES))), t_tx_s=t, pos_m=_vec(rng), cov_m2=_cov(rng),
                 n_updates=int(_pick(rng, (0, M.MAX_SEQ))), state=str(_pick(rng, M.STATES)))
        if rng.random() < 0.8:
            m["clock"] = _clock(rng, stamp_s)
        return m
    raise ValueError(f"absurd_message: no absurd {kind}")


def _ids(rng: np.random.Generator, n: int, dst: int | None) -> list[int]:
    """``n`` station ids, half of them the scenario's (``IDS``), with ``dst`` among them if given."""
    ids = np.where(rng.random(n) < 0.5, rng.choice(IDS, n), rng.integers(1, M.MAX_ID + 1, n)).tolist()
    return ids if dst is None or not ids else [int(dst), *ids[1:]]


def absurd_phy(rng: np.random.Generator, t_s: float, pos_m) -> dict:
    """A ``phy`` block: mostly the honest one, sometimes at its limits (a receiver's channel layer
    derives time of flight from the named sender's truth, not from this)."""
    if rng.random() < 0.7:
        return {"pos_m": [float(x) for x in pos_m], "t_true_s": float(t_s)}
    return {"pos_m": _vec(rng), "t_true_s": float(_pick(rng, (t_s, *EXTREMES)))}


# --------------------------------------------------------------------------- the insider

@dataclass
class FieldClock:
    """The field's time read off the navs it hears (an insider need not know the fleet's epoch):
    ``t = wall * speed - offset``, the offset the smallest ``wall * speed - stamp`` seen (the
    fastest delivery) over the last 200 navs; before any, ``fallback(wall)`` if given."""

    speed: float = 1.0
    _offsets: deque = field(default_factory=lambda: deque(maxlen=200))
    fallback: Callable[[float], float] | None = None

    def observe(self, stamp_s: float, wall_s: float) -> None:
        self._offsets.append(wall_s * self.speed - float(stamp_s))

    def known(self) -> bool:
        return bool(self._offsets) or self.fallback is not None

    def now(self, wall_s: float) -> float:
        if self._offsets:
            return wall_s * self.speed - min(self._offsets)
        if self.fallback is not None:
            return self.fallback(wall_s)
        raise RuntimeError("field time unknown: no nav heard yet")


class Insider:
    """What station ``me`` sends in each mode (sans-I/O: :meth:`heard` and :meth:`tick` take the
    wall time; :meth:`tick` returns ``[(key, payload, signed)]`` - ``signed`` False: the bytes go
    out as they are (replays), True: the bus signs them with N's key)."""

    def __init__(self, me: int, rng: np.random.Generator, clock: FieldClock, victims=(), cycle_s: float = 1.0,
                 slot_s: float = 0.01, budget_per_cycle: int = 4, delay_s: float = 1.0):
        self.me = int(me)
        self.rng = rng
        self.clock = clock
        self.victims = [int(v) for v in victims if int(v) != self.me]
        self.cycle_s = float(cycle_s)
        self.slot_s = float(slot_s)
        self.budget = int(budget_per_cycle)
        self.delay_s = float(delay_s)
        self.seq = 10**9  # above the real station's sequence numbers
        self.heard_ids: set[int] = set()
        self.last_nav: dict | None = None
        self.last_phy: dict | None = None
        self.captured: deque = deque(maxlen=4096)  # (wall, key, bytes) of N's own signed samples
        self.sent: Counter[str] = Counter()
        self._sent_cycle: dict[tuple[str, str], tuple[int, int]] = {}
        self._sub = 0

    # ------------------------------------------------------------------ input
    def heard(self, key: str, data: bytes, wall_s: float) -> None:
        pk = M.parse_key(key)
        if pk is None or pk[0] != "station":
            return
        if pk[1] == self.me:
            self.captured.append((wall_s, key, bytes(data)))
        try:
            msg, phy = M.decode(data)
        except M.MessageError:
            return
        if msg["kind"] != "nav":
            return
        if msg["src"] != self.me:  # (our own navs: the real station's, its clock is the field's too)
            self.heard_ids.add(int(msg["src"]))
        self.clock.observe(msg["stamp_s"], wall_s)
        if msg["src"] == self.me:
            self.last_nav, self.last_phy = msg, phy

    # ------------------------------------------------------------------ helpers
    def _next_seq(self) -> int:
        self.seq += 1
        return self.seq

    def _within_budget(self, key: str, t_s: float, what: str = "", n_max: int | None = None) -> bool:
        """At most ``budget`` (``n_max``) samples per key (and ``what``) and cycle (the receivers' flood
        guard / per-key budget)."""
        cyc = int(math.floor(t_s / self.cycle_s))
        c, n = self._sent_cycle.get((key, what), (cyc, 0))
        if c != cyc:
            n = 0
        budget = self.budget if n_max is None else n_max
        # paced over the cycle (the receivers' Zenoh flood guard lets one per cycle / budget through)
        if n >= budget or t_s - cyc * self.cycle_s < n * self.cycle_s / budget:
            return False
        self._sent_cycle[(key, what)] = (cyc, n + 1)
        return True

    def _pos(self) -> list[float]:
        return list(self.last_nav["pos_m"]) if self.last_nav else [0.0, 0.0, 0.0]

    def _phy(self, t_s: float) -> dict:
        pos = self.last_phy["pos_m"] if self.last_phy else self._pos()
        return {"pos_m": [float(x) for x in pos], "t_true_s": float(t_s)}

    def _nav(self, t_s: float, **over) -> dict:
        """A plausible nav of ours at ``t_s`` (a copy of the real station's last, or a neutral one)."""
        cyc = int(math.floor(t_s / self.cycle_s))
        base = dict(self.last_nav) if self.last_nav else {
            "kind": "nav", "src": self.me, "pos_m": [0.0, 0.0, 0.0], "cov_m2": (np.eye(3) * 0.01).tolist(),
            "n_updates": 100, "state": "surveying", "ranges": [], "members": []}
        base.update(seq=self._next_seq(), stamp_s=float(t_s), cycle=cyc, slot=self.me - 1, t_tx_s=float(t_s))
        base.update(over)
        return base

    def _out(self, msg: dict, phy: dict | None, mode: str) -> tuple[str, bytes, bool]:
        self.sent[mode] += 1
        return M.key_for(msg), M.encode(msg, phy), True

    # ------------------------------------------------------------------ modes
    def tick(self, mode: str, wall_s: float) -> list[tuple[str, bytes, bool]]:
        """The samples mode ``mode`` sends now (call it every few milliseconds)."""
        if mode == "replay":
            return self._replay(wall_s)
        if not self.clock.known():
            return []
        t = self.clock.now(wall_s)
        return getattr(self, "_" + mode)(t)

    def _ids(self, t: float) -> list:
        key = M.station_key(self.me, "nav")
        if not self._within_budget(key, t):
            return []
        n = M.MAX_LIST
        invented = self.rng.choice(np.arange(100, M.MAX_ID + 1), size=n, replace=False)
        ranges = [[int(i), float(self.rng.uniform(10.0, 3000.0)), float(t - self.rng.uniform(0.0, 0.9)),
                   float(self.rng.normal(0.0, 1e-6))] for i in invented]
        return [self._out(self._nav(t, ranges=ranges), self._phy(t), "ids")]

    def _slots(self, t: float) -> list:
        """Inside a victim's slot (at +2 ms), a nav claiming that slot."""
        cyc = int(math.floor(t / self.cycle_s))
        off = t - cyc * self.cycle_s
        slot = int(off / self.slot_s)
        if not 0.002 <= off - slot * self.slot_s <= 0.006:
            return []
        owner = slot + 1
        targets = [v for v in (self.victims or sorted(self.heard_ids)) if v != self.me]
        # one victim per cycle, in turn (the flood guard lets one nav per quarter cycle through, and
        # the slots of a field's first stations all lie in the first quarter)
        if not targets or owner != targets[cyc % len(targets)]:
            return []
        key = M.station_key(self.me, "nav")
        if not self._within_budget(key, t, f"slot{slot}", 1) or not self._within_budget(key, t):
            return []
        return [self._out(self._nav(t, slot=slot), self._phy(t), "slots")]

    def _absurd(self, t: float) -> list:
        out = []
        nav_key = M.station_key(self.me, "nav")
        if self._within_budget(nav_key, t):
            out.append(self._out(absurd_message(self.rng, "nav", self.me, self._next_seq(), t), self._phy(t), "absurd"))
        for v in self.victims:
            for kind in ("range_req", "range_rsp", "poll", "reply"):
                m = absurd_message(self.rng, kind, self.me, self._next_seq(), t, dst=v)
                if self._within_budget(M.key_for(m), t):
                    out.append(self._out(m, self._phy(t), "absurd"))
        return out

    def _replay(self, wall_s: float) -> list:
        out = []
        while self.captured and wall_s - self.captured[0][0] >= self.delay_s:
            _, k, d = self.captured.popleft()
            self.sent["replay"] += 1
            out.append((k, d, False))
        return out

    def _flood(self, t: float) -> list:
        out = []
        nav_key = M.station_key(self.me, "nav")
        if self._within_budget(nav_key, t):
            out.append(self._out(self._nav(t), self._phy(t), "flood"))
        cyc = int(math.floor(t / self.cycle_s))
        for v in self.victims:
            req = {"kind": "range_req", "src": self.me, "seq": self._next_seq(), "stamp_s": float(t), "dst": v,
                   "cycle": cyc, "slot": self.me - 1, "t_tx_s": float(t)}
            if self._within_budget(M.key_for(req), t):
                out.append(self._out(req, self._phy(t), "flood"))
            rsp = {"kind": "range_rsp", "src": self.me, "seq": self._next_seq(), "stamp_s": float(t), "dst": v,
                   "req_seq": self.seq, "turnaround_s": 0.002, "pos_m": self._pos(),
                   "cov_m2": (np.eye(3) * 0.01).tolist(), "n_updates": 100, "state": "surveying",
                   "t_rx_s": float(t) - 0.002, "t_tx_s": float(t)}
            if self._within_budget(M.key_for(rsp), t):
                out.append(self._out(rsp, self._phy(t), "flood"))
        return out

    def _subkeys(self, t: float) -> list:
        out = []
        m = self._nav(t)
        env = M.encode(m, self._phy(t))
        for _ in range(self.budget):
            self._sub += 1
            sub = ("x", str(self._sub)) if self._sub % 3 else ("nav", "extra", str(self._sub))
            out.append((M.station_key(self.me, *sub), env, True))
            self.sent["subkeys"] += 1
        return out


# --------------------------------------------------------------------------- the shell

def _put(bus, key: str, data: bytes, signed: bool) -> None:
    """A sample on the wire: ``signed`` ones sealed with our key (no cached publisher per key: the
    sub-key spam names thousands of keys), replays as the original bytes."""
    sec = getattr(bus, "security", None)
    if signed and sec is not None:
        data = sec.seal(key, data)
    put_raw = getattr(bus, "put_raw", None)
    if put_raw is not None:
        put_raw(key, data)
    else:
        bus.session.put(key, data)


def run(bus, insider: Insider, modes, duration_s: float, wall: Callable[[], float] = time.time,
        sleep: Callable[[float], None] = time.sleep, period_s: float = 0.002) -> list[dict]:
    """Each mode in ``modes`` in turn for an equal share of ``duration_s``; returns one dict per mode
    (what it sent). ``bus`` must already be subscribed (``insider.heard``) and linked."""
    modes = list(modes)
    out = []
    t_end = wall() + duration_s
    share = duration_s / max(1, len(modes))
    for i, mode in enumerate(modes):
        if mode not in MODES:
            raise ValueError(f"unknown insider mode {mode!r} (one of {', '.join(MODES)})")
        stop = min(t_end, wall() + share) if i < len(modes) - 1 else t_end
        if mode == "replay":  # only what is captured from now on is replayed
            insider.captured.clear()
        before = insider.sent[mode]
        t0 = wall()
        while (now := wall()) < stop:
            for key, data, signed in insider.tick(mode, now):
                _put(bus, key, data, signed)
            sleep(period_s)
        out.append({"attack": "insider", "mode": mode, "as": f"station-{insider.me}",
                    "sent": insider.sent[mode] - before, "seconds": round(wall() - t0, 3)})
    return out


def attack_insider(args) -> list[dict]:
    """`larns attack --as station-N --mode M` over Zenoh with N's credentials from ``--secure DIR``
    (as `larns station --secure` loads them). Prints one JSON line per mode; returns them."""
    import json

    from larns.adversary.attacks import _bus, _wait_linked

    me = int(args.as_id)
    bus = _bus(args, f"station-{me}")
    linked = _wait_linked(bus, args.link_wait)
    fallback = None
    if args.epoch is not None:  # the fleet's epoch given: field time before any nav is heard
        fallback = (lambda w, e=float(args.epoch), s=float(args.speed): (w - e) * s)
    clock = FieldClock(speed=float(args.speed), fallback=fallback)
    victims = [v for v in (args.victims or []) if v != me]
    ins = Insider(me, np.random.default_rng(args.seed), clock, victims=victims, delay_s=args.delay,
                  budget_per_cycle=args.budget)
    bus.subscribe("larns/station/*/nav/**", lambda k, d: ins.heard(k, d, time.time()))
    t0 = time.time()
    while not clock.known() and time.time() - t0 < args.link_wait:  # the field's time off its navs
        time.sleep(0.05)
    if not victims:
        ins.victims = sorted(ins.heard_ids - {me}) or [v for v in range(1, 11) if v != me]
    modes = list(MODES) if args.mode == "all" else [args.mode]
    res = []
    for mode in modes:
        r = run(bus, ins, [mode], args.duration / len(modes))[0]
        r["links"] = linked
        print(json.dumps(r), flush=True)
        res.append(r)
    bus.close()
    return res
