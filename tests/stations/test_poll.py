"""Protocol v2 through the station core (issue 31, docs/protocol.md "Protocol v2"): one poll, every
member replies in its sub-slot, the poller's nav is the final. Cores talk through a tiny hand-made
channel (exact time of flight, no noise) or the simulator."""

from __future__ import annotations

import heapq
import tomllib

import msgpack
import numpy as np
import pytest

from nav.geometry import SPEED_OF_LIGHT_M_S
from net import messages as M
from net.channel import Clock
from net.scenario import ScenarioError, from_dict, load
from stations.core import StationConfig, StationCore
from stations.sim import Simulator, make_core
from stations.tdma import TdmaPlan

POS = np.array([[0.0, 0.0, 0.0], [900.0, 0.0, 5.0], [300.0, 1100.0, -20.0], [-700.0, 600.0, 40.0]])


def _cores(clocks, ranging="poll", spacing_s=0.0005, freq_sigma=2e-5):
    """Four founders (ids 1-4) at ``POS``, each with its oscillator (``clocks``); cores on their local time."""
    ids = list(range(1, len(POS) + 1))
    cores = []
    for k, sid in enumerate(ids):
        cfg = StationConfig(id=sid, tdma=TdmaPlan(1.0, 0.01), known_ids=tuple(i for i in ids if i != sid),
                            ranging=ranging, reply_spacing_s=spacing_s, guard_s=0.0001, field_radius_m=1300.0,
                            clock_offset_sigma_s=1e-4, clock_freq_sigma=freq_sigma)
        pos0 = np.zeros(3) if sid == 1 else POS[k] + 3.0
        cov0 = np.zeros((3, 3)) if sid == 1 else np.eye(3) * 100.0
        cores.append(StationCore(cfg, pos0, cov0, start_s=clocks[k].to_local(0.0)))
    return cores


def _run(cores, clocks, until_s, delay_s=None, nav_late_s=0.0):
    """A tiny channel: every air message reaches every other core after its exact time of flight (plus
    ``delay_s[(src, dst)]`` on air for a reply); records every range each core's survey takes.
    ``nav_late_s``: navs are handed over that much later than they were heard, their receive stamps
    unchanged (a process reading its navs in batches, as the Zenoh node does)."""
    n = len(cores)
    taken = {c.id: [] for c in cores}
    for c in cores:
        def rec(peer, r, t, initiated, pp, pc, _c=c, _f=c.est.on_range):
            taken[_c.id].append((peer, r, initiated))
            return _f(peer, r, t, initiated, pp, pc)
        c.est.on_range = rec
    heap, order = [], 0

    def push(t, ev):
        nonlocal order
        order += 1
        heapq.heappush(heap, (t, order, ev))

    def arm(k):
        dl = cores[k].next_deadline()
        if dl is not None:
            push(clocks[k].to_true(dl), ("timer", k, dl))

    def emit(k, outs):
        for m in outs:
            if m["kind"] not in ("poll", "reply", "nav", "range_req", "range_rsp"):
                continue
            t_tx = clocks[k].to_true(m["t_tx_s"])
            for j in range(n):
                if j == k:
                    continue
                tof = np.linalg.norm(POS[k] - POS[j]) / SPEED_OF_LIGHT_M_S
                extra = (delay_s or {}).get((k + 1, j + 1), 0.0) if m["kind"] == "reply" else 0.0
                t = float(t_tx + tof + extra)
                push(t + (nav_late_s if m["kind"] == "nav" else 0.0),
                     ("rx", j, M.validate_msg(m), float(clocks[j].to_local(t))))

    for k in range(n):
        arm(k)
    timers = [None] * n
    while heap and heap[0][0] <= until_s:
        t, _, ev = heapq.heappop(heap)
        k = ev[1]
        if ev[0] == "timer":
            if cores[k].next_deadline() != ev[2] or timers[k] == ev[2]:
                continue  # superseded
            timers[k] = ev[2]
            outs = cores[k].on_timer(ev[2])
        else:
            outs = cores[k].on_message(ev[2], ev[3])
        emit(k, outs)
        arm(k)
    return taken


