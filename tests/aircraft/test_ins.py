"""Inertial aircraft: rotations, strapdown mechanization, IMU emulator, error-state EKF, seed 003's
fictitious stations, and the navigator/world import boundary (docs/ins.md)."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from aircraft.events import to_msgs
from aircraft.navigator import fict_kf
from aircraft.navigator.ins_ekf import InsEkf, InsTuning, PositionComponent, initial_covariance
from aircraft.world.imu import ImuEmulator, allan_dev, gm_allan_var, preset
from aircraft.world.motion import G_L, Coning, ConstantRate, Ellipse, Hover
from nav import errorstate as es
from nav import strapdown as sd
from nav.rotations import dcm_from_euler, euler_from_dcm, exp_so3, log_so3

ROOT = Path(__file__).resolve().parents[2]


# -- rotations ---------------------------------------------------------------------------------------

def test_exp_log_euler_roundtrip():
    rng = np.random.default_rng(0)
    phi = rng.normal(0, 1, (50, 3))
    phi *= (rng.uniform(1e-9, 3.0, 50) / np.linalg.norm(phi, axis=1))[:, None]
    C = exp_so3(phi)
    assert np.allclose(np.swapaxes(C, -1, -2) @ C, np.eye(3), atol=1e-14)
    assert np.allclose(log_so3(C), phi, atol=1e-9)
    # small angles: I + K + K^2/2 to 1e-18
    small = np.array([1e-9, -2e-9, 3e-9])
    from nav.rotations import skew

    Ks = skew(small)
    assert np.abs(exp_so3(small) - (np.eye(3) + Ks + Ks @ Ks / 2.0)).max() <= 2.3e-16
    e = rng.uniform([-3, -1.4, -3], [3, 1.4, 3], (50, 3))
    assert np.allclose(euler_from_dcm(dcm_from_euler(*e.T)), e, atol=1e-12)


# -- strapdown against closed-form motions --------------------------------------------------------------

def _fly(motion, dt, n, coning=True):
    dth, dv = motion.increments(0.0, dt, n)
    p, v, _ = motion.pva(np.array([0.0, n * dt]))
    C = motion.attitude(np.array([0.0, n * dt]))
    s = sd.NavState(p[0], v[0], C[0])
    if not coning:  # plain exp(dtheta) updates, no coning/sculling terms
        Cn = C[0].copy()
        for k in range(n):
            Cn = Cn @ exp_so3(dth[k])
        return np.abs(log_so3(C[1].T @ Cn)).max()
    e = sd.run(s, dth, dv, G_L, dt)
    return np.abs(e.p_m - p[1]).max(), np.abs(e.v_m_s - v[1]).max(), np.abs(log_so3(C[1].T @ e.C_nb)).max()


def test_strapdown_static_is_exact():
    ep, ev, ea = _fly(Hover(np.array([10.0, -5.0, 300.0]), yaw0_rad=0.7), 0.01, 3000)
    assert ep == 0.0 and ev == 0.0 and ea < 1e-15


def test_strapdown_constant_rate():
    """Rotation about a fixed axis at rest: attitude exact to 1e-10 rad; the velocity error is the
    two-sample algorithm's third-order term |w|^2 dt^2 / 6 of g per step (bounded, not more)."""
    w = np.array([0.1, -0.2, 0.3])
    dt, n = 0.01, 3000
    ep, ev, ea = _fly(ConstantRate(w), dt, n)
    assert ea < 1e-10
    assert ev < n * (w @ w) * dt**2 / 6.0 * sd.G0_M_S2 * dt


def test_strapdown_coning_fourth_order():
    """Classical coning (half-angle 0.05 rad at 2 Hz): the coning-corrected attitude error falls as dt^4
    and is > 50 x below the uncorrected one (270 x at 10 ms)."""
    m = Coning(0.05, 2 * np.pi * 2.0)
    errs = []
    for dt in (0.02, 0.01):
        n = int(round(10.0 / dt))
        errs.append(_fly(m, dt, n)[2])
        assert errs[-1] < _fly(m, dt, n, coning=False) / 50.0
    assert errs[0] / errs[1] > 12.0
    assert errs[1] < 2e-6


def test_strapdown_ellipse_with_climb():
    """A banked ellipse with climbs: noise-free increments reproduce the truth to sub-micrometre."""
    m = Ellipse((0.0, 0.0), (3000.0, 2000.0), 500.0, 50.0, climb_amp_m=50.0, climb_period_s=120.0)
    ep, ev, ea = _fly(m, 0.01, 6000)
    assert ep < 1e-5 and ev < 1e-6 and ea < 1e-9


