"""Ground vehicle (seed 004): map routes, truth, filters, constellation."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import numpy as np
import pytest

from nav import orbits
from nav.constellation import glonass_like, gps_like
from vehicle import sim
from vehicle.navigator.cdekf import FreeFilter, Intensities, MapFilter, _Base
from vehicle.route import great_circle_route, load_route, route_from_geojson, straight_route
from vehicle.world import truth as wt

ROOT = Path(__file__).resolve().parents[2]
PAPER_PTS = [(47.23, 39.72), (47.40, 39.80)]


@pytest.fixture(scope="module")
def route():
    return great_circle_route(PAPER_PTS, 100.0, [20.0])


@pytest.fixture(scope="module")
def short_truth(route):
    dt, N = 0.01, 1000
    plan = wt.speed_plan(route)
    tg = np.arange(N + 1) * dt
    return dt, N, wt.sample(route, plan, tg), wt.sample(route, plan, (np.arange(N) + 0.5) * dt)


# ----------------------------------------------------------------------------------------- routes
def test_route_constants_reproduce_endpoints_spec_check():
    """Spec appendix A: 47.2 N 39.7 E -> 55.75 N 37.6 E at R_E + 100 m reproduce both endpoints."""
    r = great_circle_route([(47.2, 39.7), (55.75, 37.6)], 100.0)
    seg = r.segments[0]
    for pt in (seg.A, seg.B):
        p, _, _ = r.pos(np.array([pt[1]]), np.array([0]))
        assert np.max(np.abs(p[0] - pt)) < 1e-6
    assert abs(seg.a0**2 - (1 + seg.P**2)) < 1e-12
    assert abs(seg.a1 - seg.r**2 / (1 + seg.P**2)) < 1e-3


def test_route_derivatives_coefficient_one_and_speed(route):
    """dp/deta by central differences matches eq. 3 with coefficient 1 (not the paper's 2)."""
    seg = route.segments[0]
    k = np.array([0])
    eta = np.array([0.5 * (seg.A[1] + seg.B[1])])
    p, dp, ddp = route.pos(eta, k)
    h = 1.0
    fd = (route.pos(eta + h, k)[0] - route.pos(eta - h, k)[0]) / (2 * h)
    fdd = (route.pos(eta + h, k)[1] - route.pos(eta - h, k)[1]) / (2 * h)
    assert np.allclose(dp, fd, rtol=1e-7, atol=1e-9)
    assert np.allclose(ddp, fdd, rtol=1e-5, atol=1e-12)
    sf, dsf = route.speed_factor_d(eta, k)
    assert np.isclose(sf[0], np.linalg.norm(dp[0]))
    fds = (route.speed_factor(eta + h, k) - route.speed_factor(eta - h, k)) / (2 * h)
    assert np.isclose(dsf[0], fds[0], rtol=1e-5)
    # the paper's variant (factor 2) would not match
    s = np.sqrt(seg.a1 - eta**2)
    wrong = seg.cP0 * seg.P + 2 * seg.sP0 * seg.a0 * eta / s
    assert not np.isclose(wrong[0], fd[0, 0], rtol=1e-3)


def test_pseudorange_theta_form_equals_direct(route):
    """H_zR on the great circle (Theta1..3, spec 3.5) equals the direct range."""
    seg = route.segments[0]
    sat = orbits.greenwich_from_ecef(glonass_like().ecef(0.0)[0][3])
    eta = np.linspace(seg.A[1], seg.B[1], 7)
    p, _, _ = route.pos(eta, np.zeros(7, int))
    xc, yc, zc = sat
    th1 = xc**2 + yc**2 + zc**2 + seg.r**2
    th2 = -2 * (xc * seg.cP0 * seg.P + yc + zc * seg.sP0 * seg.P)
    th3 = 2 * (xc * seg.sP0 - zc * seg.cP0) * seg.a0
    h = np.sqrt(th1 + th2 * eta + th3 * np.sqrt(seg.a1 - eta**2))
    assert np.allclose(h, np.linalg.norm(sat - p, axis=-1), rtol=1e-9)


def test_vertex_and_equator_refused():
    with pytest.raises(ValueError, match="vertex"):
        great_circle_route([(50.0, 0.0), (50.0, 60.0)], 0.0)  # an east-west arc crosses its vertex
    with pytest.raises(ValueError, match="equatorial"):
        great_circle_route([(0.0, 0.0), (0.0, 10.0)], 0.0, geodetic=False)


def test_route_files(tmp_path):
    toml = tmp_path / "r.toml"
    toml.write_text('[route]\nkind = "great_circle"\nheight_m = 50.0\n'
                    'points_deg = [[47.23, 39.72], [47.30, 39.75], [47.35, 39.85]]\nspeeds_m_s = [20.0, 10.0]\n')
    r = load_route(toml)
    assert r.n_segments == 2 and r.speeds_m_s == [20.0, 10.0]
    gj = {"type": "Feature", "properties": {"speeds_m_s": [15.0, 12.0]},
          "geometry": {"type": "LineString", "coordinates": [[39.72, 47.23, 50.0], [39.75, 47.30, 50.0], [39.85, 47.35, 50.0]]}}
    (tmp_path / "r.geojson").write_text(json.dumps(gj))
    r2 = load_route(tmp_path / "r.geojson")
    assert np.allclose(r2.segments[1].B, r.segments[1].B)
    with pytest.raises(ValueError, match="speeds"):
        route_from_geojson({**gj, "properties": {"speeds_m_s": [1.0]}})
    with pytest.raises(ValueError, match="points_deg"):
        (tmp_path / "bad.toml").write_text('[route]\nkind = "great_circle"\n')
        load_route(tmp_path / "bad.toml")


# ----------------------------------------------------------------------------------------- truth
def test_truth_kinematics_consistent(short_truth, route):
    dt, N, tr, _ = short_truth
    v_fd = (tr.p_g[2:] - tr.p_g[:-2]) / (2 * dt)
    assert np.max(np.abs(v_fd - tr.v_g[1:-1])) < 1e-6
    C = tr.C_gb
    W = np.einsum("tji,tjk->tik", C[1:-1], (C[2:] - C[:-2]) / (2 * dt))
    assert np.isclose(W[5, 0, 2], 20.0 / route.segments[0].r, rtol=1e-6)  # pitch rate s'/r about body y
    assert np.allclose(np.einsum("tij,tkj->tik", C, C), np.eye(3), atol=1e-12)


def test_multisegment_truth_stops_and_turns():
    r = great_circle_route([(47.23, 39.72), (47.26, 39.74), (47.28, 39.70)], 100.0, [15.0, 8.0])
    plan = wt.speed_plan(r, v_start_m_s=0.0, turn_s=10.0)
    t = np.arange(0.0, plan[-1].t0 + 5.0, 0.05)
    tr = wt.sample(r, plan, t)
    assert set(np.unique(tr.seg)) == {0, 1}
    assert tr.speed.max() <= 15.0 + 1e-9 and np.any(tr.speed == 0.0)
    assert np.allclose(tr.p_g[-1], r.segments[-1].B, atol=1e-6)  # stops at the last node
    assert np.max(np.abs(np.diff(tr.p_g, axis=0))) < 15.0 * 0.05 + 1e-6  # continuous through the node
    turn = [ph for ph in plan if ph.turn != 0.0]
    assert len(turn) == 1
    # during the turn the yaw rate integrates to the heading change
    m = (t >= turn[0].t0) & (t < turn[0].t1)
    assert np.isclose(np.trapezoid(tr.w_ib_b[m, 2] - np.einsum("tji,j->ti", tr.C_gb[m], orbits.OMEGA_VEC_G)[:, 2], t[m]),
                      turn[0].turn, rtol=2e-2)


# ----------------------------------------------------------------------------------------- filters
def _propagate_noise_free(case, short_truth):
    dt, N, tr, tm = short_truth
    x0 = sim.true_state(case, tr, 0)[None]
    q = Intensities(0.0, 0.0, 1.0)
    if case.filter == "map":
        f = MapFilter(case.route, x0, np.zeros((1, 11, 11)), np.zeros(1, int), q, odometer=False)
    else:
        f = FreeFilter(x0, np.zeros((1, 15, 15)), q, odometer=False)
    for i in range(N):
        f.step(i * dt, dt, tm.w_ib_b[i][None], tm.f_b[i][None], None)
    return f, sim.true_state(case, tr, N)


def test_reduced_model_matches_full_model_on_great_circle(route, short_truth):
    """Noise-free IMU: the 11-state and the 15-state models both reproduce the truth, so they agree."""
    fm, xm = _propagate_noise_free(sim.Case(route=route, runs=1), short_truth)
    ff, xf = _propagate_noise_free(sim.Case(route=route, runs=1, filter="free"), short_truth)
    assert np.max(np.abs(fm.x[0] - xm)[:9]) < 1e-12
    assert abs(fm.x[0, 9] - xm[9]) < 1e-6 and abs(fm.x[0, 10] - xm[10]) < 1e-8
    assert np.max(np.abs(ff.x[0] - xf)) < 1e-6
    pm, vm = fm.pos_vel(10.0)
    pf, vf = ff.pos_vel(10.0)
    assert np.allclose(pm, pf, atol=1e-5) and np.allclose(vm, vf, atol=1e-7)


def _num_jac(fun, x, eps):
    cols = []
    for i in range(x.size):
        d = np.zeros_like(x)
        d[i] = eps[i]
        cols.append((fun(x + d) - fun(x - d)) / (2 * eps[i]))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("kind", ["map", "free", "map_clock"])
def test_jacobians_vs_finite_differences(route, short_truth, kind):
    """F from the covariance equation (FP with P = I) and the radio H against central differences."""
    dt, N, tr, tm = short_truth
    clock = kind == "map_clock"
    case = sim.Case(route=route, runs=1, filter="free" if kind == "free" else "map", clock_states=clock)
    x = sim.true_state(case, tr, 300)
    if clock:
        x = np.concatenate([x, [30.0, 0.5]])
    n = x.size
    q = Intensities(0.0, 0.0, 1.0, 0.0, 0.0)
    Cls = (lambda x_, P_: MapFilter(route, x_, P_, np.zeros(1, int), q, clock=clock, odometer=False)) \
        if kind != "free" else (lambda x_, P_: FreeFilter(x_, P_, q, odometer=False))
    f = Cls(x[None], np.eye(n)[None])
    f._Qd = np.zeros((1, 9, 9))
    w, fb, t = tm.w_ib_b[300][None], tm.f_b[300][None], 3.0
    # recover F column by column from dP/dt = F P + P F^T with P = e_i e_last^T (no noise, no odometer)
    F = np.zeros((n, n))
    for i in range(n):
        P = np.zeros((1, n, n))
        P[0, i, n - 1] = 1.0
        _, Pd = f.deriv(t, x[None], P, w, fb, None)
        F[:, i] = Pd[0, :, n - 1]
        F[n - 1, i] -= 0.5 * Pd[0, n - 1, n - 1]
    _, Ps = f.deriv(t, x[None], np.zeros((1, n, n)), w, fb, None)
    eps = np.r_[np.full(9, 1e-6), np.full(n - 9, 1e-3)]
    J = _num_jac(lambda y: f.deriv(t, y[None], np.zeros((1, n, n)), w, fb, None)[0][0], x, eps)
    assert np.allclose(F, J, atol=1e-7 * max(1.0, np.abs(J).max()))
    assert np.allclose(Ps, 0.0)
    # measurement Jacobians: pseudorange and Doppler to two satellites
    pe, ve = glonass_like().ecef(t)
    sp, sv = orbits.greenwich_from_ecef(pe[:2]), orbits.greenwich_from_ecef(ve[:2])

    def h(y):
        pos, vel, _, _ = f.geometry(t, y[None])
        d = sp - pos
        r = np.linalg.norm(d, axis=-1)
        rr = np.einsum("ni,ni->n", d / r[:, None], sv - vel)
        if clock:
            r, rr = r + y[11], rr + y[12]
        return np.concatenate([r, rr])

    pos, vel, Jp, Jv = f.geometry(t, x[None])
    d = sp - pos
    r = np.linalg.norm(d, axis=-1)
    u = d / r[:, None]
    wv = sv - vel
    rr = np.einsum("ni,ni->n", u, wv)
    H = np.concatenate([-u @ Jp[0], ((rr[:, None] * u - wv) / r[:, None]) @ Jp[0] - u @ Jv[0]])
    if clock:
        H[:2, 11] = 1.0
        H[2:, 12] = 1.0
    Hn = _num_jac(h, x, eps)
    assert np.allclose(H, Hn, rtol=1e-5, atol=1e-6)


def test_odometer_function_equals_direct(route, short_truth):
    """k |V_eta| sqrt(1 + P^2 + a0^2 eta^2 / (a1 - eta^2)) equals the truth's |v_G|."""
    dt, N, tr, _ = short_truth
    k = np.zeros(tr.t_s.size, int)
    sf, _ = route.speed_factor_d(tr.p_g[:, 1], k)
    assert np.allclose(route.fwd_sign(k) * tr.v_g[:, 1] * sf, np.linalg.norm(tr.v_g, axis=-1), rtol=1e-9)


class _Linear(_Base):
    """A linear test model in the same Kalman-Bucy/RK4 machinery: x = [p, v], z = v + w."""

    clock = False
    ib = 0

    def __init__(self, x0, P0, q_acc, r):
        self.n = 2
        super().__init__(x0, P0, Intensities(0.0, q_acc, r), odometer=True)

    def odo_hph(self, t, P):
        return P[:, 1, 1]

    def _rk4(self, t, dt, w, f, z):
        self._Qd = None
        x, P = self.x, self.P
        h2 = 0.5 * dt
        k1 = self.deriv(t, x, P, w, f, z)
        k2 = self.deriv(t, x + h2 * k1[0], P + h2 * k1[1], w, f, z)
        k3 = self.deriv(t, x + h2 * k2[0], P + h2 * k2[1], w, f, z)
        k4 = self.deriv(t, x + dt * k3[0], P + dt * k3[1], w, f, z)
        self.x = x + dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        self.P = P + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])

    def deriv(self, t, x, P, w, f, z):
        F = np.array([[0.0, 1.0], [0.0, 0.0]])
        H = np.array([0.0, 1.0])
        PH = P @ H
        xd = x @ F.T + PH * ((z - x @ H) / self.noise.odometer)[:, None]
        Pd = F @ P + P @ F.T + np.diag([0.0, self.noise.accel]) - PH[:, :, None] * PH[:, None, :] / self.noise.odometer
        return xd, Pd


