"""Wire messages: one schema module for every kind in ``docs/protocol.md``.

The envelope on the bus is one msgpack map ``{"v": 1, "msg": {...}, "phy": {...}}``. ``msg`` is
what the station core / aircraft estimator sees; ``phy`` (optional) is the emulated physical layer
(sender's true position and true transmit time) that the receiving channel layer consumes and
strips.

``encode(msg, phy)`` -> bytes (numpy arrays and scalars become plain lists / numbers) and
``decode(data)`` -> ``(msg, phy)``. ``decode`` validates strictly and raises a single exception
type, :class:`MessageError`, on anything malformed: size, msgpack syntax, envelope shape, version,
unknown kind, missing or unknown fields, wrong types, wrong shapes (3 / 3x3), non-finite numbers,
ids out of range, over-long lists and strings. Receivers count and drop (:class:`DropCounter`).

Key expressions (``key_for``) follow the table in ``docs/protocol.md``.
"""

from __future__ import annotations

import logging
import math
import re
import time
from collections import Counter
from typing import Any, Callable, Iterable, Iterator, TypeVar

import msgpack
import numpy as np

VERSION = 1
MAX_PAYLOAD_BYTES = 64 * 1024
MAX_ID = 65535
MAX_LIST = 1024          # members, ranges
MAX_STR = 64
MAX_ABS = 1e12           # any number on the wire (metres, seconds, m^2) stays below this
MAX_SEQ = 2**63 - 1
STATES = ("frame", "joining", "surveying")
NAME_RE = re.compile(r"^[A-Za-z0-9_\-]{1,32}$")

KEY_PREFIX = "larns"


class MessageError(ValueError):
    """A payload that is not a valid LARNS envelope. ``reason`` is a short machine-friendly tag."""

    def __init__(self, reason: str, detail: str = ""):
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason


# --------------------------------------------------------------------------- field validators
# Each validator returns the normalized value or raises MessageError.

def _num(v: Any, name: str) -> float:
    t = type(v)
    if t is not float and t is not int:  # bool is a subclass of int, not int itself: rejected
        raise MessageError("type", f"{name} must be a number, got {t.__name__}")
    f = float(v)
    if not -MAX_ABS <= f <= MAX_ABS:  # also false for NaN; inf is beyond MAX_ABS
        raise MessageError("value", f"{name} not finite or out of range")
    return f


def _nonneg(v: Any, name: str) -> float:
    f = _num(v, name)
    if f < 0.0:
        raise MessageError("value", f"{name} must be >= 0")
    return f


def _int(lo: int, hi: int) -> Callable[[Any, str], int]:
    def check(v: Any, name: str) -> int:
        if isinstance(v, bool) or not isinstance(v, int):
            raise MessageError("type", f"{name} must be an int, got {type(v).__name__}")
        if not lo <= v <= hi:
            raise MessageError("range", f"{name}={v} outside [{lo}, {hi}]")
        return v
    return check


_station_id = _int(1, MAX_ID)
_count = _int(0, MAX_SEQ)
_slot = _int(0, MAX_ID)


def _name(v: Any, name: str) -> str:
    if not isinstance(v, str) or not NAME_RE.match(v):
        raise MessageError("type", f"{name} must match {NAME_RE.pattern}")
    return v


def _text(v: Any, name: str) -> str:
    if not isinstance(v, str) or len(v) > MAX_STR:
        raise MessageError("type", f"{name} must be a string of <= {MAX_STR} chars")
    return v


def _state(v: Any, name: str) -> str:
    if v not in STATES:
        raise MessageError("value", f"{name} must be one of {STATES}")
    return v


def _vec3(v: Any, name: str) -> list[float]:
    if type(v) is list and len(v) == 3:  # fast path: three in-range floats (every valid sender)
        a, b, c = v
        if (type(a) is float and type(b) is float and type(c) is float
                and -MAX_ABS <= a <= MAX_ABS and -MAX_ABS <= b <= MAX_ABS and -MAX_ABS <= c <= MAX_ABS):
            return [a, b, c]
    if not isinstance(v, (list, tuple)) or len(v) != 3:
        raise MessageError("shape", f"{name} must be a list of 3 numbers")
    return [_num(v[0], name), _num(v[1], name), _num(v[2], name)]


def _mat33(v: Any, name: str) -> list[list[float]]:
    if not isinstance(v, (list, tuple)) or len(v) != 3:
        raise MessageError("shape", f"{name} must be 3x3")
    return [_vec3(r, name) for r in v]


def _cov33(v: Any, name: str) -> list[list[float]]:
    m = _mat33(v, name)
    if m[0][0] < 0.0 or m[1][1] < 0.0 or m[2][2] < 0.0:
        raise MessageError("value", f"{name} has a negative variance")
    return m


