"""The triad (seed 002): orbits, geodesy, Jacobians, linear-case equivalence, NEES, rising/setting
satellites, the field tie, the baro."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from aircraft.navigator import field_tie as ft
from aircraft.navigator.ins_ekf import BaroAltitude, InsTuning, PositionComponent, Pseudorange
from aircraft.navigator.triad_ekf import TRIAD_LAYOUT, Epoch, PaperFilter, PaperTuning, TriadEkf, paper_p0
from aircraft.world import baro as wbaro
from aircraft.world.imu import preset
from nav import errorstate as es
from nav import orbits
from nav.constellation import EnuFrame, gps_like, satellite_elevation_deg
from nav.kalman import kf_update
from nav.strapdown import G0_M_S2

ROOT = Path(__file__).resolve().parents[2]
FRAME = EnuFrame(55.75, 37.62, 0.0)


def _tuning(**kw):
    return InsTuning.from_preset(preset("navigation").with_(rate_hz=10.0), max_prop_s=1.0, **kw)


def _filter(M=1, p=(0.0, 0.0, 10_000.0), P0=None, cls=TriadEkf, t0=3000.0):
    tn = _tuning()
    L = TRIAD_LAYOUT
    P = es.ErrorLayout(turn_on=True, tilt=False, clock=True, baro=True)
    from aircraft.navigator.ins_ekf import initial_covariance

    P0 = initial_covariance(P, tn, np.zeros(2), 1.0) if P0 is None else P0
    pp = np.tile(np.asarray(p, float), (M, 1))
    return TriadEkf(tn, gps_like(), FRAME, pp, np.zeros((M, 3)), np.tile(np.eye(3), (M, 1, 1)), np.zeros((M, 2)),
                    P0, 3.0, 10.0, t0), tn, L


def _rest_increments(M, dt):
    """Perfect IMU at rest, level, body = ENU: no rotation, specific force +g up."""
    return np.zeros((M, 3)), np.tile([0.0, 0.0, G0_M_S2 * dt], (M, 1))


# --- orbits and geodesy ----------------------------------------------------------------------------


def test_kepler_hand_checked_cases():
    a = orbits.WGS84_A_M + 20_180e3
    T = 2 * np.pi * np.sqrt(a**3 / orbits.MU_EARTH_M3_S2)
    # polar circular orbit, node on +X: a quarter period later the satellite is over the pole
    p, v = orbits.kepler_eci(a, 0.0, np.pi / 2, 0.0, 0.0, 0.0, np.array([0.0, T / 4]))
    assert np.allclose(p[0], [a, 0, 0], atol=1e-3) and np.allclose(p[1], [0, 0, a], atol=1e-2)
    assert np.allclose(v[0], [0, 0, np.sqrt(orbits.MU_EARTH_M3_S2 / a)], atol=1e-6)
    # e = 0.5, equatorial: perigee a (1 - e) on +X at M = 0, apogee a (1 + e) on -X half a period later
    p, _ = orbits.kepler_eci(a, 0.5, 0.0, 0.0, 0.0, 0.0, np.array([0.0, T / 2]))
    assert np.allclose(p[0], [0.5 * a, 0, 0], atol=1e-3) and np.allclose(p[1], [-1.5 * a, 0, 0], atol=1e-2)
    # ECEF: an equatorial inertial point at t is rotated back by the Earth's turn
    t = 3600.0
    pe, _ = orbits.eci_to_ecef(np.array([a, 0.0, 0.0]), np.zeros(3), t)
    th = orbits.OMEGA_EARTH_RAD_S * t
    assert np.allclose(pe, [a * np.cos(th), -a * np.sin(th), 0.0], atol=1e-6)


def test_geodetic_round_trip():
    p = np.array([[1234.5, -40_000.0, 10_000.0], [-80_000.0, 65_000.0, 35.0]])
    lat, lon, h = FRAME.to_geodetic(p)
    assert np.allclose(FRAME.from_geodetic(lat, lon, h), p, atol=1e-6)
    import pymap3d

    e = np.stack(pymap3d.geodetic2ecef(lat, lon, h), axis=-1)
    assert np.allclose(FRAME.from_ecef(e), p, atol=1e-6)
    # the origin's up is the local vertical: a satellite straight above has 90 deg elevation
    assert satellite_elevation_deg(np.array([0, 0, 2e7]), np.zeros(3)) == pytest.approx(90.0)


# --- Jacobians ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("model", ["range", "baro"])
def test_pseudorange_and_baro_jacobians_match_finite_differences(model):
    ekf, tn, L = _filter()
    ekf.clk[:] = [[30.0, 0.4]]
    ekf.bh[:] = 7.0
    for _ in range(5):
        ekf.imu(*_rest_increments(1, tn.dt_s))
    t_rx = ekf.t_s - 0.04  # inside the last IMU step: exercises the -T terms
    m = Pseudorange(np.array([20e3, -15e3, 40.0]), t_rx) if model == "range" else BaroAltitude(np.array([0, 0, 1.0]), t_rx, 12.0)
    _, H = m.predict(ekf)
    eps = 1e-3
    Hn = np.zeros_like(H)
    for i in range(L.n):
        d = np.zeros((1, L.n))
        d[0, i] = eps
        state = (ekf.p.copy(), ekf.v.copy(), ekf.v_prev.copy(), ekf.C.copy(), ekf.clk.copy(), ekf.bh.copy())
        ekf.inject(d)
        hp, _ = m.predict(ekf)
        ekf.p, ekf.v, ekf.v_prev, ekf.C, ekf.clk, ekf.bh = (x.copy() for x in state)
        ekf.inject(-d)
        hm, _ = m.predict(ekf)
        ekf.p, ekf.v, ekf.v_prev, ekf.C, ekf.clk, ekf.bh = state
        Hn[0, i] = (hp - hm)[0] / (2 * eps)
    assert np.allclose(H, Hn, atol=1e-6), np.c_[H[0], Hn[0]]


# --- linear case -------------------------------------------------------------------------------------


def test_triad_update_equals_linear_kf_batch():
    """Linear measurements (three position axes and the baro), one epoch, diagonal R: the triad's
    sequential scalar Joseph updates equal one batch Kalman update (nav.kalman.kf_update)."""
    rng = np.random.default_rng(5)
    ekf, tn, L = _filter()
    A = rng.standard_normal((L.n, L.n)) * 0.1
    P0 = ekf.P[0] + A @ A.T  # a correlated prior
    ekf.P[0] = P0
    p0, bh0 = ekf.p.copy(), ekf.bh.copy()
    t = ekf.t_s
    models = [PositionComponent(e, t) for e in np.eye(3)] + [BaroAltitude(np.array([0, 0, 1.0]), t, 0.0)]
    R = np.array([4.0, 9.0, 2.0, tn.sigma_baro_m**2])
    z = np.array([3.0, -2.0, 10_001.0, 10_030.0])
    H = np.zeros((4, L.n))
    pred = np.zeros(4)
    for i, m in enumerate(models):
        pi, Hi = m.predict(ekf)
        H[i], pred[i] = Hi[0], pi[0]
    for i, m in enumerate(models):
        ekf.update(m, z[i:i + 1], R[i])
    dx, P, _, _ = kf_update(np.zeros(L.n), P0, z - pred, H, np.diag(R))
    assert np.allclose(ekf.p[0], p0[0] + dx[L.P], atol=1e-9)
    assert np.allclose(ekf.bh[0], bh0[0] + dx[L.BARO][0], atol=1e-9)
    assert np.allclose(ekf.P[0], P, atol=1e-9 * np.abs(P).max())


def test_paper_filter_propagation_is_the_spec_closed_form():
    """Spec sec. 1.4: per axis [[1, T, Ta^2 (e^-T/Ta - 1 + T/Ta)], [0, 1, Ta (1 - e^-T/Ta)], [0, 0, e^-T/Ta]]."""
    from aircraft.navigator.triad_ekf import paper_matrices

    pt, tn = PaperTuning(tc_a_s=300.0), _tuning()
    A, Q = paper_matrices(pt, tn)
    T, Ta = 1.0, 300.0
    Phi, _ = es.discretize(A, Q, T)
    e = np.exp(-T / Ta)
    exact = np.array([[1, T, Ta**2 * (e - 1 + T / Ta)], [0, 1, Ta * (1 - e)], [0, 0, e]])
    assert np.allclose(Phi[np.ix_([0, 3, 8], [0, 3, 8])], exact, atol=1e-9)
    assert np.allclose(Phi[6:8, 6:8], [[1, T], [0, 1]])


# --- satellites rising and setting -------------------------------------------------------------------


def _sky_epoch(ekf, truth_p, t, ids, rng, sigma=3.0):
    """Noisy pseudoranges of ``ids`` from a receiver at ``truth_p`` with zero clock (test-side truth)."""
    from aircraft.navigator.triad_ekf import broadcast_corrections_m, satellites_at_transmission

    rho = np.full((ekf.M, len(ids)), 2.2e7)
    for _ in range(3):  # consistent with the receiver's own transmission-time model
        s = satellites_at_transmission(ekf.alm, FRAME, ids, t, rho, np.zeros(ekf.M))
        r = np.linalg.norm(truth_p - s, axis=-1)
        rho = r + broadcast_corrections_m(ekf.alm, ids, t, s, np.broadcast_to(truth_p, (ekf.M, 3)))
    return rho + sigma * rng.standard_normal(rho.shape)


def _visible(t, p, mask=10.0):
    alm = gps_like()
    e, _ = alm.ecef(t)
    el = satellite_elevation_deg(FRAME.from_ecef(e), p)
    order = np.argsort(-el)
    return order[el[order] >= mask], el


def test_masked_satellite_changes_nothing_and_is_counted():
    truth = np.array([0.0, 0.0, 10_000.0])
    ids, el = _visible(3000.0, truth)
    mid = 0.5 * (el[ids[-1]] + el[ids[-2]])  # between the two lowest satellites
    out = []
    for mask, sats in ((mid, ids[:-1]), (mid, ids)):
        rng = np.random.default_rng(1)
        ekf, tn, _ = _filter()
        ekf.mask_deg = mask
        rho_all = _sky_epoch(ekf, truth, 3000.0, ids, rng)
        rho = rho_all[:, [list(ids).index(s) for s in sats]]
        out.append((ekf.epoch(Epoch(3000.0, sats, rho)), ekf.p.copy(), ekf.P.copy()))
    assert out[1][0]["sat_masked"] == 1 and out[0][0]["sat_masked"] == 0, (out[0][0], out[1][0])
    assert out[0][0]["sat_used"] == out[1][0]["sat_used"] == len(ids) - 1
    assert np.array_equal(out[0][1], out[1][1]) and np.array_equal(out[0][2], out[1][2])


def test_satellite_setting_mid_run_changes_the_set_without_a_state_jump():
    """A static receiver with a perfect IMU tracks the visible sky; at t = 30 s one satellite sets
    (removed from the epochs): the position step at that epoch is no larger than the ordinary steps
    around it, and the state dimension and clock are continuous."""
    truth = np.array([0.0, 0.0, 10_000.0])
    ids, _ = _visible(3000.0, truth)
    rng = np.random.default_rng(3)
    ekf, tn, _ = _filter(p=truth + [20.0, -15.0, 10.0])
    n = int(round(1.0 / tn.dt_s))
    steps, used = [], []
    for k in range(1, 61):
        for _ in range(n):
            ekf.imu(*_rest_increments(1, tn.dt_s))
        t = 3000.0 + k
        sats = ids if k < 30 else ids[:-1]
        p_before = ekf.p.copy()
        s = ekf.epoch(Epoch(t, sats, _sky_epoch(ekf, truth, t, sats, rng), baro_m=np.array([truth[2]])))
        steps.append(float(np.linalg.norm(ekf.p - p_before)))
        used.append(s["sat_used"])
    assert used[28] == len(ids) and used[29] == len(ids) - 1
    ordinary = np.array(steps[10:28] + steps[31:])
    assert steps[29] < 4.0 * np.sqrt(np.mean(ordinary**2)) + 0.05
    assert np.linalg.norm(ekf.p[0] - truth) < 5.0


# --- Monte Carlo consistency -------------------------------------------------------------------------


def test_triad_nees_seeded():
    """4 satellites + baro, 24 runs, 120 s: the run-mean position NEES (3 dof), averaged over time, is
    inside a band of the chi-square mean (time-correlated: a looser band than one epoch's) and the
    RMS radial error is within 1.3x the posterior CRLB."""
    from aircraft.montecarlo.triad import TriadCase, simulate

    r = simulate(TriadCase(n_sv=4, duration_s=120.0, runs=24, seed=11, paper_filter=True))
    nees = r.nees_pos[:, 20:].mean()
    assert 1.5 < nees < 4.5, nees
    rms = np.sqrt(np.mean(np.sum(r.err_m[:, 20:] ** 2, axis=-1)))
    pcrb = np.sqrt(np.mean(np.trace(r.pcrb_pos[20:], axis1=-2, axis2=-1)))
    assert rms < 1.3 * pcrb, (rms, pcrb)
    assert r.nees_paper[:, 20:].mean() < 6.0


# --- tie, baro, boundaries ---------------------------------------------------------------------------


def test_field_tie_recovers_the_frame_and_its_covariance():
    rng = np.random.default_rng(7)
    from nav.geometry import to_network_frame

    g = np.array([[50e3, 50e3, 30.0], [-50e3, -50e3, 10.0], [50e3, -50e3, 50.0], [-50e3, 50e3, 20.0]])
    pn, _, _ = to_network_frame(g, z_ref=3)
    exact = ft.tie(pn, 0.5, np.array([0, 1, 2]), g[:3], np.array([0.05, 0.05, 0.1]))
    assert np.allclose(exact.stations_m, g, atol=1e-6)
    errs = []
    for _ in range(400):
        t = ft.tie(pn + 0.5 * rng.standard_normal(pn.shape), 0.5, np.array([0, 1, 2]),
                   g[:3] + np.array([0.05, 0.05, 0.1]) * rng.standard_normal((3, 3)), np.array([0.05, 0.05, 0.1]))
        errs.append(t.stations_m[3] - g[3])
    emp = np.cov(np.array(errs).T)
    # the linearized covariance of the untied station matches the Monte Carlo to sampling accuracy
    assert np.trace(emp) / np.trace(exact.cov_m2[3]) == pytest.approx(1.0, abs=0.2)


def test_baro_bias_is_gauss_markov():
    rng = np.random.default_rng(2)
    m = wbaro.BaroModel(sigma_m=0.0, sigma_bias_m=20.0, tc_s=600.0)
    t = np.arange(0.0, 601.0, 1.0)
    b = wbaro.sample(m, np.zeros(t.size), t, 4000, rng)
    assert np.std(b[-1]) == pytest.approx(20.0, rel=0.05)
    rho = np.corrcoef(b[0], b[-1])[0, 1]
    assert rho == pytest.approx(np.exp(-1.0), abs=0.05)


def test_triad_navigator_never_imports_world():
    for name in ("triad_ekf.py", "field_tie.py"):
        tree = ast.parse((ROOT / "aircraft" / "navigator" / name).read_text())
        for node in ast.walk(tree):
            mods = []
            if isinstance(node, ast.ImportFrom):
                mods = [node.module or ""]
            elif isinstance(node, ast.Import):
                mods = [a.name for a in node.names]
            for nm in mods:
                assert "world" not in nm and "montecarlo" not in nm, (name, nm)


def test_station_state_jacobian_and_injection():
    """The ranged station's position-error columns are ``-u`` (finite differences through the filter's
    own injection), and the station prior is the tie's joint covariance."""
    from aircraft.navigator.triad_ekf import StationPseudorange

    g = np.array([[50e3, 50e3, 30.0], [-50e3, -50e3, 10.0]])
    C = np.kron(np.eye(2), np.diag([0.2, 0.3, 0.4]))
    C[0, 3] = C[3, 0] = 0.05
    tie = ft.FieldTie(g, np.stack([C[:3, :3], C[3:, 3:]]), np.eye(3), np.zeros(3), C)
    tn = _tuning()
    from aircraft.navigator.ins_ekf import initial_covariance

    P0 = initial_covariance(TRIAD_LAYOUT, tn, np.zeros(2), 1.0)
    ekf = TriadEkf(tn, gps_like(), FRAME, [[0.0, 0.0, 1e4]], np.zeros((1, 3)), np.eye(3)[None], np.zeros((1, 2)),
                   P0, stations=tie)
    L = ekf.L
    assert L.n == TRIAD_LAYOUT.n + 6 and np.allclose(ekf.P[0, L.base_n:, L.base_n:], C)
    m = StationPseudorange(1, ekf.t_s)
    h0, H = m.predict(ekf)
    for i in range(L.base_n, L.n):
        d = np.zeros((1, L.n))
        d[0, i] = 1e-3
        gs0, p0 = ekf.gs.copy(), ekf.p.copy()
        ekf.inject(d)
        h1, _ = m.predict(ekf)
        ekf.gs, ekf.p = gs0, p0
        assert (h1 - h0)[0] / 1e-3 == pytest.approx(H[0, i], abs=1e-6)
    assert np.allclose(H[0, L.GS(1)], -H[0, L.P]) and np.allclose(H[0, L.GS(0)], 0.0)