def test_continuous_filter_equals_discretized_kf_as_step_shrinks():
    """Kalman-Bucy (RK4) vs a discrete KF with measurement variance r/dt: the gap shrinks with dt."""
    from nav.kalman import kf_predict, kf_update

    q_acc, r, T = 0.05, 0.02, 2.0
    x0, P0 = np.array([[0.0, 1.0]]), np.diag([4.0, 1.0])[None]
    z_of_t = lambda t: 1.0 + 0.3 * np.sin(3 * t)  # noqa: E731 - any deterministic input
    lin = _Linear(x0, P0, q_acc, r)
    dtc = 1e-3
    for i in range(int(T / dtc)):
        lin.step(i * dtc, dtc, None, None, np.array([z_of_t((i + 0.5) * dtc)]))
    gaps = []
    for dt in (0.02, 0.005, 0.00125):
        x, P = x0[0].copy(), P0[0].copy()
        F = np.array([[1.0, dt], [0.0, 1.0]])
        Q = q_acc * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
        for i in range(int(round(T / dt))):
            x, P = kf_predict(x, P, F, Q)
            x, P, _, _ = kf_update(x, P, np.array([z_of_t((i + 0.5) * dt)]), np.array([[0.0, 1.0]]), np.array([[r / dt]]))
        gaps.append(np.abs(P - lin.P[0]).max() + np.abs(x - lin.x[0]).max())
    assert gaps[0] > gaps[1] > gaps[2]
    assert gaps[2] < 0.02 * np.abs(lin.P[0]).max() + 0.02


