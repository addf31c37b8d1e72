"""The radio aircraft starts and keeps going like a receiver (aircraft/navigator/receiver.py, issue 28).

Synthetic field: 8 stations on a 2 km square with 80 m of height spread, an aircraft hovering 1.5 km
out at 60 m, pseudoranges every 10 ms slot (one station per slot, one 80 ms cycle per 8 slots), each
station's broadcast clock error drawn from the covariance it broadcasts. Rule 5's start on a surveyed
field and rule 3's floor test fly over the five stations of tests/scenario_text.py (and a sixth) instead.
"""

from __future__ import annotations

import numpy as np
import pytest

from aircraft.events import to_msgs
from aircraft.navigator import receiver as rx
from aircraft.navigator.radio.estimator import AircraftEstimator, EstimatorConfig
from aircraft.radio_core import RadioAircraftCore
from net import messages as M

RNG_STATIONS = np.random.default_rng(7)
STATIONS = np.column_stack([RNG_STATIONS.uniform(0, 2000, 8), RNG_STATIONS.uniform(0, 2000, 8),
                            RNG_STATIONS.uniform(0, 80, 8)])
TRUTH = np.array([3500.0, 900.0, 60.0])
SIGMA_M = 1.0
CLOCK_M = 250.0  # the receiver's clock offset, m
# the rules that choose the cycle a filter starts from are tested on the one-cycle start (without the
# batch start over many cycles, tests/aircraft/test_batch_start.py, which takes the cycles they pass)
ONE_CYCLE = {"batch_start": None}


def _slots(n_cycles: int, clock_sd_m, rng, bias_m=None):
    """(t_s, id, pos, cov, rho, clock_var) per slot; ``clock_sd_m(cycle, j)`` the broadcast clock sigma,
    the clock error drawn from it; ``bias_m(cycle, j)`` an extra range error not covered by any sigma."""
    for c in range(n_cycles):
        for j in range(len(STATIONS)):
            sd = float(clock_sd_m(c, j))
            err = sd * rng.standard_normal() + (0.0 if bias_m is None else bias_m(c, j))
            rho = np.linalg.norm(TRUTH - STATIONS[j]) + CLOCK_M + err + SIGMA_M * rng.standard_normal()
            yield c * 0.08 + j * 0.01, j + 1, STATIONS[j], np.eye(3) * 0.25, rho, sd**2


def _feed(est, slots):
    for t, sid, pos, cov, rho, cvar in slots:
        est.on_measurement(t, sid, pos, cov, rho, clock_var_m2=cvar)


def test_unsynchronized_broadcasts_are_not_used_for_the_first_fix():
    """Cycles 0-1 broadcast clocks known to 10^5 m / 10^3 m (a field just switched on): none is used,
    the filter starts from cycle 2's synchronized broadcasts and its first estimate is near the truth.
    Without the gate the same broadcasts start it hundreds of kilometres off."""
    sd = lambda c, j: {0: 1e5, 1: 1e3}.get(c, 0.5)  # noqa: E731
    est = AircraftEstimator("ekf-pr", EstimatorConfig(**ONE_CYCLE))
    _feed(est, _slots(2, sd, np.random.default_rng(1)))
    assert est.tracker is None and est.status == rx.WAITING
    assert est.stats["nav_unsynchronized"] == 16
    _feed(est, _slots(4, sd, np.random.default_rng(1)))
    e = est.estimate()
    assert est.status == rx.TRACKING and e is not None
    assert np.linalg.norm(np.array(e["pos_m"]) - TRUTH) < 100.0

    off = AircraftEstimator("ekf-pr", EstimatorConfig(receiver=None, **ONE_CYCLE))
    _feed(off, _slots(4, sd, np.random.default_rng(1)))
    assert np.linalg.norm(np.array(off.estimate()["pos_m"]) - TRUTH) > 1e3


