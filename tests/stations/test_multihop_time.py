"""Multi-hop network time (issue 33 item 3): stations that hear none of the founders take the
founders' time scale through their neighbours, and the bench's per-hop table (docs/sync.md
"Multi-hop network time")."""

import numpy as np
import pytest

from larns.bench.sync import common_time_errors, crlb_offset_var, hops_from_founders, per_hop_table
from net.scenario import load
from stations.clocksync import STEER_P, UNROOTED_SD_S, consensus_step
from stations.sim import Simulator
from scenario_text import strip_toml

# a 12 km x 1.5 km strip of 10 stations on 10 m masts at -8 dBm (links of ~2-3 km): hops 0-3 from the
# founders; coarse fixes (10 m), so the clocks are measured on a surveyed field
STRIP = strip_toml("strip-time", "a 12 km strip of 10 stations, weak radio, coarse fix 10 m", n=10, depth_m=1500.0,
                   cycle_s=0.5, tx_power_dbm=-8.0, sigma0_m=10.0, clock="tcxo")


def test_consensus_step_lazy_average_and_its_noise_gate():
    """The weighted mean of the disagreements, the lazy gain n / (n + 1) where they are far above their
    noise, the least gain STEER_P where they are within it, and R the variance of the mean whatever the errors'
    correlation (equal variances: one disagreement's, not 1 / n of it)."""
    sd = 1e-9
    d, g, R = consensus_step(np.array([20e-9, 40e-9, 30e-9]), np.array([sd**2, sd**2, 4 * sd**2]))
    assert d == pytest.approx((20 + 40 + 30 / 4) / 2.25 * 1e-9)
    assert R == pytest.approx(((2 * sd + 0.5 * sd) / 2.25) ** 2)
    assert g == pytest.approx(0.75 * d * d / (d * d + R)) and g > 0.74
    d, g, R = consensus_step(np.full(4, 0.3 * sd), np.full(4, sd**2))
    assert R == pytest.approx(sd**2) and g == STEER_P  # within its noise: the least gain


def test_consensus_on_a_path_falls_geometrically():
    """Definitions along a 12-station path (each hears its two neighbours), steered by consensus_step
    on exact disagreements: their spread falls every cycle, by a factor of 49 in 150 cycles (the former
    fixed gain of 0.3 on the mean disagreement: 6.5)."""
    n = 12
    N0 = np.linspace(0.0, 100e-9, n)

    def run(cycles, step):
        N, spread = N0.copy(), []
        for _ in range(cycles):
            nb = [[j for j in (i - 1, i + 1) if 0 <= j < n] for i in range(n)]
            N = N + np.array([step(np.array([N[j] - N[i] for j in nb[i]])) for i in range(n)])
            spread.append(float(np.std(N)))
        return np.array(spread)

    lazy = run(150, lambda dd: (lambda d, g, _R: g * d)(*consensus_step(dd, np.full(len(dd), 1e-24))))
    fixed = run(150, lambda dd: 0.3 * float(np.mean(dd)))
    assert np.all(np.diff(lazy) < 0)
    assert lazy[-1] < 0.025 * np.std(N0) and fixed[-1] > 0.1 * np.std(N0)


def test_hops_from_founders_follow_the_realized_links():
    # 0-1-2 founders, 3 hears 2, 4 hears 3, 5 hears 4 and 3, 6 never linked
    pairs = [(0, 1), (1, 2), (3, 2), (4, 3), (5, 4), (3, 5)]
    assert hops_from_founders(pairs, 7).tolist() == [0, 0, 0, 1, 2, 2, -1]


def test_common_time_errors_remove_only_the_common_mode():
    rng = np.random.default_rng(4)
    x = rng.normal(0.0, 1e-3, (5, 6))  # true phases
    e = rng.normal(0.0, 1e-9, (5, 6))  # estimation errors
    est = x + e + 7e-6  # any common choice of the definition: not an error
    est[:, 5] = np.nan  # a station not alive
    got = common_time_errors(est, x)
    assert np.isnan(got[:, 5]).all()
    want = e[:, :5] - e[:, :5].mean(axis=1, keepdims=True)
    assert np.allclose(got[:, :5], want, atol=1e-15)


