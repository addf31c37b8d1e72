"""Issue 32's fuzz bar for the navigators: wire-valid navs from station 2 (its key stolen) with every
field at its schema limits (larns/adversary/insider.py ``absurd_message``: numbers at +-1e12, 0, -1,
tiny; non-positive-definite covariances; clock frequency -1; lists of up to 1,024) through the
radio aircraft (RadioAircraftCore's message entry, filters and snapshot), the inertial aircraft, the triad
and the vehicle, interleaved with the field's honest broadcasts. Each navigator runs beside a twin
that hears only the honest broadcasts: no exception escapes, and no estimate moves away from its
twin's by more than 3 sigma (the twin's covariance, per axis), at every honest broadcast.

The messages are strictly decoded (``net.messages.decode``), i.e. what a receive guard hands over
once the signature checked; the signature path with absurd content is fuzzed in
tests/stations/test_admission.py. Sans-I/O: the cores are fed directly, no Zenoh. The default case
runs 500 absurd messages per navigator; the bar's 20,000 per navigator is ``-m slow``.
"""

from __future__ import annotations

import copy
from collections import Counter

import numpy as np
import pytest

from aircraft.events import to_msgs
from larns.adversary.insider import absurd_message
from net import messages as M
from net.scenario import load

THIEF = 2


def _honest_nav(src: int, seq: int, t: float, pos) -> dict:
    return {"kind": "nav", "src": src, "seq": seq, "stamp_s": t, "cycle": int(t), "slot": src - 1, "t_tx_s": t,
            "pos_m": [float(x) for x in pos], "cov_m2": (np.eye(3) * 0.0025).tolist(), "n_updates": 50,
            "state": "frame", "ranges": [], "members": [], "clock": [t, 0.0, 0.0, 1e-22, 0.0, 1e-26]}


def _absurd(rng, seq: int, t: float) -> dict:
    m = absurd_message(rng, "nav", THIEF, seq, t, p_long=0.002)
    return M.decode(M.encode(m))[0]


class Radio:
    """RadioAircraftCore (seed000) with the filters and the snapshot LSQ."""

    algos = ("ukf-pr", "ekf-pr", "ukf-tdoa", "lsq-pr")

    def __init__(self):
        from aircraft.config import from_scenario
        from aircraft.radio_core import RadioAircraftCore

        self.scn = load("seed000")
        self.core = RadioAircraftCore(from_scenario(self.scn), self.algos, "ac1", np.random.default_rng(1),
                                      horizon_s=200.0)
        self.pos = {i: self.scn.true_pos(i) for i in self.scn.ids}
        self.slot_s, self.ids = self.scn.tdma.slot_s, list(self.scn.ids)

    def feed(self, core, msg, phy, t):
        return to_msgs(core.on_nav(msg, phy))

    def estimates(self, outs):
        return {o["algo"]: o for o in outs if o["kind"] == "ac_estimate"}


class Ins(Radio):
    """InsAircraftCore (seed003-text, adis16480)."""

    def __init__(self):
        from aircraft.config import from_scenario
        from aircraft.ins_core import InsAircraftCore

        self.scn = load("seed003-text")
        self.core = InsAircraftCore(self.scn, from_scenario(self.scn), "ac1", np.random.default_rng(1),
                                    imu="adis16480")
        self.pos = {i: self.scn.pos_m[k] for k, i in enumerate(self.scn.ids)}
        self.slot_s, self.ids = self.scn.tdma.slot_s, list(self.scn.ids)

    def feed(self, core, msg, phy, t):
        core.advance_to(t - 0.05)
        return to_msgs(core.on_nav(msg, phy))

    def estimates(self, outs):
        return {o.get("algo", "ins"): o for o in outs if o["kind"] == "ac_estimate"}


class Triad(Ins):
    """TriadAircraftCore (seed003-text, 4 satellites)."""

    def __init__(self):
        from aircraft.config import from_scenario
        from aircraft.triad_core import TriadAircraftCore

        self.scn = load("seed003-text")
        self.core = TriadAircraftCore(self.scn, from_scenario(self.scn), "ac1", n_sv=4, seed=5)
        self.pos = {i: self.scn.pos_m[k] for k, i in enumerate(self.scn.ids)}
        self.slot_s, self.ids = self.scn.tdma.slot_s, list(self.scn.ids)

    def feed(self, core, msg, phy, t):
        core.advance_to(t - core.lag_s)
        return to_msgs(core.on_nav(msg, phy))


class Vehicle(Radio):
    """VehicleCore (seed000, the default route)."""

    def __init__(self):
        from vehicle.core import VehicleCore
        from vehicle.field import field_layout

        self.scn = load("seed000")
        self.core = VehicleCore(self.scn, "veh1", t0_s=0.0, imu_rate_hz=10.0)
        _, _, pos, _, _ = field_layout(self.scn)
        self.pos = {i: pos[k] for k, i in enumerate(self.scn.ids)}
        self.slot_s, self.ids = self.scn.tdma.slot_s, list(self.scn.ids)

    def feed(self, core, msg, phy, t):
        return core.advance_to(t - 0.25) + core.on_nav(msg, phy)

    def estimates(self, outs):
        return {"cdekf-map": o for o in outs if o["kind"] == "veh_estimate"}


