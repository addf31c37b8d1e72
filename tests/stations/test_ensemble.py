"""Ensemble network time (issue 30): the time scale's definition on simulated clocks, membership changes
without a step, and the world's ensemble truth against the stations' clock filters."""

from __future__ import annotations

import numpy as np
import pytest

from net.channel import Clock
from net.clock import (TimeScale, clock_params, ensemble_change, ensemble_step_s, scale_at,
                       true_network_offset_s, OscillatorClock)
from net.scenario import load
from stations.sim import Simulator


def _tcxo_clocks(n: int, seed: int = 7) -> dict[int, OscillatorClock]:
    p = clock_params({"model": "tcxo"})
    return {i: OscillatorClock(p, np.random.default_rng([seed, i, 0])) for i in range(1, n + 1)}


def _true_state(clocks: dict, ids, T_s: float) -> tuple[dict, dict, float]:
    """Offsets and frequencies of ``ids`` against clock 1 when clock 1 reads ``T_s`` (linear clocks),
    and that true time."""
    tau = T_s
    for _ in range(5):
        tau = T_s - clocks[1].error_s(tau)
    x1 = clocks[1].error_s(tau)
    th = {k: clocks[k].error_s(tau) - x1 for k in ids}
    # d theta / dT for t_local = tau (1 + d) + o: (d_k - d_1) / (1 + d_1)
    f = {k: (clocks[k].drift - clocks[1].drift) / (1.0 + clocks[1].drift) for k in ids}
    return th, f, tau


def test_ensemble_time_of_simulated_clocks_is_the_weighted_mean_of_their_phases():
    clocks = _tcxo_clocks(5)
    w = {1: 0.1, 2: 0.2, 3: 0.3, 4: 0.15, 5: 0.25}
    scale = TimeScale(tuple(sorted(w.items())))
    for tau in (0.0, 3.3, 47.9, 300.1):
        x = {k: c.error_s(tau) for k, c in clocks.items()}
        mean = sum(w[k] * x[k] for k in w)
        for k in clocks:
            off = true_network_offset_s(clocks, [scale], k, tau)
            assert off == pytest.approx(x[k] - mean, abs=1e-15)
        # the weighted mean of every clock's offset against the ensemble is zero, whichever clock the
        # time axis is placed on
        for ref in (1, 4):
            offs = {k: true_network_offset_s(clocks, [scale], k, tau, ref_id=ref) for k in clocks}
            assert abs(sum(w[k] * offs[k] for k in w)) < 1e-15


def test_membership_change_on_noise_free_clocks_makes_no_step():
    rng = np.random.default_rng(3)
    clocks = {k: Clock(float(rng.normal(0, 1e-3)), float(rng.normal(0, 2e-6))) for k in range(1, 7)}
    s0 = TimeScale(((1, 1.0),))
    th, f, _ = _true_state(clocks, range(1, 7), 10.0)
    s1 = ensemble_change(s0, {k: 0.2 for k in range(1, 6)}, th, f, 10.0)  # founders 2-5 enter
    th, f, _ = _true_state(clocks, range(1, 7), 40.0)
    s2 = ensemble_change(s1, {k: 0.25 for k in (2, 3, 4, 6)}, th, f, 40.0)  # 1 and 5 leave, 6 enters
    assert s1.jump_s != 0 and s2.jump_s != 0  # the changes are real, not no-ops
    for tau in np.linspace(0.0, 200.0, 41):
        a = true_network_offset_s(clocks, [s0], 3, tau)
        b = true_network_offset_s(clocks, [s0, s1, s2], 3, tau)
        assert abs(a - b) < 1e-15, tau
    assert ensemble_step_s(clocks, s0, s1) == pytest.approx(0.0, abs=1e-15)
    assert ensemble_step_s(clocks, s1, s2) == pytest.approx(0.0, abs=1e-15)
    assert scale_at([s0, s1, s2], 39.9) is s1 and scale_at([s0, s1, s2], 40.0) is s2
    # a wrong phase term is seen as a step of that size
    bad = TimeScale(s2.weights, s2.a_s + 1e-10, s2.b, s2.T_ref_s, s2.jump_s + 1e-10)
    assert ensemble_step_s(clocks, s1, bad) == pytest.approx(1e-10, rel=1e-6)


def _noise_free_world():
    """seed000 with clocks that have offsets (1 ms) and frequencies (2 ppm) but no noise, and little range
    noise (1 cm: 33 ps per time transfer; much less makes the noise-free clock filter degenerate in
    float64)."""
    return load("seed000", seed=4, channel={"sigma_d_m": 0.01},
                clock={"model": "custom", "offset_s": 1e-3, "freq_ppm": 2.0})


