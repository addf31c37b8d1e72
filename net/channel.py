"""Air-channel emulation (pure, seeded): clocks, time of flight, timing noise, NLOS, air loss, and
with a scenario ``[radio]`` the radio horizon and link budget (:mod:`net.radio`).

The channel turns a transmission's physical part (true sender position, true transmit time)
into the receiver's *local* reception timestamp. Two-way ranging then sees exactly what real
hardware would: ``range = c (rtt_local - turnaround_reported) / 2`` with the clock drift of both
ends acting on the turnaround and the flight time.

Range noise: each one-way arrival timestamp carries Gaussian noise ``sigma_t = sqrt(2) sigma_d / c``,
so that a two-way range (two legs) has standard deviation ``sigma_d``.

Keyed draws: a channel built with ``key = (world seed, receiver id)`` draws each reception's loss,
noise and NLOS from its own generator keyed by (seed, receiver, sender, transmit time to 100 ns), so
one transmission meets the same air in the simulator and in the fleet at any host speed, whatever
order the host delivers it in ("one world per seed").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nav.geometry import SPEED_OF_LIGHT_M_S, frame_free_mask

from . import streams
from .clock import ClockParams, OscillatorClock
from .radio import link
from .scenario import ChannelParams


@dataclass(frozen=True)
class Clock:
    """Local clock: ``t_local = t_true (1 + drift) + offset_s`` (drift is fractional, 1e-6 = 1 ppm)."""

    offset_s: float = 0.0
    drift: float = 0.0

    def to_local(self, t_true_s: float) -> float:
        return t_true_s * (1.0 + self.drift) + self.offset_s

    def to_true(self, t_local_s: float) -> float:
        return (t_local_s - self.offset_s) / (1.0 + self.drift)

    def error_s(self, t_true_s: float) -> float:
        """Local minus true time at ``t_true_s``."""
        return t_true_s * self.drift + self.offset_s


@dataclass(frozen=True)
class JumpClock:
    """A clock that steps by ``jump_s`` at true time ``at_s`` (wraps any clock with to_local/to_true):
    a scenario's ``clock_jump`` fault, the clock the station's shell reads and the channel's truth of it."""

    base: object
    jump_s: float
    at_s: float

    def to_local(self, t_true_s: float) -> float:
        return self.base.to_local(t_true_s) + (self.jump_s if t_true_s >= self.at_s else 0.0)

    def to_true(self, t_local_s: float) -> float:
        t = self.base.to_true(t_local_s - self.jump_s)
        return t if t >= self.at_s else self.base.to_true(t_local_s)

    def error_s(self, t_true_s: float) -> float:
        """Local minus true time, the jump included (the truth record's clock error)."""
        return self.base.error_s(t_true_s) + (self.jump_s if t_true_s >= self.at_s else 0.0)

    def __getattr__(self, name):  # offset_s, drift, ... of the wrapped clock
        return getattr(self.base, name)


def with_clock_faults(clock, faults, station_id: int):
    """``clock`` with the scenario's ``clock_jump`` faults of ``station_id`` applied (``faults``: the
    scenario's ``[[faults]]``)."""
    for f in faults:
        if f.kind == "clock_jump" and f.station == station_id:
            clock = JumpClock(clock, f.jump_s, f.at_s)
    return clock


def station_rng(seed: int, station_id: int, purpose: int) -> np.random.Generator:
    """Independent, reproducible stream per (world seed, station, purpose).

    Purposes (:mod:`net.streams`): ``CLOCK`` 0, ``COARSE_FIX`` 1 (coarse initial fix), ``AIR`` 2 (air
    channel at this receiver), ``WIRE`` 3 (wire faults). The simulator and the Zenoh node derive the
    same streams, so they draw the same world.
    """
    return streams.rng(seed, station_id, purpose)


