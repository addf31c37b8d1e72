"""Network time (issue 10): oscillator model, two-way time transfer, the network clock filter, slots
on network time and clock-honest aircraft pseudoranges."""

from __future__ import annotations

import numpy as np
import pytest

from nav.geometry import SPEED_OF_LIGHT_M_S as C
from net.channel import AirChannel, Clock
from net.clock import PRESETS, ClockParams, OscillatorClock, allan_deviation, clock_params
from net.scenario import ChannelParams, load
from stations.clocksync import ClockEstimator, ClockModel, transition
from stations.core import StationConfig, StationCore
from stations.sim import Simulator


@pytest.mark.parametrize("preset", ["tcxo", "ocxo"])
def test_oscillator_allan_deviation_matches_the_preset(preset):
    p = clock_params({"model": preset})
    assert p == ClockParams(preset, **PRESETS[preset])
    adev2 = {1: [], 10: [], 100: []}
    for s in range(12):
        c = OscillatorClock(p, np.random.default_rng([s, 1, 0]), step_s=1.0)
        x = c.phase_grid(20000)
        for m in adev2:
            adev2[m].append(allan_deviation(x, 1.0, m) ** 2)
    for m, v in adev2.items():
        # 12 x 20000 s: the Allan variance estimate at 100 s is good to a few percent
        assert np.sqrt(np.mean(v)) == pytest.approx(float(p.adev(m)), rel=0.06), m


def test_oscillator_is_one_function_of_time_whatever_the_query_order():
    p = clock_params({"model": "tcxo"})
    a, b = (OscillatorClock(p, np.random.default_rng([3, 2, 0])) for _ in range(2))
    ts = np.random.default_rng(0).uniform(0, 300, 200)
    la = [a.to_local(t) for t in ts]
    lb = [b.to_local(t) for t in ts[::-1]][::-1]
    assert la == lb
    back = np.array([a.to_true(t) for t in la])
    assert np.max(np.abs(back - ts)) < 1e-12
    assert abs(a.error_s(0.0)) < 5e-3 and a.error_s(100.0) != a.error_s(0.0)


def test_clock_section_errors_name_the_key():
    with pytest.raises(ValueError, match=r"\[clock\] offset_sx"):
        clock_params({"model": "tcxo", "offset_sx": 1.0})
    with pytest.raises(ValueError, match=r"\[clock\] model"):
        clock_params({"model": "rubidium"})
    assert load("seed000").clock.model == "tcxo"


def _cfg(i, **kw):
    return StationConfig(id=i, sigma_d_m=0.5, known_ids=(1, 2), clock_offset_sigma_s=1e-3, clock_freq_sigma=2e-6,
                         **kw)


@pytest.mark.parametrize("seed", range(5))
def test_two_way_time_transfer_is_exact_on_a_noiseless_exchange(seed):
    """Whatever the offsets and frequencies, the exchange's dtheta is the true offset difference at the
    exchange midpoint and the range (durations scaled by the estimated frequencies) the distance."""
    rng = np.random.default_rng(seed)
    ci = Clock(offset_s=rng.uniform(-1e-3, 1e-3), drift=rng.uniform(-20e-6, 20e-6))
    cj = Clock(offset_s=rng.uniform(-1e-3, 1e-3), drift=rng.uniform(-20e-6, 20e-6))
    air = AirChannel(ChannelParams(sigma_d_m=0.0), rng)
    pi, pj = np.zeros(3), np.array([1500.0, 300.0, 20.0]) * rng.uniform(0.5, 2)
    a, b = StationCore(_cfg(2), pi, np.eye(3)), StationCore(_cfg(3), pj, np.eye(3))
    # the responder's broadcast frequency: give it the true one (as a synchronized station would)
    b.clk.x[1] = cj.drift - 0.0
    a.clk.x[1] = ci.drift
    t1 = 10.01  # slot 1 of cycle 10 on a's clock
    req = {"kind": "range_req", "src": 2, "seq": 1, "stamp_s": t1, "dst": 3, "cycle": 10, "slot": 1, "t_tx_s": t1}
    a.pending[1] = (3, t1, t1 + 1.0)
    t2 = air.arrival_local_s(pi, ci.to_true(t1), pj, cj)
    (rsp,) = b.on_message(req, t2)
    t4 = air.arrival_local_s(pj, cj.to_true(rsp["t_tx_s"]), pi, ci)
    a.on_message(rsp, t4)
    peer, range_m, t_mid, dtheta = a.ranges_out[-1]
    tau_mid = ci.to_true(t_mid)
    assert tau_mid == pytest.approx(cj.to_true(0.5 * (t2 + rsp["t_tx_s"])), abs=1e-12)
    assert dtheta == pytest.approx(ci.error_s(tau_mid) - cj.error_s(tau_mid), abs=1e-12)
    # frequency scaling of the two durations: exact up to the drift-squared terms (~1e-9 m)
    assert range_m == pytest.approx(np.linalg.norm(pj - pi) * (1 + 0.0), abs=1e-6)


