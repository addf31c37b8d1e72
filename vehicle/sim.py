"""In-process Monte Carlo of the vehicle: world (truth, sensors) -> navigator (filters) -> errors.

The world is drawn from per-purpose streams of one seed (common random numbers across filter
variants): ``[seed, 1, block]`` IMU and odometer noise per 1 s block, ``[seed, 2]`` radio, ``[seed, 3]``
receiver clock, ``[seed, 4]`` initial errors. The filter only receives the sensor outputs, the
broadcast emitter positions and the map; the truth is used to draw the initial estimate from the
filter's own prior and to score the errors.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from nav import kalman as kf
from nav.constellation import CONSTELLATIONS
from nav.orbits import OMEGA_VEC_G, earth_rotation
from vehicle.navigator.cdekf import FreeFilter, Intensities, MapFilter, xi_matrix
from vehicle.route import Route
from vehicle.world import sensors, truth as world_truth

ARCMIN = np.pi / (180.0 * 60.0)


@dataclass
class Case:
    """One Monte Carlo configuration (defaults: seed 004's case, spec Sec. 3.7 and 3.9)."""

    route: Route
    duration_s: float = 1000.0
    dt_s: float = 0.01
    epoch_s: float = 1.0
    outage_s: tuple[float, float] | None = (400.0, 700.0)
    convention: str = "per_sample"
    radio: str = "satellites"  # or "stations"
    constellation: str = "glonass"
    mask_deg: float = 10.0
    sigma_rho_m: float = 15.0
    sigma_rate_m_s: float = 0.5
    stations_g: np.ndarray | None = None
    station_sigma_m: float = 0.2
    station_consider: bool = True  # stations' survey error as Schmidt consider parameters (False: white noise)
    filter: str = "map"  # or "free"
    clock_states: bool = False
    clock_in_measurements: bool = False
    odometer: bool = True
    doppler: bool = True
    sigma_q0: float = 10.0
    sigma_v0: float = 0.1
    sigma_att0_arcmin: float = 1.0
    v_start_m_s: float | None = None
    stop_at_end: bool = False
    imu: sensors.ImuSpec = field(default_factory=sensors.ImuSpec)
    odo: sensors.OdometerSpec = field(default_factory=sensors.OdometerSpec)
    clock: sensors.ClockSpec = field(default_factory=sensors.ClockSpec)
    runs: int = 50
    seed: int = 4


@dataclass
class Result:
    t_s: np.ndarray  # (K,) record times (1 Hz)
    err_pos: np.ndarray  # (M, K, 3) Greenwich
    err_vel: np.ndarray  # (M, K, 3)
    err_att: np.ndarray  # (M, K, 3) body-frame small angles (rad)
    sig_pos: np.ndarray  # (M, K, 3) filter sigma of the Greenwich position
    sig_vel: np.ndarray
    sig_att: np.ndarray  # (M, K, 3) body-frame attitude sigma
    nees: np.ndarray  # (M, K) on the observable subspace
    nees_dof: int
    var_polar_rot: np.ndarray  # (M, K) variance of the inertial rotation about the polar axis
    nis: np.ndarray  # (M, K) NaN where no update
    nis_dof: np.ndarray  # (K,)
    wall_s: float
    steps: int
    cpu_s: float  # process CPU time of the filter loop (the machine may be shared: wall >= cpu)
    n_states: int


def _with_convention(case: Case):
    imu = sensors.ImuSpec(case.imu.gyro, case.imu.accel, case.convention, case.imu.gyro_offset_rad_s)
    odo = sensors.OdometerSpec(case.odo.sigma, case.convention, case.odo.k, case.odo.scale_error)
    return imu, odo


def vee_skew(A: np.ndarray) -> np.ndarray:
    """Small-angle vector of the skew part of A (..., 3, 3)."""
    return 0.5 * np.stack([A[..., 2, 1] - A[..., 1, 2], A[..., 0, 2] - A[..., 2, 0], A[..., 1, 0] - A[..., 0, 1]], -1)


def run(case: Case, progress=None) -> Result:
    """Run ``case.runs`` Monte Carlo runs of one filter configuration; errors recorded at 1 Hz."""
    route, dt, M = case.route, case.dt_s, case.runs
    n_steps = int(round(case.duration_s / dt))
    per_epoch = int(round(case.epoch_s / dt))
    plan = world_truth.speed_plan(route, case.v_start_m_s, stop_at_end=case.stop_at_end)
    t_grid = np.arange(0, n_steps + 1, per_epoch) * dt
    tr = world_truth.sample(route, plan, t_grid)
    t_mid = (np.arange(n_steps) + 0.5) * dt
    tm = world_truth.sample(route, plan, t_mid)
    imu, odo = _with_convention(case)

    # radio epochs (every epoch_s, none inside the outage, none at t = 0)
    ep_idx = np.arange(1, t_grid.size)
    if case.outage_s is not None:
        a, b = case.outage_s
        ep_idx = ep_idx[(t_grid[ep_idx] < a) | (t_grid[ep_idx] > b)]
    clk = case.clock.sample(t_grid, M, np.random.default_rng([case.seed, 3])) if case.clock_in_measurements else None
    rng_r = np.random.default_rng([case.seed, 2])
    if case.radio == "satellites":
        alm = CONSTELLATIONS[case.constellation]()
        radio = sensors.satellite_epochs(alm, tr, ep_idx, M, rng_r, case.sigma_rho_m, case.sigma_rate_m_s,
                                         case.mask_deg, clk)
    elif case.radio == "stations":
        radio, _ = sensors.station_epochs(case.stations_g, case.station_sigma_m**2, tr, ep_idx, M, rng_r,
                                          case.sigma_rho_m, case.sigma_rate_m_s, clk, consider=case.station_consider)
    else:
        raise ValueError(f"radio must be satellites or stations, got {case.radio!r}")
    epoch_of = {int(i): j for j, i in enumerate(ep_idx)}

    # filter noise intensities (the filter knows the convention in force)
    q = Intensities(
        gyro=sensors.intensity(imu.gyro, imu.convention, dt),
        accel=sensors.intensity(imu.accel, imu.convention, dt),
        odometer=sensors.intensity(odo.sigma, odo.convention, dt),
        q_b=case.clock.q_b, q_d=case.clock.q_d,
    )
    filt = _init_filter(case, tr, q, np.random.default_rng([case.seed, 4]))

    K = t_grid.size
    out = {k: np.full((M, K, 3), np.nan) for k in ("err_pos", "err_vel", "err_att", "sig_pos", "sig_vel", "sig_att")}
    nees = np.full((M, K), np.nan)
    vpr = np.full((M, K), np.nan)
    nis = np.full((M, K), np.nan)
    nis_dof = np.zeros(K, int)
    _record(filt, case, tr, 0, out, nees, vpr)
    if getattr(filt, "_one_run", lambda: False)():
        from vehicle.navigator.fused import warm_up

        warm_up()  # the single-run kernel compiled (or loaded from numba's cache) before the clock starts
    t0 = time.perf_counter()
    c0 = time.process_time()
    for blk in range(K - 1):
        rng_b = np.random.default_rng([case.seed, 1, blk])
        sl = slice(blk * per_epoch, (blk + 1) * per_epoch)
        gyro, acc = imu.sample(tm.w_ib_b[sl], tm.f_b[sl], M, dt, rng_b)
        z = odo.sample(tm.speed[sl], M, dt, rng_b) if case.odometer else None
        gyro = gyro - imu.gyro_offset_rad_s  # the known mean offset m_d, subtracted (eq. 2)
        for j in range(per_epoch):
            i = blk * per_epoch + j
            filt.step(i * dt, dt, gyro[j], acc[j], None if z is None else z[j])
        k = blk + 1
        if k in epoch_of:
            e = epoch_of[k]
            filt.update(t_grid[k], radio.src_pos[e], radio.src_vel[e], radio.rho[e], radio.rate[e],
                        radio.var_rho[e], radio.var_rate[e], use_rate=case.doppler,
                        src_cov=radio.src_cov if case.radio == "stations" and case.station_consider else None)
            nis[:, k] = filt.last_nis
            nis_dof[k] = filt.last_nis_dof
        else:
            filt.orthonormalize()
        _record(filt, case, tr, k, out, nees, vpr)
        if progress and k % 100 == 0:
            progress(k, K - 1)
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    return Result(t_grid, out["err_pos"], out["err_vel"], out["err_att"], out["sig_pos"], out["sig_vel"],
                  out["sig_att"], nees, _nees_dof(case), vpr, nis, nis_dof, wall, n_steps, cpu, filt.n)


def _nees_dof(case: Case) -> int:
    """Attitude (2 angles off the polar axis on the map, 3 free) + position/velocity states; clock excluded."""
    return 4 if case.filter == "map" else 9


def true_state(case: Case, tr, i: int) -> np.ndarray:
    """The filter's state for the truth sample ``i`` (clock excluded)."""
    Dt = tr.D[i].T.reshape(9)
    if case.filter == "map":
        if case.route.kind == "great_circle":
            qv = [tr.p_g[i, 1], tr.v_g[i, 1]]
        else:
            qv = [tr.s[i], tr.speed[i]]
        return np.concatenate([Dt, qv])
    G = earth_rotation(tr.t_s[i])
    p_i = G.T @ tr.p_g[i]
    v_i = G.T @ (tr.v_g[i] + np.cross(OMEGA_VEC_G, tr.p_g[i]))
    return np.concatenate([Dt, p_i, v_i])


def _init_filter(case: Case, tr, q: Intensities, rng: np.random.Generator):
    M = case.runs
    xt = true_state(case, tr, 0)
    n_nav = xt.size
    n = n_nav + (2 if case.clock_states else 0)
    x0 = np.zeros((M, n))
    P0 = np.zeros((M, n, n))
    # attitude: D_hat = D exp([d x]) (body-frame error), P_DD = Xi sigma^2 Xi^T (rank 3, spec 3.6 D)
    s_att = case.sigma_att0_arcmin * ARCMIN
    d = s_att * rng.standard_normal((M, 3))
    from scipy.spatial.transform import Rotation

    Dt_hat = np.swapaxes(tr.D[0] @ Rotation.from_rotvec(d).as_matrix(), 1, 2)
    x0[:, :9] = Dt_hat.reshape(M, 9)
    Xi = xi_matrix(Dt_hat)
    P0[:, :9, :9] = s_att**2 * Xi @ np.swapaxes(Xi, 1, 2)
    if case.filter == "map":
        sig = np.array([case.sigma_q0, case.sigma_v0])
    else:
        sig = np.array([case.sigma_q0] * 3 + [case.sigma_v0] * 3)
    x0[:, 9:n_nav] = xt[9:] + sig * rng.standard_normal((M, sig.size))
    P0[:, np.arange(9, n_nav), np.arange(9, n_nav)] = sig**2
    if case.clock_states:
        P0[:, n_nav, n_nav] = case.clock.sigma_b0_m**2
        P0[:, n_nav + 1, n_nav + 1] = case.clock.sigma_d0_m_s**2
    if case.filter == "map":
        seg0 = np.full(M, int(tr.seg[0]))
        return MapFilter(case.route, x0, P0, seg0, q, clock=case.clock_states, odometer=case.odometer, k_odo=case.odo.k)
    return FreeFilter(x0, P0, q, clock=case.clock_states, odometer=case.odometer, k_odo=case.odo.k)


def _record(filt, case: Case, tr, k: int, out: dict, nees: np.ndarray, vpr: np.ndarray) -> None:
    t = tr.t_s[k]
    M = filt.x.shape[0]
    p, v, Jp, Jv = filt.geometry(t, filt.x)
    out["err_pos"][:, k] = p - tr.p_g[k]
    out["err_vel"][:, k] = v - tr.v_g[k]
    P = filt.P
    out["sig_pos"][:, k] = np.sqrt(np.maximum(np.einsum("mij,mjk,mik->mi", Jp, P, Jp), 0.0))
    out["sig_vel"][:, k] = np.sqrt(np.maximum(np.einsum("mij,mjk,mik->mi", Jv, P, Jv), 0.0))
    G = earth_rotation(t)
    D_hat = filt.D()
    C_hat = G @ D_hat
    out["err_att"][:, k] = vee_skew(np.swapaxes(tr.C_gb[k], 0, 1)[None] @ C_hat)
    # covariances in the error coordinates [e_I (3), rest]
    Pe = filt.error_state_cov()
    Pi = Pe[:, :3, :3]
    # body-frame attitude sigma: e_b = D^T e_I
    Pb = np.swapaxes(D_hat, 1, 2) @ Pi @ D_hat
    out["sig_att"][:, k] = np.sqrt(np.maximum(np.einsum("mii->mi", Pb), 0.0))
    vpr[:, k] = Pi[:, 1, 1]
    e_I = vee_skew(D_hat @ tr.D[k].T[None])
    xt = true_state(case, tr, k)
    dx = filt.x[:, 9:xt.size] - xt[9:]
    if case.filter == "map":
        ok = filt.seg == tr.seg[k]
        err = np.concatenate([e_I[:, [0, 2]], dx], axis=1)
        sel = [0, 2] + list(range(3, 3 + dx.shape[1]))
    else:
        ok = np.ones(M, bool)
        err = np.concatenate([e_I, dx], axis=1)
        sel = list(range(3 + dx.shape[1]))
    Ps = Pe[:, sel][:, :, sel]
    nees[:, k] = np.where(ok, kf.nees(err, Ps + 1e-30 * np.eye(len(sel))), np.nan)