def test_world_ensemble_truth_equals_the_filters_definition_on_a_noise_free_world():
    scn = _noise_free_world()
    sim = Simulator(scn, stop_s={1: 25.0})
    r = sim.run(45.0, [20.0, 24.0, 45.0])
    ok = ~np.isnan(r.clock_err_s)
    assert ok[0].all() and not ok[-1, 0]
    # tens of picoseconds (the time transfers' noise), where the clocks are a millisecond and 2 ppm apart:
    # the world evaluates the definition the filters realize, and the filters' sigma covers the rest
    assert np.max(np.abs(r.clock_err_s[ok])) < 0.1e-9
    assert np.mean(r.clock_err_s[ok] ** 2 / r.clock_var_s2[ok]) < 4.0
    clocks = sim.true_clocks()
    for sid, log in r.time_scales.items():
        if sid == 1:
            continue
        assert log[0].w == {1: 1.0}  # station 1's clock until the others are known
        assert set(log[-1].w) == set(range(2, 11))  # station 1 left, the others stay, equal weights
        assert all(abs(v - 1 / 9) < 1e-15 for v in log[-1].w.values())
        for prev, sc in zip(log, log[1:]):
            assert abs(ensemble_step_s(clocks, prev, sc)) < 0.05e-9


def test_founders_leave_the_tcxo_field_without_a_step():
    """Real oscillators (TCXO), sigma_d 0.5 m: stations 1 and 2 fall silent; the survivors' network time
    renormalizes (dated back to the leaver's last exchange, within the cycle before it fell silent),
    with steps far below the sync error, and they stay in sync."""
    scn = load("seed000", seed=5)
    sim = Simulator(scn, stop_s={1: 30.0, 2: 45.0})
    times = np.arange(20.0, 70.0 + 1e-9, 1.0)
    r = sim.run(70.0, times)
    clocks = sim.true_clocks()
    for sid, log in r.time_scales.items():
        if sid in (1, 2):
            continue
        assert set(log[-1].w) == set(range(3, 11))
        gone = {}
        for prev, sc in zip(log, log[1:]):
            for g in set(prev.w) - set(sc.w):
                gone[g] = (sc.T_ref_s, ensemble_step_s(clocks, prev, sc))
        assert 29.0 <= gone[1][0] <= 30.0 and 44.0 <= gone[2][0] <= 45.0
        assert all(abs(step) < 0.1e-9 for _, step in gone.values()), gone
    e = r.clock_err_s[times >= 31.0][:, 2:]
    assert np.max(np.abs(e)) < 2e-9
    assert np.sqrt(np.mean(e**2)) < 0.8e-9


def test_a_clock_enters_with_weight_zero_until_it_is_known():
    scn = load("seed000", seed=2)
    sim = Simulator(scn)
    r = sim.run(20.0, [1.0, 20.0])  # (formed at ~13-15 s: entry asks the frequency known as well, ENTER_FREQ_SD)
    for sid, log in r.time_scales.items():
        assert log[0].w == {1: 1.0}
        assert scale_at(log, 1.0).w == {1: 1.0}  # at 1 s nobody else is known to 2 ns
        assert len(log[-1].w) == 10
        core = sim.cores[scn.ids.index(sid)]
        assert all(s.T_ref_s >= 2.0 for s in log[1:] if s.w != log[0].w)  # membership changes (not steering)
        assert core.clk.scale is log[-1]


def test_leave_and_kill_faults_silence_stations_in_the_simulator():
    from net.scenario import ScenarioError

    scn = load("seed000", seed=5, faults=[{"kind": "kill", "station": 1, "at_s": 20.0},
                                          {"kind": "leave", "station": 3, "at_s": 25.0}])
    assert [f.onset_s for f in scn.faults] == [20.0, 25.0]
    sim = Simulator(scn)
    assert sim.stop_s == {1: 20.0, 3: 25.0}
    r = sim.run(40.0, [19.0, 40.0])
    assert np.isfinite(r.clock_err_s[0]).all()
    assert np.isnan(r.clock_err_s[1, [0, 2]]).all() and np.isfinite(r.clock_err_s[1, [1, *range(3, 10)]]).all()
    assert set(r.time_scales[2][-1].w) == {2, *range(4, 11)}  # both left network time
    with pytest.raises(ScenarioError, match=r"faults\[0\]\.at_s: missing"):
        load("seed000", faults=[{"kind": "kill", "station": 1}])
    with pytest.raises(ScenarioError, match=r"faults\[0\]\.kind: .*kill.*leave"):
        load("seed000", faults=[{"kind": "die", "station": 1, "at_s": 3.0}])