@pytest.mark.parametrize("offsets_s, drifts", [
    ((0.0, 3e-5, -4e-5, 1e-5), (0.0, 0.0, 0.0, 0.0)),
    ((2e-5, -3e-5, 5e-5, -1e-5), (1.8e-5, -1.9e-5, 7e-6, -1.2e-5)),
])
def test_each_member_forms_the_double_sided_range_exactly(offsets_s, drifts, monkeypatch):
    """Noiseless exchanges: every member's DS-TWR range to the poller (formed from its own stamps and
    the final's) is the true distance, whatever the clocks' offsets; with drifts, within the bound of
    eq. (V5) for the frequency errors of the cores' estimates (``d (|dfa| + |dfb|) / 2``, 2 cm here), while the
    poller's single-sided ranges of the same exchanges, frequency-blind too, are off by up to
    ``(fa - fb) Db / 2`` - metres at the later sub-slots."""
    import stations.core as core_mod

    used = {}  # range -> the frequencies it was formed with (poller's broadcast, the member's own)

    def ds(*a):
        r = core_mod_ds(*a)
        used[r.item()] = (a[6], a[7])
        return r

    core_mod_ds = core_mod.ds_twr_range_m
    monkeypatch.setattr(core_mod, "ds_twr_range_m", ds)
    # the members on DS-TWR throughout: these frequency-blind cores' filters would pass the gate of the
    # averaged single-sided ranges (V4b), which needs the frequencies they are made to ignore
    monkeypatch.setattr(core_mod, "sym_twr_range_m", ds)
    clocks = [Clock(offset_s=o, drift=f) for o, f in zip(offsets_s, drifts)]
    cores = _cores(clocks)
    for c in cores:  # the single-sided ranges frequency-blind (the filters' estimates still broadcast)
        c.clk.freq = lambda: 0.0
    taken = _run(cores, clocks, 3.0)
    n_ds = 0
    ss_err = []
    for k, c in enumerate(cores):
        assert c.counters["reply_window"] == c.counters["final_window"] == 0
        for peer, r, initiated in taken[c.id]:
            d = float(np.linalg.norm(POS[k] - POS[peer - 1]))
            if initiated:  # the poller's single-sided range
                ss_err.append(abs(r - d))
                continue
            n_ds += 1
            # + 10 um: stamps of ~3 s carry 4.4e-16 s (0.13 um) per rounding, about ten of them between
            # the channel's clock conversions and the formula
            fp, fr = used[r]
            bound = d * (abs(drifts[peer - 1] - fp) + abs(drifts[k] - fr)) / 2 * 1.01 + 1e-5
            assert abs(r - d) <= bound, (c.id, peer, r - d, bound)
    assert n_ds >= 3 * 4 * 2  # every member of every poll, two cycles at least
    # a 20 ppm class: the first single-sided ranges wait for the frequencies (rate gate, counted)
    assert sum(c.counters["ss_gated"] for c in cores) > 0
    if any(drifts):
        assert max(ss_err) > 1.0  # the rate difference acts on the whole reply delay (V6)


def test_members_average_the_two_single_sided_ranges_once_the_frequencies_are_known(monkeypatch):
    """Noiseless exchanges, drifting clocks, the cores' own frequency estimates: the first finals (the
    frequencies not known yet) give DS-TWR ranges (V4), the later ones the averaged single-sided
    ranges (V4b, the exchange's bound 3/4 sigma_d^2), whose rate bias the gate keeps within
    0.25 sigma_d (1-sigma): every member range within 3 x that of the truth."""
    import stations.core as core_mod

    kinds = []
    for name in ("ds_twr_range_m", "sym_twr_range_m"):
        def rec(*a, _f=getattr(core_mod, name), _n=name):
            kinds.append(_n)
            return _f(*a)
        monkeypatch.setattr(core_mod, name, rec)
    drifts = (1.8e-5, -1.9e-5, 7e-6, -1.2e-5)
    clocks = [Clock(offset_s=o, drift=f) for o, f in zip((2e-5, -3e-5, 5e-5, -1e-5), drifts)]
    cores = _cores(clocks)
    taken = _run(cores, clocks, 6.0)
    assert kinds[0] == "ds_twr_range_m" and kinds[-1] == "sym_twr_range_m"
    sigma_d = cores[0].cfg.sigma_d_m
    for k, c in enumerate(cores):
        for peer, r, initiated in taken[c.id]:
            if not initiated:
                assert abs(r - float(np.linalg.norm(POS[k] - POS[peer - 1]))) < 3 * 0.25 * sigma_d