def test_a_start_set_with_one_inconsistent_station_leaves_it_out_or_is_refused():
    """Station 3 is 400 m off beyond what it claims: the start leaves it out (the other 7 agree), and
    with two such stations the set is refused until they agree."""
    est = AircraftEstimator("ekf-pr", EstimatorConfig(fde=None, **ONE_CYCLE))
    _feed(est, _slots(2, lambda c, j: 0.5, np.random.default_rng(2), bias_m=lambda c, j: 400.0 * (j == 2)))
    assert est.stats["start_left_one_out"] == 1
    assert np.linalg.norm(est.init.fix[:3] - TRUTH) < 3.0 * est.init.fix_sigma_m  # 400 m off: not from station 3

    two = AircraftEstimator("ekf-pr", EstimatorConfig(fde=None, **ONE_CYCLE))
    bad = lambda c, j: 400.0 * (j in (2, 5)) * (c < 3)  # noqa: E731
    _feed(two, _slots(3, lambda c, j: 0.5, np.random.default_rng(3), bias_m=bad))
    assert two.tracker is None and two.stats["start_inconsistent"] >= 2
    _feed(two, _slots(6, lambda c, j: 0.5, np.random.default_rng(3), bias_m=bad))
    assert two.tracker is not None


def test_a_moving_aircraft_is_judged_by_the_weights_its_start_fix_was_given():
    """seed003's field (8 stations over 40 x 30 km, 0.1 s slots, 0.8 s cycle) and its 50 m/s aircraft
    at 1000 m: each batch spans 0.7 s, 35 m of flight. The start's fix is weighted with the motion it
    tests for, so consistent batches start the filter: over 40 batches along the ellipse (surveyed
    stations, 0.9 m noise) at most one is refused. Weighted without the motion but tested with it, the
    fix failed about a third of such batches (in one 90 s fleet the filters did not start before 64 s)."""
    stations = np.array([[0, 0, 0], [30e3, 0, 0], [15e3, 12e3, 0], [15e3, -12e3, 50], [-3e3, 10e3, 30],
                         [33e3, -10e3, 30], [-3e3, -10e3, 0], [33e3, 10e3, 0]], float)
    rng = np.random.default_rng(11)
    refused = 0
    for k in range(40):
        est = AircraftEstimator("ekf-pr", EstimatorConfig(fde=None, **ONE_CYCLE))
        th0 = 2.0 * np.pi * k / 40
        for slot in range(8):
            t = 0.1 * slot
            th = th0 + 50.0 * t / 15300.0  # 50 m/s on the 18 x 12 km ellipse
            truth = np.array([15e3 + 18e3 * np.cos(th), 12e3 * np.sin(th), 1000.0])
            rho = np.linalg.norm(truth - stations[slot]) + CLOCK_M + 0.9 * rng.standard_normal()
            est.on_measurement(t, slot + 1, stations[slot], np.eye(3) * 0.01, rho, clock_var_m2=0.0)
        est.on_measurement(0.8, 1, stations[0], np.eye(3) * 0.01, 0.0, clock_var_m2=0.0)  # closes the batch
        refused += est.stats["start_inconsistent"]
        assert est.stats["start_inconsistent"] or est.tracker is not None
    assert refused <= 1, refused


def test_divergence_restarts_a_lost_filter_but_not_for_one_faulty_station():
    cfg = rx.ReceiverConfig(window=10)
    mon = rx.DivergenceMonitor(cfg)
    rng = np.random.default_rng(4)
    # one station with a large bias (every fourth update), the rest nominal: not divergence
    for k in range(200):
        i = k % 4
        w = rng.chisquare(1) + (400.0 if i == 2 else 0.0)
        assert not mon.push(w, 1, {i: w}), k
    # every station disagrees: lost
    lost = [mon.push(50.0 + rng.chisquare(1), 1, {k % 4: 50.0}) for k in range(10)]
    assert lost[-1]


def test_one_absurd_measurement_is_not_read_as_a_lost_filter():
    """A pseudorange 1e12 m off has an NIS of ~1e24, and its station's share of it (the FDE's snooping)
    differs from it in the last digit: the window's Q - W_i of two 1e24 sums is then rounding of
    ~1e8 (it restarted a healthy filter, found with the FDE's gate test). Taken update by update, what
    is left of that update is 0."""
    cfg = rx.ReceiverConfig(window=20)
    rng = np.random.default_rng(5)
    for q_bad in (2.4121804875124937e24, 3.7e18, 1e12):
        mon = rx.DivergenceMonitor(cfg)
        for k in range(19):
            w = rng.chisquare(1)
            assert not mon.push(w, 1, {k % 4: w})
        assert not mon.push(q_bad, 1, {3: q_bad * (1 - 2e-16)}), q_bad


