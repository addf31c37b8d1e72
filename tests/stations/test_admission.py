"""Plausibility before trust (issue 32): every bound of ``stations/admission.py`` in the core, and a
fuzz of 20,000 wire-valid but absurd messages from one compromised station through a converged core."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from net import messages as M
from net.scenario import load
from stations.core import StationConfig, StationCore
from stations.sim import Simulator
from stations.tdma import TdmaPlan

PLAN = TdmaPlan(1.0, 0.01)


@pytest.fixture(scope="module")
def converged() -> StationCore:
    """Station 5 of seed000 (TCXO clocks) after 30 s: a converged survey and network clock."""
    sim = Simulator(load("seed000", seed=3))
    sim.run(30.0, [30.0])
    return sim.cores[4]


def _core(**kw) -> StationCore:
    cfg = StationConfig(id=5, tdma=PLAN, known_ids=(1, 2, 3, 4), field_radius_m=2000.0,
                        clock_offset_sigma_s=1e-3, clock_freq_sigma=2e-6, **kw)
    return StationCore(cfg, np.array([100.0, 200.0, 10.0]), np.eye(3) * 100.0, start_s=0.0)


def _nav(src=2, t=1.015, **over) -> dict:
    """A plausible nav of ``src`` sent in its slot of cycle 1, received at ``t``."""
    m = {"kind": "nav", "src": src, "seq": 1, "stamp_s": t, "cycle": 1, "slot": src - 1, "t_tx_s": t,
         "pos_m": [500.0, 0.0, 0.0], "cov_m2": np.eye(3).tolist(), "n_updates": 3, "state": "surveying",
         "ranges": [], "members": [1, 3, 4, 5], "clock": [t, 1e-4, 1e-6, 1e-12, 0.0, 1e-14]}
    m.update(over)
    return M.validate_msg(m)  # wire-valid: only the plausibility checks can refuse it


def _dropped(core: StationCore, msg: dict, t: float) -> dict:
    before = dict(core.admission.dropped)
    core.on_message(msg, t)
    return {k: v - before.get(k, 0) for k, v in core.admission.dropped.items() if v != before.get(k, 0)}


def test_a_plausible_nav_is_admitted():
    core = _core()
    assert _dropped(core, _nav(), 1.015) == {}
    assert 2 in core.peers and core.heard_slots[2] == 1 and core.counters["implausible"] == 0


@pytest.mark.parametrize("over, reason", [
    ({"pos_m": [3100.0, 0.0, 0.0]}, "pos"),                 # beyond the field (2 km) + margin (1 km)
    ({"pos_m": [1e12, 0.0, 0.0]}, "pos"),
    ({"cov_m2": (np.eye(3) * 1e12).tolist()}, "cov"),
    ({"t_tx_s": 1e11, "stamp_s": 1.015}, "time"),            # the "1e11 clock" attack
    ({"clock": [1.015, 5.0, 1e-6, 1e-12, 0.0, 1e-14]}, "clock"),       # offset beyond the class
    ({"clock": [1.015, 1e-4, -1.0, 1e-12, 0.0, 1e-14]}, "clock"),      # frequency -1
    ({"clock": [1.015, 1e-4, 1e-6, 100.0, 0.0, 1e-14]}, "clock"),      # offset variance
    ({"clock": [1.015, 1e-4, 1e-6, 1e-12, 1e-3, 1e-14]}, "clock"),     # not a covariance
    ({"clock": [1e9, 1e-4, 1e-6, 1e-12, 0.0, 1e-14]}, "clock"),        # reference time
])
def test_a_nav_outside_a_bound_is_dropped_and_counted(over, reason):
    core = _core()
    assert _dropped(core, _nav(**over), 1.015) == {reason: 1}
    assert 2 not in core.peers and core.counters["implausible"] == 1


@pytest.mark.parametrize("entry, reason", [
    ([5, 0.0, 1.01, 1e-6], "range"),
    ([5, 1e7, 1.01, 1e-6], "range"),            # beyond the field's diameter
    ([5, 500.0, 1.015 - 10.0, 1e-6], "time"),    # older than the nav's window
    ([5, 500.0, 1.015 + 1.0, 1e-6], "time"),     # after the nav was sent
    ([5, 500.0, 1.01, 50.0], "clock"),           # time transfer beyond the clock class
])
def test_a_range_entry_outside_a_bound_is_dropped_alone(entry, reason):
    core = _core()
    good = [3, 480.0, 1.01, 1e-6]
    assert _dropped(core, _nav(ranges=[entry, good]), 1.015) == {reason: 1}
    assert 2 in core.peers  # the nav itself is used
    assert core.counters["ranges_in"] == 0


def test_a_range_reply_with_frequency_minus_one_is_dropped_not_raised():
    core = _core()
    out = core.on_timer(core.next_deadline())
    req = next(m for m in out if m["kind"] == "range_req")
    rsp = {"kind": "range_rsp", "src": req["dst"], "seq": 1, "stamp_s": req["t_tx_s"] + 0.001, "dst": 5,
           "req_seq": req["seq"], "turnaround_s": 0.001, "pos_m": [500.0, 0.0, 0.0], "cov_m2": np.eye(3).tolist(),
           "n_updates": 1, "state": "surveying", "t_tx_s": req["t_tx_s"] + 0.001, "t_rx_s": req["t_tx_s"],
           "clock": [req["t_tx_s"], 0.0, -1.0, 0.0, 0.0, 0.0]}
    assert _dropped(core, M.validate_msg(rsp), req["t_tx_s"] + 0.001003) == {"clock": 1}
    rsp["clock"] = [req["t_tx_s"], 0.0, 0.0, 0.0, 0.0, 0.0]
    rsp["turnaround_s"] = 5.0
    assert _dropped(core, M.validate_msg(rsp), req["t_tx_s"] + 0.001003) == {"turnaround": 1}


def test_invented_ids_are_bounded_per_sender_per_cycle_and_in_total():
    """The issue's attack: one nav naming 1,024 invented ids used to add 1,024 clocks."""
    core = _core()
    n0 = len(core.clk.index)
    ranges = [[100 + k, 500.0, 1.01, 1e-7] for k in range(M.MAX_LIST)]
    core.on_message(_nav(ranges=ranges), 1.015)
    assert core.admission.dropped["new_ids"] == M.MAX_LIST - 2
    assert len(core.clk.index) <= n0 + 3  # the sender and its two new ids at most
    for cycle in range(2, 300):  # one nav per cycle: at most one peer per slot in total
        t = cycle + 0.015
        ranges = [[100 + k, 500.0, t - 0.005, 1e-7] for k in range(M.MAX_LIST)]
        core.on_message(_nav(t=t, seq=cycle, cycle=cycle, ranges=ranges,
                             clock=[t, 1e-4, 1e-6, 1e-12, 0.0, 1e-14]), t)
    assert len(core.admission.ids) == PLAN.slots_per_cycle + 1
    assert len(core.clk.index) <= PLAN.slots_per_cycle + 1
    assert core.admission.dropped["peers_full"] > 0