def test_a_reply_outside_its_sub_slot_is_dropped_and_counted_never_misattributed():
    """Station 3's replies to station 1 arrive one reply spacing late - inside station 4's sub-slot
    window, not its own: station 1 drops them (``reply_window``), forms no range with 3, and still
    ranges 2 and 4; station 3 forms no range to 1 either (its stamp is not in the final)."""
    clocks = [Clock() for _ in POS]
    cores = _cores(clocks, freq_sigma=2e-6)  # (a TCXO's class: its single-sided ranges pass the rate gate)
    taken = _run(cores, clocks, 3.0, delay_s={(3, 1): 0.0005})
    c1 = cores[0]
    assert c1.counters["reply_window"] >= 2
    assert {p for p, _, ini in taken[1] if ini} == {2, 4}
    assert 1 not in {p for p, _, ini in taken[3] if not ini}
    assert cores[2].counters["final_lost"] >= 2
    # the others' exchanges with station 1 are untouched
    assert {p for p, _, ini in taken[2] if not ini} >= {1}


def test_a_final_read_after_the_next_poll_still_closes_its_exchange():
    """A process that reads its navs in batches can hear a poller's next poll before the final of the
    previous one: each member keeps its latest polls per poller (``POLLED_KEEP``), so every final
    still closes its own exchange (by the poll's seq), and none is counted lost."""
    clocks = [Clock() for _ in POS]
    on_time = _cores(clocks, freq_sigma=2e-6)
    late = _cores(clocks, freq_sigma=2e-6)
    taken = _run(on_time, clocks, 4.0)
    taken_late = _run(late, clocks, 4.0, nav_late_s=1.3)  # after the next cycle's poll
    for a, b in zip(on_time, late):
        assert b.counters["final_lost"] == 0 and b.counters["final_window"] == 0, b.counters
        ds = sorted(p for p, _, ini in taken[a.id] if not ini)
        ds_late = sorted(p for p, _, ini in taken_late[b.id] if not ini)
        assert ds_late and set(ds_late) == set(ds), (a.id, ds, ds_late)
        assert len(ds_late) >= len(ds) - 3  # only the finals still in flight at the end are missing


def test_a_poll_plan_that_cannot_fit_the_slot_is_refused_naming_the_keys():
    with open(load("seed000").source, "rb") as f:
        raw = tomllib.load(f)
    raw["tdma"].update(ranging="poll", reply_spacing_s=0.001)
    with pytest.raises(ScenarioError, match=r"^\[tdma\] slot_s: .*\[channel\] turnaround_s .*\[tdma\] reply_spacing_s"):
        from_dict(raw)
    raw["tdma"]["reply_spacing_s"] = 0.0005
    assert from_dict(raw).tdma.poll  # 1 ms + 9 x 0.5 ms + frame, path and guard: fits in 10 ms
    raw["tdma"]["ranging"] = "polled"
    with pytest.raises(ScenarioError, match=r"^\[tdma\] ranging: got 'polled'"):
        from_dict(raw)
    raw["tdma"].update(ranging="poll", assignment="distributed")
    with pytest.raises(ScenarioError, match=r"^\[tdma\] ranging"):
        from_dict(raw)


def _poll_scenario():
    with open(load("seed000").source, "rb") as f:
        raw = tomllib.load(f)
    raw["tdma"]["ranging"] = "poll"
    return from_dict(raw)


def test_a_poll_core_replays_bit_for_bit_from_its_journal():
    """Journal (through msgpack and the wire's validation) and init record rebuild each core of a
    poll field exactly; the default path's init record carries no poll key."""
    def make(*a, **k):
        c, clock = make_core(*a, **k)
        c.journal = True
        return c, clock

    sim = Simulator(_poll_scenario(), core_factory=make)
    sim.run(6.0, [6.0])
    kinds = set()
    for c in sim.cores:
        entries = msgpack.unpackb(msgpack.packb(c.take_inputs()), raw=False)
        M.validate_msg({"kind": "core_input", "src": c.id, "seq": 1, "stamp_s": 0.0, "entries": entries[:4000]})
        kinds |= {e[2]["kind"] for e in entries if e[0] == "m"}
        c2 = StationCore.from_init_record(msgpack.unpackb(msgpack.packb(c.init_record), raw=False))
        assert c2.poll and c2.cfg.reply_spacing_s == c.cfg.reply_spacing_s
        c2.replay(entries)
        assert np.array_equal(c2.est.pos_m, c.est.pos_m) and np.array_equal(c2.est.cov_m2, c.est.cov_m2)
        assert np.array_equal(c2.clk.x, c.clk.x) and c2.counters == c.counters
    assert kinds == {"poll", "reply", "nav"}
    plain, _ = make_core(load("seed000"), 2)
    assert "ranging" not in plain.init_record["cfg"] and not plain.poll