def _explicit_kf(n, prior, q, events, var_z, t_end):
    """Centralized linear KF of n clocks [theta_k, f_k] (reference excluded), textbook matrices."""
    x = np.zeros(2 * n)
    P = np.kron(np.eye(n), np.diag(prior))
    t = 0.0
    for te, a, b, z in events:
        F1, Q1 = transition(te - t, *q)
        F, Q = np.kron(np.eye(n), F1), np.kron(np.eye(n) + np.ones((n, n)), Q1)  # + station 1's wander
        x, P = F @ x, F @ P @ F.T + Q
        t = te
        H = np.zeros(2 * n)
        if a > 1:
            H[2 * (a - 2)] += 1
        if b > 1:
            H[2 * (b - 2)] -= 1
        S = H @ P @ H + var_z
        K = P @ H / S
        x = x + K * (z - H @ x)
        P = (np.eye(2 * n) - np.outer(K, H)) @ P @ (np.eye(2 * n) - np.outer(K, H)).T + var_z * np.outer(K, K)
    F1, Q1 = transition(t_end - t, *q)
    F, Q = np.kron(np.eye(n), F1), np.kron(np.eye(n) + np.ones((n, n)), Q1)
    return F @ x, F @ P @ F.T + Q


def test_network_clock_filter_equals_a_linear_kf_on_a_linear_problem():
    rng = np.random.default_rng(7)
    q = (1e-20, 3e-22)
    model = ClockModel(q[0], q[1], 1e-6, 2e-8)  # after coarse sync (a 1 ms prior costs float precision)
    # an algebra test: its transfers (100 ns) are far outside the model's noise (1.7 ns), which the
    # clock-step gate would refuse as steps
    est = ClockEstimator(2, model, 0.0, 0.5, step_nis=np.inf)
    for sid in (3, 4, 5):  # the same state order as the explicit filter
        est._add(sid)
    events = []
    t = 0.0
    for _ in range(80):
        t += rng.uniform(0.01, 0.7)
        a, b = rng.choice([1, 2, 3, 4, 5], 2, replace=False)
        events.append((t, int(a), int(b), float(rng.normal(0, 1e-7))))
    for te, a, b, z in events:
        est.on_exchange(a, b, te, z)
    est.predict(t + 1.0)
    x, P = _explicit_kf(4, (1e-12, 4e-16), q, events, (0.5 / C) ** 2, t + 1.0)
    assert np.allclose(est.x, x, rtol=1e-6, atol=1e-15)
    assert np.allclose(est.P, P, rtol=1e-6, atol=1e-26)


