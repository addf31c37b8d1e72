"""Monte Carlo of the inertial aircraft (``ins-ekf``) on a LARNS field, vectorized over runs.

Joins the world (:mod:`aircraft.world`: 6-DOF motion, IMU emulator, receiver clock, field geometry)
and the navigator (:mod:`aircraft.navigator.ins_ekf`): the filter only receives IMU increments,
pseudoranges with their reception times and the broadcast station positions.

Initialization (emulated, see docs/ins.md): position, velocity and clock as an initial LARNS fix
drawn from the filter's prior; attitude as a levelling + track-heading alignment *against the
assumed-level frame* (``tau^ = 0``), so its level error contains the frame's true tilt, plus an
alignment error drawn from the prior; biases at zero (the emulator draws the true ones from the same
prior). Which way +Z points comes from the initial fix: the aircraft flies above the stations.

The posterior CRLB is computed by one extra run appended to the batch: a perfect IMU, a perfect
clock, noise-free ranges and a zero initial error, so its nominal stays on the truth and its
covariance is the Kalman recursion with every Jacobian evaluated along the true trajectory (the
Tichavsky bound of the linearized model, as :mod:`nav.pcrb` does for the CV filters).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from nav import errorstate as es
from nav.rotations import exp_so3, log_so3

from .navigator.ins_ekf import InsEkf, InsTuning, initial_covariance, tilt_attitude_jacobian
from .world import clock as wclock
from .world.field import Field
from .world.imu import ImuEmulator, ImuPreset
from .world.motion import Motion


@dataclass
class InsRun:
    """Settings of one Monte Carlo."""

    runs: int = 64
    duration_s: float = 600.0
    slot_s: float = 0.1
    cycle_s: float = 0.8
    sigma_m: float = 0.9
    tilt: str = "estimate"  # "estimate" (tilt states), "oracle" (true tilt given), "ignore" (assume level)
    outages: list[tuple[float, float]] = field(default_factory=list)  # (start, length) s
    record_every_s: float = 1.0
    chunk_s: float = 30.0
    seed: int = 1
    clock: wclock.ClockModel = field(default_factory=wclock.ClockModel)
    pcrb: bool = True


@dataclass
class InsResult:
    t_s: np.ndarray  # (K,) record times
    err_m: np.ndarray  # (M, K, 3) position errors (estimate - truth)
    P_pos: np.ndarray  # (M, K, 3, 3)
    nees: np.ndarray  # (M, K) NEES of [p, v, phi] (9 dof)
    pcrb_pos: np.ndarray | None  # (K, 3, 3)
    wall_s: float
    flight_s: float
    runs: int
    cpu_s: float = 0.0  # process CPU time of the loop (the machine may be shared)
    nsq: np.ndarray | None = None  # (M, K, 9) squared errors of [p, v, phi] over their variances
    nees8: np.ndarray | None = None  # (M, K) NEES of [p, v, phi_x, phi_y] (8 dof, without the heading)
    var9: np.ndarray | None = None  # (M, K, 9) the filter's variances of [p, v, phi]
    pcrb9: np.ndarray | None = None  # (K, 9) the bound's variances of [p, v, phi]

    def rmse_h(self) -> np.ndarray:
        return np.sqrt(np.mean(np.sum(self.err_m[..., :2] ** 2, axis=-1), axis=0))

    def pcrb_h(self) -> np.ndarray:
        return np.sqrt(self.pcrb_pos[:, 0, 0] + self.pcrb_pos[:, 1, 1])


@dataclass
class Start:
    """Emulated initial fix and alignment (nominal states (M, ...)), prior, and the truth at t0."""

    p: np.ndarray
    v: np.ndarray
    C: np.ndarray
    tau: np.ndarray
    P0: np.ndarray
    sign: float
    p_true: np.ndarray
    v_true: np.ndarray
    C_true: np.ndarray
    tau_true: np.ndarray


def emulated_start(fld: Field, motion: Motion, tn: InsTuning, L: es.ErrorLayout, rng: np.random.Generator,
                   M: int, tilt: str = "estimate", t0_s: float = 0.0) -> Start:
    """World-side emulation of the navigator's start (module doc): an initial LARNS fix (position,
    velocity drawn from the prior around the truth), a levelling + track-heading alignment against
    the assumed-level frame (its level error is the frame's true tilt plus a drawn alignment error),
    the tilt prior at zero (``tilt="estimate"``/``"ignore"``) or at the truth (``"oracle"``, a
    yardstick only). Which way +Z points is decided from the fix (the aircraft is above the stations).
    """
    p0, v0, C0 = (x[0] for x in fld.truth(motion, np.array([t0_s])))
    up_true = fld.up_n
    sign = 1.0 if up_true[2] > 0 else -1.0
    tau_true = sign * up_true[:2]
    tau_nom = np.zeros(2) if tilt != "oracle" else tau_true.copy()
    P0 = initial_covariance(L, tn, tau_nom, sign)
    J = tilt_attitude_jacobian(tau_nom, sign)
    Ls = es.ErrorLayout(turn_on=True, tilt=True, clock=True)
    P0s = initial_covariance(Ls, tn, tau_nom, sign)
    A = P0s[Ls.ATT, Ls.ATT] - J @ (tn.p0_tilt_rad**2 * np.eye(2)) @ J.T  # alignment part only
    d_pos = rng.standard_normal((M, 3)) * tn.p0_pos_m
    d_vel = rng.standard_normal((M, 3)) * tn.p0_vel_m_s
    phi_al = rng.standard_normal((M, 3)) @ np.linalg.cholesky(A + 1e-30 * np.eye(3)).T
    phi0 = phi_al + (J @ (tau_true - tau_nom))[None, :]
    p_hat = p0 - d_pos
    nav_sign = float(np.sign(np.median(p_hat[:, 2]) - np.mean(fld.stations_n[:, 2])))
    return Start(p_hat, v0 - d_vel, exp_so3(-phi0) @ C0, np.broadcast_to(tau_nom, (M, 2)).copy(), P0, nav_sign,
                 p0, v0, C0, tau_true)


def _in_outage(t: float, outages) -> bool:
    return any(a <= t < a + L for a, L in outages)


def simulate(fld: Field, motion: Motion, preset: ImuPreset, cfg: InsRun, tuning: InsTuning | None = None,
             progress=None) -> InsResult:
    """Fly ``motion`` over ``fld`` with ``cfg.runs`` IMUs (plus one bound run); see the module doc."""
    rng = np.random.default_rng([cfg.seed, 12])
    M = cfg.runs
    MM = M + (1 if cfg.pcrb else 0)
    tn = tuning or InsTuning.from_preset(preset, sigma_range_m=cfg.sigma_m, q_b=cfg.clock.q_b_m2_s,
                                         q_d=cfg.clock.q_d_m2_s3, p0_clock_m=cfg.clock.b0_sigma_m,
                                         p0_drift_m_s=cfg.clock.d0_sigma_m_s)
    L = es.ErrorLayout(turn_on=True, tilt=(cfg.tilt == "estimate"), clock=True)
    dt = tn.dt_s
    # --- world: truth at t = 0, true tilt, emulated initial fix/alignment -------------------------
    start = emulated_start(fld, motion, tn, L, rng, M, cfg.tilt)
    p_hat, v_hat, C_hat, tau0, P0, nav_sign = start.p, start.v, start.C, start.tau, start.P0, start.sign
    p0, v0, C0, tau_true = start.p_true, start.v_true, start.C_true, start.tau_true
    ns = fld.stations_n
    imu = ImuEmulator(preset, M, rng)
    if cfg.pcrb:
        p_hat = np.vstack([p_hat, p0])
        v_hat = np.vstack([v_hat, v0])
        C_hat = np.concatenate([C_hat, C0[None]])
        tau0 = np.vstack([tau0, tau_true])
    ekf = InsEkf(tn, L, p_hat, v_hat, C_hat, np.zeros((MM, 2)), P0, tau0, nav_sign)
    # --- measurement schedule -------------------------------------------------------------------
    m = len(ns)
    n_slots = int(np.floor(cfg.duration_s / cfg.slot_s))
    k = np.arange(n_slots)
    slot_in_cycle = k % int(round(cfg.cycle_s / cfg.slot_s))
    ok = slot_in_cycle < m
    t_tx = k[ok] * cfg.slot_s
    sidx = slot_in_cycle[ok]
    t_rx, r_true = fld.reception(motion, t_tx, sidx)
    clk = wclock.sample(cfg.clock, t_rx, M, rng)  # (K, M, 2)
    rho = r_true[:, None] + clk[:, :, 0] + cfg.sigma_m * rng.standard_normal((t_rx.size, M))
    if cfg.pcrb:
        rho = np.hstack([rho, r_true[:, None]])
    # --- main loop --------------------------------------------------------------------------------
    n_imu = int(round(cfg.duration_s / dt))
    rec_every = max(int(round(cfg.record_every_s / dt)), 1)
    n_rec = n_imu // rec_every
    t_rec = np.empty(n_rec)
    err = np.empty((M, n_rec, 3))
    Pp = np.empty((M, n_rec, 3, 3))
    nees = np.empty((M, n_rec))
    nsq = np.empty((M, n_rec, 9))
    nees8 = np.empty((M, n_rec))
    var9 = np.empty((M, n_rec, 9))
    pcrb9 = np.empty((n_rec, 9)) if cfg.pcrb else None
    pcrb = np.empty((n_rec, 3, 3)) if cfg.pcrb else None
    chunk = max(int(round(cfg.chunk_s / dt)), rec_every)
    j = 0  # next measurement
    i_rec = 0
    w0 = time.perf_counter()
    c0_cpu = time.process_time()
    sl9 = np.r_[0:9]
    for c0 in range(0, n_imu, chunk):
        n = min(chunk, n_imu - c0)
        dth_t, dv_t = motion.increments(c0 * dt, dt, n)
        g_m, a_m = imu.measure(dth_t, dv_t)
        if cfg.pcrb:
            g_m = np.concatenate([g_m, dth_t[:, None, :]], axis=1)
            a_m = np.concatenate([a_m, dv_t[:, None, :]], axis=1)
        for i in range(n):
            ekf.imu(g_m[i], a_m[i])
            t = ekf.t_s
            did = False
            while j < t_rx.size and t_rx[j] <= t + 1e-12:
                if not _in_outage(t_rx[j], cfg.outages):
                    ekf.pseudorange(t_rx[j], ns[sidx[j]], rho[j])
                    did = True
                j += 1
            if not did:
                ekf.maybe_propagate()
            if (c0 + i + 1) % rec_every == 0 and i_rec < n_rec:
                ekf.propagate()
                pt, vt, Ct = (x[0] for x in fld.truth(motion, np.array([t])))
                e_p = ekf.p[:M] - pt
                t_rec[i_rec] = t
                err[:, i_rec] = e_p
                Pp[:, i_rec] = ekf.P[:M, :3, :3]
                d = np.concatenate([-e_p, vt - ekf.v[:M], log_so3(Ct @ np.swapaxes(ekf.C[:M], -1, -2))], axis=-1)
                P9 = ekf.P[:M][:, sl9][:, :, sl9]
                nees[:, i_rec] = np.einsum("mi,mi->m", d, np.linalg.solve(P9, d[..., None])[..., 0])
                var9[:, i_rec] = np.einsum("mii->mi", P9)
                d8 = d[:, :8]
                nees8[:, i_rec] = np.einsum("mi,mi->m", d8, np.linalg.solve(P9[:, :8, :8], d8[..., None])[..., 0])
                nsq[:, i_rec] = d**2 / var9[:, i_rec]
                if cfg.pcrb:
                    pcrb[i_rec] = ekf.P[M, :3, :3]
                    pcrb9[i_rec] = np.diag(ekf.P[M])[:9]
                i_rec += 1
        if progress:
            progress(f"{(c0 + n) * dt:.0f}/{cfg.duration_s:.0f} s")
    wall = time.perf_counter() - w0
    return InsResult(t_rec, err, Pp, nees, pcrb, wall, cfg.duration_s, M, time.process_time() - c0_cpu, nsq, nees8, var9, pcrb9)


def open_loop_drift(fld: Field, motion: Motion, preset: ImuPreset, duration_s: float, runs: int = 64,
                    seed: int = 1, t0_s: float = 0.0) -> float:
    """RMS horizontal position error after ``duration_s`` of free inertial navigation from a
    *calibrated start*: exact initial position, velocity, attitude and gravity, turn-on biases and
    scale factors removed; the in-run (Gauss-Markov) bias and white noise remain."""
    from nav import strapdown as sd

    rng = np.random.default_rng([seed, 13])
    imu = ImuEmulator(preset.with_(gyro_turn_on_rad_s=0.0, accel_turn_on_m_s2=0.0, gyro_sf=0.0, accel_sf=0.0),
                      runs, rng)
    dt = 1.0 / preset.rate_hz
    n = int(round(duration_s / dt))
    dth, dv = motion.increments(t0_s, dt, n)
    g, a = imu.measure(dth, dv)
    p, v, C = (x[0] for x in fld.truth(motion, np.array([t0_s])))
    s = sd.NavState(np.broadcast_to(p, (runs, 3)).copy(), np.broadcast_to(v, (runs, 3)).copy(),
                    np.broadcast_to(C, (runs, 3, 3)).copy(), t0_s)
    e = sd.run(s, g, a, fld.g_n, dt)
    pt = fld.truth(motion, np.array([t0_s + n * dt]))[0][0]
    eh = e.p_m - pt
    # horizontal in the physical sense: remove the component along up
    eh = eh - np.outer(eh @ fld.up_n, fld.up_n)
    return float(np.sqrt(np.mean(np.sum(eh**2, axis=-1))))