# -- IMU emulator ---------------------------------------------------------------------------------------

def test_imu_allan_deviation_matches_preset():
    """Static gyro: overlapping Allan deviation against white noise + Gauss-Markov theory, and the
    GM peak equals the preset's bias instability."""
    p = preset("adis16480").with_(gyro_tc_s=2.0, gyro_turn_on_rad_s=0.0, gyro_sf=0.0)
    imu = ImuEmulator(p, 4, np.random.default_rng(5))
    n = 400_000
    g, _ = imu.measure(np.zeros((n, 3)), np.zeros((n, 3)))
    rate = g.reshape(n, -1) / imu.dt_s
    m = np.array([10, 100, 400, 1000])
    tau = m * imu.dt_s
    adev = np.mean([allan_dev(rate[:, j], imu.dt_s, m) for j in range(rate.shape[1])], axis=0)
    theory = np.sqrt(p.arw_rad_sqrt_s**2 / tau + gm_allan_var(tau, p.gyro_gm_sigma, p.gyro_tc_s))
    assert np.all(np.abs(adev / theory - 1.0) < 0.08), adev / theory
    peak = np.sqrt(gm_allan_var(np.logspace(-1, 2, 2000), p.gyro_gm_sigma, p.gyro_tc_s).max())
    assert peak == pytest.approx(p.gyro_bi_rad_s, rel=1e-3)


def test_imu_turn_on_bias_and_seeding():
    p = preset("tactical")
    a = ImuEmulator(p, 3, np.random.default_rng(1))
    b = ImuEmulator(p, 3, np.random.default_rng(1))
    z = np.zeros((10, 3))
    assert np.array_equal(a.measure(z, z)[0], b.measure(z, z)[0])
    with pytest.raises(ValueError, match="unknown IMU preset"):
        preset("nope")


# -- error-state filter ---------------------------------------------------------------------------------

def _tuning(**kw):
    return InsTuning.from_preset(preset("adis16480"), **kw)


def test_errorstate_equals_linear_kf_on_linear_case():
    """No rotation, exact gyros, no attitude uncertainty, random-walk accelerometer bias and linear
    position measurements: the closed-loop error-state filter equals a linear KF on the total state
    [p, v, phi, ba, bg] with the same discretization."""
    tn = _tuning().__class__(**{**_tuning().__dict__, "arw": 0.0, "sigma_gm_g": 0.0, "tc_a_s": 1e12,
                                "sigma_gm_a": np.sqrt(1e-6 * 1e12 / 2.0)})
    L = es.ErrorLayout(turn_on=False, tilt=False, clock=False)
    rng = np.random.default_rng(3)
    P0 = np.zeros((L.n, L.n))
    P0[L.P, L.P] = 4.0 * np.eye(3)
    P0[L.V, L.V] = 0.25 * np.eye(3)
    P0[L.BA, L.BA] = 1e-4 * np.eye(3)
    g = np.array([0.0, 0.0, -sd.G0_M_S2])
    ekf = InsEkf(tn, L, np.zeros((1, 3)), np.zeros((1, 3)), np.eye(3)[None], None, P0, np.zeros((1, 2)), 1.0)
    ekf._g = np.broadcast_to(g, (1, 3)).copy()
    x = np.zeros(L.n)
    P = P0.copy()
    f = np.array([0.3, -0.2, sd.G0_M_S2 + 0.1])
    dt = tn.dt_s
    Qc = tn.qc(L)
    for k in range(50):
        for _ in range(10):
            ekf.imu(np.zeros((1, 3)), (f * dt)[None])
        ekf.propagate()
        T = 10 * dt
        F = es.f_matrix(L, np.eye(3), f, None, tn.tc_a_s, tn.tc_g_s)
        Phi, Qd = es.discretize(F, Qc, T)
        u = np.zeros(L.n)
        u[L.P] = 0.5 * (f + g) * T**2
        u[L.V] = (f + g) * T
        x = Phi @ x + u
        P = Phi @ P @ Phi.T + Qd
        e = np.eye(3)[k % 3]
        z = float(e @ rng.normal(0, 2, 3)) + k * 0.1
        ekf.update(PositionComponent(e, ekf.t_s), np.array([z]), 1.5)
        H = np.zeros(L.n)
        H[L.P] = e
        S = H @ P @ H + 1.5
        K = P @ H / S
        x = x + K * (z - H @ x)
        IKH = np.eye(L.n) - np.outer(K, H)
        P = IKH @ P @ IKH.T + 1.5 * np.outer(K, K)
    assert np.allclose(ekf.p[0], x[L.P], atol=1e-9)
    assert np.allclose(ekf.v[0], x[L.V], atol=1e-9)
    assert np.allclose(ekf.ba[0], x[L.BA], atol=1e-12)
    assert np.allclose(ekf.P[0], P, atol=1e-10)