class _DenseClockFilter:
    """The network clock filter written densely (the implementation before the O(n) update): every
    input predicts the whole covariance, the update is the expanded Joseph form. ``dtype``:
    ``np.longdouble`` gives a reference with 3 more digits."""

    def __init__(self, est: ClockEstimator, dtype=float):
        self.id, self.m, self.T = est.id, est.model, est.T_s
        self.var_z, self.coarse_var, self.gate = est.var_z, est.coarse_var, est.coarse_gate_s
        self.index = dict(est.index)
        self.x = np.array(est.x, dtype)
        self.P = np.array(est.P, dtype)

    def predict(self, T):
        dt = T - self.T
        if dt <= 0:
            return
        n = len(self.x) // 2
        F1, Q1 = transition(dt, self.m.q_wf_s, self.m.q_rw_per_s)
        F = np.kron(np.eye(n), F1).astype(self.P.dtype)
        self.x = F @ self.x
        self.P = F @ self.P @ F.T + np.kron(np.eye(n) + np.ones((n, n)), Q1)
        self.T = T

    def add(self, sid):
        if sid not in self.index:
            self.index[sid] = len(self.index)
            n = len(self.x)
            P = np.zeros((n + 2, n + 2), self.P.dtype)
            P[:n, :n] = self.P
            P[n, n], P[n + 1, n + 1] = self.m.offset_sigma_s**2, self.m.freq_sigma**2
            self.P, self.x = P, np.concatenate([self.x, np.zeros(2, self.P.dtype)])
        return self.index[sid]

    def row(self, T, terms):
        ks = [(2 * self.add(sid), sign) for sid, sign in terms if sid != 1]
        h = np.zeros(len(self.x), self.P.dtype)
        for k, sign in ks:
            h[k], h[k + 1] = h[k] + sign, h[k + 1] + sign * (T - self.T)
        return h

    def update(self, h, z, r):
        PH = self.P @ h
        S = h @ PH + r
        K = PH / S
        self.x = self.x + K * (z - h @ self.x)
        P = self.P - np.outer(K, PH) - np.outer(PH, K) + S * np.outer(K, K)
        self.P = 0.5 * (P + P.T)

    def on_exchange(self, a, b, T, z, t_var=0.0):
        self.predict(T)
        h = self.row(T, [(a, 1.0), (b, -1.0)])
        r = self.var_z
        if t_var > 0:
            hf = np.zeros_like(h)
            hf[1::2] = h[0::2]
            r += ((hf @ self.x) ** 2 + hf @ self.P @ hf) * t_var
        self.update(h, z, r)

    def on_coarse(self, src, T, z):
        self.predict(T)
        self.update(self.row(T, [(self.id, 1.0), (src, -1.0)]), z, self.coarse_var)


def _replay(est, events):
    """Feed recorded clock-filter inputs to the fast filter and to dense float64 / long-double copies;
    the largest state and covariance differences to the long-double reference in units of its sigma."""
    dense, ref = _DenseClockFilter(est), _DenseClockFilter(est, np.longdouble)
    worst = np.zeros((2, 2))
    for i, ev in enumerate(events):
        if ev[0] == "x":
            assert est._exchange(*ev[1:]) is not None
            dense.on_exchange(*ev[1:])
            ref.on_exchange(*ev[1:])
        else:  # a coarse update: the inputs as the filter used them
            src, T, z = ev[1:]
            est.predict(T)
            est._update(*est._terms(T, [(est.id, 1.0), (src, -1.0)]), z, est.coarse_var)
            dense.on_coarse(src, T, z)
            ref.on_coarse(src, T, z)
        if i % 10 == 9 or i == len(events) - 1:
            dense.predict(est.T_s)
            ref.predict(est.T_s)
            sd = np.sqrt(np.diag(ref.P)).astype(float)
            for j, (x, P) in enumerate(((est.x, est.P), (dense.x, dense.P))):
                worst[j] = np.maximum(worst[j], [np.max(np.abs((x - ref.x).astype(float)) / sd),
                                                 np.max(np.abs((P - ref.P).astype(float)) / np.outer(sd, sd))])
    return worst  # rows: fast, dense float64; columns: x, P