def test_per_hop_table_rms_bound_ratio_and_growth():
    T, K, n = 2, 3, 4
    hop = np.array([[0, 1, 1, 2], [0, 1, 2, 2]])
    err = np.full((T, K, n), 1e-9)
    err[:, :, 3] = 3e-9
    err[1, :, 2] = 3e-9  # hop 2 in trial 1
    bound = np.full((T, K, n), 1e-18)
    var = np.full((T, K, n), 4e-18)
    sel = np.array([False, True, True])
    rows = per_hop_table(err, bound, var, hop, sel)
    assert [r["hop"] for r in rows] == [0, 1, 2] and [r["stations"] for r in rows] == [2, 3, 3]
    assert rows[0]["rms_ns"] == pytest.approx(1.0) and rows[2]["rms_ns"] == pytest.approx(3.0)
    assert rows[2]["ratio"] == pytest.approx(3.0) and rows[2]["nees"] == pytest.approx(9.0 / 4.0)
    assert rows[2]["growth_ns"] == pytest.approx(2.0) and rows[1]["bound_growth_ns"] == pytest.approx(0.0)
    assert "growth_ns" not in rows[0]


@pytest.fixture(scope="module")
def strip(tmp_path_factory):
    path = tmp_path_factory.mktemp("mht") / "strip.toml"
    path.write_text(STRIP)
    scn = load(path)
    sim = Simulator(scn)
    times = np.arange(1.0, 60.0 + 1e-9, 1.0)
    return scn, sim, sim.run(60.0, times), times


def test_far_stations_take_the_founders_time_through_their_neighbours(strip):
    """Every station ends on a definition that descends from the founders' (none broadcasts the
    1 ms of a local one), the definitions agree, and each station's error against the field's one
    network time is near the centralized bound of the same exchanges at every hop. Before the rules
    of docs/sync.md "Multi-hop network time" the far stations kept definitions of their own,
    tens of microseconds from the founders' (the 60-station field: 52 us RMS)."""
    scn, sim, r, times = strip
    hop = hops_from_founders([(a, b) for _t, a, b in sim.exchange_log], len(r.ids))
    assert hop.max() >= 3 and (hop >= 0).all()  # multi-hop, and every station linked
    assert all(c.clk._rooted for c in sim.cores)
    assert all(c.clk.correction(c.clk.local_time(c.clk.T_s))[3] < UNROOTED_SD_S**2 * 1e-6 for c in sim.cores)
    spread = sim.definition_spread_s(r, times)
    assert np.all(spread[times >= 30.0] < 5e-9), spread * 1e9
    clocks = sim.true_clocks()
    x = np.array([[clocks[sid].error_s(t) for sid in r.ids] for t in times])
    com = common_time_errors(r.clock_err_s + r.clock_true_s, x)
    crlb, _ = crlb_offset_var(scn, sim.exchange_log, r.ids, times)
    sel = times >= 40.0
    rows = per_hop_table(com[None], crlb[None], r.clock_var_s2[None], hop[None], sel)
    # seed 2 (measured: ratios 1.07 / 0.92 / 1.14 / 1.80 at hops 0-3 over 40-60 s, one hop-3 station,
    # the field 1.16 x; 1.19 / 0.96 / 1.35 / 2.09 and 1.31 x with the fixed steering gain of 0.3):
    # within 2.5 x the bound at every hop, and the field as a whole within 1.5 x
    assert all(row["ratio"] < 2.5 for row in rows), rows
    assert np.sqrt(np.nanmean(com[sel] ** 2)) < 1.5 * np.sqrt(np.nanmean(crlb[sel])), rows
