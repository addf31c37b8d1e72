"""World side: network time as the field realizes it, for receivers that run on it (aircraft, vehicle).

Network time is an ensemble of the station clocks that each station realizes through its own clock
filter (docs/sync.md). A user receiver in the emulator is *disciplined to network time* up to its own
clock model (seed 001's receiver clock), as the old single-master design had it run on station 1's
oscillator. The ensemble has no oscillator to draw, so the world reconstructs it from what the stations
realize: station ``i``'s true clock ``x_i(t)`` (drawn from the seed exactly as its process draws it) minus
its broadcast correction ``theta_i(T) = offset + freq (T - t_ref)`` on its own reading ``T = t + x_i(t)``
is its realization ``E_i(t) = x_i(t) - theta_i(T)`` of network time minus true time. The receiver's
network time is their weighted mean (weights ``1 / (var_i + floor^2)``, stations whose broadcast clock
sigma exceeds ``max_sd_s`` left out): exact in time at any instant, and within the stations' own sync
errors of every station's definition. Before any station is synchronized it falls back to the lowest
id's oscillator (the founder's clock, as network time starts).

This is truth: only world code (channel layers) may use it, never a navigator.
"""

from __future__ import annotations

import math

from . import streams
from .channel import draw_clock, station_rng
from .clock import broadcast_time_error_s


class RealizedNetworkTime:
    """``observe(msg)`` every nav; ``error_s(t_true_s)``: network time minus true time (s)."""

    def __init__(self, clock_params, seed: int, founder_id: int = 1, max_sd_s: float = 1e-6,
                 floor_s: float = 1e-10):
        self.params = clock_params
        self.seed = int(seed)
        self.founder_id = int(founder_id)
        self.max_var_s2 = float(max_sd_s) ** 2
        self.floor_s2 = float(floor_s) ** 2
        self._clocks: dict[int, object] = {}
        self._corr: dict[int, tuple[float, ...]] = {}

    def clock(self, sid: int):
        """Station ``sid``'s true oscillator (the draw its own process makes: ``station_rng(seed, sid, 0)``)."""
        c = self._clocks.get(sid)
        if c is None:
            c = self._clocks[sid] = draw_clock(self.params, station_rng(self.seed, sid, streams.CLOCK))
        return c

    def observe(self, msg: dict | None) -> None:
        """Keep the latest finite clock correction of a station's nav (bounded: one per station id)."""
        if not msg or msg.get("kind") != "nav":
            return
        corr = msg.get("clock")
        if corr is None or len(corr) < 6 or not all(math.isfinite(float(v)) for v in corr[:6]):
            return
        self._corr[int(msg["src"])] = tuple(float(v) for v in corr[:6])

    def error_s(self, t_true_s: float) -> float:
        num = den = 0.0
        for sid, (t_ref, off, freq, p00, p01, p11) in self._corr.items():
            x = self.clock(sid).error_s(t_true_s)
            dT = t_true_s + x - t_ref
            var = p00 + 2.0 * dT * p01 + dT * dT * p11
            if not (0.0 <= var <= self.max_var_s2):
                continue
            w = 1.0 / (var + self.floor_s2)
            num += w * (x - (off + freq * dT))
            den += w
        return num / den if den > 0.0 else self.clock(self.founder_id).error_s(t_true_s)


def network_time(scn, seed: int) -> RealizedNetworkTime | None:
    """The receivers' network time of a scenario (None: perfect clocks, network time is true time)."""
    if scn.clock.perfect:
        return None
    return RealizedNetworkTime(scn.clock, seed, founder_id=min(scn.ids))


def pseudorange_time_error_s(msg: dict | None, t_tx_true_s: float, t_rx_true_s: float,
                             net_time: RealizedNetworkTime | None) -> float:
    """:func:`net.clock.broadcast_time_error_s` for a receiver on ``net_time``, which first takes this
    broadcast's correction into its realization."""
    if net_time is not None:
        net_time.observe(msg)
    return broadcast_time_error_s(msg, t_tx_true_s, t_rx_true_s, net_time)