def _random_events(n_st, seed, cycles=12):
    """One exchange per slot of a 1 s cycle of n_st 20 ms slots, random pairs; some inputs late (their
    network time before the previous input's) and some with an uncertain time (nav-heard exchanges)."""
    rng = np.random.default_rng(seed)
    ev = []
    for c in range(cycles):
        for k in range(n_st):
            a, b = rng.choice(np.arange(1, n_st + 1), 2, replace=False)
            T = c + 0.02 * k + 0.005 - (0.03 if k % 7 == 3 else 0.0)
            ev.append(("x", int(a), int(b), T, float(rng.normal(0, 1e-9)), 1e-18 if k % 3 == 0 else 0.0))
    return ev


@pytest.mark.parametrize("n_st", [5, 30])
def test_fast_clock_update_equals_the_dense_filter(n_st):
    """The O(n) update (covariance at a reference time, P h from the two clocks' columns, rank-1
    Joseph) equals the dense filter (whole covariance predicted at every input, expanded Joseph): on a
    well-conditioned problem both agree with a long-double reference to ~1e-14 of the posterior sigma."""
    model = ClockModel(1e-20, 3e-22, 2e-9, 1e-10)
    est = ClockEstimator(2, model, 0.0, 0.5, rebase_s=0.5)
    for sid in range(3, n_st + 1):
        est._add(sid)
    worst = _replay(est, _random_events(n_st, n_st))
    assert np.all(worst[0] < 1e-12), worst
    assert np.all(worst[1] < 1e-12), worst
    assert est.n_updates == 12 * n_st


def test_fast_clock_update_equals_the_dense_filter_on_a_recorded_station(monkeypatch):
    """The inputs one station's filter really got in the simulator (seed 000, TCXO: 1 ms prior, coarse
    sync, nav-heard exchanges with uncertain times, late inputs) replayed into a fresh fast filter and
    the dense one. The 1 ms prior collapsing to 1 ns costs float64 ~12 digits of the variance, so both
    float64 filters are judged against a long-double reference: the fast one as close as the dense."""
    cls = ClockEstimator
    events, seen = [], {}
    orig_x, orig_u = cls._exchange, cls._update

    def rec_x(self, a, b, T, z, t_var, z_var=None):
        n = self.n_updates
        out = orig_x(self, a, b, T, z, t_var, z_var)
        if self.id == 4 and self.n_updates > n:  # used (not deferred)
            events.append(("x", a, b, T, z, t_var))
        return out

    def rec_u(self, ks, signs, dt_h, z, r, gate=np.inf):
        if self.id == 4:
            seen.setdefault("est", self)
            if r == self.coarse_var:
                src = [sid for sid, k in self.index.items() if k == ks[-1]][0] if len(ks) == 2 else 1
                events.append(("c", src, self.T_s + dt_h, z))
        return orig_u(self, ks, signs, dt_h, z, r, gate)

    monkeypatch.setattr(cls, "_exchange", rec_x)
    monkeypatch.setattr(cls, "_update", rec_u)
    scn = load("seed000", seed=3)
    sim = Simulator(scn)
    sim.run(8.0, [8.0])
    est = seen["est"]
    assert est.n_coarse >= 1 and len(events) > 50
    monkeypatch.undo()
    fresh = ClockEstimator(4, est.model, 0.0, 0.5)
    fresh.T_s = fresh._T0 = sim.cores[scn.ids.index(4)].init_record["start_s"]
    worst = _replay(fresh, events)
    fresh.predict(est.T_s)  # the same filter, replayed (to rounding: the live one was also moved by reads)
    assert np.max(np.abs(fresh.x - est.x) / np.sqrt(np.diag(est.P))) < 1e-3
    assert worst[0, 0] < 1e-3 and worst[0, 1] < 1e-3, worst
    assert np.all(worst[0] < 10 * worst[1] + 1e-9), worst