def _ellipse_filter(L, M=2):
    tn = _tuning()
    m = Ellipse((0.0, 0.0), (3000.0, 2000.0), 800.0, 50.0, climb_amp_m=30.0, climb_period_s=200.0)
    p, v, _ = m.pva(np.array([0.0]))
    C = m.attitude(np.array([0.0]))
    tau = np.array([[2e-3, -1e-3]] * M)
    ekf = InsEkf(tn, L, np.repeat(p, M, 0), np.repeat(v, M, 0), np.repeat(C, M, 0), np.zeros((M, 2)),
                 initial_covariance(L, tn, tau[0], 1.0), tau, 1.0)
    return ekf, m, tn


def test_error_dynamics_jacobian_vs_finite_differences():
    """Perturb the nominal by a small error state, fly both through the mechanization with the same
    raw increments for 0.1 s: the difference equals Phi times the initial error (to second order)."""
    L = es.ErrorLayout()
    ekf, m, tn = _ellipse_filter(L)
    rng = np.random.default_rng(7)
    scale = np.sqrt(np.diag(initial_covariance(L, tn, np.zeros(2), 1.0)))
    d0 = rng.normal(0, 1, L.n) * scale * 1e-3
    dx = np.zeros((2, L.n))
    dx[1] = d0
    ekf.inject(dx)
    dth, dv = m.increments(0.0, tn.dt_s, 10)
    for k in range(10):
        ekf.imu(np.repeat(dth[k][None], 2, 0), np.repeat(dv[k][None], 2, 0))
    ekf.propagate()
    d1 = np.zeros(L.n)
    d1[L.P] = ekf.p[1] - ekf.p[0]
    d1[L.V] = ekf.v[1] - ekf.v[0]
    d1[L.ATT] = log_so3(ekf.C[1] @ ekf.C[0].T)
    d1[L.BA], d1[L.BG] = ekf.ba[1] - ekf.ba[0], ekf.bg[1] - ekf.bg[0]
    d1[L.BAC], d1[L.BGC] = ekf.bac[1] - ekf.bac[0], ekf.bgc[1] - ekf.bgc[0]
    d1[L.TILT], d1[L.CLK] = ekf.tau[1] - ekf.tau[0], ekf.clk[1] - ekf.clk[0]
    pred = ekf.last_phi[1] @ d0
    # agreement to ~1e-4 of each component's scale (second-order terms are ~1e-3 of the perturbation)
    assert np.all(np.abs(d1 - pred) <= 1e-4 * scale * 1e-3 * 10 + 1e-12), np.abs(d1 - pred) / (scale * 1e-3)


def test_pseudorange_jacobian_vs_finite_differences():
    L = es.ErrorLayout()
    ekf, m, tn = _ellipse_filter(L, M=1)
    dth, dv = m.increments(0.0, tn.dt_s, 5)
    for k in range(5):
        ekf.imu(dth[k][None], dv[k][None])
    ekf.clk[:] = [[30.0, 0.4]]
    st = np.array([5000.0, 4000.0, 20.0])
    t_rx = ekf.t_s - 0.0063
    pred, H = ekf.predict_range(t_rx, st)
    for i in range(L.n):
        e = np.zeros((1, L.n))
        h = 1e-6
        e[0, i] = h
        ekf.inject(e)
        pp, _ = ekf.predict_range(t_rx, st)
        e[0, i] = -h
        ekf.inject(e)
        num = (pp - pred) / h
        assert num[0] == pytest.approx(H[0, i], abs=2e-5), (i, num, H[0, i])


def test_ins_ekf_seeded_nees_and_pcrb():
    """Seed 003 field (text heights, tilted frame), ADIS16480, 16 runs x 120 s: mean NEES of [p v phi]
    inside its 95 % band or below it (and not absurdly below), horizontal RMSE <= 1.3 x PCRB."""
    from aircraft.montecarlo.ins import InsRun, simulate
    from aircraft.world.field import Field
    from net.scenario import load

    fld = Field.from_scenario(load("seed003-text"))
    mo = Ellipse((15000.0, 0.0), (20000.0, 15000.0), 1000.0, 50.0)
    res = simulate(fld, mo, preset("adis16480"), InsRun(runs=16, duration_s=120.0, seed=4))
    k = res.t_s >= 30.0
    from scipy.stats import chi2

    hi = chi2.ppf(0.975, 9 * 16 * k.sum()) / (16 * k.sum())
    mean_nees = res.nees[:, k].mean()
    assert 0.4 * 9 < mean_nees <= hi, mean_nees
    ratio = np.sqrt(np.mean(res.rmse_h()[k] ** 2)) / np.sqrt(np.mean(res.pcrb_h()[k] ** 2))
    assert ratio < 1.3, ratio


