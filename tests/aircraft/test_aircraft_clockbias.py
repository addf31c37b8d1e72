"""Aircraft filters with the stations' residual clock errors as Gauss-Markov bias states (issue 10).

Each station's residual sync error after the broadcast correction is a slowly varying range bias
(docs/sync.md); the pseudorange and TDOA filters carry one first-order Gauss-Markov state per
station heard, the posterior CRLB is that of the same augmented model (nav.pcrb.augment_biases).
"""

from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from aircraft.montecarlo import radio as sim
from aircraft.navigator.radio import models as mdl
from aircraft.navigator.radio.tracker import CvTracker
from aircraft.navigator.radio.tuning import Prior, Tuning
from aircraft.world.clock import ReceiverClock
from nav.pcrb import augment_biases, gauss_markov_block, pcrb_linear_gaussian, prior_before_first_step

# first-order, one pass, Cartesian: the EKF is then exactly the textbook EKF
PLAIN = Tuning(rules=(), floor_z_m=None, clock_bias_tau_s=4.0)


def _stations(m, rng, spread_m=20_000.0):
    s = rng.uniform(-spread_m, spread_m, (m, 3))
    s[:, 2] = rng.uniform(0.0, 50.0, m)
    return s


def _textbook(model, x, P, z, st, D, R, base=0):
    """Textbook EKF update (explicit gain, Joseph form) on the augmented state [x, beta]."""
    n = 8 if model == "pr" else 6
    if model == "pr":
        H = np.hstack([mdl.jac_pr(x[:n], st), D])
        hx = mdl.h_pr(x[:n], st) + D @ x[n:]
    else:
        G = mdl.g_matrix(st.shape[0], base)
        H = np.hstack([mdl.jac_tdoa(x[:n], st, base), G @ D])
        hx = mdl.h_tdoa(x[:n], st, base) + G @ D @ x[n:]
        R = G @ R @ G.T
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    A = np.eye(len(x)) - K @ H
    return x + K @ (z - hx), A @ P @ A.T + K @ R @ K.T