def _ranges(v: Any, name: str) -> list[list[Any]]:
    if not isinstance(v, (list, tuple)) or len(v) > MAX_LIST:
        raise MessageError("shape", f"{name} must be a list of <= {MAX_LIST} entries")
    out = []
    for r in v:
        if not isinstance(r, (list, tuple)) or len(r) not in (3, 4):
            raise MessageError("shape", f"{name} entries must be [peer, range_m, t_s] or [peer, range_m, t_s, dtheta_s]")
        e = [_station_id(r[0], name), _nonneg(r[1], name), _num(r[2], name)]
        if len(r) == 4:  # two-way time transfer: own clock minus the peer's, s
            e.append(_num(r[3], name))
        out.append(e)
    return out


def _closed(v: Any, name: str) -> list[list[Any]]:
    """A nav's ``closed`` (protocol v2): the sender's averaged ranges (V4b) of the polls it answered since
    its last nav, ``[[poller, range_m, poll seq], ...]``."""
    return _rows(v, name, name, "[poller, range_m, poll_seq]", (_station_id, _nonneg, _count))


def _rows(v: Any, name: str, label: str, shape: str, cells: tuple) -> list[list[Any]]:
    """A list of at most ``MAX_LIST`` fixed-length rows, each cell checked by its function of ``cells``
    (``label``: the list's name in the error messages, ``shape``: a row's as they state it)."""
    if not isinstance(v, (list, tuple)) or len(v) > MAX_LIST:
        raise MessageError("shape", f"{label} must be a list of <= {MAX_LIST} entries")
    out = []
    for r in v:
        if not isinstance(r, (list, tuple)) or len(r) != len(cells):
            raise MessageError("shape", f"{label} entries must be {shape}")
        out.append([f(x, name) for f, x in zip(cells, r)])
    return out


def _clock(v: Any, name: str) -> list[float]:
    """Clock correction ``[t_ref_s, offset_s, freq, var_offset_s2, cov_s, var_freq]`` (sender's clock)."""
    if not isinstance(v, (list, tuple)) or len(v) != 6:
        raise MessageError("shape", f"{name} must be [t_ref_s, offset_s, freq, P_tt, P_tf, P_ff]")
    out = [_num(x, name) for x in v]
    if out[3] < 0.0 or out[5] < 0.0:
        raise MessageError("value", f"{name} has a negative variance")
    return out


def _members(v: Any, name: str) -> list[int]:
    if not isinstance(v, (list, tuple)) or len(v) > MAX_LIST:
        raise MessageError("shape", f"{name} must be a list of <= {MAX_LIST} ids")
    for x in v:
        if type(x) is not int or not 1 <= x <= MAX_ID:
            raise MessageError("range", f"{name} must hold station ids 1..{MAX_ID}")
    return list(v)


def _poll_final(v: Any, name: str) -> dict[str, Any]:
    """A nav's ``poll`` (protocol v2, the final of the sender's poll): ``{"seq": the poll's seq, "t1": its
    transmit stamp, "rx": [[member, T4: the sender's receive stamp of its reply], ...]}``."""
    if not isinstance(v, dict) or set(v) != {"seq", "t1", "rx"}:
        raise MessageError("shape", f"{name} must be a map with exactly ['rx', 'seq', 't1']")
    out = _rows(v["rx"], name, f"{name}.rx", "[member, t4_s]", (_station_id, _num))
    return {"seq": _count(v["seq"], name), "t1": _num(v["t1"], name), "rx": out}


MAX_SLOTS = 1024  # slots of a distributed assignment's cycle (net.scenario.MAX_CYCLE_SLOTS)
SLOT_STATES = (1, 2, 3)  # stations.slots CLEAN, SOFT, GARBAGE (FREE slots are not sent)


def _slot_summary(v: Any, name: str) -> dict[str, Any]:
    """A nav's slot summary (distributed assignment, docs/slots.md): ``{"n": C, "claim": cycle,
    "v": [[slot, state, owner, since], ...]}`` - the cycle's slot count, the cycle the sender claimed
    its slot in (-1: none), and one entry per slot not free in its one-hop view (state 1 clean,
    2 soft, 3 garbage; owner 0: none; since -1: none), slots unique and below ``n``."""
    if not isinstance(v, dict) or set(v) != {"n", "claim", "v"}:
        raise MessageError("shape", f"{name} must be a map with exactly n, claim and v")
    n = _int(1, MAX_SLOTS)(v["n"], f"{name}.n")
    claim = _int(-1, MAX_SEQ)(v["claim"], f"{name}.claim")
    ent = v["v"]
    if not isinstance(ent, (list, tuple)) or len(ent) > n:
        raise MessageError("shape", f"{name}.v must be a list of <= {name}.n entries")
    out, seen = [], set()
    for e in ent:
        if not isinstance(e, (list, tuple)) or len(e) != 4:
            raise MessageError("shape", f"{name}.v entries must be [slot, state, owner, since]")
        k, st = _int(0, n - 1)(e[0], f"{name}.v slot"), _int(1, 3)(e[1], f"{name}.v state")
        own, since = _int(0, MAX_ID)(e[2], f"{name}.v owner"), _int(-1, MAX_SEQ)(e[3], f"{name}.v since")
        if k in seen:
            raise MessageError("value", f"{name}.v: slot {k} twice")
        seen.add(k)
        out.append([k, st, own, since])
    return {"n": n, "claim": claim, "v": out}