def test_estimator_restarts_when_its_filter_has_lost_the_aircraft():
    est = AircraftEstimator("ukf-pr", EstimatorConfig(**ONE_CYCLE))
    _feed(est, _slots(6, lambda c, j: 0.5, np.random.default_rng(5)))
    assert est.status == rx.TRACKING
    x = est.tracker.x.copy()
    x[:2] += [3000.0, -2000.0]
    est.tracker.x = x
    est.tracker.P = est.tracker.P * 1e-4  # confidently wrong
    _feed(est, ((t + 0.48, *rest) for t, *rest in _slots(10, lambda c, j: 0.5, np.random.default_rng(6))))
    assert est.stats["diverged"] >= 1
    assert np.linalg.norm(np.array(est.estimate()["pos_m"]) - TRUTH) < 100.0


@pytest.mark.parametrize("seed", range(6))
def test_no_published_estimate_is_ever_invalid_over_random_broadcast_sets(seed):
    """Property: random broadcast sets (clock sigmas from 0.1 m to 10^6 m, wild station covariances,
    biases, missing stations) through the live core never yield an ``ac_estimate`` that the wire
    refuses or that has a non-finite / non-PSD covariance; what it does not publish it says in
    ``ac_status``."""
    from aircraft.config import from_scenario
    from net.scenario import load

    rng = np.random.default_rng(100 + seed)
    ac = from_scenario(load("seed000"))
    core = RadioAircraftCore(ac, ("ekf-pr", "ukf-pr", "ukf-tdoa", "lsq-pr"), "ac1", np.random.default_rng(seed),
                             horizon_s=120.0)
    t_s, kinds = 0.0, set()
    for k in range(600):
        j = int(rng.integers(0, 8))
        t_s += 0.01 + 0.05 * rng.random()
        sd = float(10 ** rng.uniform(-1, 6))
        cov = np.eye(3) * float(10 ** rng.uniform(-2, 5))
        msg = {"kind": "nav", "src": j + 1, "seq": k + 1, "stamp_s": t_s, "cycle": k // 8, "slot": j, "t_tx_s": t_s,
               "pos_m": (STATIONS[j] + rng.normal(0, 1, 3) * (0 if rng.random() < 0.7 else 500)).tolist(),
               "cov_m2": cov.tolist(), "n_updates": k, "state": "surveying", "ranges": [], "members": [],
               "clock": [t_s, sd * float(rng.standard_normal()) / 3e8, 0.0, (sd / 3e8) ** 2, 0.0, 0.0]}
        phy = {"pos_m": STATIONS[j].tolist(), "t_true_s": t_s}
        for out in to_msgs(core.on_nav(msg, phy)):
            kinds.add(out["kind"])
            out, _ = M.decode(M.encode(out))  # what the wire takes (raises if it would refuse it)
            if out["kind"] == "ac_estimate":
                P = np.asarray(out["cov_m2"])
                assert np.all(np.isfinite(P)) and np.linalg.eigvalsh(P)[0] >= -1e-6 * np.abs(P).max()
    assert "ac_status" in kinds


def test_live_core_says_why_it_publishes_nothing():
    """Unsynchronized broadcasts: no estimate, an ``ac_status`` 'waiting' that names the counter."""
    from aircraft.config import from_scenario
    from net.scenario import load

    core = RadioAircraftCore(from_scenario(load("seed000")), ("ukf-pr",), "ac1", np.random.default_rng(0),
                             horizon_s=60.0)
    outs = []
    for k in range(16):
        j = k % 8
        msg = {"kind": "nav", "src": j + 1, "seq": k + 1, "stamp_s": 0.01 * k, "cycle": 0, "slot": j,
               "t_tx_s": 0.01 * k, "pos_m": STATIONS[j].tolist(), "cov_m2": np.eye(3).tolist(), "n_updates": 1,
               "state": "surveying", "ranges": [], "members": [], "clock": [0.0, 0.0, 0.0, 1e-6, 0.0, 0.0]}
        outs += to_msgs(core.on_nav(msg, {"pos_m": STATIONS[j].tolist(), "t_true_s": 0.01 * k}))
    status = [o for o in outs if o["kind"] == "ac_status"]
    assert not [o for o in outs if o["kind"] == "ac_estimate"]
    assert status and status[0]["state"] == rx.WAITING and status[-1]["counts"]["nav_unsynchronized"] >= 1
    assert M.key_for(status[0]) == "larns/aircraft/ac1/status/ukf-pr"
    assert M.decode(M.encode(status[0]))[0]["detail"] == "waiting for synchronized stations"