@pytest.mark.parametrize("model", ["pr", "tdoa"])
def test_bias_states_equal_a_textbook_kf_as_stations_appear_and_variances_change(model):
    rng = np.random.default_rng(3)
    st_all = _stations(6, rng)
    sig = PLAIN.sigma_m
    n = 8 if model == "pr" else 6
    x_true = np.array([1000.0, 2000.0, 1500.0, 30.0, -20.0, 0.0, 50.0, 0.6])[:n]
    x0 = x_true + rng.normal(0, 5.0, n)
    trk = CvTracker("ekf", model, x0, PLAIN)
    x, P = x0.copy(), PLAIN.prior_cov(mdl.StateLayout(model, drift=model == "pr"))
    ids: list[int] = []
    var_of = {}
    dt = 0.1
    for k in range(1, 30):
        # stations 0-3 from the start, 4 from step 10, 5 from step 20; variances vary per broadcast
        batch = [0, 1, 2, 3] + ([4] if k >= 10 else []) + ([5] if k >= 20 else [])
        var = np.array([(0.2 + 0.05 * j + 0.01 * (k % 3)) ** 2 for j in batch])
        st = st_all[batch]
        # reference: predict with the stationary variances of the previous broadcasts, then add states
        F = mdl.cv_transition(n, dt)
        Q = mdl.cv_noise(n, dt, PLAIN.q_acc, PLAIN.q_clock, PLAIN.q_drift)
        if ids:
            A, Qb = gauss_markov_block(len(ids), [var_of[i] for i in ids], PLAIN.clock_bias_tau_s, dt)
            F = np.block([[F, np.zeros((n, len(ids)))], [np.zeros((len(ids), n)), A]])
            Q = np.block([[Q, np.zeros((n, len(ids)))], [np.zeros((len(ids), n)), Qb]])
        x, P = F @ x, F @ P @ F.T + Q
        for j, v in zip(batch, var):
            if j not in ids:
                ids.append(j)
                x = np.append(x, 0.0)
                P = np.block([[P, np.zeros((len(P), 1))], [np.zeros((1, len(P))), np.array([[v]])]])
            var_of[j] = v
        D = np.zeros((len(batch), len(ids)))
        D[np.arange(len(batch)), [ids.index(j) for j in batch]] = 1.0
        beta = rng.normal(0, np.sqrt(var))
        rho = mdl.h_pr(np.append(x_true, 0.0)[:8] if model == "tdoa" else x_true, st) + beta \
            + rng.normal(0, sig, len(batch))
        z = rho if model == "pr" else mdl.g_matrix(len(batch), 0) @ rho
        x, P = _textbook(model, x, P, z, st, D, sig**2 * np.eye(len(batch)))
        trk.predict_to(k * dt)
        trk.update(st, rho, bias_ids=batch, bias_var_m2=var)
        assert trk.bias_ids == ids
        np.testing.assert_allclose(trk.x, x, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(trk.P, P, rtol=1e-7, atol=1e-9)


def test_unheard_station_bias_is_marginalized():
    rng = np.random.default_rng(4)
    st = _stations(5, rng)
    tu = PLAIN
    trk = CvTracker("ekf", "pr", np.array([1000.0, 2000.0, 1500.0, 0, 0, 0, 0, 0]), tu)
    trk.biases.drop_s = 1.0  # (the tuning's is a minute)
    for k in range(1, 6):
        trk.predict_to(0.1 * k)
        trk.update(st, rng.normal(0, 1, 5) + 3000.0, bias_ids=[1, 2, 3, 4, 5], bias_var_m2=0.04)
    x_before, P_before = trk.x.copy(), trk.P.copy()
    trk.predict_to(2.0)
    x_pred, P_pred = trk.x.copy(), trk.P.copy()
    trk.predict_to(2.0)
    # stations 2..5 go on, station 1 is silent for > 1 s: its state leaves, the rest is the marginal
    keep = [0, 1, 2, 3, 4, 5, 6, 7, 9, 10, 11, 12]
    tr2 = CvTracker("ekf", "pr", x_pred[:8], tu)
    tr2._x, tr2._P = x_pred[keep].copy(), P_pred[np.ix_(keep, keep)].copy()
    tr2.bias_ids, tr2._bias_var, tr2._bias_t = [2, 3, 4, 5], np.full(4, 0.04), np.full(4, 0.5)
    tr2.t_s = trk.t_s
    rho = rng.normal(0, 1, 4) + 3000.0
    trk.update(st[1:], rho, bias_ids=[2, 3, 4, 5], bias_var_m2=0.04)
    tr2.update(st[1:], rho, bias_ids=[2, 3, 4, 5], bias_var_m2=0.04)
    assert trk.bias_ids == [2, 3, 4, 5]
    np.testing.assert_allclose(trk.x, tr2.x, rtol=1e-12)
    np.testing.assert_allclose(trk.P, tr2.P, rtol=1e-12)
    assert x_before.shape == (13,)


@pytest.mark.parametrize("model", ["pr", "tdoa"])
@pytest.mark.parametrize("coords", ["cartesian", "inverse"])
def test_measurement_model_jacobian_with_bias_states(model, coords):
    rng = np.random.default_rng(5)
    st = _stations(5, rng, 100.0)
    n = 8 if model == "pr" else 6
    x0 = np.array([900.0, 700.0, 300.0, 40.0, -10.0, 2.0, 30.0, 0.6])[:n]
    trk = CvTracker("ekf", model, x0, replace(PLAIN, rules=("inverse",) if coords == "inverse" else ()))
    dt = np.array([-0.04, -0.03, -0.02, -0.01, 0.0])
    D = np.zeros((5, 3))
    D[[0, 2, 4], [0, 1, 2]] = 1.0
    h, jac = trk.measurement_model(st, dt, D)
    X = np.concatenate([x0, [0.1, -0.2, 0.3]])
    J = jac(X)
    eps = 1e-5
    Jn = np.stack([(h(X + eps * e) - h(X - eps * e)) / (2 * eps) for e in np.eye(len(X))], axis=-1)
    np.testing.assert_allclose(J, Jn, rtol=1e-6, atol=1e-8)
    # the bias columns: pseudoranges see beta_j, differences G beta
    Dm = D if model == "pr" else mdl.g_matrix(5, 0) @ D
    np.testing.assert_array_equal(J[:, n:], Dm)


@pytest.mark.parametrize("kind", ["ekf", "ukf"])
def test_filter_covariance_equals_the_augmented_pcrb_on_a_linear_problem(kind):
    """Stations 10^6 m away: the ranges are linear over the filter's uncertainty, so the filter's
    covariance is the linear KF's, which is the posterior CRLB of the augmented model."""
    rng = np.random.default_rng(6)
    m = 5
    dirs = rng.normal(size=(m, 3))
    dirs[:, 2] = -np.abs(dirs[:, 2])
    st = 1e6 * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    x_true = np.array([0.0, 0.0, 1000.0, 0.0, 0.0, 0.0, 10.0, 0.6])
    tu = replace(PLAIN, p0=Prior(pos_m=5.0, clock_m=5.0))
    trk = CvTracker(kind, "pr", x_true, tu)
    var = np.array([0.1, 0.2, 0.15, 0.3, 0.25]) ** 2
    dt, T = 0.1, 40
    H = []
    for k in range(1, T + 1):
        trk.predict_to(k * dt)
        xt = x_true.copy()
        xt[6] += 0.6 * k * dt
        trk.update(st, mdl.h_pr(xt, st), bias_ids=list(range(m)), bias_var_m2=var)
        H.append(mdl.jac_pr(xt, st))
    F = mdl.cv_transition(8, dt)
    Q = mdl.cv_noise(8, dt, tu.q_acc, tu.q_clock, tu.q_drift)
    P0a, Fa, Qa, Ha = augment_biases(tu.prior_cov(mdl.StateLayout("pr", True)), F, Q, np.array(H), np.eye(m), var,
                                     tu.clock_bias_tau_s, dt)
    # the filter's prior is at t = 0, its first step a prediction: the recursion from P0a as is
    Pb = pcrb_linear_gaussian(P0a, Fa, Qa, Ha, tu.sigma_m**2 * np.eye(m))[-1]
    np.testing.assert_allclose(trk.P, Pb, rtol=2e-3, atol=1e-9)
    assert prior_before_first_step(P0a, Fa, Qa).shape == P0a.shape


def _nees_run(clock_bias, runs=24, seconds=12.0):
    """EKF-PR with slowly varying station biases, seeded world; mean NEES of the 8 navigation states."""
    rng = np.random.default_rng(11)
    st = np.array([[0.0, 0.0, 0.0], [3000.0, 0.0, 20.0], [0.0, 3000.0, -10.0], [-3000.0, 500.0, 5.0],
                   [500.0, -3000.0, 0.0]])
    dt = 0.1
    t = np.arange(0.0, seconds, dt)
    from aircraft.world.trajectory import Track

    pos = np.array([2000.0, 1500.0, 1000.0]) + np.outer(t, [20.0, -10.0, 0.0])
    track = Track(t_s=t, pos_m=pos, vel_m_s=np.broadcast_to([20.0, -10.0, 0.0], pos.shape).copy())
    clock = ReceiverClock()
    tau_s = 5.0  # the world's; the filter models it ("states") or takes it as white (tau 0)
    tu = replace(Tuning().without("inverse"), clock_bias_tau_s=tau_s if clock_bias == "states" else 0.0)
    sync_m = 1.0  # 3.3 ns: the bias dominates the 0.5 m timing noise
    rho = sim.pseudoranges(track, st, clock, tu.sigma_m, runs, rng)
    a = np.exp(-dt / tau_s)
    b = np.empty(rho.shape)
    b[0] = rng.standard_normal(rho.shape[1:])
    for k in range(1, len(t)):
        b[k] = a * b[k - 1] + np.sqrt(1 - a * a) * rng.standard_normal(rho.shape[1:])
    res = sim.run_algo("ekf-pr", track, st, rho + sync_m * b, tu, clock, rng, clock_var_m2=sync_m**2)
    return float(res.nees[:, t >= 4.0].mean()), runs


def test_nees_with_correlated_station_biases_inside_band_and_white_model_overconfident():
    nees, runs = _nees_run("states")
    lo, hi = stats.chi2.ppf([0.025, 0.975], runs * 8) / runs
    assert nees < hi, (nees, hi)
    assert nees > 0.5 * lo, (nees, lo)  # not grossly pessimistic either
    nees_white, _ = _nees_run("white")
    assert nees_white > 1.5 * hi, nees_white  # the white model is overconfident in the same world


@pytest.mark.parametrize("algo", ["ekf-pr", "ukf-tdoa"])
def test_message_api_carries_one_bias_per_station_heard_on_tdma_slots(algo):
    """The node's path: one TDMA slot at a time with the broadcast clock variance; the filter adds a
    bias state per station as it is heard, and the final error is within its covariance."""
    from aircraft.config import from_scenario
    from aircraft.navigator.radio.estimator import AircraftEstimator, EstimatorConfig
    from aircraft.world import trajectory
    from net.scenario import load

    ac = from_scenario(load("seed003"))
    t = np.arange(0.0, 40.0, 0.1)
    tr = trajectory.from_config(ac.world.trajectory, t, ac.world.centre_m)
    rng = np.random.default_rng(15)
    m = len(ac.world.stations_m)
    sync_m = 0.6  # 2 ns
    a = np.exp(-0.1 / 6.0)
    beta = sync_m * rng.standard_normal(m)
    e = AircraftEstimator(algo, EstimatorConfig(tuning=ac.nav.tuning), x0_guess_m=ac.world.centre_m + [0, 0, 1000.0])
    for k, tk in enumerate(t):
        beta = a * beta + np.sqrt(1 - a * a) * sync_m * rng.standard_normal(m)
        j = k % m
        rho = (np.linalg.norm(tr.pos_m[k] - ac.world.stations_m[j]) + ac.world.clock.bias_m(tk) + beta[j]
               + ac.world.sigma_m * rng.standard_normal())
        e.on_measurement(tk, j + 1, ac.world.stations_m[j], None, rho, clock_var_m2=sync_m**2)
    assert e.n_resets == 0
    assert sorted(e.tracker.bias_ids) == list(range(1, m + 1))
    n = e.tracker.n_base
    assert e.tracker.x.shape[-1] == n + m
    est = e.estimate()
    p, _ = tr.at(est["t_s"])
    d = np.array(est["pos_m"]) - p
    assert d @ np.linalg.solve(np.array(est["cov_m2"]), d) < stats.chi2.ppf(0.999, 3)
    # the receiver clock is a state of the pseudorange filter only (a TDOA state's 7th entry is a bias)
    assert (est["clock_m"] is None) == algo.endswith("tdoa")


def test_live_aircraft_core_models_each_station_clock_from_its_broadcast():
    """RadioAircraftCore (the process's sans-I/O core): navs whose broadcast clock correction is off by a
    slowly varying residual; the filters hold one bias state per station with the broadcast variance."""
    from aircraft.config import from_scenario
    from aircraft.radio_core import RadioAircraftCore
    from net.scenario import load

    scn = load("seed003", clock={"model": "perfect"})
    ac = from_scenario(scn)
    core = RadioAircraftCore(ac, ("ekf-pr", "ukf-pr"), "ac1", np.random.default_rng(2), horizon_s=60.0)
    rng = np.random.default_rng(3)
    ids = list(scn.ids)
    sync_s = 1e-9
    resid = {sid: sync_s * rng.standard_normal() for sid in ids}
    a = np.exp(-scn.tdma.slot_s / 6.0)
    k = 0
    for cycle in range(30):
        for sid in ids:
            t = k * scn.tdma.slot_s + 0.05
            k += 1
            for s2 in ids:
                resid[s2] = a * resid[s2] + np.sqrt(1 - a * a) * sync_s * rng.standard_normal()
            # perfect station clock, broadcast offset estimate off by the residual; P_tt = (1 ns)^2
            msg = {"state": "frame", "src": sid, "pos_m": scn.true_pos(sid).tolist(),
                   "cov_m2": np.zeros((3, 3)).tolist(), "t_tx_s": t, "clock": [t, resid[sid], 0.0, sync_s**2, 0.0, 0.0]}
            core.on_nav(msg, {"pos_m": scn.true_pos(sid).tolist(), "t_true_s": t})
    for algo, est in core.estimators.items():
        assert est.tracker is not None, algo
        assert sorted(est.tracker.bias_ids) == sorted(ids), algo
        np.testing.assert_allclose(est.tracker._bias_var, (299792458.0 * sync_s) ** 2, rtol=1e-9)


@pytest.mark.slow
def test_bench_aircraft_clocks_smoke(tmp_path, capsys):
    """`larns bench aircraft --clocks`: both worlds on the same draws; the bound with station clocks
    is above the perfect-clock one at every point (it includes the residual sync errors)."""
    import json

    from larns.cli import main

    js = tmp_path / "c.json"
    rc = main(["bench", "aircraft", "--quick", "--clocks", "--trials", "2", "--duration", "1.5", "--warmup", "0.5",
               "--no-sweep", "--no-speed", "--json", str(js)])
    assert rc == 0
    out = json.loads(js.read_text())
    assert out["bar"]["factor"] == 1.15 and out["settings"]["sync_ns"] == 0.7
    assert out["settings"]["sync_tau_s"] == 6.0 and out["settings"]["clock_bias"] == "states"
    pf = out["perfect_clocks"]
    for kind in ("hover", "turn"):
        for algo, pts in out["pcrb_m"][kind].items():
            for d, v in pts.items():
                assert v > pf["pcrb_m"][kind][algo][d]
    assert "beside perfect clocks" in capsys.readouterr().out


def test_linearization_error_counted_as_repeated_near_a_transmitter():
    """seed001 hover 50 m is 2.6 m above transmitter 1; with station clocks on (0.21 m biases, 6 s) the
    bound (1.19 m) is half that distance. Counting the second-order (linearization) covariance once
    per 100 Hz update (``linearization_corr_s = 0``) lets the filter read the range's curvature as
    information: overconfident (NEES ~ 90 for 8 dof with the floor truncation fed back at every update,
    ~22 with the floor counted once, 8 runs) and ~1.7 x the PCRB; counted as repeating over
    ``linearization_corr_s`` (default 10 s) it is consistent and at the bound (bench: 0.98 x, NEES 6.8)."""
    from larns.bench.aircraft import run_point, setup

    _sc, ac = setup("seed001")
    sync_m = 0.7 * 0.299792458
    out = {}
    for corr in (10.0, 0.0):
        a = ac.with_tuning(ac.nav.tuning if corr else ac.nav.tuning.without("repeats"))
        r = run_point(a, "hover", 50.0, 8, 24.0, 10.0, None, np.random.default_rng(3), algos=("ekf-pr",),
                      sync_m=sync_m, sync_tau_s=6.0, fde=False)
        out[corr] = (r["rmse_m"]["ekf-pr"] / r["pcrb_m"]["ekf-pr"], r["nees"]["ekf-pr"], r["nees_band"]["ekf-pr"])
    ratio, nees, band = out[10.0]
    assert ratio < 1.3 and nees < 1.5 * band[1], out
    ratio0, nees0, _ = out[0.0]
    assert nees0 > 1.5 * band[1] and ratio0 > 1.3 * ratio, out