slot_summary = _slot_summary  # the stations' cores check a summary handed to them directly (the simulator)


def _nav_slots_plausible(m: dict[str, Any]) -> None:
    """A nav's summary against the nav itself: its slot within the summary's cycle, and no claim
    (its own or a neighbour's) dated after the cycle it is sent in plus one (a claim takes effect
    the cycle after it is made)."""
    s = m.get("slots")
    if s is None:
        return
    if m["slot"] >= s["n"]:
        raise MessageError("value", f"nav: slot {m['slot']} outside the summary's {s['n']} slots")
    top = m["cycle"] + 1
    if s["claim"] > top or any(e[3] > top for e in s["v"]):
        raise MessageError("value", f"nav: a slot claim after cycle {top}")


def _extra(v: Any, name: str) -> dict[str, float]:
    if not isinstance(v, dict) or len(v) > 32:
        raise MessageError("shape", f"{name} must be a map of <= 32 numbers")
    return {_text(k, name): _num(x, name) for k, x in v.items()}


# core journal (docs/protocol.md "Core journal"): what a station core consumed, for offline replay
AIR_MSG_KINDS = ("range_req", "range_rsp", "nav", "poll", "reply")
MAX_JOURNAL = 4 * MAX_LIST  # entries per core_input message


def _opt(check: Callable[[Any, str], Any]) -> Callable[[Any, str], Any]:
    def f(v: Any, name: str) -> Any:
        return None if v is None else check(v, name)
    return f


_COMPOUND = object()  # _scalar: not a scalar, the caller decides


def _scalar(v: Any, name: str) -> Any:
    """A journal scalar: None, bool, an int within +-MAX_SEQ, a finite number or a short string
    (checked); ``_COMPOUND`` for anything else."""
    if v is None or isinstance(v, bool):
        return v
    if type(v) is int:
        if not -MAX_SEQ <= v <= MAX_SEQ:
            raise MessageError("range", f"{name} out of range")
        return v
    if type(v) is float:
        return _num(v, name)
    if isinstance(v, str):
        return _text(v, name)
    return _COMPOUND


def _cfg_value(v: Any, name: str) -> Any:
    """A station-config value: bool, int, finite number, short string or a list of ids (kept as is)."""
    out = _scalar(v, name)
    if out is not _COMPOUND:
        return out
    if isinstance(v, (list, tuple)):
        return _members(v, name)
    raise MessageError("type", f"{name}: unsupported config value {type(v).__name__}")


def _init_record(v: Any, name: str) -> dict[str, Any]:
    need = {"cfg", "tdma", "init_pos_m", "init_cov_m2", "start_s"}
    if not isinstance(v, dict) or set(v) != need:
        raise MessageError("shape", f"{name} must be a map with exactly {sorted(need)}")
    cfg = v["cfg"]
    if not isinstance(cfg, dict) or len(cfg) > 32:
        raise MessageError("shape", f"{name}.cfg must be a map of <= 32 entries")
    tdma = v["tdma"]
    if not isinstance(tdma, (list, tuple)) or len(tdma) != 2:
        raise MessageError("shape", f"{name}.tdma must be [cycle_s, slot_s]")
    return {"cfg": {_text(k, name): _cfg_value(x, f"{name}.cfg.{k}") for k, x in cfg.items()},
            "tdma": [_nonneg(tdma[0], name), _nonneg(tdma[1], name)],
            "init_pos_m": _opt(_vec3)(v["init_pos_m"], f"{name}.init_pos_m"),
            "init_cov_m2": _opt(_cov33)(v["init_cov_m2"], f"{name}.init_cov_m2"),
            "start_s": _num(v["start_s"], f"{name}.start_s")}


def _journal(v: Any, name: str) -> list[list[Any]]:
    """``[["t", t_local_s] | ["m", t_rx_local_s, msg] | ["g", t_rx_local_s], ...]``; msg an air message,
    validated; ``g``: a collision heard (distributed slot assignment, docs/slots.md)."""
    if not isinstance(v, (list, tuple)) or len(v) > MAX_JOURNAL:
        raise MessageError("shape", f"{name} must be a list of <= {MAX_JOURNAL} entries")
    out: list[list[Any]] = []
    for e in v:
        if isinstance(e, (list, tuple)) and len(e) == 2 and e[0] == "t":
            out.append(["t", _num(e[1], name)])
        elif isinstance(e, (list, tuple)) and len(e) == 2 and e[0] == "g":  # energy, nothing decodable
            out.append(["g", _num(e[1], name)])
        elif isinstance(e, (list, tuple)) and len(e) == 3 and e[0] == "m":
            m = validate_msg(e[2])
            if m["kind"] not in AIR_MSG_KINDS:
                raise MessageError("kind", f"{name}: {m['kind']} is not an air message")
            out.append(["m", _num(e[1], name), m])
        else:
            raise MessageError("shape", f"{name} entries must be ['t', t], ['m', t, msg] or ['g', t]")
    return out