def _fuzz(nav, n_absurd: int, warm_cycles: int = 25, attack_cycles: int = 10, seed: int = 32) -> dict:
    """Warm ``nav`` up on honest broadcasts, copy it (the twin), then ``attack_cycles`` cycles in which
    both hear the same honest broadcasts and the core also ``n_absurd`` absurd navs, spread over them."""
    rng = np.random.default_rng(seed)
    core = nav.core
    seq = Counter()
    ids = nav.ids

    def honest(c, j):
        sid = ids[j]
        t = c * nav.scn.tdma.cycle_s + j * nav.slot_s + 0.005
        seq[sid] += 1
        return t, _honest_nav(sid, seq[sid], t, nav.pos[sid]), {"pos_m": [float(x) for x in nav.pos[sid]],
                                                                   "t_true_s": t}

    for c in range(warm_cycles):
        for j in range(len(ids)):
            t, m, phy = honest(c, j)
            nav.feed(core, m, phy, t)
    twin = copy.deepcopy(core)
    per_slot = n_absurd / (attack_cycles * len(ids))
    escaped, worst, compared, owed = 0, 0.0, 0, 0.0
    phy2 = [float(x) for x in nav.pos[THIEF]]
    for c in range(warm_cycles, warm_cycles + attack_cycles):
        for j in range(len(ids)):
            t, m, phy = honest(c, j)
            a = nav.estimates(nav.feed(core, copy.deepcopy(m), phy, t))
            b = nav.estimates(nav.feed(twin, m, phy, t))
            for algo, eb in b.items():
                if algo in a:
                    d = np.abs(np.subtract(a[algo]["pos_m"], eb["pos_m"]))
                    sd = np.sqrt(np.diag(eb["cov_m2"]))
                    worst = max(worst, float(np.max(d / sd)))
                    compared += 1
            owed += per_slot
            k = 0
            while owed >= 1.0:  # the thief's navs between this broadcast and the next
                owed -= 1.0
                k += 1
                seq[THIEF] += 1
                ta = t + 0.0005 * k
                try:
                    nav.feed(core, _absurd(rng, 10**6 + seq[THIEF], ta), {"pos_m": phy2, "t_true_s": ta}, ta)
                except Exception:  # noqa: BLE001 - counted: none may escape
                    escaped += 1
    stats = getattr(core, "stats", Counter())
    return {"escaped": escaped, "worst_sigma": worst, "compared": compared, "sent": int(seq[THIEF]),
            "implausible": {k: v for k, v in stats.items() if str(k).startswith("implausible")},
            "unusable_state": int(stats.get("nav_unusable_state", 0))}


NAVIGATORS = {"radio": Radio, "ins": Ins, "triad": Triad, "vehicle": Vehicle}


def _check(r: dict, n: int) -> None:
    print(r)
    assert r["escaped"] == 0, r
    assert r["sent"] >= n - 1 and r["compared"] >= 10, r
    assert r["worst_sigma"] <= 3.0, r
    # dropped before any filter: implausible, or not from a surveyed station ("joining"); the rest are
    # plausible lies (a position near station 1, a clock within its class) that the filters judge
    assert sum(r["implausible"].values()) + r["unusable_state"] > 0.9 * r["sent"], r


@pytest.mark.parametrize("name", sorted(NAVIGATORS))
def test_fuzz_absurd_navs_through_every_navigator(name):
    _check(_fuzz(NAVIGATORS[name](), 500), 500)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(NAVIGATORS))
def test_fuzz_20000_absurd_navs_through_every_navigator(name):
    _check(_fuzz(NAVIGATORS[name](), 20_000), 20_000)


def test_the_aircraft_node_drops_a_nav_whose_phy_claims_a_time_far_from_now():
    """A compromised host's ``phy`` claiming 1e12 s had the aircraft's channel read network time's
    oscillators there (drawing their random walk up to it: it never returned). The node refuses a
    claim more than 60 fleet seconds ahead of its own time or before the epoch (``time``) before the
    core."""
    import time

    from aircraft.node import AircraftNode, AircraftOptions
    from fake_bus import FakeBus

    class Bus(FakeBus):
        def publish(self, key, data, block=False):
            super().publish(key, data)

    scn = load("seed000")
    node = AircraftNode(scn, AircraftOptions(name="ac1", quiet=True, epoch_unix_s=time.time() - 20.0), Bus())
    p = scn.true_pos(2).tolist()
    for k, t in enumerate((1e12, node.fleet_now() + 120.0, -1e12, -1.0)):  # (nothing is sent before the epoch)
        m = dict(_honest_nav(2, k + 1, t, p), cycle=1)
        t0 = time.process_time()
        node._ingest(M.key_for(m), M.encode(m, {"pos_m": p, "t_true_s": t}))
        assert time.process_time() - t0 < 1.0
    assert node.drops.by_reason["time"] == 4
    t = node.fleet_now()
    m = _honest_nav(2, 9, t, p)
    node._ingest(M.key_for(m), M.encode(m, {"pos_m": p, "t_true_s": t}))
    assert node.drops.by_reason["time"] == 4 and node.core.stats["measurements"] == 1