def test_jacobian_force_is_low_passed():
    """``jac_force_tc_s``: the specific force in F's attitude column is the exponential average of
    the intervals' mean forces (weight T / tc), the interval's own with 0; the nominal is untouched."""
    L = es.ErrorLayout()
    out = {}
    for tc in (0.0, 20.0):
        ekf, m, tn = _ellipse_filter(L, M=1)
        ekf.tn = InsTuning(**{**tn.__dict__, "jac_force_tc_s": tc})
        dth, dv = m.increments(0.0, tn.dt_s, 300)
        fj, means = [], []
        for k in range(300):
            ekf.imu(dth[k][None], dv[k][None])
            if (k + 1) % 10 == 0:
                means.append(ekf._fsum[0] / (10 * tn.dt_s))
                ekf.propagate()
                fj.append(ekf.f_jac[0].copy())
        out[tc] = (np.array(fj), np.array(means), ekf.p.copy())
    fj0, m0, p0 = out[0.0]
    fj2, m2, p2 = out[20.0]
    np.testing.assert_allclose(fj0, m0, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(p0, p2)
    ref = m2[0].copy()
    for i in range(1, len(m2)):
        ref = ref + (0.1 / 20.0) * (m2[i] - ref)
        np.testing.assert_allclose(fj2[i], ref, rtol=0, atol=1e-9)
    assert np.abs(fj2[-1] - m2[-1]).max() > 1e-3  # it is a low-pass on a turning aircraft, not a copy


@pytest.mark.slow
def test_heading_nees_consistent_over_a_long_flight():
    """Seed 003 field, ADIS16480, 16 runs x 1500 s at 1000 m (~3 min loaded): over 1000-1500 s the
    heading error's NEES (1 dof, mean over runs and time) is 2.3 with the low-passed Jacobian force
    and was 4.3 with the former linearization (``jac_force_tc_s = 0``, same seed): asserted <= 3.
    It is not yet inside chi2(16)/16's 99.5 % bound (2.16) for this seed (docs/ins.md: the fix is
    partial late in the lap). The 9-dof NEES inside its 97.5 % bound (11.19; it was 11.3 before);
    horizontal RMSE within 1.15 x its PCRB."""
    from scipy.stats import chi2

    from aircraft.montecarlo.ins import InsRun, simulate
    from aircraft.world.field import Field
    from net.scenario import load

    fld = Field.from_scenario(load("seed003-text"))
    mo = Ellipse((15000.0, 0.0), (20000.0, 15000.0), 1000.0, 50.0, np.pi)
    res = simulate(fld, mo, preset("adis16480"), InsRun(runs=16, duration_s=1500.0, seed=5))
    k = res.t_s >= 1000.0
    yaw = res.nsq[:, k, 8].mean()
    assert 0.2 < yaw <= 3.0, yaw
    assert res.nees[:, k].mean() <= chi2.ppf(0.975, 9 * 16) / 16, res.nees[:, k].mean()
    ratio = np.sqrt(np.mean(res.rmse_h()[k] ** 2)) / np.sqrt(np.mean(res.pcrb_h()[k] ** 2))
    assert ratio < 1.15, ratio


# -- honest start (aircraft/navigator/ins_start.py) ------------------------------------------------------

def _start_world(M: int, t_start_s: float, seed: int):
    """Seed 003 field, ADIS16480, ellipse at 1000 m: the first 10 s window after ``t_start_s`` as the
    navigator receives it (pseudoranges with a drifting receiver clock, IMU increments), and the truth."""
    from aircraft.navigator.ins_start import StartConfig, radio_fix, start
    from aircraft.world import clock as wclock
    from aircraft.world.field import Field
    from net.scenario import load

    fld = Field.from_scenario(load("seed003-text"))
    mo = Ellipse((15000.0, 0.0), (20000.0, 15000.0), 1000.0, 50.0)
    pre = preset("adis16480")
    cm = wclock.ClockModel()
    tn = InsTuning.from_preset(pre, sigma_range_m=0.9, q_b=cm.q_b_m2_s, q_d=cm.q_d_m2_s3,
                               p0_clock_m=cm.b0_sigma_m, p0_drift_m_s=cm.d0_sigma_m_s)
    rng = np.random.default_rng(seed)
    cfg = StartConfig()
    n = int(round(cfg.window_s / tn.dt_s))
    t_e = t_start_s + n * tn.dt_s
    imu = ImuEmulator(pre, M, rng)
    g, a = imu.measure(*mo.increments(t_start_s, tn.dt_s, n))
    k = np.arange(int(round(cfg.window_s / 0.1)))
    sl = k % 8
    t_rx, r = fld.reception(mo, t_start_s + 0.1 * k, sl)
    clk = wclock.sample(cm, np.r_[t_rx, t_e], M, rng)
    rho = r[:, None] + clk[:-1, :, 0] + 0.9 * rng.standard_normal((t_rx.size, M))
    L = es.ErrorLayout()
    fix = radio_fix(t_rx, fld.stations_n[sl], None, rho.T, 0.81, t_e, 0.9, cfg, tn.q_b, tn.q_d)
    st = start(L, tn, fix, np.where(fix.llr() >= 0.0, 0, 1), g, a, t_e, cfg)  # one window decides at 1000 m
    pt, vt, Ct = (x[0] for x in fld.truth(mo, np.array([t_e])))
    up = fld.up_n
    e = np.zeros((M, L.n))  # true - nominal, in the filter's error convention
    e[:, L.P], e[:, L.V] = pt - st.p, vt - st.v
    e[:, L.ATT] = log_so3(Ct @ np.swapaxes(st.C, -1, -2))
    e[:, L.BA], e[:, L.BG] = imu.accel_gm, imu.gyro_gm
    e[:, L.BAC], e[:, L.BGC] = imu.accel_turn_on, imu.gyro_turn_on
    e[:, L.TILT] = (1.0 if up[2] > 0 else -1.0) * up[:2] - st.tau
    e[:, L.CLK] = clk[-1] - st.clock
    return st, e, L, np.linalg.norm(vt)


def _nees(e, P, sl):
    d = e[:, sl]
    Ps = P[:, sl][:, :, sl]
    return np.einsum("mi,mi->m", d, np.linalg.solve(Ps, d[..., None])[..., 0])


def test_start_from_a_moving_aircraft_matches_its_error_model():
    """The start on a banked aircraft at 43-54 m/s (seeded, 60 runs, two places on the ellipse): the
    position, velocity, clock and levelling errors match ``P0`` (mean NEES inside the 99.9 % band of
    its chi-square; levelling = the two horizontal attitude components); the heading is inside or
    below (its prior carries a crab angle the still-air world does not have); which way +Z points is
    found (the text's frame points down)."""
    from scipy.stats import chi2

    M = 60
    for t_start, seed in ((0.0, 21), (700.0, 22)):
        st, e, L, speed = _start_world(M, t_start, seed)
        assert speed > 40.0 and np.all(st.sign == -1.0)
        band = lambda dof: (chi2.ppf(0.0005, dof * M) / M, chi2.ppf(0.9995, dof * M) / M)  # noqa: E731
        for name, sl in (("p", L.P), ("v", L.V), ("clock", L.CLK)):
            dof = sl.stop - sl.start
            lo, hi = band(dof)
            nees = _nees(e, st.P0, sl).mean()
            assert lo < nees < hi, (t_start, name, nees, lo, hi)
        # levelling given the frame's tilt error (the tilt is one fixed draw of this world, 1.07 mrad
        # against its 5 mrad prior, so it is conditioned on rather than tested)
        lv, tl = slice(6, 8), L.TILT
        G = st.P0[:, lv, tl] @ np.linalg.inv(st.P0[:, tl, tl])
        Pc = st.P0[:, lv, lv] - G @ st.P0[:, tl, lv]
        d = e[:, lv] - np.einsum("mij,mj->mi", G, e[:, tl])
        nees = np.einsum("mi,mi->m", d, np.linalg.solve(Pc, d[..., None])[..., 0]).mean()
        lo, hi = band(2)
        assert lo < nees < hi, (t_start, "level | tilt", nees, lo, hi)
        assert _nees(e, st.P0, slice(8, 9)).mean() < band(1)[1]
        assert np.all(np.linalg.norm(e[:, :2], axis=1) < 4.0)
        # the start's levelling uses the fitted acceleration: the 17 mrad bank of the turn is not an error
        assert np.sqrt(np.mean(e[:, 6:8] ** 2)) < 0.012


def test_a_window_whose_two_fits_ended_on_one_side_gives_no_side_evidence():
    """Seen in 1 of 64 bench runs at 250 m: the fit started from the mirror guess crossed the plane and
    stopped in a poor local fit on the other side; its cost counted as the far side's (LLR 23.6 in one
    window, ten times the usual) and decided the wrong side. Such a window gives LLR 0, cannot end the
    test, and the next guess moves on from its one real fit."""
    from aircraft.navigator.ins_start import RadioFix, SideTest, StartConfig, moved_on

    x = np.zeros((2, 2, 11))
    x[:, 0, 0], x[:, 1, 0] = 1.0, 2.0
    x[:, :, 3] = 10.0  # 10 m/s along x
    fix = RadioFix(x, np.zeros((2, 2, 11, 11)), np.array([[98.4, 145.6], [98.4, 145.6]]),
                   separated=np.array([True, False]), valid=np.array([0, 1]))
    np.testing.assert_allclose(fix.llr(), [23.6, 0.0])
    sides = SideTest(StartConfig(decide_llr=10.0), 2)
    sides.llr = np.array([-20.0, -20.0])
    sides.add(fix)
    assert list(sides.decided()) == [False, False]  # run 0: -20 + 23.6 = 3.6; run 1: -20, unseparated
    sides.llr = np.array([30.0, 30.0])
    assert list(sides.decided()) == [True, False]  # the unseparated window cannot end the test
    g = moved_on(fix, np.array([0, 0]), 1.0)
    np.testing.assert_allclose(g[:, 0], [1.0 + 10.0, 2.0 + 10.0])  # run 1: its one real fit (slot 1)
    sub = fix.rows(slice(1, None))
    assert sub.x.shape == (1, 2, 11) and list(sub.separated) == [False]


def test_side_of_the_stations_plane_decided_over_windows_at_250_m():
    """The text's stations are 30-50 m out of plane: at 250 m one 10 s window cannot tell the aircraft's
    side of their plane from its mirror (some runs' |LLR| is below the decision level), the summed
    log-likelihood ratio of consecutive windows does, and picks the true side in every run."""
    from aircraft.navigator.ins_start import SideTest, StartConfig, moved_on, radio_fix
    from aircraft.world.field import Field
    from net.scenario import load

    fld = Field.from_scenario(load("seed003-text"))
    mo = Ellipse((15000.0, 0.0), (20000.0, 15000.0), 250.0, 50.0)
    cfg = StartConfig()
    M = 16
    rng = np.random.default_rng(31)
    k = np.arange(int(round(cfg.max_windows * cfg.window_s / 0.1)))
    sl = k % 8
    t_rx, r = fld.reception(mo, 0.1 * k, sl)
    rho = r[:, None] + 0.9 * rng.standard_normal((t_rx.size, M))  # a synchronized clock, for brevity
    sides = SideTest(cfg, M)
    guess, first = None, None
    for w in range(cfg.max_windows):
        t_e = (w + 1) * cfg.window_s
        j = (t_rx > t_e - cfg.window_s) & (t_rx <= t_e)
        fix = radio_fix(t_rx[j], fld.stations_n[sl[j]], None, rho[j].T, 0.81, t_e, 0.9, cfg, guess=guess)
        sides.add(fix)
        first = np.abs(sides.llr) if first is None else first
        if np.all(sides.decided()):
            break
        guess = moved_on(fix, sides.side(), cfg.window_s)
    assert np.any(first < cfg.decide_llr)
    # side 0 lies along the plane's normal with n_z > 0; the truth is on the side of physical up
    up = fld.up_n
    c = fld.stations_n.mean(axis=0)
    _, _, vt = np.linalg.svd(fld.stations_n - c)
    n = vt[2] if vt[2][2] >= 0 else -vt[2]
    true_side = 0 if (fld.truth(mo, np.array([t_e]))[0][0] - c) @ n >= 0 else 1
    assert (n @ up > 0) == (true_side == 0)
    assert np.all(sides.side() == true_side), sides.llr


def test_start_never_reads_truth(monkeypatch):
    """The navigator's start module imports nothing of the world (not even indirectly), and while it
    runs in the Monte Carlo harness every world-side truth accessor raises."""
    import subprocess
    import sys

    code = ("import sys, aircraft.navigator.ins_start; "
            "print(sorted(m for m in sys.modules if m.startswith(('aircraft', 'net', 'stations', 'larns'))))")
    mods = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT).stdout
    for bad in ("world", "montecarlo", "ins_core", "trajectory", "net.", "larns"):
        assert bad not in mods, (bad, mods)

    from aircraft.montecarlo import ins as mc_ins
    from aircraft.montecarlo.ins import InsRun, simulate
    from aircraft.world import motion as wmotion
    from aircraft.world.field import Field
    from net.scenario import load

    inside = {"start": False, "calls": 0}

    def guarded(fn):
        def run(*a, **k):
            inside["start"] = True
            inside["calls"] += 1
            try:
                return fn(*a, **k)
            finally:
                inside["start"] = False
        return run

    def guard(fn):
        def wrapped(*a, **k):
            assert not inside["start"], f"truth accessed during the start: {fn.__name__}"
            return fn(*a, **k)
        return wrapped

    monkeypatch.setattr(mc_ins, "start", guarded(mc_ins.start))
    monkeypatch.setattr(mc_ins, "radio_fix", guarded(mc_ins.radio_fix))
    for name in ("truth", "reception"):
        monkeypatch.setattr(Field, name, guard(getattr(Field, name)))
    for name in ("pva", "attitude", "increments"):
        monkeypatch.setattr(wmotion.Ellipse, name, guard(getattr(wmotion.Ellipse, name)))
    fld = Field.from_scenario(load("seed003-text"))
    mo = wmotion.Ellipse((15000.0, 0.0), (20000.0, 15000.0), 1000.0, 50.0)
    res = simulate(fld, mo, preset("adis16480"), InsRun(runs=2, duration_s=40.0, seed=3))
    # a radio fix per window, then the runs' start and the bound run's prior
    assert inside["calls"] == res.start_windows + 2 and res.t_s[0] > 10.0