# vehicle journal (docs/protocol.md "Vehicle journal"): the navigator's init record and inputs
VEH_RECORD_NUMBERS = ("t0_s", "dt_s", "q_gyro", "q_accel", "q_odo", "q_b", "q_d", "k_odo", "gyro_offset_rad_s",
                      "sigma_rho_m", "sigma_rate_m_s", "sigma_q0_m", "sigma_v0_m_s", "sigma_att0_arcmin",
                      "sigma_b0_m", "sigma_d0_m_s")
VEH_MAX_POINTS = 64


def _vec3_list(max_n: int) -> Callable[[Any, str], list[list[float]]]:
    def check(v: Any, name: str) -> list[list[float]]:
        if not isinstance(v, (list, tuple)) or len(v) > max_n:
            raise MessageError("shape", f"{name} must be a list of <= {max_n} 3-vectors")
        return [_vec3(x, name) for x in v]
    return check


def _num_list(max_n: int) -> Callable[[Any, str], list[float]]:
    def check(v: Any, name: str) -> list[float]:
        if not isinstance(v, (list, tuple)) or len(v) > max_n:
            raise MessageError("shape", f"{name} must be a list of <= {max_n} numbers")
        return [_num(x, name) for x in v]
    return check


def _veh_record(v: Any, name: str) -> dict[str, Any]:
    """The vehicle navigator's init record: the map and its settings (vehicle/navigator/live.py)."""
    shaped = {"route_enu_m": _vec3_list(VEH_MAX_POINTS), "origin_deg": _vec3,
              "speeds_m_s": _num_list(VEH_MAX_POINTS - 1), "net_to_enu": _mat33, "net_offset_m": _vec3}
    need = set(shaped) | set(VEH_RECORD_NUMBERS)
    if not isinstance(v, dict) or set(v) != need:
        raise MessageError("shape", f"{name} must be a map with exactly {sorted(need)}")
    out = {k: f(v[k], f"{name}.{k}") for k, f in shaped.items()}
    out.update({k: _num(v[k], f"{name}.{k}") for k in VEH_RECORD_NUMBERS})
    if len(out["route_enu_m"]) < 2 or len(out["speeds_m_s"]) != len(out["route_enu_m"]) - 1:
        raise MessageError("shape", f"{name}: a route of >= 2 points and one speed per leg")
    return out


def _veh_journal(v: Any, name: str) -> list[list[Any]]:
    """``[["imu", k0, gyro (n, 3), accel (n, 3), odo (n,)] | ["m", tau, src, pos_n, cov_n, clock_var, rho,
    rate], ...]``."""
    if not isinstance(v, (list, tuple)) or len(v) > MAX_LIST:
        raise MessageError("shape", f"{name} must be a list of <= {MAX_LIST} entries")
    out: list[list[Any]] = []
    for e in v:
        if isinstance(e, (list, tuple)) and len(e) == 5 and e[0] == "imu":
            g, a, z = (_vec3_list(MAX_LIST)(e[2], name), _vec3_list(MAX_LIST)(e[3], name),
                       _num_list(MAX_LIST)(e[4], name))
            if not len(g) == len(a) == len(z):
                raise MessageError("shape", f"{name}: imu entry with unequal gyro / accel / odometer lengths")
            out.append(["imu", _count(e[1], name), g, a, z])
        elif isinstance(e, (list, tuple)) and len(e) == 8 and e[0] == "m":
            out.append(["m", _num(e[1], name), _station_id(e[2], name), _vec3(e[3], name), _cov33(e[4], name),
                        _nonneg(e[5], name), _num(e[6], name), _num(e[7], name)])
        else:
            raise MessageError("shape", f"{name} entries must be ['imu', k0, gyro, accel, odo] or "
                                        "['m', tau, src, pos, cov, clock_var, rho, rate]")
    return out


# aircraft journal (docs/replay.md "Aircraft journal"): the navigator's init record and inputs
AC_RECORD_MAX = 64  # entries of the init record


def _ac_value(v: Any, name: str, depth: int = 0) -> Any:
    """A value of the aircraft init record: None, bool, a finite number, a short string, or a list
    (<= MAX_LIST) / map (<= AC_RECORD_MAX) of them, nested at most 3 deep."""
    out = _scalar(v, name)
    if out is not _COMPOUND:
        return out
    if depth >= 3:
        raise MessageError("shape", f"{name} nested too deep")
    if isinstance(v, (list, tuple)) and len(v) <= MAX_LIST:
        return [_ac_value(x, name, depth + 1) for x in v]
    if isinstance(v, dict) and len(v) <= AC_RECORD_MAX:
        return {_text(k, name): _ac_value(x, f"{name}.{k}", depth + 1) for k, x in v.items()}
    raise MessageError("shape", f"{name}: unsupported value {type(v).__name__}")