def test_start_waits_for_a_surveyed_field():
    """Receiver rule 5 (aircraft/navigator/receiver.py): a filter does not start while a station of the
    batch is known to worse than ``start_station_sigma_m`` (one station 6 m) and the others are too few
    for a snapshot with redundancy; it starts from the first batch of surveyed stations, from the
    surveyed ones alone where there are enough, or from whatever it has once ``start_wait_s`` have
    passed; a snapshot LSQ does not wait. Stations of tests/scenario_text.py (and a sixth), the
    aircraft hovering 1.5 km out."""
    st = np.array([[0.0, 0.0, 0.0], [1800.0, 0.0, 5.0], [900.0, 1500.0, 0.0], [800.0, 500.0, 60.0],
                   [300.0, 1200.0, 20.0], [1500.0, 1300.0, 30.0]])
    p_ac = np.array([2260.0, 640.0, 316.0])
    cfg = rx.ReceiverConfig()
    rng = np.random.default_rng(5)

    def run(algo, sigma_5_m, n_cycles, n_st=5):
        e = AircraftEstimator(algo, EstimatorConfig(fde=None, **ONE_CYCLE))
        for c in range(n_cycles):
            for k in range(n_st):
                s = sigma_5_m if k == 4 else 0.3
                rho = np.linalg.norm(p_ac - st[k]) + 0.5 * rng.standard_normal()
                e.on_measurement(0.25 * c + 0.05 * k, k + 1, st[k], np.eye(3) * s**2, rho)
        return e

    held = run("ukf-pr", 6.0, 20)                     # 5 s: held all along
    assert held.tracker is None and held.status == rx.WAITING and held.stats["start_wait_survey"] >= 18
    surveyed = run("ukf-pr", 2.0, 3)                  # every station within 3 m: starts at once
    assert surveyed.tracker is not None and surveyed.stats["start_wait_survey"] == 0
    subset = run("ukf-pr", 6.0, 3, n_st=6)            # five surveyed of six: starts from those five
    assert subset.tracker is not None and subset.stats["start_surveyed_subset"] == 1
    assert subset.stats["start_wait_survey"] == 0
    late = run("ekf-pr", 6.0, int(cfg.start_wait_s / 0.25) + 3)   # never surveyed: starts after the wait
    assert late.tracker is not None and late.t_first_batch_s is not None
    assert late.tracker.t_s - late.t_first_batch_s > cfg.start_wait_s
    lsq = run("lsq-pr", 6.0, 3)
    assert lsq.fix is not None and lsq.stats["start_wait_survey"] == 0


def test_a_filter_under_the_floor_restarts():
    """Receiver rule 3's floor test: a filter whose own Gaussian has gone more than ``floor_lost_sigma``
    under the height floor (its truncated moments confident on the station plane, as a starved fleet's
    ukf-pr at a true 316 m: docs/aircraft.md "Cold start") restarts; a filter above it runs on. The
    innovation test is held off (a window it never fills) so that the floor test alone is seen."""
    st = np.array([[0.0, 0.0, 0.0], [1800.0, 0.0, 5.0], [900.0, 1500.0, 0.0], [800.0, 500.0, 60.0],
                   [300.0, 1200.0, 20.0]])
    p_ac = np.array([2260.0, 640.0, 316.0])
    rng = np.random.default_rng(9)

    def cycles(e, c0, n):
        for c in range(c0, c0 + n):
            for k in range(5):
                rho = np.linalg.norm(p_ac - st[k]) + 0.5 * rng.standard_normal()
                e.on_measurement(0.25 * c + 0.05 * k, k + 1, st[k], np.eye(3) * 0.01, rho)

    for algo in ("ukf-pr", "ekf-pr"):
        e = AircraftEstimator(algo, EstimatorConfig(fde=None, receiver=rx.ReceiverConfig(window=10**6)))
        cycles(e, 0, 8)
        assert e.tracker is not None and e.stats["under_floor"] == 0 and not e._under_floor(), algo
        trk = e.tracker
        x, P = trk.x.copy(), trk.P.copy()
        x[2] = -150.0                      # planted: 150 m under the floor at sigma 20 m
        P[2, :], P[:, 2] = 0.0, 0.0
        P[2, 2] = 400.0
        trk.x, trk.P = x, P
        assert trk.x[2] > -1.0 and e._under_floor()   # its truncated moments: on the floor
        cycles(e, 8, 1)
        assert e.stats["under_floor"] == 1 and e.n_resets == 1, (algo, dict(e.stats))
        cycles(e, 9, 12)                   # restarts from the next consistent batch
        assert e.tracker is not None and abs(e.estimate()["pos_m"][2] - p_ac[2]) < 100.0, algo


