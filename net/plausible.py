"""Plausibility of a station's nav broadcast for a receiver that navigates on it (issue 32 item 1).

A signature proves who sent a nav, not that its values are sane: a stolen station key signs anything
the wire schema (``net/messages.py``) accepts, numbers up to 1e12 included. The aircraft and the
vehicle (``aircraft/navigator/plausible.py``, ``vehicle/navigator/plausible.py``) check each nav
against physical bounds of the field *before* it reaches their channel layer's realization of
network time or any filter; one outside its bounds is dropped and counted by reason, never
down-weighted. The stations' own admission (``stations/admission.py``) applies the same bounds
(same formulas) to what a peer sends them.

Bounds (:class:`NavBounds`, from the scenario):

* ``pos``: the broadcast position within the field's extent (largest distance of a deployed station
  from station 1, the network frame's origin) plus a margin (1 km);
* ``cov``: a finite, symmetric, positive semi-definite covariance, variances below ``(10 pos)^2``;
* ``clock``: the clock correction ``[t_ref, offset, freq, P_tt, P_tf, P_ff]`` within the oscillator
  class: ``|offset|`` below 10 sigma of the offset at the epoch plus 10 sigma of the frequency over a
  day, ``|freq|`` below 20 sigma (never below 10 ms / 1 ppm, never 1e-3 or more; a receiver that does
  not know the class takes the loosest, 50 ppm: 43 s and 1e-3), variances below the squares of those, ``|P_tf| <= sqrt(P_tt P_ff)``, ``t_ref`` within the time window of ``t_tx``;
* ``time``: the transmit time ``t_tx`` within ``2 offset + window`` of the receiver's own reading of
  the reception time (``window``: six cycles, a station's dead-after horizon);
* ``state``: only ``frame`` / ``surveying`` stations are navigated on (checked by the cores).

Pure: no clock, no RNG, no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from nav.spd3 import chol3

DAY_S = 86400.0


@dataclass(frozen=True)
class NavBounds:
    """Bounds of one field (module docstring); all finite and positive."""

    pos_m: float
    var_m2: float
    clock_offset_s: float
    clock_freq: float
    time_window_s: float

    @classmethod
    def of(cls, stations_m, clock_offset_sigma_s: float | None = None, clock_freq_sigma: float | None = None,
           cycle_s: float = 1.0, margin_m: float = 1000.0, dead_after_cycles: int = 5) -> "NavBounds":
        """From the deployed stations ``stations_m`` (n, 3) in the network frame (station 1 at the origin:
        the field's extent is their largest distance from it) and the stations' oscillator class (``[clock]``: offset sigma at the
        epoch, fractional frequency sigma); without a class, the loosest one the stations accept."""
        p = np.asarray(stations_m, float).reshape(-1, 3)
        radius = float(np.max(np.linalg.norm(p, axis=1))) if len(p) else 0.0
        pos = radius + float(margin_m)
        if clock_offset_sigma_s is None or clock_freq_sigma is None:  # the loosest class: 50 ppm
            clock_offset_sigma_s, clock_freq_sigma = 0.0, 5e-5
        return cls(pos_m=pos, var_m2=(10.0 * pos) ** 2,
                   clock_offset_s=max(0.01, 10.0 * clock_offset_sigma_s + 10.0 * clock_freq_sigma * DAY_S),
                   clock_freq=min(1e-3, max(1e-6, 20.0 * clock_freq_sigma)),
                   time_window_s=(dead_after_cycles + 1) * float(cycle_s))

    @classmethod
    def of_scenario(cls, scn) -> "NavBounds":
        """From a :class:`net.scenario.Scenario`: its stations, ``[clock]`` class and TDMA cycle."""
        return cls.of(scn.pos_m, scn.clock.offset_s, scn.clock.freq_sigma, scn.tdma.cycle_s)


@lru_cache(maxsize=64)
def _cached(key: bytes, offset_s: float | None, freq_sigma: float | None, cycle_s: float) -> NavBounds:
    return NavBounds.of(np.frombuffer(key, float).reshape(-1, 3), offset_s, freq_sigma, cycle_s)


def bounds_for(stations_m, clock_offset_sigma_s: float | None = None, clock_freq_sigma: float | None = None,
               cycle_s: float = 1.0) -> NavBounds:
    """:meth:`NavBounds.of`, cached per field (a core may call it on every message)."""
    a = np.ascontiguousarray(np.asarray(stations_m, float).reshape(-1, 3))
    return _cached(a.tobytes(), clock_offset_sigma_s, clock_freq_sigma, float(cycle_s))


def cholesky3_ok(a) -> bool:
    """Whether the Cholesky factorization of the finite symmetric 3x3 ``a`` succeeds: ``a`` is then
    positive definite up to the factorization's backward error (a few ulp of its largest entry),
    far inside ``lambda_min >= -1e-9 lambda_max``, so a success answers that test without an
    eigendecomposition (a failure leaves it to one)."""
    return _chol3_ok(float(a[0, 0]), float(a[1, 0]), float(a[2, 0]), float(a[1, 1]), float(a[2, 1]),
                     float(a[2, 2]))


def _chol3_ok(d0: float, a10: float, a20: float, a11: float, a21: float, a22: float) -> bool:
    """:func:`cholesky3_ok` on the lower triangle's six floats."""
    return chol3(d0, a10, a20, a11, a21, a22) is not None


def cov_ok(c, bound_m2: float) -> bool:
    """A finite, symmetric, positive semi-definite 3x3 with variances in ``[0, bound_m2]``."""
    fast = _cov_ok_rows(c, bound_m2)
    if fast is not None:
        return fast
    a = np.asarray(c, float)
    if a.shape != (3, 3) or not np.all(np.isfinite(a)):
        return False
    d = np.diag(a)
    if np.any(d < 0.0) or np.any(d > bound_m2):
        return False
    if np.max(np.abs(a - a.T)) > 1e-9 * max(float(np.max(d)), 1e-300):
        return False
    sym = 0.5 * (a + a.T)
    if cholesky3_ok(sym):
        return True
    lam = np.linalg.eigvalsh(sym)
    return bool(lam[0] >= -1e-9 * max(float(lam[-1]), 1e-300))


def _cov_ok_rows(c, bound_m2: float) -> bool | None:
    """:func:`cov_ok` of three rows of three Python floats (a decoded message's covariance) by the
    same float operations without arrays; None for any other input, and where only the
    eigendecomposition answers (not positive definite)."""
    if type(c) not in (list, tuple) or len(c) != 3:
        return None
    if not all(type(r) in (list, tuple) and len(r) == 3 for r in c):
        return None
    v = (*c[0], *c[1], *c[2])
    if not all(type(x) is float for x in v):
        return None
    if not all(math.isfinite(x) for x in v):
        return False
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = v
    if min(a00, a11, a22) < 0.0 or max(a00, a11, a22) > bound_m2:
        return False
    if max(abs(a01 - a10), abs(a02 - a20), abs(a12 - a21)) > 1e-9 * max(a00, a11, a22, 1e-300):
        return False
    if _chol3_ok(0.5 * (a00 + a00), 0.5 * (a10 + a01), 0.5 * (a20 + a02), 0.5 * (a11 + a11),
                 0.5 * (a21 + a12), 0.5 * (a22 + a22)):
        return True
    return None


def clock_ok(corr, t_tx_s: float, b: NavBounds) -> bool:
    """A clock correction ``[t_ref, offset, freq, P_tt, P_tf, P_ff]`` within the oscillator class."""
    t_ref, off, f, ptt, ptf, pff = (float(x) for x in corr)
    return (abs(t_ref - t_tx_s) <= b.time_window_s and abs(off) <= b.clock_offset_s and abs(f) <= b.clock_freq
            and 0.0 <= ptt <= b.clock_offset_s ** 2 and 0.0 <= pff <= b.clock_freq ** 2
            and abs(ptf) <= math.sqrt(ptt * pff) * (1.0 + 1e-9))


def nav_reason(msg: dict, t_now_s: float, b: NavBounds) -> str | None:
    """Why a nav broadcast is implausible (``pos``, ``cov``, ``clock``, ``time``), or None.
    ``t_now_s``: the receiver's own reading of the reception time on network time (any reading good
    to a second does). A field the message lacks is not checked (the wire schema requires
    ``t_tx_s``, ``pos_m`` and ``cov_m2``; in-process tests may leave them out)."""
    t_tx = msg.get("t_tx_s")
    if t_tx is not None and not abs(float(t_tx) - float(t_now_s)) <= 2.0 * b.clock_offset_s + b.time_window_s:
        return "time"
    p = msg.get("pos_m")
    if p is not None and not math.sqrt(sum(float(x) * float(x) for x in p)) <= b.pos_m:
        return "pos"
    c = msg.get("cov_m2")
    if c is not None and not cov_ok(c, b.var_m2):
        return "cov"
    corr = msg.get("clock")
    if corr is not None and not clock_ok(corr, float(t_now_s if t_tx is None else t_tx), b):
        return "clock"
    return None


class NavPacer:
    """One nav per station per TDMA cycle at a user receiver (the aircraft, the vehicle): a station
    broadcasts its nav once per cycle, in its slot, so a second one from the same id within
    ``min_gap_s`` (of the receiver's reception time) is refused (``rate``). A stolen key can send
    copies at any time, and the channel - which lets a compromised box delay its signal to any
    stamp it writes - makes them good pseudoranges from that station's antenna; counted several
    times a cycle they multiply that station's weight, and with it its persistent position error,
    in every filter. The first to arrive is kept. Bounded: at most ``max_ids`` stations remembered
    (the oldest forgotten). Pure."""

    def __init__(self, min_gap_s: float, max_ids: int = 4096):
        self.min_gap_s = float(min_gap_s)
        self.max_ids = int(max_ids)
        self._last: dict[int, float] = {}

    @classmethod
    def for_cycle(cls, cycle_s: float) -> "NavPacer":
        """3/4 of the cycle: an honest station's navs are one cycle apart (less only when it moves
        to an earlier slot, which costs it one nav)."""
        return cls(0.75 * float(cycle_s))

    def refuse(self, src: int, t_rx_s: float) -> bool:
        """True if station ``src``'s nav received at ``t_rx_s`` comes too soon after its last kept one."""
        last = self._last.get(src)
        if last is not None and abs(t_rx_s - last) < self.min_gap_s:
            return True
        self._last.pop(src, None)
        self._last[src] = float(t_rx_s)
        if len(self._last) > self.max_ids:
            del self._last[next(iter(self._last))]
        return False