def test_the_user_receivers_channel_takes_the_named_senders_truth_not_its_phy():
    """The channel owns physics at the aircraft and the vehicle too (issue 32 item 2): what reaches
    their cores is the named sender's true position and the later of its claimed transmit time and
    the time its own clock stamp implies, so a compromised host can delay its signal (its own
    business) but never move its antenna or advance its transmission; a hot-joiner from outside the
    scenario is where the scenario draws it. And one nav per station per cycle (``rate``): a stolen
    key's extra copies would otherwise count that station several times a cycle."""
    import time

    from aircraft.node import AircraftNode, AircraftOptions
    from fake_bus import FakeBus
    from net.channel import draw_clock, station_rng
    from net.scenario import joiner_position
    from vehicle.node import VehicleNode, VehicleOptions

    class Bus(FakeBus):
        def publish(self, key, data, block=False):
            super().publish(key, data)

    scn = load("seed000")  # TCXO clocks: a stamp is the sender's local time, not true time
    epoch = time.time() - 20.0
    ac = AircraftNode(scn, AircraftOptions(name="ac1", quiet=True, epoch_unix_s=epoch), Bus())
    veh = VehicleNode(scn, VehicleOptions(name="veh1", quiet=True, epoch_unix_s=epoch), Bus())
    seen: list[dict] = []
    ac.core.on_nav = lambda msg, phy: seen.append(phy) or []
    t = ac.fleet_now()

    def send(sid, seq, t_true, phy, node_list=(ac, veh)):
        stamp = draw_clock(scn.clock, station_rng(scn.seed, sid, 0)).to_local(t_true)  # the station's own clock
        m = dict(_honest_nav(sid, seq, stamp, scn.true_pos(sid)), stamp_s=t_true, cycle=int(t_true))
        for node in node_list:
            node._ingest(M.key_for(m), M.encode(m, phy))

    claims = {2: (-1000.0, -1e-5),  # moved 1 km and advanced 10 us
              3: (0.0, 0.0),        # honest
              4: (0.0, 1e-3)}       # delayed by 1 ms
    for k, (sid, (dx, dt)) in enumerate(claims.items()):
        send(sid, k + 1, t, {"pos_m": (scn.true_pos(sid) + [dx, 0.0, 0.0]).tolist(), "t_true_s": t + dt})
    held = [h[3] for h in sorted(veh._held, key=lambda h: h[1])]
    for got in (seen, held):
        assert len(got) == 3
        for phy, sid in zip(got, claims):
            np.testing.assert_array_equal(phy["pos_m"], scn.true_pos(sid))
        assert abs(got[0]["t_true_s"] - t) < 1e-9 and abs(got[1]["t_true_s"] - t) < 1e-9
        assert got[2]["t_true_s"] == t + 1e-3
    # a station the scenario does not list is a hot-joiner from outside it, where its own process and
    # every other receiver put it (net.scenario.joiner_position), whatever it claims
    p = scn.true_pos(2)
    m = dict(_honest_nav(99, 9, t, p), stamp_s=t, cycle=1)
    for node in (ac, veh):
        node._ingest(M.key_for(m), M.encode(m, {"pos_m": p.tolist(), "t_true_s": t}))
    j = joiner_position(scn, 99)
    assert np.linalg.norm(j - p) > 100.0
    np.testing.assert_array_equal(seen[3]["pos_m"], j)
    np.testing.assert_array_equal(max(veh._held, key=lambda h: h[1])[3]["pos_m"], j)
    # station 3 again 0.3 s later (a copy outside its slot): refused; a cycle after its first: taken
    send(3, 20, t + 0.3, {"pos_m": scn.true_pos(3).tolist(), "t_true_s": t + 0.3})
    assert len(seen) == 4 and ac.drops.by_reason["rate"] == 1 and veh.drops.by_reason["rate"] == 1
    send(3, 21, t + scn.tdma.cycle_s, {"pos_m": scn.true_pos(3).tolist(), "t_true_s": t + scn.tdma.cycle_s})
    assert len(seen) == 5 and ac.drops.by_reason["rate"] == 1


def test_nav_pacer_keeps_one_nav_per_station_and_cycle_and_stays_bounded():
    from net.plausible import NavPacer

    pacer = NavPacer.for_cycle(1.0)
    assert not pacer.refuse(2, 10.0) and pacer.refuse(2, 10.5) and pacer.refuse(2, 9.5)
    assert not pacer.refuse(3, 10.5)            # another station: its own pace
    assert not pacer.refuse(2, 11.0)            # the next cycle
    small = NavPacer(0.75, max_ids=3)
    for sid in range(1, 10):
        assert not small.refuse(sid, 1.0)
    assert len(small._last) == 3
