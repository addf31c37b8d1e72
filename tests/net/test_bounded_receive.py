"""Issue 32, the network half: the bounded drop-oldest receive queue, the rate limiter across a
wall-clock step, and the channel's physics from the named sender's truth."""

from __future__ import annotations

import queue
import threading
import time

import numpy as np
import pytest

from net.channel import Clock, SenderTruth
from net.queues import DropOldestQueue
from net.security import RateLimiter, monotonic_fleet_clock


def test_drop_oldest_queue_keeps_the_newest_and_counts():
    q = DropOldestQueue(3)
    assert all(q.put(i) for i in range(3))
    assert q.put(3) is False and q.put(4) is False
    assert q.dropped == 2 and q.qsize() == 3
    assert [q.get_nowait() for _ in range(3)] == [2, 3, 4]
    with pytest.raises(queue.Empty):
        q.get_nowait()
    t0 = time.monotonic()
    with pytest.raises(queue.Empty):
        q.get(timeout=0.05)
    assert time.monotonic() - t0 >= 0.04


def test_drop_oldest_queue_under_a_flood_from_threads_stays_bounded():
    q = DropOldestQueue(100)
    got = []

    def flood(base):
        for i in range(20_000):
            q.put((base, i))

    ths = [threading.Thread(target=flood, args=(b,)) for b in range(4)]
    for t in ths:
        t.start()
    while any(t.is_alive() for t in ths) or not q.empty():
        try:
            got.append(q.get(timeout=0.01))
        except queue.Empty:
            pass
        assert q.qsize() <= 100
    for t in ths:
        t.join()
    assert len(got) + q.dropped == 80_000
    for b in range(4):  # each producer's items stay in order
        seq = [i for bb, i in got if bb == b]
        assert seq == sorted(seq)


def test_a_blocked_reader_wakes_on_put():
    q = DropOldestQueue(4)
    threading.Timer(0.05, q.put, args=("x",)).start()
    assert q.get(timeout=2.0) == "x"


def test_rate_limiter_survives_a_backward_step_of_the_fleet_clock():
    """The issue: a 30 s backward wall-clock step blocked all receiving for 28 s (negative refill)."""
    rl = RateLimiter(4.0, 8.0)
    assert all(rl.allow("k", 100.0 + 0.25 * i) for i in range(40))  # 4 per s: always within budget
    t = 100.0 + 0.25 * 40 - 30.0  # the wall clock is set back 30 s
    assert rl.allow("k", t)
    assert all(rl.allow("k", t + 0.25 * (i + 1)) for i in range(40))  # and keeps receiving at once


def test_rate_limiter_on_the_monotonic_clock_ignores_the_given_time():
    now = [50.0]
    rl = RateLimiter(2.0, 2.0, clock=lambda: now[0])
    assert rl.allow("k", -1e9) and rl.allow("k", 1e9)
    assert not rl.allow("k", 1e12)  # the burst is spent whatever time the caller claims
    now[0] += 0.5
    assert rl.allow("k", 0.0) and not rl.allow("k", 0.0)
    assert rl.throttled["k"] == 2


def test_monotonic_fleet_clock_runs_at_fleet_rate():
    c = monotonic_fleet_clock(5.0)
    a = c()
    time.sleep(0.05)
    assert 0.2 <= c() - a <= 1.0


def test_the_channel_takes_the_named_senders_truth_not_its_phy():
    pos = {2: np.array([100.0, 0.0, 0.0]), 3: np.array([0.0, 200.0, 0.0])}
    clocks = {2: Clock(offset_s=1e-3, drift=2e-6), 3: Clock()}
    st = SenderTruth(pos, clocks.__getitem__)
    t_local = 10.0
    t_true = clocks[2].to_true(t_local)
    p, t = st.transmission(2, t_true, t_local)  # honest: exactly what it claims
    assert t == t_true and np.array_equal(p, pos[2])
    p, t = st.transmission(2, t_true - 1e-6, t_local)  # claims to have sent 1 us earlier: not believed
    assert t == t_true
    p, t = st.transmission(2, t_true + 1e-6, t_local)  # a later signal (a delay) is its own business
    assert t == t_true + 1e-6
    assert st.transmission(99, t_true, t_local) is None  # not in the world
    msg = {"src": 2, "t_tx_s": t_local}
    assert st.receive(msg, {"t_true_s": t_true - 1e-6}, now_s=t_true)[1] == t_true
    assert st.receive(msg, {"t_true_s": t_true}, now_s=t_true + 61.0) == "time"  # far from the receiver's now
    assert st.receive({"src": 99, "t_tx_s": t_local}, {"t_true_s": t_true}, now_s=t_true) == "sender_unknown"


def test_the_channels_truth_of_a_scenario_has_its_clock_faults():
    """``scenario_senders``: each station's clock drawn from its own stream, as its process draws it,
    with the scenario's clock jumps (a station's stamps after its jump map back to true time)."""
    from net.channel import JumpClock, draw_clock, scenario_senders, station_rng
    from net.scenario import load

    scn = load("seed000", faults=[{"kind": "clock_jump", "station": 3, "at_s": 5.0, "jump_s": 1e-3}])
    st = scenario_senders(scn, 7)
    own = draw_clock(scn.clock, station_rng(7, 3, 0))
    jumped = JumpClock(own, 1e-3, 5.0)
    for t_true in (4.0, 6.0):
        p, t = st.transmission(3, 0.0, jumped.to_local(t_true))
        assert abs(t - t_true) < 1e-12 and np.array_equal(p, scn.true_pos(3))
    p, t = st.transmission(2, 0.0, draw_clock(scn.clock, station_rng(7, 2, 0)).to_local(6.0))
    assert abs(t - 6.0) < 1e-12