def _ac_record(v: Any, name: str) -> dict[str, Any]:
    """The aircraft navigator's init record (aircraft/journal.py): ``kind`` radio / ins / triad and
    the navigator's settings."""
    if not isinstance(v, dict) or v.get("kind") not in ("radio", "ins", "triad"):
        raise MessageError("shape", f"{name} must be a map with kind radio, ins or triad")
    return _ac_value(v, name)


def _opt_num(v: Any, name: str) -> float | None:
    return None if v is None else _num(v, name)


def _ac_journal(v: Any, name: str) -> list[list[Any]]:
    """``[["m", t_rx, src, pos, cov, clock_var, rho] | ["imu", k0, gyro (n, 3), accel (n, 3)] |
    ["sv", k, ranges (n,) or None each, baro or None], ...]``."""
    if not isinstance(v, (list, tuple)) or len(v) > MAX_LIST:
        raise MessageError("shape", f"{name} must be a list of <= {MAX_LIST} entries")
    out: list[list[Any]] = []
    for e in v:
        if isinstance(e, (list, tuple)) and len(e) == 7 and e[0] == "m":
            out.append(["m", _num(e[1], name), _station_id(e[2], name), _vec3(e[3], name), _cov33(e[4], name),
                        _nonneg(e[5], name), _num(e[6], name)])
        elif isinstance(e, (list, tuple)) and len(e) == 4 and e[0] == "imu":
            g, a = _vec3_list(MAX_LIST)(e[2], name), _vec3_list(MAX_LIST)(e[3], name)
            if len(g) != len(a):
                raise MessageError("shape", f"{name}: imu entry with unequal gyro / accel lengths")
            out.append(["imu", _count(e[1], name), g, a])
        elif isinstance(e, (list, tuple)) and len(e) == 4 and e[0] == "sv" and isinstance(e[2], (list, tuple)) \
                and len(e[2]) <= MAX_LIST:
            out.append(["sv", _count(e[1], name), [_opt_num(x, name) for x in e[2]], _opt_num(e[3], name)])
        else:
            raise MessageError("shape", f"{name} entries must be ['m', t, src, pos, cov, clock_var, rho], "
                                        "['imu', k0, gyro, accel] or ['sv', k, ranges, baro]")
    return out


# kind -> (required fields, optional fields); common fields added below
_COMMON_STATION = {"src": _station_id, "seq": _count, "stamp_s": _num}
_COMMON_AIRCRAFT = {"src": _name, "seq": _count, "stamp_s": _num}

SCHEMAS: dict[str, tuple[dict[str, Callable], dict[str, Callable]]] = {
    "range_req": ({**_COMMON_STATION, "dst": _station_id, "cycle": _count, "slot": _slot,
                   "t_tx_s": _num}, {}),
    "range_rsp": ({**_COMMON_STATION, "dst": _station_id, "req_seq": _count,
                   "turnaround_s": _num, "pos_m": _vec3, "cov_m2": _cov33, "n_updates": _count,
                   "state": _state}, {"t_tx_s": _num, "t_rx_s": _num, "clock": _clock}),
    "nav": ({**_COMMON_STATION, "cycle": _count, "slot": _slot, "t_tx_s": _num, "pos_m": _vec3,
             "cov_m2": _cov33, "n_updates": _count, "state": _state, "ranges": _ranges,
             "members": _members}, {"clock": _clock, "excluded": _members, "slots": _slot_summary,
                                    "poll": _poll_final, "closed": _closed}),
    # protocol v2 (docs/protocol.md "Protocol v2"): one poll naming its members, one reply per member
    "poll": ({**_COMMON_STATION, "cycle": _count, "slot": _slot, "t_tx_s": _num, "members": _members}, {}),
    "reply": ({**_COMMON_STATION, "dst": _station_id, "poll_seq": _count, "t_rx_s": _num, "t_tx_s": _num,
               "pos_m": _vec3, "cov_m2": _cov33, "n_updates": _count, "state": _state}, {"clock": _clock}),
    "estimate": ({**_COMMON_STATION, "t_s": _num, "pos_m": _vec3, "cov_m2": _cov33,
                  "n_updates": _count, "estimator": _text, "state": _state},
                 {"slot": _slot, "cycle": _count, "dropped": _count, "clock_offset_s": _num,
                  "clock_freq": _num, "clock_offset_sd_s": _nonneg, "clock_freq_sd": _nonneg}),
    "truth": ({**_COMMON_STATION, "t_s": _num, "pos_m": _vec3}, {"clock_error_s": _num}),
    "core_init": ({**_COMMON_STATION, "record": _init_record}, {}),
    "core_input": ({**_COMMON_STATION, "entries": _journal}, {}),
    "ac_estimate": ({**_COMMON_AIRCRAFT, "t_s": _num, "pos_m": _vec3, "cov_m2": _cov33,
                     "algo": _name},
                    {"vel_m_s": _vec3, "vel_cov": _cov33, "n_updates": _count, "extra": _extra,
                     # integrity (issue 14, aircraft/navigator/radio/fde.py): protection levels, excluded station ids
                     "hpl_m": _nonneg, "vpl_m": _nonneg, "excluded": _members}),
    "ac_truth": ({**_COMMON_AIRCRAFT, "t_s": _num, "pos_m": _vec3},
                 {"vel_m_s": _vec3, "extra": _extra}),
    # what a navigator is doing when it publishes no estimate (aircraft/navigator/receiver.py)
    "ac_status": ({**_COMMON_AIRCRAFT, "t_s": _num, "algo": _name, "state": _text},
                  {"detail": _text, "counts": _extra}),
    # the vehicle process (vehicle/core.py; docs/vehicle.md "The vehicle process")
    "veh_estimate": ({**_COMMON_AIRCRAFT, "t_s": _num, "pos_m": _vec3, "cov_m2": _cov33, "vel_m_s": _vec3,
                      "algo": _name, "n_updates": _count}, {"vel_cov": _cov33, "extra": _extra}),
    "veh_truth": ({**_COMMON_AIRCRAFT, "t_s": _num, "pos_m": _vec3, "vel_m_s": _vec3}, {"extra": _extra}),
    "veh_init": ({**_COMMON_AIRCRAFT, "record": _veh_record}, {}),
    "veh_input": ({**_COMMON_AIRCRAFT, "entries": _veh_journal}, {}),
    "ac_init": ({**_COMMON_AIRCRAFT, "record": _ac_record}, {}),
    "ac_input": ({**_COMMON_AIRCRAFT, "entries": _ac_journal}, {}),
}
DECISIONS = ("exclude", "readmit")