# -- seed 003 fictitious stations ------------------------------------------------------------------------

def test_fictitious_stations_leave_ranges_unchanged():
    """Eqs. 8-11: with the exact acceleration, |r0 + v0 t_i - p~_i| equals the true range |r(t_i) - p_i|
    over a cycle of a banked, climbing ellipse."""
    m = Ellipse((15000.0, 0.0), (20000.0, 15000.0), 1000.0, 50.0, climb_amp_m=100.0, climb_period_s=60.0)
    dt = 0.001
    t0 = 123.4
    t = t0 + np.arange(0, 801) * dt
    p, v, a = m.pva(t)
    _, S = fict_kf.double_integral(a, dt)
    stations = np.array([[0, 0, 0], [30000, 0, 0], [15000, 12000, 0], [15000, -12000, 50.0]])
    idx = np.arange(0, 800, 100)
    for j, i in enumerate(idx):
        s = stations[j % 4]
        pf = fict_kf.fictitious_stations(s, S[i])
        r_f = np.linalg.norm(p[0] + v[0] * (t[i] - t0) - pf)
        r_t = np.linalg.norm(p[i] - s)
        assert abs(r_f - r_t) < 1e-6
    # the uniform-motion model alone (eq. 5) is off by the manoeuvre
    assert np.linalg.norm(p[700] - (p[0] + v[0] * 0.7)) > 1e-3