def test_exchange_placed_by_an_unknown_clock_waits_until_the_clock_is_known():
    """An exchange timed by a clock unknown to 1 ms (x ppm frequency differences: an error as large as
    the measurement, shared by every exchange so placed) is not charged as white noise: it waits on
    that clock's local time and is used, at its corrected network time, once the clock is known."""
    model = ClockModel(1e-20, 3e-22, 1e-3, 2e-6)
    est = ClockEstimator(2, model, 0.0, 0.5)
    est._add(3)
    t_loc = 0.5  # the exchange's midpoint on clock 3, whose offset is still unknown to 1 ms
    T, var = est.peer_time(3, t_loc)
    assert var == pytest.approx(1e-6, rel=1e-5)
    assert est.on_exchange(3, 2, T, 2e-4, var) is None and est.n_deferred == 1 and est.n_updates == 0
    # clock 3 gets known (an exchange with station 1 at a well-known time), then the next input
    # places the waiting one with the improved estimate of clock 3
    assert est.on_exchange(3, 1, 0.6, 4e-4, 0.0) is not None
    assert est.n_updates == 2 and not est._pending and est.n_untimed == 0
    # never known within defer_s: dropped and counted
    est2 = ClockEstimator(2, model, 0.0, 0.5, defer_s=1.0)
    est2._add(3)
    T, var = est2.peer_time(3, 0.5)
    est2.on_exchange(3, 2, T, 2e-4, var)
    est2.on_exchange(2, 1, 2.0, 1e-4, 0.0)
    assert est2.n_untimed == 1 and not est2._pending


@pytest.mark.parametrize("seed", [11, 12, 13, 14, 15, 16])
def test_clock_filter_nees_early_seeded(seed):
    """Consistency in the first seconds (coarse-to-fine, 1 ms initial offsets), where an exchange timed
    by an unknown clock used to make the filter overconfident. Per trial the 9 stations share network
    time's common mode, so one trial's mean NEES at 4-8 s is loosely bounded; the mean over the
    six seeds is checked in the last one."""
    scn = load("seed000", seed=seed)
    r = Simulator(scn).run(8.0, [4.0, 5.0, 6.0, 7.0, 8.0])
    nees = float(np.mean(r.clock_err_s[:, 1:] ** 2 / r.clock_var_s2[:, 1:]))
    _NEES.append(nees)
    assert nees < 4.0
    if len(_NEES) == 6:
        assert np.mean(_NEES) < 1.6, _NEES


_NEES: list[float] = []


def test_clock_filter_is_consistent_in_the_simulator_and_syncs_below_2ns():
    scn = load("seed000", seed=5)
    # (at 20 s, not 10 s: the ensemble forms at ~13-15 s since entry asks the frequency as well,
    # ENTER_FREQ_SD; before, station 1's clock alone is network time and its own error is 0)
    r = Simulator(scn).run(30.0, [20.0, 30.0])
    e, v = r.clock_err_s, r.clock_var_s2
    assert np.all(np.abs(e[-1]) < 3e-9)
    assert np.mean(e**2 / v) < 3.0  # one trial, 10 stations: loose, honest band
    # network time is the ensemble of all ten clocks (issue 30): station 1 has an error like the others
    assert np.all(r.clock_err_s[:, 0] != 0) and all(len(log[-1].weights) == 10 for log in r.time_scales.values())


@pytest.mark.parametrize("offset_s, drift", [(1e-3, 20e-6), (-1e-3, -20e-6), (1e-3, -20e-6), (-1e-3, 20e-6)])
def test_station_with_clock_ahead_or_behind_completes_all_its_exchanges(offset_s, drift):
    from stations.sim import make_core

    scn = load("seed000", seed=2)

    def make(scn_, sid, **kw):
        return make_core(scn_, sid, clock=Clock(offset_s, drift) if sid == 5 else None, **kw)

    sim = Simulator(scn, core_factory=make)
    r = sim.run(40.0, [40.0])
    c5 = r.counters[5]
    assert c5["requests"] >= 39 and c5["responses"] == c5["requests"] and c5["late"] == 0
    assert all(c["lost"] == 0 and c["late"] == 0 and c["ignored"] == 0 for c in r.counters.values())
    # its requests go out at its slot start on network time (to well under the slot guard)
    core = sim.cores[scn.ids.index(5)]
    t_req = sim.clocks[scn.ids.index(5)].to_true(core.next_request_s())
    T_req = t_req + sim.ref_clock.error_s(t_req)
    assert abs(T_req - round(T_req / scn.tdma.slot_s) * scn.tdma.slot_s) < 1e-6
    assert abs(r.clock_err_s[-1, scn.ids.index(5)]) < 3e-9