def test_polar_rotation_unobservable_and_filter_consistent(route):
    """Short Monte Carlo: the rotation about the polar axis never shrinks; NEES and NIS near their dof."""
    case = sim.Case(route=route, duration_s=30.0, outage_s=(10.0, 20.0), runs=30, seed=11)
    res = sim.run(case)
    v = res.var_polar_rot
    assert np.all(np.diff(v, axis=1) >= -1e-12 * v[:, :-1])
    nees = np.nanmean(res.nees[:, 5:])
    assert 0.6 * res.nees_dof < nees < 1.5 * res.nees_dof
    nis = np.nanmean(res.nis / np.where(res.nis_dof > 0, res.nis_dof, np.nan))
    assert 0.7 < nis < 1.3
    # errors stay bounded through the short outage (map constraint + odometer)
    assert np.max(np.abs(res.err_pos[:, -1])) < 15.0


def test_clock_states_and_stations_straight_route():
    """LARNS field: stations, straight level route, receiver clock in the truth and in the filter."""
    from vehicle import field

    _, phys, _, R, t = field.field_layout("seed000")
    froute, pts_net = field.field_route(phys, R, t, speed_m_s=10.0)
    assert froute.kind == "straight" and pts_net.shape == (2, 3)
    case = sim.Case(route=froute, duration_s=20.0, outage_s=None, runs=8, radio="stations",
                    stations_g=field.stations_greenwich(phys), sigma_rho_m=0.5, sigma_rate_m_s=0.15,
                    clock_states=True, clock_in_measurements=True, seed=3)
    res = sim.run(case)
    assert res.n_states == 13
    assert np.median(np.linalg.norm(res.err_pos[:, -1], axis=-1)) < 2.0
    nis = np.nanmean(res.nis / np.where(res.nis_dof > 0, res.nis_dof, np.nan))
    assert 0.6 < nis < 1.5