def test_paper_filter_steady_state_matches_spec_table():
    """Seed spec sec. 2.6: DWNA, sigma_a = 0.015, T = 0.8 s, per-axis measurement sigma 1.0 / 4.0 m
    gives a steady-state per-axis sigma of 0.36 / 1.04 m."""
    for sm, expect in ((1.0, 0.36), (4.0, 1.04)):
        R = np.broadcast_to(sm**2 * np.eye(3), (400, 3, 3))
        P = fict_kf.covariance_curves(R, 0.8)
        assert np.sqrt(P[-1, 0, 0]) == pytest.approx(expect, abs=0.006)


# -- boundaries ----------------------------------------------------------------------------------------

def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            mod = node.module or ""
            out.add("." * node.level + mod)
    return out


def test_navigator_never_imports_world():
    files = sorted((ROOT / "aircraft" / "navigator").rglob("*.py"))
    assert files
    for f in files:
        for name in _imports(f):
            assert "world" not in name, f"{f.name} imports {name}"
            assert "montecarlo" not in name, f"{f.name} imports {name}"


def test_nav_depends_on_nothing_of_ours():
    for f in sorted((ROOT / "nav").glob("*.py")):
        for name in _imports(f):
            assert not name.split(".")[0] in ("aircraft", "stations", "larns", "net"), f"{f.name} imports {name}"