def test_poll_field_measures_every_link_every_cycle():
    """seed000 with the poll: each station's poll is answered by the nine others (N ranges per slot,
    not one); the simulator's realized links (the bench CRLB's input) count them."""
    sim = Simulator(_poll_scenario())
    r = sim.run(5.0, [5.0])
    links = r.link_counts[-1]
    off = ~np.eye(len(r.ids), dtype=bool)
    assert links[off].min() >= 3 and links.sum() >= 10 * 9 * 4
    for sid, cnt in r.counters.items():
        assert cnt["reply_window"] == cnt["final_window"] == 0
        assert cnt["ranges_in"] >= 9 * 3


def test_implausible_poll_fields_are_dropped_and_counted():
    clocks = [Clock() for _ in POS]
    c = _cores(clocks)[1]
    base = {"src": 1, "seq": 1, "stamp_s": 0.0, "cycle": 0, "slot": 0, "t_tx_s": 0.0}
    assert c.on_message({**base, "kind": "poll", "members": [2, 2, 3]}, 1e-6) == []
    assert c.admission.dropped["members"] == 1
    nav = {**base, "kind": "nav", "t_tx_s": 0.006, "pos_m": [0.0, 0.0, 0.0], "cov_m2": np.zeros((3, 3)).tolist(),
           "n_updates": 0, "state": "frame", "ranges": [], "members": [2, 3, 4],
           "poll": {"seq": 1, "t1": 0.0, "rx": [[2, 0.007]]}}  # a reply heard after the final left
    c.on_message(nav, 0.006)
    assert c.admission.dropped["poll"] == 1
    rep = {"src": 3, "seq": 1, "stamp_s": 0.0, "kind": "reply", "dst": 2, "poll_seq": 1, "t_rx_s": 0.002,
           "t_tx_s": 0.001, "pos_m": [1.0, 2.0, 3.0], "cov_m2": np.eye(3).tolist(), "n_updates": 0, "state": "surveying"}
    c.on_message(rep, 0.0011)
    assert c.admission.dropped["turnaround"] == 1
    with pytest.raises(M.MessageError):
        M.validate_msg({**nav, "poll": {"seq": 1, "t1": float("nan"), "rx": []}})


def test_an_unconverged_poll_station_re_solves_on_the_navs_it_hears():
    """Protocol v2 (stations/core.py ``POLL_RESOLVE_SIGMA_D``): while its horizontal sigma is above
    sigma_d a station re-solves on each nav it hears and publishes the estimate; converged, it solves
    and publishes once per cycle, before its nav. seed000: stations 4..10 within sigma_d (mean) at 2 s."""
    est: dict[int, list[float]] = {}

    def publish(t, sid, msg, phy):
        if msg["kind"] == "estimate":
            est.setdefault(sid, []).append(t)

    scn = _poll_scenario()
    sim = Simulator(scn, publish=publish)
    r = sim.run(8.0, [2.0, 8.0])
    h = np.hypot(*(r.pos_m[0, 3:, :2] - r.truth_m[3:, :2]).T)
    assert h.mean() < scn.channel.sigma_d_m
    for sid in scn.ids[1:]:
        t = np.asarray(est[sid])
        assert np.count_nonzero((t >= 1.0) & (t < 2.0)) > 1  # cycle 1: the navs heard
        assert np.count_nonzero((t >= 6.0) & (t < 8.0)) == 2  # converged: one per cycle


def test_the_poller_takes_the_members_averaged_range_of_its_exchange():
    """stations/core.py ``POLL_CLOSED``: each member lists its averaged range (V4b) of the polls it answered
    in its next nav (``closed``); the poller's survey takes it as its range of that exchange, in place
    of its single-sided range (which bridged until then). Every exchange of ours the member closed
    arrives (``closed_in``), each link's kept ranges are the members' V4b of our polls and our own V4b
    of theirs, one range per exchange: no single-sided range is left but the exchanges whose member
    has not sent its nav yet."""
    clocks = [Clock(offset_s=o, drift=f) for o, f in zip((2e-5, -3e-5, 5e-5, -1e-5), (1.8e-5, -1.9e-5, 7e-6, -1.2e-5))]
    cores = _cores(clocks, freq_sigma=2e-6)
    closed: dict[tuple[int, int], list[float]] = {}  # (poller, member) -> the member's V4b of its polls
    for c in cores:
        def nav(t_s, _c=c, _f=c._nav_msg):
            m = _f(t_s)
            for poller, r, _ in m.get("closed", ()):
                closed.setdefault((poller, _c.id), []).append(r)
            return m
        c._nav_msg = nav
    taken = _run(cores, clocks, 5.0)
    for c in cores:
        assert c.counters["closed_in"] == sum(len(v) for (p, _), v in closed.items() if p == c.id) > 0
        for peer in c.est.links:
            kept = sorted(c.est.link_ranges(peer)[0].tolist())
            own_v4b = [r for p, r, ini in taken[c.id] if p == peer and not ini]
            ss = [r for p, r, ini in taken[c.id] if p == peer and ini]
            from_member = closed.get((c.id, peer), [])
            assert set(from_member) <= set(kept) and set(own_v4b) <= set(kept)
            bridging = set(kept) - set(from_member) - set(own_v4b)
            assert bridging <= set(ss) and len(bridging) <= 1, (c.id, peer, bridging)
            assert len(kept) == len(own_v4b) + len(from_member) + len(bridging)


