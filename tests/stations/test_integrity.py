"""Issue 14: NLOS-robust survey, scenario faults, station-side integrity."""

from __future__ import annotations

import numpy as np
import pytest

from net.scenario import load
from stations.estimators import DistributedMap
from stations.sim import Simulator


def _solve_case(robust, outlier_m: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    truth = np.array([300.0, 400.0, 20.0])
    peers = {2: [1000.0, 0, 0], 3: [200.0, 900.0, 0], 4: [700.0, 800.0, 60.0], 5: [-300.0, 600.0, 30.0],
             6: [900.0, 500.0, -20.0], 7: [-100.0, -200.0, 10.0]}
    est = DistributedMap(8, truth + rng.normal(0, 3.0, 3), np.eye(3) * 9.0, 0.5, robust=robust)
    for pid, p in peers.items():
        p = np.asarray(p)
        est.on_peer(pid, p, np.eye(3) * 0.01)
        for _ in range(6):
            est.on_range(pid, np.linalg.norm(truth - p) + rng.normal(0, 0.5), 0.0, True, None, None)
        est.refresh()
    est.on_range(4, np.linalg.norm(truth - np.asarray(peers[4])) + outlier_m, 0.0, True, None, None)
    for _ in range(3):
        est._dirty = True
        est.refresh()
    return est, truth


def test_single_outlier_range_is_down_weighted():
    rob, truth = _solve_case("tukey", 25.0)
    pla, _ = _solve_case(None, 25.0)
    ranges, w = rob.link_ranges(4)
    assert len(ranges) == 7 and w[-1] == 0.0 and np.all(w[:-1] > 0.5)
    e_rob = np.linalg.norm((rob.pos_m - truth)[:2])
    e_pla = np.linalg.norm((pla.pos_m - truth)[:2])
    clean, _ = _solve_case("tukey", 0.0)
    assert e_rob < 0.5 and e_pla > 2 * e_rob
    assert np.linalg.norm((rob.pos_m - clean.pos_m)[:2]) < 0.05  # the outlier changed (almost) nothing


def test_robust_equals_plain_on_clean_data():
    """Seeded: on clean ranges the robust dmap's estimates match plain dmap-ls within a fraction of sigma_d."""
    d_h, e_rob, e_pla = [], [], []
    for seed in (3, 4):
        scn = load("seed000", seed=seed)
        out = {}
        for est in ("dmap", "dmap-ls"):
            r = Simulator(scn, estimator=est).run(30.0, [30.0])
            out[est] = r.pos_m[0, 3:] - r.truth_m[3:]
        d_h.append(np.hypot(*(out["dmap"] - out["dmap-ls"])[:, :2].T))
        e_rob.append(np.hypot(*out["dmap"][:, :2].T))
        e_pla.append(np.hypot(*out["dmap-ls"][:, :2].T))
    d_h = np.concatenate(d_h)
    assert np.sqrt((d_h**2).mean()) < 0.1  # sigma_d = 0.5 m
    rms = lambda e: np.sqrt((np.concatenate(e) ** 2).mean())
    assert rms(e_rob) < 1.2 * rms(e_pla)


def test_los_cluster_picks_the_shortest_recurring_range():
    from stations.estimators import los_cluster

    c, n = los_cluster(np.array([130.0, 100.2, 99.9, 112.0, 100.1, 131.0]), 2.0)
    assert n == 3 and abs(c - 100.1) < 1e-9  # the NLOS pair at 130-131 m is a smaller cluster
    assert los_cluster(np.array([120.0, 100.0]), 2.0) == (100.0, 1)  # no agreement: unconfirmed


def _nlos_case(robust, seed: int, p_leg: float = 0.2, excess_m: float = 20.0, rounds: int = 9):
    """One station among 6 well-known peers; ranges arrive link by link in rounds (as in the TDMA
    cycle), each range with two legs that are NLOS with probability ``p_leg`` (exponential excess)."""
    rng = np.random.default_rng(seed)
    truth = np.array([300.0, 400.0, 20.0])
    peers = {2: [1000.0, 0, 0], 3: [200.0, 900.0, 0], 4: [700.0, 800.0, 60.0], 5: [-300.0, 600.0, 30.0],
             6: [900.0, 500.0, -20.0], 7: [-100.0, -200.0, 10.0]}
    est = DistributedMap(8, truth + rng.normal(0, 10.0, 3), np.eye(3) * 100.0, 0.5, robust=robust)
    for _ in range(rounds):
        for pid, p in peers.items():
            p = np.asarray(p, float)
            nlos = rng.random(2) < p_leg
            excess = float((nlos * rng.exponential(excess_m, 2)).sum())
            est.on_range(pid, np.linalg.norm(truth - p) + rng.normal(0, 0.5) + excess, 0.0, True, p, np.eye(3) * 0.01)
        est.refresh()
    return est, truth


def test_nlos_20_percent_of_legs_stays_near_the_truth():
    """Seeded: with 36 % of the ranges lengthened (20 % of legs, mean excess 20 m) the robust dmap's
    horizontal error stays within a loose 1 m (sigma_d = 0.5 m, 9 ranges per link) on every seed,
    where plain least squares is off by metres; its covariance is not overconfident on average."""
    e_rob, e_pla, nees = [], [], []
    for seed in range(6):
        rob, truth = _nlos_case("tukey", seed)
        pla, _ = _nlos_case(None, seed)
        e = rob.pos_m - truth
        e_rob.append(np.hypot(*e[:2]))
        e_pla.append(np.hypot(*(pla.pos_m - truth)[:2]))
        nees.append(float(e @ np.linalg.solve(rob.cov_m2, e)))
    assert max(e_rob) < 1.0
    assert np.median(e_pla) > 3.0 * max(e_rob)
    assert np.mean(nees) < 2 * 3.42  # the bar: mean NEES <= 2 x the upper edge of the band


def _feed_rounds(est, seed: int, p_leg: float, rounds: int):
    """Ranges of one station to 6 known peers, link by link in rounds; legs NLOS with ``p_leg``."""
    rng = np.random.default_rng(seed)
    truth = np.array([300.0, 400.0, 20.0])
    peers = {2: [1000.0, 0, 0], 3: [200.0, 900.0, 0], 4: [700.0, 800.0, 60.0], 5: [-300.0, 600.0, 30.0],
             6: [900.0, 500.0, -20.0], 7: [-100.0, -200.0, 10.0]}
    for _ in range(rounds):
        for pid, p in peers.items():
            p = np.asarray(p, float)
            excess = float(((rng.random(2) < p_leg) * rng.exponential(20.0, 2)).sum())
            est.on_range(pid, np.linalg.norm(truth - p) + rng.normal(0, 0.5) + excess, 0.0, True, p, np.eye(3) * 0.01)
        est.refresh()
    return est


def test_default_dmap_keeps_two_agreeing_ranges_weak_only_where_its_ranges_show_nlos():
    """The default ``dmap`` adapts how long a link stays weak to its own ranges: cautious (a link needs
    three agreeing ranges, as ``dmap-nlos``) until it holds ``clean_after_n`` ranges in links with two or
    more, then two agreeing ranges give full weight while the ranges look clean; once they show NLOS
    (20 % of legs) a link needs three again. The decision is re-made from the kept ranges."""
    from stations.estimators import make_estimator

    pos0, cov0 = np.array([305.0, 395.0, 20.0]), np.eye(3) * 100.0
    for seed in range(4):
        early = _feed_rounds(make_estimator("dmap", 8, pos0, cov0, 0.5), seed, 0.0, 2)
        assert early.clean_after_n > 12 and early.nlos_seen  # 12 ranges: not yet evidence of clean ranges
        clean = _feed_rounds(make_estimator("dmap", 8, pos0, cov0, 0.5), seed, 0.0, 5)
        assert not clean.nlos_seen
        clean._centre_key = None
        clean._support[:6] = 2  # as if every link held two agreeing ranges: full weight when clean
        clean._adapt_weakness(clean._rk[:clean._nr], clean._rv[:clean._nr], 6)
        assert np.all(clean._centre_factor[:6] == 1.0)
        nlos = _feed_rounds(make_estimator("dmap", 8, pos0, cov0, 0.5), 10 + seed, 0.2, 4)
        assert nlos.nlos_seen
        two = nlos._support[:6] == 2
        assert two.any() and np.all(nlos._centre_factor[:6][two] == nlos.unconfirmed_weight)
        ref = _feed_rounds(make_estimator("dmap-nlos", 8, pos0, cov0, 0.5), 10 + seed, 0.2, 4)
        assert np.array_equal(nlos._centre_factor, ref._centre_factor)  # the weights of dmap-nlos


# ---------------------------------------------------------------- scenario [[faults]] and [[links]]
from net import messages as M  # noqa: E402
from net.scenario import ScenarioError  # noqa: E402


@pytest.mark.parametrize("entry, key", [
    ({"kind": "liar", "offset_m": [1.0, 2.0, 3.0]}, "faults[0].station"),
    ({"kind": "teleport", "station": 5}, "faults[0].kind"),
    ({"kind": "liar", "station": 5, "offset_m": [1.0, 2.0]}, "faults[0].offset_m"),
    ({"kind": "liar", "station": 5, "offset_m": [1.0, 2.0, "x"]}, "faults[0].offset_m"),
    ({"kind": "range_bias", "station": 5}, "faults[0].bias_m"),
    ({"kind": "range_bias", "station": 99, "bias_m": 5.0}, "faults[0].station"),
    ({"kind": "clock_jump", "station": 5, "jump_s": 1e-6, "at_s": 3.0, "bias_m": 1.0}, "faults[0].bias_m"),
    ({"kind": "bad_fix", "station": 5, "offset_m": [50.0, 0.0, 0.0], "sigma0_m": -1.0}, "faults[0].sigma0_m"),
])
def test_malformed_faults_name_the_key(entry, key):
    with pytest.raises(ScenarioError, match=key.replace("[", r"\[").replace("]", r"\]")):
        load("seed000", faults=[entry])


@pytest.mark.parametrize("entry, key", [
    ({"nlos_prob": 0.5}, "links[0].station"),
    ({"station": 4, "nlos_prob": 1.5}, "links[0].nlos_prob"),
    ({"stations": [4, 4], "bias_m": 1.0}, "links[0].stations"),
    ({"station": 4, "colour": "red"}, "links[0].colour"),
])
def test_malformed_links_name_the_key(entry, key):
    with pytest.raises(ScenarioError, match=key.replace("[", r"\[").replace("]", r"\]")):
        load("seed000", links=[entry])


def test_link_bias_and_range_bias_fault_lengthen_ranges_in_the_simulator():
    scn = load("seed000", seed=2, channel={"sigma_d_m": 0.01}, clock={"model": "perfect"},  # faults alone
               links=[{"stations": [4, 5], "bias_m": 3.0}],
               faults=[{"kind": "range_bias", "station": 7, "bias_m": 5.0, "from_s": 0.0}])
    sim = Simulator(scn)
    sim.run(20.0, [20.0])
    ids = scn.ids
    for t, i, j, rng_m in sim.range_log:
        a, b = ids[i], ids[j]
        excess = rng_m - np.linalg.norm(scn.pos_m[i] - scn.pos_m[j])
        want = 3.0 * ({a, b} == {4, 5}) + 5.0 * (7 in (a, b))
        assert excess == pytest.approx(want, abs=0.1)


def _node(scn, station_id):
    import time as _time

    from stations.node import NodeOptions, StationNode

    class Bus:
        sent: list = []

        def publish(self, key, data):
            self.sent.append((key, data))

        def subscribe(self, *a):
            return None

        def declare_token(self, *a):
            return None

    bus = Bus()
    bus.sent = []
    speed = 0.01
    epoch = _time.time() - (30.0 + 2 * scn.tdma.slot_s + 0.001) / speed  # inside slot 2 of cycle 30
    node = StationNode(scn, NodeOptions(station_id=station_id, speed=speed, epoch_unix_s=epoch, quiet=True), bus)
    node.start_core()
    bus.sent.clear()
    return node, bus


def test_faults_are_applied_by_the_node_shell_like_the_simulator():
    from nav.geometry import SPEED_OF_LIGHT_M_S
    from net.channel import JumpClock
    from stations.sim import make_core

    faults = [{"kind": "liar", "station": 2, "offset_m": [30.0, 0.0, 0.0], "from_s": 0.0},
              {"kind": "range_bias", "station": 2, "bias_m": 5.0, "from_s": 0.0},
              {"kind": "clock_jump", "station": 3, "jump_s": 1e-3, "at_s": 5.0},
              {"kind": "bad_fix", "station": 4, "offset_m": [50.0, 0.0, 0.0], "sigma0_m": 10.0}]
    scn = load("seed000", layout={"n": 4}, faults=faults, clock={"model": "perfect"})  # the faults alone
    clean = load("seed000", layout={"n": 4}, clock={"model": "perfect"})
    # bad_fix and clock_jump live in make_core, which the node's start_core and the simulator share
    core4, _ = make_core(scn, 4)
    core4c, _ = make_core(clean, 4)
    assert core4.est.pos_m - core4c.est.pos_m == pytest.approx([50.0, 0.0, 0.0])
    assert core4.est.cov_m2 == pytest.approx(np.eye(3) * 100.0)
    _, clk3 = make_core(scn, 3)
    assert isinstance(clk3, JumpClock) and clk3.to_local(6.0) - clk3.to_local(4.0) == pytest.approx(2.0 + 1e-3)
    assert clk3.to_true(clk3.to_local(6.0)) == pytest.approx(6.0)
    # the node: a range request to the lying, biased station 2
    node, bus = _node(scn, 2)
    t_tx = node.fleet_now()
    m = {"kind": "range_req", "src": 3, "seq": 1, "stamp_s": t_tx, "dst": 2, "cycle": 30, "slot": 2, "t_tx_s": t_tx}
    node._on_bytes(M.key_for(m), M.encode(m, {"pos_m": scn.true_pos(3), "t_true_s": t_tx}))
    rsp = [M.decode(d) for k, d in bus.sent if "/range/rsp/" in k]
    assert len(rsp) == 1
    msg, phy = rsp[0]
    assert np.asarray(msg["pos_m"]) - node.core.est.pos_m == pytest.approx([30.0, 0.0, 0.0])  # the lie
    tof = np.linalg.norm(scn.true_pos(3) - scn.true_pos(2)) / SPEED_OF_LIGHT_M_S
    # the request's leg into station 2 is 5 m / c late (the answer's leg is delayed at station 3)
    assert phy["t_true_s"] == pytest.approx(t_tx + tof + 5.0 / SPEED_OF_LIGHT_M_S + scn.channel.turnaround_s, abs=20e-9)
    # the simulator's shell lies the same way
    sim = Simulator(scn)
    out = sim.shell[1].outgoing({"kind": "nav", "pos_m": [1.0, 2.0, 3.0]}, 1.0)
    assert out["pos_m"] == [31.0, 2.0, 3.0]


# ---------------------------------------------------------------- station-side integrity
def test_integrity_message_validates_and_round_trips():
    m = {"kind": "integrity", "src": 3, "seq": 1, "stamp_s": 21.0, "t_s": 21.0, "suspect": 6,
         "statistic": 123.4, "threshold": 15.1, "dof": 1, "p_fa": 1e-4, "decision": "exclude", "excluded": [6]}
    back, phy = M.decode(M.encode(m))
    assert back == m and phy is None and M.key_for(m) == "larns/station/3/integrity"
    with pytest.raises(M.MessageError):
        M.encode({**m, "decision": "maybe"})
    with pytest.raises(M.MessageError):
        M.encode({**m, "p_fa": 2.0})


def test_liar_is_excluded_by_its_neighbours():
    scn = load("seed000", seed=5, faults=[{"kind": "liar", "station": 6, "offset_m": [30.0, 0.0, 0.0], "from_s": 20.0}])
    sim = Simulator(scn)
    sim.run(32.0, [32.0])
    first = [min((t for t, s, d, _ in c.integrity.events if s == 6 and d == "exclude"), default=np.inf)
             for c in sim.cores if c.id != 6]
    assert np.median(first) < 30.0 and min(first) >= 20.0
    assert all(s == 6 for c in sim.cores if c.id != 6 for _, s, _, _ in c.integrity.events)


@pytest.mark.parametrize("roll_back", [True, False])
def test_exclusion_rolls_the_field_back_from_a_liars_height_pull(roll_back, monkeypatch):
    """World seed 38 of ``larns bench integrity --recovery``: in the liar's first second its bounded
    pull lifts stations 8-10 by 40-90 m in height, the whole field with them, and without the roll-back
    they stay there after the exclusion, 6-7 sigma off (the case that must fail here); with it every
    honest station is back within 4 sigma in each axis 15 s after the onset."""
    from stations.core import StationCore

    if not roll_back:
        monkeypatch.setattr(StationCore, "_roll_back", lambda self, t_s: None)
    scn = load("seed000", seed=38, faults=[{"kind": "liar", "station": 6, "offset_m": [30.0, 0.0, 0.0], "from_s": 20.0}])
    r = Simulator(scn).run(35.0, [35.0])
    honest = np.array([i >= 4 and i != 6 for i in scn.ids])
    err = (r.pos_m - r.truth_m)[0, honest]
    sig = np.sqrt(np.einsum("nii->ni", r.cov_m2[0, honest]))
    worst = float(np.max(np.abs(err) / sig))
    if roll_back:
        assert worst < 4.0, (worst, err.round(1).tolist())
    else:
        assert worst > 5.0, worst


def test_station_chi_square_false_alarm_rate_on_clean_data():
    """Seeded: on clean data the per-test statistic is (at most) chi-square(1): its alarm rate at
    p_fa = 1e-2 stays at or below 1e-2 (the estimates are conservative), and exclusions at the
    default p_fa = 1e-4 are as rare as that rate allows: at most the Poisson 99.9 % quantile of
    (tests x p_fa), each followed by a re-admission (seen: seed 7, station 6 - itself 2.7 sigma off
    across track - excluded station 10 at 39 s with T = 16.1 against 15.1 and re-admitted it at 59 s; at
    64 s since the founders hand the frame to the field at about 45 s, docs/architecture.md)."""
    from scipy.stats import chi2, poisson

    stats = []
    n_tests = n_excluded = n_readmitted = 0
    for seed in (7, 8):
        sim = Simulator(load("seed000", seed=seed))
        sim.run(70.0, [70.0])
        for c in sim.cores:
            n_excluded += sum(e[2] == "exclude" for e in c.integrity.events)
            n_readmitted += sum(e[2] == "readmit" for e in c.integrity.events)
            for p in c.integrity.peers.values():
                assert p.n_tests > 30
                n_tests += p.n_tests
        # re-evaluate the statistic at the end for every link: a sample of T under H0
        for c in sim.cores:
            for pid, (ppos, pcov) in c.peers.items():
                T = c.integrity.statistic(pid, c.integrity.peers[pid].ranges[-1][0], c.est.pos_m, c.est.cov_m2,
                                          ppos, pcov)
                if T is not None:
                    stats.append(T)
    stats = np.array(stats)
    assert n_excluded <= poisson.ppf(0.999, 1e-4 * n_tests), (n_excluded, n_tests)
    assert n_readmitted == n_excluded
    assert len(stats) > 150
    assert np.mean(stats > chi2.ppf(0.99, 1)) <= 0.02
    assert 0.2 < stats.mean() < 1.3  # chi-square(1) has mean 1; conservative covariances give less


def test_info_shows_a_station_excluded_by_its_neighbours(tmp_path):
    from larns.analysis.summary import summarize
    from larns.commands.info import format_info
    from larns.log import LogWriter

    p = tmp_path / "i.mcap"
    with LogWriter(p) as w:
        for src, seq in ((3, 1), (4, 1)):
            m = {"kind": "integrity", "src": src, "seq": seq, "stamp_s": 21.0, "t_s": 21.0, "suspect": 6,
                 "statistic": 99.0, "threshold": 15.1, "dof": 1, "p_fa": 1e-4, "decision": "exclude", "excluded": [6]}
            w.write(M.key_for(m), M.encode(m), log_time=10**9 * (20 + src))
        est = {"kind": "estimate", "src": 6, "seq": 1, "stamp_s": 22.0, "t_s": 22.0, "pos_m": [1.0, 2.0, 3.0],
               "cov_m2": np.eye(3).tolist(), "n_updates": 3, "estimator": "dmap", "state": "surveying"}
        w.write(M.key_for(est), M.encode(est), log_time=10**9 * 25)
    s = summarize([p])
    assert s["stations"][6]["excluded_by"] == [3, 4]
    assert "station 6 EXCLUDED by 3,4" in format_info(s)


def test_quorum_of_announced_exclusions():
    """A peer excluded by at least 2 and more than half of the live announcers (other than itself) is
    excluded here too, while the quorum holds; one announcer alone (an insider) excludes nobody."""
    from stations.integrity import StationIntegrity

    mon = StationIntegrity(1, 0.5)
    live = {2, 3, 4, 5, 6}
    for a in live:
        mon.on_announcement(a, [], 0.0)
    mon.on_announcement(2, [6], 1.0)
    assert mon.quorum(1.0, live) == [] and mon.excluded == set()  # one voice: nobody
    mon.on_announcement(3, [6], 1.0)
    assert mon.quorum(1.0, live) == []  # 2 of the 4 voters other than 6: not more than half
    mon.on_announcement(4, [6], 1.0)
    (d,) = mon.quorum(1.5, live)
    assert (d["suspect"], d["decision"], d["dof"], d["statistic"], d["threshold"]) == (6, "exclude", 0, 3.0, 3.0)
    assert mon.excluded == {6} and mon.own_excluded == set() and d["excluded"] == [6]
    assert mon.quorum(2.0, live) == []  # no repeated decision
    mon.on_announcement(1, [6, 1], 2.0)  # our own id as an announcer or a suspect: ignored
    mon.on_announcement(4, [], 3.0)  # 4 re-admits 6: the quorum lapses
    (d,) = mon.quorum(3.0, live)
    assert (d["suspect"], d["decision"]) == (6, "readmit") and mon.excluded == set()
    # stale announcements and announcers no longer live do not vote
    mon.on_announcement(4, [6], 3.0)
    assert mon.quorum(3.0 + mon.window_s + 1.0, live) == []
    assert mon.quorum(3.0, live - {2, 4}) == []  # 2 and 4 no longer live: 3 alone of 3, 5
    assert [e[2] for e in mon.events] == ["exclude", "readmit"]


def test_roll_back_movement_test_takes_the_coordinates_free_then_and_now():
    """A founder in the datum mode is free in x, y, z but its estimate of before the hand-over had
    zero variances in the coordinates the frame fixed: the movement test uses the others, never
    inverts a singular covariance."""
    from stations.core import _moved_beyond

    free = np.ones(3, bool)
    founder_then = np.diag([0.04, 0.0, 0.0])  # station 2 under the founders' frame: only x free
    assert not _moved_beyond(np.array([0.3, 50.0, 50.0]), founder_then, free)  # 1.5 sigma in x
    assert _moved_beyond(np.array([1.0, 0.0, 0.0]), founder_then, free)  # 5 sigma in x
    assert not _moved_beyond(np.array([9.0, 9.0, 9.0]), np.zeros((3, 3)), free)
    full = np.diag([1.0, 1.0, 25.0])
    assert not _moved_beyond(np.array([1.0, 1.0, 10.0]), full, free)  # chi2 = 6 < 16.27
    assert _moved_beyond(np.array([0.0, 0.0, 21.0]), full, free)  # chi2 = 17.6


def test_the_newest_ranges_cluster_is_an_unbiased_mode_not_a_cut_around_one_range():
    """stations/integrity.py newest_mode: on a clean link's window (hundreds of ranges, seed001's 25 Hz)
    the newest range's cluster, centred on the mode by mean shift and with its count discounted by the
    cut's variance factor (1.29 at 2 sigma), gives a statistic ``(mean - d)^2 / (sigma^2 / n_eff)``
    that is chi-square(1); centred on the newest range itself (as before) it read a 1-sigma range as a
    fault. A 5-sigma step in the last 12 ranges is its own mode: found with the step's size."""
    from scipy.stats import chi2

    from stations.integrity import _skipped_mean_factor, newest_mode

    assert _skipped_mean_factor(2.0) == pytest.approx(1.2924, abs=1e-4)
    rng = np.random.default_rng(5)
    sigma, d0 = 0.5, 70.0
    t_new, t_old = [], []
    for _ in range(3000):
        d = d0 + sigma * rng.standard_normal(300)
        m, n_eff = newest_mode(d, 2.0 * sigma, _skipped_mean_factor(2.0))
        t_new.append((m - d0) ** 2 / (sigma**2 / n_eff))
        old = d[np.abs(d - d[-1]) <= 2.0 * sigma]
        t_old.append((old.mean() - d0) ** 2 / (sigma**2 / old.size))
    t_new, t_old = np.array(t_new), np.array(t_old)
    assert 0.85 < t_new.mean() < 1.15 and np.mean(t_new > chi2.ppf(0.99, 1)) < 0.02
    assert np.mean(t_old > chi2.ppf(1 - 1e-4, 1)) > 0.1  # the cut around one range: 10 % read as faults
    d = d0 + sigma * rng.standard_normal(300)
    d[-12:] += 5.0 * sigma
    m, n_eff = newest_mode(d, 2.0 * sigma, _skipped_mean_factor(2.0))
    assert m - d0 == pytest.approx(5.0 * sigma, abs=0.5 * sigma) and n_eff < 12


def test_a_four_station_field_ranging_at_25_hz_excludes_nobody():
    """seed001 (4 stations, 10 ms slots in a 40 ms cycle: hundreds of ranges per link in the test's
    window), clean: no station excludes a peer and every station ends within 3 sigma (3-D) + 5 cm.
    With the newest range's cluster cut around that range, every station of world 1 excluded every
    peer and stations 3 and 4 ended 2.6 and 2.0 m off."""
    scn = load("seed001")
    sim = Simulator(scn, seed=1)
    res = sim.run(30.0, [30.0])
    assert not [e for c in sim.cores for e in c.integrity.events]
    err = np.linalg.norm(res.pos_m[-1] - res.truth_m, axis=1)
    sig = np.sqrt(np.trace(res.cov_m2[-1], axis1=1, axis2=2))
    assert np.all(err <= 3.0 * sig + 0.05), (err, sig)