def test_aircraft_pseudorange_error_equals_the_station_sync_error_times_c():
    from aircraft.config import from_scenario
    from aircraft.radio_core import RadioAircraftCore
    from net.channel import draw_clock, station_rng

    scn = load("seed003", aircraft={"sigma_m": 0.0})
    ac = from_scenario(scn)
    net_clock = draw_clock(scn.clock, station_rng(scn.seed, 1, 0))
    st_clock = draw_clock(scn.clock, station_rng(scn.seed, 5, 0))
    from net.nettime import network_time

    # the receiver's network time as the field realizes it; no station nav observed: the founder's clock
    core = RadioAircraftCore(ac, ("ekf-pr",), "ac1", np.random.default_rng(0), net_clock=network_time(scn, scn.seed))
    rng = np.random.default_rng(1)
    for tau_tx in (3.0, 40.0, 400.0):
        t_tx = st_clock.to_local(tau_tx)
        true_theta = st_clock.error_s(tau_tx) - net_clock.error_s(tau_tx)
        sync_err = rng.normal(0, 2e-9)
        f_hat = st_clock.freq_at(tau_tx) - net_clock.freq_at(tau_tx)
        # the station's broadcast correction, referenced 0.3 s before the transmission
        corr = [t_tx - 0.3, true_theta + sync_err - 0.3 * f_hat, f_hat, 4e-18, 1e-19, 1e-20]
        msg = {"t_tx_s": t_tx, "clock": corr}
        phy = {"pos_m": scn.true_pos(5).tolist(), "t_true_s": tau_tx}
        t_rx, rho, p, _ = core.measure(phy, msg)
        r = np.linalg.norm(p - scn.true_pos(5))
        err = rho - r - ac.world.clock.bias_m(t_rx)
        # c x the residual sync error; network time runs at station 1's rate (r x its ppm-level drift)
        assert err == pytest.approx(C * sync_err, abs=r * 1e-5 + 1e-6)
        assert core.clock_var_m2(msg) == pytest.approx(C**2 * (4e-18 + 2 * 0.3 * 1e-19 + 0.09 * 1e-20))


def test_a_station_powering_on_after_station_1_left_gets_network_time_from_the_others():
    """Station 1 (the filter's coordinate clock) silent from 20 s; station 10 powers on at 30 s: it
    anchors on the peers' broadcast corrections, redefines its time scale over the clocks it hears,
    adopts the field's, and ranges in its slot (issue 30)."""
    scn = load("seed000", seed=2)
    sim = Simulator(scn, stop_s={1: 20.0}, start_s={10: 30.0})
    r = sim.run(50.0, [40.0, 45.0, 50.0])
    core = sim.cores[-1]
    assert core.clk.n_anchor >= 1 and 1 not in core.clk.scale.w
    assert np.all(np.abs(r.clock_err_s[:, -1]) < 2e-9), r.clock_err_s[:, -1]
    assert np.all(np.abs(r.clock_err_s[:, 1:-1]) < 2e-9)  # the survivors too
    assert core.counters["responses"] >= 15 and core.counters["lost"] <= 1