def test_straight_route_must_be_level():
    with pytest.raises(ValueError, match="level"):
        straight_route([[0, 0, 0], [1000, 0, 100]], (47.0, 39.0, 0.0))


# ----------------------------------------------------------------------------------------- constellation
def test_constellations_geometry_and_visibility():
    for alm, alt in ((glonass_like(), 19_100e3), (gps_like(), 20_180e3)):
        p, v = alm.eci(np.array([0.0, 100.0]))
        assert np.allclose(np.linalg.norm(p, axis=-1), orbits.WGS84_A_M + alt)
        pe0, ve = alm.ecef(0.0)
        pe1, _ = alm.ecef(1e-3)
        assert np.allclose((pe1 - pe0) / 1e-3, ve, atol=1e-2)  # Earth-fixed velocity
    rx = orbits.sphere_point(47.23, 39.72, orbits.R_EARTH_MEAN_M + 100.0)
    n_vis = [glonass_like().visible(rx, t).size for t in np.arange(0.0, 86400.0, 3600.0)]
    assert 4 <= min(n_vis) and max(n_vis) <= 14


def test_navigator_never_imports_world():
    for path in (ROOT / "vehicle" / "navigator").glob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""] + [f"{node.module}.{a.name}" for a in node.names]
            for nm in names:
                assert not nm.startswith("vehicle.world") and not nm.startswith("vehicle.sim"), (path, nm)