def _decision(v: Any, name: str) -> str:
    if v not in DECISIONS:
        raise MessageError("bad_field", f"{name} must be one of {DECISIONS}")
    return v


def _prob(v: Any, name: str) -> float:
    x = _num(v, name)
    if not 0.0 < x < 1.0:
        raise MessageError("bad_field", f"{name} must be a probability in (0, 1)")
    return x


# integrity (issue 14): a station's conclusion about a peer (docs/protocol.md)
SCHEMAS["integrity"] = ({**_COMMON_STATION, "t_s": _num, "suspect": _station_id, "statistic": _nonneg,
                         "threshold": _nonneg, "dof": _count, "p_fa": _prob, "decision": _decision},
                        {"excluded": _members})
KINDS = tuple(SCHEMAS)
PHY_SCHEMA: dict[str, Callable] = {"pos_m": _vec3, "t_true_s": _num}


def validate_msg(msg: Any) -> dict[str, Any]:
    """Validate one ``msg`` map; returns a normalized copy (plain lists and floats)."""
    if not isinstance(msg, dict):
        raise MessageError("envelope", "msg must be a map")
    kind = msg.get("kind")
    if not isinstance(kind, str) or kind not in SCHEMAS:
        raise MessageError("kind", f"unknown kind {str(kind)[:32]!r}")
    req, opt = SCHEMAS[kind]
    checks = _MERGED.get(kind)
    if checks is None or len(checks) != len(req) + len(opt) + 1:  # (schemas may change after import)
        checks = _MERGED[kind] = {**opt, **req, "kind": None}
    out: dict[str, Any] = {}
    for k, v in msg.items():
        try:
            check = checks[k]
        except (KeyError, TypeError):
            raise MessageError("field", f"{kind}: unknown field {str(k)[:32]!r}") from None
        out[k] = kind if check is None else check(v, k)
    if not req.keys() <= out.keys():
        raise MessageError("field", f"{kind}: missing {[k for k in req if k not in out]}")
    if kind == "nav":
        _nav_slots_plausible(out)
    return out


_MERGED: dict[str, dict[str, Callable | None]] = {}


def validate_phy(phy: Any) -> dict[str, Any]:
    if not isinstance(phy, dict) or set(phy) != set(PHY_SCHEMA):
        raise MessageError("phy", f"phy must be a map with exactly {sorted(PHY_SCHEMA)}")
    return {k: PHY_SCHEMA[k](v, f"phy.{k}") for k, v in phy.items()}


# --------------------------------------------------------------------------- encode / decode

def _plain(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"cannot encode {type(o).__name__}")


_SCALARS = frozenset((int, float, str, bool, type(None), bytes))