@pytest.mark.parametrize("seed", [1, 3])
def test_a_founder_powering_on_late_and_the_field_agree_on_one_time(seed):
    """Station 1 powers on 5 s after the others, which have defined network time without it by then.
    Since the multi-hop rules (docs/sync.md "Multi-hop network time") their definitions, formed over
    each other's clocks without a founder, do not descend from the founders' (they broadcast 1 ms more)
    and take station 1's in full, phase and rate, however far it lies (the clocks' offsets over the
    members: hundreds of microseconds); until then the founder took theirs. Before either rule a
    disagreement beyond 10 us was no steering input and station 1 kept a definition 0.7 ms from the
    field's for good (seed 1), and in the real fleet a founder a few seconds late rang 60 ns off the
    field for 30 s (issue 30)."""
    scn = load("seed000", seed=seed)
    sim = Simulator(scn, start_s={1: 5.0})
    times = np.arange(1.0, 40.0 + 1e-9, 1.0)
    r = sim.run(40.0, times)
    spread = sim.definition_spread_s(r, times)
    # within 2 ns from 35 s, 30 s after the founder (the bench's late_founder bar; from 30 s until the
    # frequency entry gate, ENTER_FREQ_SD, which delays the definitions' formation: seed 1 2.75 ns at 30 s,
    # 1.92 at 31 s, 0.38 at 35 s)
    assert np.all(spread[times >= 35.0] < 2e-9), spread * 1e9
    assert np.all(np.abs(r.clock_err_s[-1]) < 2e-9), r.clock_err_s[-1]  # every station at 40 s


@pytest.mark.parametrize("gate", [True, False])
def test_a_clock_that_steps_leaves_the_time_scale_and_comes_back(gate, monkeypatch):
    """Station 6's clock jumps 1 ms at 20 s (``larns bench integrity`` case clock_jump, world seed 1).
    Every filter refuses its time transfers with the step gate, re-initializes its clock after
    ``STEP_N`` refusals and drops it from the time scale where it was last good: the others' clocks stay
    within 2 ns of network time from 22 s, nobody's survey moves (no range bias, no false exclusion),
    and 6 is back in every station's scale by 60 s. Without the gate (the case that must fail) the
    1 ms innovation went into every filter: ranges 0.4-1 m short and honest stations excluded."""
    import math

    from stations.clocksync import ClockEstimator

    if not gate:
        init = ClockEstimator.__init__

        def no_gate(self, *a, **k):
            init(self, *a, **k)
            self.step_nis = math.inf
        monkeypatch.setattr(ClockEstimator, "__init__", no_gate)
    scn = load("seed000", seed=1, faults=[{"kind": "clock_jump", "station": 6, "jump_s": 1e-3, "at_s": 20.0}])
    sim = Simulator(scn)
    t = np.array([22.0, 25.0, 40.0, 60.0])
    r = sim.run(60.0, t)
    honest = np.array([i != 6 for i in scn.ids])
    sync_ns = np.abs(np.asarray(r.clock_err_s)[:, honest]) * 1e9
    err = (r.pos_m - r.truth_m)[-1, honest]
    false_exc = sum(e[2] == "exclude" and e[1] != 6 for c in sim.cores if c.id != 6 for e in c.integrity.events)
    if gate:
        assert sync_ns.max() < 2.0, sync_ns.max()
        assert np.hypot(err[:, 0], err[:, 1]).max() < 0.3 and false_exc == 0
        assert all(c.clk.n_reinit >= 1 and 6 in c.clk.scale.w for c in sim.cores)
    else:
        assert false_exc > 0 or np.hypot(err[:, 0], err[:, 1]).max() > 0.4


def test_one_jump_needs_agreeing_innovations_from_three_partners():
    """A step shows one jump to every partner; NLOS excesses scatter in sign and size, and one NLOS link
    repeats its own excess."""
    from stations.clocksync import _one_jump

    assert _one_jump([(1.0e-3, 2), (1.0001e-3, 10), (0.9999e-3, 1), (1.0e-3, 1)])
    assert not _one_jump([(1.0e-3, 2), (1.0e-3, 2), (1.0e-3, 2), (1.0e-3, 3)])  # two partners
    assert not _one_jump([(6.0e-8, 2), (-5.0e-8, 3), (7.0e-8, 4), (6.5e-8, 5)])  # signs differ
    assert not _one_jump([(2.0e-8, 2), (9.0e-8, 3), (5.0e-8, 4), (3.0e-8, 5)])  # sizes scatter