def test_a_new_sender_beyond_the_peer_bound_is_refused():
    core = _core(max_peers=6)  # self, 1..4 known, room for one more
    assert _dropped(core, _nav(src=7, slot=6), 1.075) == {"slot_time": 1} or 7 in core.peers
    assert _dropped(core, _nav(src=8, t=1.075, slot=7), 1.075) == {"peers_full": 1}
    assert 8 not in core.peers


def test_a_slot_claim_must_be_sent_in_that_slot():
    """Slot hijacking: a lower id re-announcing our slot outside it does not send us back to joining."""
    core = _core()
    assert core.slot == 4
    assert _dropped(core, _nav(slot=4), 1.015) == {"slot_time": 1}  # sent in slot 1, claims slot 4
    assert core.slot == 4 and core.state != "joining"
    assert core.heard_slots.get(2) is None


def test_slot_changes_are_rate_limited():
    core = _core()
    for k in range(6):  # a sender claiming another slot each cycle, each time inside it
        slot = 10 + k
        t = 1.0 + k + slot * 0.01 + 0.005
        core.on_message(_nav(t=t, seq=k + 1, cycle=1 + k, slot=slot), t)
    assert core.admission.dropped["slot_rate"] == 2  # first claim + 3 changes believed
    assert core.heard_slots[2] == 13


def test_a_plausible_slot_collision_still_resolves():
    core = _core()
    t = 1.0 + 4 * 0.01 + 0.005  # in slot 4 of cycle 1: station 2 (lower id) claims our slot
    core.on_message(_nav(t=t, slot=4), t)
    assert core.slot is None and core.state == "joining"


# --------------------------------------------------------------------------- fuzzing

ABSURD = (M.MAX_ABS, -M.MAX_ABS, 1e11, -1e11, 1e6, -1e6, 3.0, -1.0)


def _absurd_nav(rng, tpl: dict, t: float, seq: int, me: int) -> dict:
    """A wire-valid nav of the compromised station with at least one of its own fields, or every
    range entry, at an absurd value (every field at its wire or physical limits)."""
    m = copy.deepcopy(tpl)
    m.update(seq=seq, stamp_s=t, t_tx_s=t)
    m["clock"] = [t, *m["clock"][1:]]
    bad = rng.choice(["pos", "cov", "time", "clock", "ranges", "slot"], size=rng.integers(1, 4), replace=False)
    a = lambda: float(rng.choice(ABSURD))  # noqa: E731
    if "pos" in bad:
        m["pos_m"] = [a(), a(), a()]
    if "cov" in bad:
        m["cov_m2"] = (np.eye(3) * float(rng.choice([M.MAX_ABS, 1e11, 1e9]))).tolist()
    if "time" in bad:
        m["t_tx_s"] = float(rng.choice([1e11, -1e11, M.MAX_ABS, -M.MAX_ABS, t + 1e3]))
    if "clock" in bad:
        k = int(rng.integers(0, 6))
        m["clock"][k] = abs(a()) if k in (3, 5) else a()
    if "slot" in bad:
        m["slot"] = int(rng.integers(0, M.MAX_ID + 1))
    n = int(rng.choice([0, 1, 4, 16, M.MAX_LIST], p=[0.2, 0.3, 0.3, 0.19, 0.01])) if "ranges" in bad else 0
    entries = []
    for _ in range(n):
        if rng.random() < 0.3:  # an invented id (no time transfer): only the id bounds can refuse it
            entries.append([int(rng.integers(11, M.MAX_ID + 1)), 500.0, t])
            continue
        e = [int(rng.choice([me, 1, 3, 4, int(rng.integers(1, M.MAX_ID + 1))])), 500.0, t, 1e-6]
        for k in rng.choice([1, 2, 3], size=rng.integers(1, 4), replace=False):  # >= 1 value at a limit
            e[k] = float(rng.choice({1: [0.0, 1e7, M.MAX_ABS], 2: [t - 1e6, t + 5.0, M.MAX_ABS, -M.MAX_ABS],
                                     3: [1e3, -M.MAX_ABS, M.MAX_ABS, 5.0]}[int(k)]))
        entries.append(e)
    m["ranges"] = entries
    return m