def to_plain(o: Any) -> Any:
    """Recursively convert numpy arrays / scalars (and tuples) into msgpack-native values.
    Flat lists of plain scalars (the common case) are returned without recursion."""
    t = type(o)
    if t in _SCALARS:
        return o
    if t is dict:
        return {k: to_plain(v) for k, v in o.items()}
    if t is list or t is tuple:
        scal = _SCALARS
        for x in o:
            if type(x) not in scal:
                return [to_plain(v) for v in o]
        return o if t is list else list(o)
    if t is np.ndarray:
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, dict):
        return {k: to_plain(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [to_plain(v) for v in o]
    return o


def encode(msg: dict[str, Any], phy: dict[str, Any] | None = None, validate: bool = True) -> bytes:
    """Envelope ``msg`` (+ optional ``phy``) as msgpack bytes. Validates by default so a bug in a
    sender fails loudly at the source instead of being dropped silently at every receiver."""
    if validate:
        m = validate_msg(to_plain(msg))
        p = validate_phy(to_plain(phy)) if phy is not None else None
    else:  # numpy values are converted by msgpack's ``default`` hook
        m, p = msg, phy
    env: dict[str, Any] = {"v": VERSION, "msg": m}
    if p is not None:
        env["phy"] = p
    data = msgpack.packb(env, use_bin_type=True, default=_plain)
    if len(data) > MAX_PAYLOAD_BYTES:
        raise MessageError("size", f"{len(data)} bytes > {MAX_PAYLOAD_BYTES}")
    return data


def decode(data: bytes | bytearray | memoryview) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """Parse and validate one envelope. Returns ``(msg, phy)``, ``phy`` None when absent."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise MessageError("type", "payload must be bytes")
    if len(data) > MAX_PAYLOAD_BYTES:
        raise MessageError("size", f"{len(data)} bytes > {MAX_PAYLOAD_BYTES}")
    if data[:1] == SIGNED_MARK:  # a signed frame (net/security.py): the envelope inside, unverified
        data = _strip_signature(data)
    try:
        env = msgpack.unpackb(
            bytes(data), raw=False, strict_map_key=True, use_list=True,
            max_str_len=MAX_PAYLOAD_BYTES, max_bin_len=0, max_array_len=MAX_LIST * 4,
            max_map_len=64, max_ext_len=0,
        )
    except Exception as e:  # msgpack raises several types (ExtraData, ValueError, StackError...)
        raise MessageError("msgpack", type(e).__name__) from None
    if not isinstance(env, dict):
        raise MessageError("envelope", "not a map")
    v = env.get("v")
    if isinstance(v, bool) or v != VERSION:
        raise MessageError("version", f"unsupported version {str(v)[:16]}")
    extra = set(env) - {"v", "msg", "phy"}
    if extra:
        raise MessageError("envelope", "unknown envelope keys")
    msg = validate_msg(env.get("msg"))
    phy = validate_phy(env["phy"]) if env.get("phy") is not None else None
    return msg, phy


SIGNED_MARK = b"\xc1"  # never the first byte of a msgpack value


def _strip_signature(data: bytes) -> bytes:
    from net.security import strip_signature  # (net.security does not import this module at load)

    return strip_signature(bytes(data))


def peek_stamp(data: bytes) -> float | None:
    """The sender's ``stamp_s`` from raw bytes without full validation (for the recorder)."""
    try:
        if data[:1] == SIGNED_MARK:
            data = _strip_signature(data)
        env = msgpack.unpackb(data, raw=False, strict_map_key=False, max_bin_len=0, max_ext_len=0)
        s = env["msg"]["stamp_s"]
        if isinstance(s, (int, float)) and not isinstance(s, bool) and math.isfinite(s):
            return float(s)
    except Exception:
        pass
    return None


# --------------------------------------------------------------------------- key expressions

def station_key(station_id: int, *rest: str | int) -> str:
    return "/".join([KEY_PREFIX, "station", str(int(station_id)), *map(str, rest)])


def aircraft_key(name: str, *rest: str) -> str:
    return "/".join([KEY_PREFIX, "aircraft", name, *rest])


def vehicle_key(name: str, *rest: str) -> str:
    return "/".join([KEY_PREFIX, "vehicle", name, *rest])


# Every key a sender publishes under its own prefix ``larns/<role>/<name>/`` (``*``: one chunk, the
# destination station, the algorithm or a station's nav tile: net/tiles.py; a live station sends its
# navs on ``nav/<tile>``, ``nav`` is the key of :func:`key_for` and of recordings from before tiles).
# The access rules (net/security.py) allow exactly these, so an invented sub-key is refused by every receiver's Zenoh.
OWN_KEYS = {
    "station": ("nav/*", "nav", "estimate", "truth", "init", "input", "integrity", "range/req/*", "range/rsp/*",
                "poll", "reply/*"),
    "aircraft": ("estimate/*", "truth", "status/*", "init", "input"),
    "vehicle": ("estimate", "truth", "init", "input"),
}


def alive_key(role: str, name: str | int) -> str:
    return f"{KEY_PREFIX}/alive/{role}/{name}"


def key_for(msg: dict[str, Any]) -> str:
    """The key expression a message is published on (``docs/protocol.md``)."""
    kind = msg["kind"]
    src = msg["src"]
    if kind == "range_req":
        return station_key(src, "range", "req", msg["dst"])
    if kind == "range_rsp":
        return station_key(src, "range", "rsp", msg["dst"])
    if kind in ("nav", "estimate", "truth", "poll"):
        return station_key(src, kind)
    if kind == "reply":
        return station_key(src, "reply", msg["dst"])
    if kind == "core_init":
        return station_key(src, "init")
    if kind == "core_input":
        return station_key(src, "input")
    if kind == "integrity":
        return station_key(src, "integrity")
    if kind == "ac_estimate":
        return aircraft_key(src, "estimate", msg["algo"])
    if kind == "ac_truth":
        return aircraft_key(src, "truth")
    if kind == "ac_status":
        return aircraft_key(src, "status", msg["algo"])
    if kind in ("ac_init", "ac_input"):
        return aircraft_key(src, kind[3:])
    if kind.startswith("veh_"):
        return vehicle_key(src, {"veh_estimate": "estimate", "veh_truth": "truth", "veh_init": "init",
                                 "veh_input": "input"}[kind])
    raise MessageError("kind", f"no key for kind {kind!r}")


def parse_key(key: str) -> tuple[str, str | int, list[str]] | None:
    """``larns/station/7/range/req/3`` -> ``("station", 7, ["range", "req", "3"])``; None if foreign."""
    parts = str(key).split("/")
    if len(parts) < 3 or parts[0] != KEY_PREFIX:
        return None
    role, name = parts[1], parts[2]
    if role == "station":
        try:
            return role, int(name), parts[3:]
        except ValueError:
            return None
    return role, name, parts[3:]


def is_nav_key(key: str) -> bool:
    """A station's nav key: ``larns/station/<id>/nav/<tile>`` (net/tiles.py) or, in a recording from
    before tiles, ``larns/station/<id>/nav``."""
    pk = parse_key(key)
    return pk is not None and pk[0] == "station" and len(pk[2]) in (1, 2) and pk[2][0] == "nav"


# --------------------------------------------------------------------------- drop counter

class DropCounter:
    """Counts rejected payloads by reason and logs at most one summary line per ``interval_s``.

    ``clock`` is injectable (defaults to ``time.monotonic``) so tests need no sleeping.
    """

    def __init__(self, name: str = "larns", interval_s: float = 5.0,
                 logger: logging.Logger | None = None, clock: Callable[[], float] = time.monotonic):
        self.name = name
        self.interval_s = float(interval_s)
        self.log = logger or logging.getLogger("larns.net")
        self.clock = clock
        self.by_reason: Counter[str] = Counter()
        self.total = 0
        self._last_log = -math.inf
        self._since_log = 0
        self.lines_logged = 0

    def drop(self, reason: str, detail: str = "") -> None:
        self.total += 1
        self._since_log += 1
        self.by_reason[reason] += 1
        now = self.clock()
        if now - self._last_log >= self.interval_s:
            self.log.warning("%s: dropped %d malformed message(s) (total %d, by reason %s); last: %s",
                             self.name, self._since_log, self.total, dict(self.by_reason),
                             detail[:200])
            self._last_log = now
            self._since_log = 0
            self.lines_logged += 1

    def drop_error(self, err: MessageError) -> None:
        self.drop(err.reason, str(err))

    def as_dict(self) -> dict[str, Any]:
        return {"total": self.total, "by_reason": dict(self.by_reason)}


_T = TypeVar("_T")


def decode_valid(items: Iterable[_T], payload: Callable[[_T], Any] = lambda x: x,
                 invalid: Counter[str] | DropCounter | None = None) -> Iterator[tuple[_T, dict[str, Any], dict[str, Any] | None]]:
    """Strictly decode a stream of payloads, skipping the invalid ones.

    Yields ``(item, msg, phy)`` for every item whose ``payload(item)`` bytes are a valid envelope
    (:func:`decode`); an invalid one is counted by reason in ``invalid`` (a ``Counter`` or a
    :class:`DropCounter`; None: not counted) and skipped, never raised. ``items`` may be recorded
    messages (``payload=lambda m: m.data``) or raw bytes (the default ``payload``)."""
    for item in items:
        try:
            msg, phy = decode(payload(item))
        except MessageError as e:
            if isinstance(invalid, DropCounter):
                invalid.drop_error(e)
            elif invalid is not None:
                invalid[e.reason] += 1
            continue
        yield item, msg, phy


def station_nav(decode: Callable[[str, bytes], tuple[dict[str, Any], dict[str, Any] | None]], key: str,
                data: bytes, drops: DropCounter) -> tuple[dict[str, Any], dict[str, Any]] | None:
    """A receiver's intake of a station broadcast: ``decode(key, data)`` (plain :func:`decode` or a
    ``--secure`` guard's), then the message must be a ``nav`` with its ``phy`` block on its own
    station's key (``larns/station/<src>/nav/<tile>``, or ``.../nav`` before tiles). Returns ``(msg, phy)``, or None with the reason
    counted in ``drops`` (the decoder's, or ``key``)."""
    try:
        msg, phy = decode(key, data)
    except MessageError as e:
        drops.drop_error(e)
        return None
    pk = parse_key(key)
    if msg["kind"] != "nav" or phy is None or pk is None or pk[0] != "station" or pk[1] != msg["src"]:
        drops.drop("key", f"{msg['kind']} on {key}")
        return None
    return msg, phy