def draw_clock(params: ChannelParams | ClockParams, rng: np.random.Generator) -> Clock | OscillatorClock:
    """One station's clock from its stream: an :class:`~net.clock.OscillatorClock` of the scenario's
    ``[clock]`` class, or (legacy ``ChannelParams``) offset ~ N(0, clock_offset_s^2), drift ~ N(0, ppm^2)."""
    if isinstance(params, ClockParams):
        return OscillatorClock(params, rng)
    return Clock(
        offset_s=float(rng.normal(0.0, params.clock_offset_s)) if params.clock_offset_s > 0 else 0.0,
        drift=float(rng.normal(0.0, params.clock_drift_ppm)) * 1e-6 if params.clock_drift_ppm > 0 else 0.0,
    )


def coarse_fix(
    true_pos_m: np.ndarray, station_id: int, sigma0_m: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Coarse external fix (e.g. a GNSS snapshot before the network runs), in the network frame.

    Free coordinates get ``N(0, sigma0^2)`` errors; constrained ones (frame stations) are exact.
    Returns ``pos_m`` (3,) and ``cov_m2`` (3, 3) (zero rows/cols on constrained coordinates).
    """
    free = frame_free_mask(4)[station_id - 1] if station_id <= 3 else np.ones(3, bool)
    err = rng.normal(0.0, sigma0_m, 3) * free
    pos = np.asarray(true_pos_m, dtype=float) + err
    pos[~free] = np.asarray(true_pos_m, dtype=float)[~free]
    return pos, np.diag(free * sigma0_m**2).astype(float)


def _seed_words(values) -> np.ndarray | None:
    """The entropy ``np.random.SeedSequence`` makes of a sequence of ints, given to it directly (the same
    generator, without its conversion of each int): each int little-endian in 32-bit words, 0 as one word.
    None if one is negative (SeedSequence's own error then)."""
    words = []
    for n in values:
        if n < 0:
            return None
        words.append(n & 0xFFFFFFFF)
        n >>= 32
        while n > 0:
            words.append(n & 0xFFFFFFFF)
            n >>= 32
    return np.array(words, dtype=np.uint32)


class AirChannel:
    """The air as seen by one receiver. Pure apart from its own seeded generator."""

    def __init__(self, params: ChannelParams, rng: np.random.Generator, key: tuple[int, int] | None = None):
        self.params = params
        self.rng = rng
        self.key = None if key is None else (int(key[0]), int(key[1]))
        self.sigma_t_s = np.sqrt(2.0) * params.sigma_d_m / SPEED_OF_LIGHT_M_S
        # the scenario's [radio] (net/radio.py): links beyond the horizon or the link budget do not
        # exist, and timing noise grows as the SNR falls; None: everyone hears everyone, noise sigma_t_s
        self.radio = getattr(params, "radio", None)
        self._memo: dict[tuple[bytes, bytes], tuple[float, float] | None] = {}

    #: pair geometries :meth:`geometry` keeps (then it starts over): a moving end only adds entries
    MEMO_SIZE = 65536

    def geometry(self, tx_pos_m, rx_pos_m) -> tuple[float, float] | None:
        """The link from ``tx_pos_m`` (3,) to ``rx_pos_m`` (3,): ``(distance m, one-way timing sigma s)``,
        or ``None`` where the radio has no link. A pure function of the two positions, kept by their
        exact values (static stations ask for the same pairs all the time)."""
        tx, rx = np.asarray(tx_pos_m, float), np.asarray(rx_pos_m, float)
        key = (tx.tobytes(), rx.tobytes())
        got = self._memo.get(key, self)
        if got is not self:
            return got
        got = (float(np.linalg.norm(rx - tx)), self.sigma_t_s)
        if self.radio is not None:
            air = link(tx, rx, self.radio)
            got = (got[0], float(np.hypot(self.sigma_t_s, air.sigma_crlb_s))) if air.exists else None
        if len(self._memo) >= self.MEMO_SIZE:
            self._memo.clear()
        self._memo[key] = got
        return got

    def draws(self, tx_id: int | None, t_tx_true_s: float) -> np.random.Generator:
        """The generator for one reception: keyed by (seed, receiver, sender, transmit time) when the
        channel has a key and the sender is named, else the receiver's stream."""
        if self.key is None or tx_id is None:
            return self.rng
        t_key = max(0, int(round(t_tx_true_s * 1e7)))  # 100 ns: one station never sends twice in it
        words = _seed_words((*self.key, int(tx_id), t_key))
        return np.random.default_rng([*self.key, int(tx_id), t_key] if words is None else words)

    def arrival_local_s(
        self, tx_pos_m: np.ndarray, t_tx_true_s: float, rx_pos_m: np.ndarray, rx_clock: Clock | OscillatorClock,
        tx_id: int | None = None,
    ) -> float | None:
        """Local reception time of a transmission, or ``None`` if it is lost on air.

        Parameters
        ----------
        tx_pos_m : (3,) true sender position. t_tx_true_s : true transmit time.
        rx_pos_m : (3,) true receiver position. rx_clock : receiver's clock.
        tx_id : sender's id; with a keyed channel it selects the reception's own draws.
        """
        p = self.params
        geometry = self.geometry(tx_pos_m, rx_pos_m)
        if geometry is None:
            return None
        d, sigma_t_s = geometry
        rng = self.draws(tx_id, t_tx_true_s)
        if p.loss_prob > 0 and rng.random() < p.loss_prob:
            return None
        t = t_tx_true_s + d / SPEED_OF_LIGHT_M_S
        if sigma_t_s > 0:
            t += float(rng.normal(0.0, sigma_t_s))
        if p.nlos_prob > 0 and rng.random() < p.nlos_prob:
            # an NLOS leg lengthens the two-way range by nlos_bias_m on average
            t += 2.0 * float(rng.exponential(p.nlos_bias_m)) / SPEED_OF_LIGHT_M_S
        return rx_clock.to_local(t)


class SenderTruth:
    """The channel owns physics (issue 32): the physical part of a reception comes from the
    scenario's truth of the *named* sender, not from the ``phy`` block it sent.

    ``positions`` maps each station id of the world to its true position; ``clock_of(id)`` builds
    that station's true clock (the world seed's draw, with its scenario faults), kept once built.
    :meth:`transmission` returns the true sender position and the true transmit time: the later of
    the time the sender's own clock stamp ``t_tx_s`` implies and the time its ``phy`` claims, so a
    compromised process can delay its signal but never advance it (no shortened ranges); None for
    an id the world does not hold. Pure apart from the clocks it builds."""

    def __init__(self, positions: dict[int, np.ndarray], clock_of):
        self.positions = {int(k): np.asarray(v, float) for k, v in positions.items()}
        self._clock_of = clock_of
        self._clocks: dict[int, object] = {}

    #: a transmission the receiver takes in lies within this of its own time (true-time timeline): its
    #: claimed time by the wire's delay, its stamp by the sender's clock error too (both far below);
    #: beyond it the stamp is refused before the sender's clock is read there (an insider's stamp of
    #: 1e12 s would have the emulated oscillator draw its random walk up to it: memory and CPU without end)
    MAX_SKEW_S = 60.0

    def plausible_time(self, claimed_t_true_s: float, t_tx_local_s: float | None, now_s: float) -> bool:
        """Whether a transmission's claimed time and clock stamp are near ``now_s`` (:attr:`MAX_SKEW_S`)."""
        if not abs(float(claimed_t_true_s) - now_s) <= self.MAX_SKEW_S:
            return False
        return t_tx_local_s is None or abs(float(t_tx_local_s) - now_s) <= self.MAX_SKEW_S

    def transmission(self, tx_id: int, claimed_t_true_s: float,
                     t_tx_local_s: float | None) -> tuple[np.ndarray, float] | None:
        pos = self.positions.get(tx_id)
        if pos is None:
            return None
        if t_tx_local_s is None:
            return pos, float(claimed_t_true_s)
        clock = self._clocks.get(tx_id)
        if clock is None:
            clock = self._clocks[tx_id] = self._clock_of(tx_id)
        return pos, max(float(claimed_t_true_s), float(clock.to_true(t_tx_local_s)))

    def receive(self, msg: dict, phy: dict, now_s: float) -> tuple[np.ndarray, float] | str:
        """The physical part of a received message as the channel takes it: ``(true sender position
        (3,), true transmit time)`` of the named sender ``msg["src"]``, or the reason it is dropped:
        ``"time"`` (stamped or claimed far from ``now_s``, :meth:`plausible_time`) or
        ``"sender_unknown"`` (an id the world does not hold). Every receiver's shell (station,
        aircraft, vehicle) calls this before its channel reads a clock or a geometry."""
        if not self.plausible_time(phy["t_true_s"], msg.get("t_tx_s"), now_s):
            return "time"
        tx = self.transmission(int(msg["src"]), phy["t_true_s"], msg.get("t_tx_s"))
        return "sender_unknown" if tx is None else tx


class UserIntake:
    """A user receiver's (the aircraft's, the vehicle's) intake of a station nav from the wire:
    decoded and on its own station's key (``net.messages.station_nav``: ``decode`` is plain or a
    ``--secure`` guard's), its ``phy`` replaced by the channel's truth of the named sender
    (:meth:`SenderTruth.receive`; nothing is sent before the fleet's epoch, so a claim before it is
    ``time`` too), and at most one per station per cycle (``net.plausible.NavPacer``).
    Drops are counted in ``drops`` by reason. The shell's part; the navigators' plausibility checks
    follow in the cores."""

    def __init__(self, scn, seed: int, net_clock, decode, drops):
        from .plausible import NavPacer

        self.senders = scenario_senders(scn, int(seed), None if net_clock is None else net_clock.clock)
        self.pacer = NavPacer.for_cycle(scn.tdma.cycle_s)  # issue 32: a stolen key's extra navs weigh nothing
        self.decode = decode
        self.drops = drops

    def take(self, key: str, data: bytes, now_s: float) -> tuple[dict, dict] | None:
        """``(msg, phy)`` of one sample, or None (counted)."""
        from .messages import station_nav

        got = station_nav(self.decode, key, data, self.drops)
        if got is None:
            return None
        msg, phy = got
        tx = "time" if not phy["t_true_s"] >= 0.0 else self.senders.receive(msg, phy, now_s)
        if isinstance(tx, str):
            self.drops.drop(tx, f"nav from {msg['src']} claimed at t = {phy['t_true_s']:.3g} s")
            return None
        phy = {"pos_m": tx[0], "t_true_s": tx[1]}
        if self.pacer.refuse(int(msg["src"]), float(phy["t_true_s"])):
            self.drops.drop("rate", f"nav from {msg['src']} within {self.pacer.min_gap_s:.2f} s of its last")
            return None
        return msg, phy


def scenario_senders(scn, seed: int, base_clock=None) -> SenderTruth:
    """The channel's truth of every station of scenario ``scn`` in world ``seed``: true positions and
    true clocks, each drawn from its station's stream (``station_rng(seed, id, 0)``, the draw its
    own process makes) unless ``base_clock(id)`` gives it (a realization the receiver already holds),
    with the scenario's clock faults; a station the scenario does not list is a hot-joiner from
    outside it, at :func:`net.scenario.joiner_position`."""
    if base_clock is None:
        def base_clock(sid: int):
            return draw_clock(scn.clock, station_rng(seed, sid, streams.CLOCK))
    from .scenario import WorldPositions

    senders = SenderTruth({i: scn.true_pos(i) for i in scn.ids},
                          lambda sid: with_clock_faults(base_clock(sid), scn.faults, sid))
    senders.positions = WorldPositions(senders.positions, scn)  # + hot-joiners from outside the scenario
    return senders