def _far_field_estimates(algo: str, seconds: float, rng, hook=None):
    """seed001 as the live core flies it (four stations on a 50 m circle, the aircraft on its turn 1-3 km
    out, one nav per 10 ms slot), the stations' broadcast positions off by a persisting survey error
    (5 cm horizontally, 0.5 m in height; broadcast sigmas 5 cm and 1 m); yields ``(event, truth,
    estimator)`` for each estimate; ``hook(t_s, estimator)`` runs before each nav."""
    from aircraft.config import from_scenario
    from net.scenario import load

    sc = load("seed001")
    ac = from_scenario(sc)
    n = len(sc.pos_m)
    err = np.column_stack([rng.normal(0.0, 0.05, (n, 2)), rng.normal(0.0, 0.5, n)])
    err[0] = 0.0  # the frame's origin
    cov = np.diag([0.05**2, 0.05**2, 1.0]).tolist()
    core = RadioAircraftCore(ac, (algo,), "ac1", rng, horizon_s=seconds + 5.0)
    est = core.estimators[algo]
    truth = None
    for k in range(int(seconds / sc.tdma.slot_s)):
        t, j = k * sc.tdma.slot_s, k % n
        if hook is not None:
            hook(t, est)
        msg = {"kind": "nav", "src": j + 1, "seq": k // n + 1, "stamp_s": t, "cycle": k // n + 1, "slot": j,
               "t_tx_s": t, "pos_m": (sc.pos_m[j] + err[j]).tolist(), "cov_m2": cov, "n_updates": k // n + 1,
               "state": "surveying", "ranges": [], "members": [], "clock": [t, 0.0, 0.0, 0.7e-9**2, 0.0, 1e-24]}
        for ev in core.on_nav(msg, {"pos_m": sc.pos_m[j].tolist(), "t_true_s": t}):
            if ev.kind == "ac_truth":
                truth = np.asarray(ev.pos_m)
            elif ev.kind == "ac_estimate":
                yield ev, truth, est


def _lsq_far_field(algo: str, seconds: float, rng):
    """:func:`_far_field_estimates` from 30 s on: each LSQ estimate's error, its published covariance
    and the batch's own ``(H^T W H)^-1`` at the fix."""
    from aircraft.navigator.radio.lsq import lsq_cov

    for ev, truth, est in _far_field_estimates(algo, seconds, rng):
        if ev.t_s >= 30.0:
            pos_b, cov_b = est._last_geom[:2]
            own = lsq_cov(est.fix[None], pos_b, est.cfg.tuning.sigma_m**2, est.model, cov_b)[0, :3, :3]
            yield np.subtract(ev.pos_m, truth), np.asarray(ev.cov_m2), own


@pytest.mark.parametrize("algo", ["lsq-pr", "lsq-tdoa"])
def test_a_runaway_lsq_fix_restarts_from_the_broadcasts(algo):
    """Receiver rule 4 for the snapshot LSQ's warm start: a fix that has walked off along the range
    (planted here 300 km out at 5 s, where seed001's far-field chain went in a CI fleet) is not
    publishable; it is dropped and the next batch starts from the broadcasts again, so estimates
    resume within a second. Without the rule the warm start (10 steps of 200 m) never comes back and
    nothing is published for the rest of the run."""
    def plant(t_s, est):
        if abs(t_s - 5.0) < 1e-9:
            est.fix = np.r_[0.0, -300e3, 40e3, 0.0][: est.fix.size]

    rows = [(ev.t_s, np.subtract(ev.pos_m, truth)) for ev, truth, _ in
            _far_field_estimates(algo, 12.0, np.random.default_rng(2), plant)]
    after = [(t, e) for t, e in rows if t > 5.0]
    assert after and after[0][0] < 6.0, [t for t, _ in rows][-5:]
    assert max(np.hypot(e[0], e[1]) for _, e in after) < 10e3
    assert sum(t > 10.0 for t, _ in after) >= 20