def _run_timers(core: StationCore, until_s: float) -> None:
    dl = core.next_deadline()
    while dl is not None and dl <= until_s:  # the core's own timers keep running (no peer answers)
        core.on_timer(dl)
        dl = core.next_deadline()


def test_fuzz_20000_absurd_messages_from_a_stolen_key(converged, tmp_path, monkeypatch):
    """Station 2's key stolen: 20,000 navs / replies with fields at their limits, signed with its real
    key and opened by station 5's real receive guard (signature, replay order; the per-key budget
    off so that every one reaches the core). No exception escapes, and the survey and clock
    estimates stay within 3 sigma of a twin core that ran the same timers and heard nothing."""
    from net.keystore import init_keystore
    from net.security import Security

    monkeypatch.setenv("LARNS_RATE_LIMITS", "off")
    init_keystore(tmp_path / "keys", [1, 2, 3, 4, 5], recorder=False)
    thief_key = Security(tmp_path / "keys", "station-2")
    now = [0.0]
    guard = Security(tmp_path / "keys", "station-5").station_guard(PLAN.cycle_s, lambda: now[0])
    core, twin = copy.deepcopy(converged), copy.deepcopy(converged)
    me, thief = core.id, 2
    t = float(core.next_deadline())
    tpl = {"kind": "nav", "src": thief, "seq": 0, "stamp_s": t, "cycle": 0, "slot": thief - 1, "t_tx_s": t,
           "pos_m": core.peers[thief][0].tolist(), "cov_m2": core.peers[thief][1].tolist(), "n_updates": 10,
           "state": "surveying", "ranges": [], "members": [1, 3, 4, 5],
           "clock": [t, 0.0, 0.0, 1e-18, 0.0, 1e-24]}
    rng = np.random.default_rng(32)
    escaped = 0
    for k in range(20_000):
        tk = t + 0.0005 * k
        if k % 20 == 0:
            _run_timers(core, tk)
            _run_timers(twin, tk)
        if rng.random() < 0.8:
            msg = _absurd_nav(rng, tpl, tk, k + 1, me)
        else:  # a range reply to no request / with absurd fields
            msg = {"kind": "range_rsp", "src": thief, "seq": k + 1, "stamp_s": tk, "dst": me,
                   "req_seq": int(rng.integers(0, 10)), "turnaround_s": float(rng.choice([0.0, 1e3, M.MAX_ABS])),
                   "pos_m": [float(rng.choice(ABSURD))] * 3, "cov_m2": np.eye(3).tolist(), "n_updates": 0,
                   "state": "surveying", "t_tx_s": tk, "t_rx_s": tk - float(rng.choice([-1.0, 1e6])),
                   "clock": [tk, 0.0, float(rng.choice([-1.0, 1e-3, -M.MAX_ABS])), 0.0, 0.0, 0.0]}
        key = M.key_for(msg)
        now[0] = tk
        msg = guard.decode(key, thief_key.seal(key, M.encode(msg)))[0]  # signed, verified: wire-valid
        try:
            core.on_message(msg, tk + 1e-6)
        except Exception:  # noqa: BLE001 - counted: none may escape
            escaped += 1
    t_end = t + 0.0005 * 20_000
    _run_timers(core, t_end)
    _run_timers(twin, t_end)
    assert escaped == 0
    sd = np.sqrt(np.diag(twin.est.cov_m2))
    dpos = np.abs(core.est.pos_m - twin.est.pos_m)
    assert np.all(dpos <= 3.0 * sd + 1e-12), (dpos, sd)
    d_off = abs(core.clk.offset_at(t_end) - twin.clk.offset_at(t_end))
    assert d_off <= 3.0 * math.sqrt(twin.clk.variance_at(t_end)), d_off
    assert core.slot == twin.slot and core.state == twin.state
    assert len(core.clk.index) <= core.admission.max_peers
    assert core.counters["implausible"] > 1000 and escaped == 0