def test_orbits_frames():
    G = orbits.earth_rotation(123.0)
    assert np.allclose(G @ G.T, np.eye(3))
    # a point fixed on the Earth: d/dt (G^T p_G) = G^T (w x p_G)
    p = np.array([1.0, 2.0, 3.0])
    d = (orbits.earth_rotation(1.0 + 1e-3).T @ p - orbits.earth_rotation(1.0 - 1e-3).T @ p) / 2e-3
    assert np.allclose(d, orbits.earth_rotation(1.0).T @ np.cross(orbits.OMEGA_VEC_G, p), atol=1e-12)
    e = np.array([[1.0, 2.0, 3.0]])
    assert np.allclose(orbits.ecef_from_greenwich(orbits.greenwich_from_ecef(e)), e)


def test_documented_route_files_load():
    for p in sorted((ROOT / "docs" / "routes").iterdir()):
        r = load_route(p)
        assert r.n_segments >= 1 and all(s.length_m > 100.0 for s in r.segments)


def test_map_filter_passes_a_node_with_stop_and_turn():
    """Two legs, a stop and a 92 deg turn in place at the node inside an outage: the filter moves to
    the next leg (node pseudo-measurement) and keeps metre-level position errors."""
    r = great_circle_route([(47.23, 39.72), (47.2325, 39.7225), (47.2340, 39.7190)], 100.0, [10.0, 8.0])
    case = sim.Case(route=r, duration_s=75.0, outage_s=(20.0, 60.0), runs=6, seed=5, stop_at_end=True)
    res = sim.run(case)
    e = np.linalg.norm(res.err_pos, axis=-1)
    assert np.median(e[:, 56:]) < 2.0  # after the node (turn 43.7-53.7 s), on the second leg
    assert np.max(e[:, 56:]) < 8.0


@pytest.mark.slow
def test_bench_vehicle_quick_json(tmp_path):
    """`larns bench vehicle --quick` writes the issue's JSON keys (smoke test, ~2 min)."""
    from larns.cli import main

    out = tmp_path / "v.json"
    assert main(["bench", "vehicle", "--quick", "--json", str(out), "--png-dir", str(tmp_path)]) == 0
    d = json.loads(out.read_text())
    for key in ("paper_case", "larns_case", "no_map", "no_odometer"):
        assert key in d
    assert set(d["paper_case"]) == {"per_sample", "psd"}
    assert set(d["paper_case"]["psd"]) == {"vel_m_s", "att_arcmin", "pos_m"}
    assert (tmp_path / "vehicle_paper.png").exists()