# -- live process core ---------------------------------------------------------------------------------

def test_ins_aircraft_core_flies_on_nav_broadcasts():
    """The live core on seed003-text: 60 s of TDMA nav broadcasts (true positions in ``phy``, the
    stations' estimates in ``msg``); the core listens for its start window (truth records only, no
    estimate), then starts in flight; every IMU step runs, estimates validate and stay near the truth."""
    from aircraft.config import from_scenario
    from aircraft.ins_core import InsAircraftCore
    from net import messages as M
    from net.scenario import load

    sc = load("seed003-text")
    ac = from_scenario(sc)
    core = InsAircraftCore(sc, ac, "ac1", np.random.default_rng(1), imu="adis16480")
    rng = np.random.default_rng(2)
    last, statuses = None, []
    window = core.start_cfg.window_s
    for k in range(600):
        t = k * sc.tdma.slot_s
        j = k % 8
        if j >= len(sc.pos_m):
            continue
        truth = sc.pos_m[j]
        msg = {"kind": "nav", "src": j + 1, "state": "frame", "pos_m": (truth + rng.normal(0, 0.05, 3)).tolist(),
               "cov_m2": (0.05**2 * np.eye(3)).tolist()}
        out = to_msgs(core.on_nav(msg, {"pos_m": truth.tolist(), "t_true_s": t}))
        core.advance_to(t + 0.05)
        started = t >= window - 1e-9  # the first broadcast received after the window starts the EKF
        for m in out:  # what the navigator is doing, once per second and at every change
            if m["kind"] == "ac_status":
                statuses.append(M.validate_msg(m)["state"])
        out = [m for m in out if m["kind"] != "ac_status"]
        assert [m["kind"] for m in out] == (["ac_truth", "ac_estimate"] if started else ["ac_truth"]), t
        M.validate_msg(out[0])
        if started:
            last = M.validate_msg(out[1])
    assert core.stats["start_measurements"] >= 90
    assert statuses[0] == "waiting" and statuses[-1] == "tracking" and "waiting" not in statuses[statuses.index("tracking"):]
    assert core.imu_steps == int(np.floor((599 * 0.1 + 0.05) / core.tn.dt_s + 1e-9))
    p, _, _ = core.truth_n(last["t_s"])
    assert np.linalg.norm(np.asarray(last["pos_m"][:2]) - p[:2]) < 5.0
    assert {"roll_rad", "pitch_rad", "yaw_rad"} <= set(last["extra"])