@pytest.mark.parametrize("algo", ["lsq-pr", "lsq-tdoa"])
def test_a_far_field_lsq_without_redundancy_reports_what_it_can_defend(algo):
    """Receiver rule 4 for the snapshot LSQ: four stations give no redundancy, so a far-field fix fits its
    ranges whatever its error (here about 1.4 km off, pulled towards the array), and its linearized
    covariance, taken where the error put the fix, is far too small; the LSQ publishes the fix with the
    wide prior's covariance instead: mean NEES of its estimates at most the 3-dof chi-square's 99.9 %
    point of one value (16.3), where the batches' own covariances give a median NEES in the hundreds
    on the same estimates (mean 1e5: docs/aircraft.md, "seed001's far field")."""
    # 30-45 s of the turn: 203 / 102 estimates (lsq-pr / lsq-tdoa), mean NEES 0.44 / 0.43, median NEES of
    # the batches' own covariances 429 / 564; ~3-4 s of CPU for the 45 s flown (the LSQ's restarts from
    # the broadcasts rationed, ReceiverConfig.lsq_restart_s; before, 104-108 estimates and ~1 s of CPU
    # per second flown: docs/aircraft.md, "A runaway warm start is dropped")
    rows = list(_lsq_far_field(algo, 45.0, np.random.default_rng(1)))
    assert len(rows) >= 100, len(rows)
    nees = np.array([e @ np.linalg.solve(P, e) for e, P, _ in rows])
    own = np.array([e @ np.linalg.solve(C, e) for e, _, C in rows])
    assert nees.mean() <= 16.3, (nees.mean(), np.median(nees))
    assert np.median(own) > 100.0, np.median(own)

@pytest.mark.parametrize("algo", ["lsq-pr", "lsq-tdoa"])
def test_a_far_field_lsq_rations_its_restarts_from_the_broadcasts(algo, monkeypatch):
    """Receiver rule 4's restarts (ReceiverConfig.lsq_restart_s): in seed001's far field the warm chain
    is dropped again and again; it starts from the broadcasts (a multi-start) at most once per
    1.5 s and otherwise warm from that multi-start's fix (once per 0.5 s where that fix was not
    publishable: no anchor), so its multi-starts stay within the first
    start's (up to 5 batches, two each) plus one per 0.5 s, while estimates keep coming (the old code:
    ~22 multi-starts a second, docs/aircraft.md "Its restarts are rationed")."""
    from aircraft.navigator.radio import estimator as E

    calls = []
    real = E.initial_state
    monkeypatch.setattr(E, "initial_state", lambda *a, **k: calls.append(1) or real(*a, **k))
    seconds = 12.0
    rows = list(_far_field_estimates(algo, seconds, np.random.default_rng(3)))
    est = rows[-1][2]
    assert est.stats["lsq_runaway"] >= 5, dict(est.stats)  # the warm chain was dropped again and again
    assert len(calls) <= 10 + int(seconds / 0.5) + 1, (len(calls), dict(est.stats))
    assert len(rows) >= 10 * seconds, len(rows)


def test_an_lsq_with_redundancy_keeps_its_own_covariance():
    """The eight stations of this module's field 1.5 km out: every batch defends its fix, and the
    published covariance is the batch's own ``(H^T W H)^-1`` to the bit."""
    from aircraft.navigator.radio.lsq import lsq_cov

    est = AircraftEstimator("lsq-pr", EstimatorConfig())
    rng = np.random.default_rng(3)
    n = 0
    for t, sid, pos, cov, rho, cvar in _slots(30, lambda c, j: 0.3, rng):
        est.on_measurement(t, sid, pos, cov, rho, clock_var_m2=cvar)
        e = est.estimate()
        if e is None or e["cov_m2"] is None:
            continue
        pos_b, cov_b = est._last_geom[:2]
        own = lsq_cov(est.fix[None], pos_b, est.cfg.tuning.sigma_m**2, "pr", cov_b)[0, :3, :3]
        assert np.array_equal(np.asarray(e["cov_m2"]), own)
        n += 1
    assert n >= 20, n