def test_a_closed_entry_of_no_exchange_of_ours_is_ignored():
    """A nav's ``closed`` naming us for a poll whose reply we did not take (or another station) changes
    nothing in our survey; the wire refuses a malformed entry."""
    clocks = [Clock() for _ in POS]
    cores = _cores(clocks, freq_sigma=2e-6)
    _run(cores, clocks, 3.0)
    c = cores[0]
    before = (c.counters["closed_in"], c.est._nr, c.est._rv[:c.est._nr].copy())
    nav = {"src": 2, "seq": 99, "stamp_s": 3.0, "kind": "nav", "cycle": 3, "slot": 1, "t_tx_s": 3.016,
           "pos_m": POS[1].tolist(), "cov_m2": np.eye(3).tolist(), "n_updates": 3, "state": "surveying",
           "ranges": [], "members": [1, 3, 4], "closed": [[1, 5.0, 9999], [3, 7.0, 1]]}
    c.on_message(M.validate_msg(nav), 3.017)
    assert (c.counters["closed_in"], c.est._nr) == before[:2] and np.array_equal(c.est._rv[:c.est._nr], before[2])
    with pytest.raises(M.MessageError):
        M.validate_msg({**nav, "closed": [[1, 5.0]]})


def test_the_integrity_test_judges_the_range_the_survey_takes_from_closed():
    """A member's ``closed`` range replaces our single-sided range of that exchange in the integrity
    test's window too, so a member lying there is tested as one lying in its reply stamps."""
    clocks = [Clock() for _ in POS]
    cores = _cores(clocks, freq_sigma=2e-6)
    _run(cores, clocks, 3.5)
    c = next(c for c in cores if any(test is not None for _, test in c._ss_open.values()))
    (member, seq), (ss, ss_test) = next((k, v) for k, v in c._ss_open.items() if v[1] is not None)
    lie = ss_test + 40.0
    nav = {"src": member, "seq": 99, "stamp_s": 3.6, "kind": "nav", "cycle": 3, "slot": 1, "t_tx_s": 3.6,
           "pos_m": POS[member - 1].tolist(), "cov_m2": np.eye(3).tolist(), "n_updates": 3, "state": "surveying",
           "ranges": [], "members": [p for p in range(1, len(POS) + 1) if p != member],
           "closed": [[c.id, lie, seq]]}
    c.on_message(M.validate_msg(nav), 3.601)
    window = [r for _, r in c.integrity.peers[member].ranges]
    assert lie in window and ss_test not in window
    assert ss is None or lie in c.est.link_ranges(member)[0].tolist()


def test_the_consider_factor_drops_once_the_station_is_converged_in_height_too():
    """stations/core.py ``POLL_PEER_CORR_LATE``: the dmap solve charges the peers' covariances 3 times
    while the station is metres off, 0.5 times from the first nav at which its horizontal sigma is at
    most sigma_d / 2 and its vertical one at most 4 sigma_d (one way); a horizontal fix with a height
    still metres off keeps 3 (the field's mirror image in height, docs/survey.md phase 4)."""
    import stations.core as core_mod

    c = _cores([Clock() for _ in POS])[3]
    sd = c.cfg.sigma_d_m
    assert c.est.peer_corr_est == core_mod.POLL_PEER_CORR_EST == 3.0
    c.est.cov_m2 = np.diag([0.01, 0.01, (8.0 * sd) ** 2])  # horizontal 0.14 m, height 4 m
    c._converged_weights()
    assert c.est.peer_corr_est == 3.0
    c.est.cov_m2 = np.diag([0.01, 0.01, (2.0 * sd) ** 2])
    c._converged_weights()
    assert c.est.peer_corr_est == core_mod.POLL_PEER_CORR_LATE == 0.5
    c.est.cov_m2 = np.diag([1.0, 1.0, 1.0])
    c._converged_weights()
    assert c.est.peer_corr_est == 0.5