def test_ins_core_is_independent_of_loop_timing():
    """Exact re-flight: the same broadcasts with different advance_to patterns give bit-identical
    estimates (the IMU is emulated in fixed, separately seeded blocks)."""
    from aircraft.config import from_scenario
    from aircraft.ins_core import InsAircraftCore
    from net.scenario import load

    sc = load("seed003-text")
    ac = from_scenario(sc)
    outs = []
    for pattern in (0.013, 0.37):
        core = InsAircraftCore(sc, ac, "ac1", np.random.default_rng(9), seed=5)
        got = []
        t_loop = 0.0
        for k in range(200):
            t = k * sc.tdma.slot_s
            j = k % 8
            while t_loop + pattern < t:  # the node's loop, integrating behind fleet time
                t_loop += pattern
                core.advance_to(t_loop)
            msg = {"kind": "nav", "src": j + 1, "state": "surveying", "pos_m": sc.pos_m[j].tolist(),
                   "cov_m2": np.zeros((3, 3)).tolist()}
            got += [o for o in to_msgs(core.on_nav(msg, {"pos_m": sc.pos_m[j].tolist(), "t_true_s": t}))
                    if o["kind"] == "ac_estimate"]
        outs.append(got)
    assert len(outs[0]) == len(outs[1]) > 90  # estimates after the 10 s start window
    assert all(a == b for a, b in zip(*outs))


@pytest.mark.slow
def test_bench_ins_quick_writes_the_keys(tmp_path):
    """`larns bench ins --quick` runs end to end and writes the issue's JSON keys."""
    import json

    from larns.cli import main

    js = tmp_path / "ins.json"
    assert main(["bench", "ins", "--quick", "--no-tilt-cost", "--no-speed", "--json", str(js),
                 "--png", str(tmp_path / "ins.png")]) == 0
    d = json.loads(js.read_text())
    for k in ("paper_fig6_max_sigma_h_m", "paper_fig7_max_sigma_v_m"):
        assert set(d[k]) == {"250", "500", "1000"}
    assert set(d["ins_rmse_h_m"]) == set(d["ins_pcrb_h_m"]) == {"1000"}
    assert set(d["outage_drift_h_m"]) == {"10", "30", "60"}
    assert d["speed"]["batched_x_real_time"] > 0
    assert (tmp_path / "ins.png").stat().st_size > 10_000