def test_window_fix_start_is_consistent():
    """The start (constant-velocity window fix over 10 s of the full sky): its error over 200 seeded
    draws is consistent with its own covariance (mean NEES of [p, v, b, d], 8 dof, within 15 %)."""
    from aircraft.navigator.triad_ekf import broadcast_corrections_m, initial_fix, satellites_at_transmission

    rng = np.random.default_rng(9)
    M, t = 200, 3000.0 + np.arange(11.0)
    p0, v = np.array([-50e3, 0.0, 1e4]), np.array([200.0, 0.0, 0.0])
    b0, d = 40.0, 0.3
    alm = gps_like()
    ids, _ = _visible(t[-1], p0 + 10 * v)
    ekf, _, _ = _filter(M=M)
    rho = np.empty((M, t.size, ids.size))
    for k, tk in enumerate(t):
        pk = p0 + v * (tk - t[0])
        r = np.full((M, ids.size), 2.2e7)
        for _ in range(3):
            s = satellites_at_transmission(alm, FRAME, ids, tk, r, np.zeros(M))
            r = np.linalg.norm(pk - s, axis=-1)
        corr = broadcast_corrections_m(alm, ids, tk, s, np.broadcast_to(pk, (M, 3)))
        rho[:, k] = r + corr + b0 + d * (tk - t[-1]) + 3.0 * rng.standard_normal((M, ids.size))
    x, cov, cost = initial_fix(alm, FRAME, t, ids, rho, 3.0, t[-1])
    truth = np.r_[p0 + v * (t[-1] - t[0]), v, b0, d]
    e = x - truth
    nees = np.einsum("mi,mi->m", e, np.linalg.solve(cov, e[..., None])[..., 0])
    assert nees.mean() == pytest.approx(8.0, rel=0.15), nees.mean()
    assert np.sqrt(np.trace(cov[0, :3, :3])) < 5.0
