"""Monte Carlo of the inertial aircraft (``ins-ekf``) on a LARNS field, vectorized over runs.

Joins the world (:mod:`aircraft.world`: 6-DOF motion, IMU emulator, receiver clock, field geometry)
and the navigator (:mod:`aircraft.navigator.ins_ekf`): the filter only receives IMU increments,
pseudoranges with their reception times and the broadcast station positions.

Start (honest, :mod:`aircraft.navigator.ins_start`): the navigator listens for the first
``StartConfig.window_s`` seconds and starts its EKF at the window's end from that window's
pseudoranges and IMU increments alone (radio fix with motion, levelling, heading from the track, a
prior ``P0`` from their error models). Nothing of the truth enters the start.

The posterior CRLB is computed by one extra run appended to the batch: a perfect IMU, a perfect
clock, noise-free ranges and a zero initial error, so its nominal stays on the truth and its
covariance is the Kalman recursion with every Jacobian evaluated along the true trajectory (the
Tichavsky bound of the linearized model, as :mod:`nav.pcrb` does for the CV filters). Its prior is
the start's own ``P0``, computed by the same start on the noise-free window (the information the
start actually has), so the bound stays the bound of this start.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from nav import kalman as kf
from nav import errorstate as es
from nav.rotations import log_so3

from ..navigator.ins_ekf import JAC_FORCE_TC_S, InsEkf, InsTuning
from ..navigator.ins_start import SideTest, StartConfig, moved_on, radio_fix, start
from ..world import clock as wclock
from ..world.field import Field
from ..world.imu import ImuEmulator, ImuPreset
from ..world.motion import Motion


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
    start: StartConfig = field(default_factory=StartConfig)
    jac_force_tc_s: float = JAC_FORCE_TC_S  # low-pass of f^_n in the Jacobian (0: the former linearization)


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
    start_s: float = 0.0  # when the EKF started (end of the deciding window)
    start_windows: int = 0  # windows listened to before the side of the stations' plane was decided
    side_wrong: int = 0  # runs that decided the wrong side (world-side count, for the report)

    def rmse_h(self) -> np.ndarray:
        return np.sqrt(np.mean(np.sum(self.err_m[..., :2] ** 2, axis=-1), axis=0))

    def pcrb_h(self) -> np.ndarray:
        return np.sqrt(self.pcrb_pos[:, 0, 0] + self.pcrb_pos[:, 1, 1])


def _in_outage(t: float, outages) -> bool:
    return any(a <= t < a + L for a, L in outages)


def _record(ekf: InsEkf, fld: Field, motion: Motion, t: float, M: int, i_rec: int, t_rec, err, Pp, nees, var9,
            nees8, nsq, pcrb, pcrb9) -> None:
    """World side: errors of the ``M`` runs against truth at ``t`` into the record buffers (slot
    ``i_rec``); the bound run's covariance (index ``M``) into ``pcrb``/``pcrb9`` when they exist."""
    ekf.propagate()
    pt, vt, Ct = (x[0] for x in fld.truth(motion, np.array([t])))
    e_p = ekf.p[:M] - pt
    t_rec[i_rec] = t
    err[:, i_rec] = e_p
    Pp[:, i_rec] = ekf.P[:M, :3, :3]
    d = np.concatenate([-e_p, vt - ekf.v[:M], log_so3(Ct @ np.swapaxes(ekf.C[:M], -1, -2))], axis=-1)
    sl9 = np.r_[0:9]
    P9 = ekf.P[:M][:, sl9][:, :, sl9]
    nees[:, i_rec] = kf.nees(d, P9)
    var9[:, i_rec] = np.einsum("mii->mi", P9)
    d8 = d[:, :8]
    nees8[:, i_rec] = np.einsum("mi,mi->m", d8, np.linalg.solve(P9[:, :8, :8], d8[..., None])[..., 0])
    nsq[:, i_rec] = d**2 / var9[:, i_rec]
    if pcrb is not None:
        pcrb[i_rec] = ekf.P[M, :3, :3]
        pcrb9[i_rec] = np.diag(ekf.P[M])[:9]


def simulate(fld: Field, motion: Motion, preset: ImuPreset, cfg: InsRun, tuning: InsTuning | None = None,
             progress=None) -> InsResult:
    """Fly ``motion`` over ``fld`` with ``cfg.runs`` IMUs (plus one bound run); see the module doc."""
    rng = np.random.default_rng([cfg.seed, 12])
    M = cfg.runs
    MM = M + (1 if cfg.pcrb else 0)
    tn = tuning or InsTuning.from_preset(preset, sigma_range_m=cfg.sigma_m, q_b=cfg.clock.q_b_m2_s,
                                         q_d=cfg.clock.q_d_m2_s3, p0_clock_m=cfg.clock.b0_sigma_m,
                                         p0_drift_m_s=cfg.clock.d0_sigma_m_s, jac_force_tc_s=cfg.jac_force_tc_s)
    L = es.ErrorLayout(turn_on=True, tilt=(cfg.tilt == "estimate"), clock=True)
    dt = tn.dt_s
    # --- world: IMU and measurement schedule ---------------------------------------------------
    ns = fld.stations_n
    imu = ImuEmulator(preset, M, rng)
    up_true = fld.up_n
    tau_true = (1.0 if up_true[2] > 0 else -1.0) * up_true[:2]  # world side: for the oracle and the bound
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
    # --- navigator start: the first window's pseudoranges and IMU increments only ------------------
    w0 = time.perf_counter()  # the start's time counts in the run's time
    c0_cpu = time.process_time()
    n_w = int(round(cfg.start.window_s / dt))
    W = n_w * dt
    tau_nom = tau_true if cfg.tilt == "oracle" else None  # the oracle is a yardstick only
    sides = SideTest(cfg.start, MM)  # which side of the stations' plane: consecutive windows
    guess = None
    n_win = 0
    while True:
        n_win += 1
        t_e = n_win * W
        j0 = int(np.searchsorted(t_rx, t_e - W + 1e-12, side="right"))
        jw = int(np.searchsorted(t_rx, t_e + 1e-12, side="right"))  # measurements of the window
        fix = radio_fix(t_rx[j0:jw], ns[sidx[j0:jw]], None, rho[j0:jw].T, tn.sigma_range_m**2, t_e,
                        tn.sigma_range_m, cfg.start, tn.q_b, tn.q_d, guess)
        sides.add(fix)
        if np.all(sides.decided()[:M]):
            break
        guess = moved_on(fix, sides.side(), W)
    n_w0 = n_win * n_w  # IMU steps before the EKF starts
    g_w, a_w = imu.measure(*motion.increments(0.0, dt, n_w0))
    dth_w, dv_w = motion.increments(t_e - W, dt, n_w)
    side = sides.side()
    st = start(L, tn, fix.rows(slice(None, M)), side[:M], g_w[-n_w:], a_w[-n_w:], t_e,
               cfg.start, tau_nom)
    p_hat, v_hat, C_hat, clk0, tau0, P0 = st.p, st.v, st.C, st.clock, st.tau, st.P0
    sign = np.broadcast_to(st.sign, (M,))
    if cfg.pcrb:  # the bound run: the same start on the noise-free window gives its prior; nominal = truth
        sb = start(L, tn, fix.rows(slice(M, None)), side[M:], dth_w[:, None], dv_w[:, None],
                   t_e, cfg.start, tau_nom)
        pe, ve, Ce = (x[0] for x in fld.truth(motion, np.array([t_e])))
        p_hat = np.vstack([p_hat, pe])
        v_hat = np.vstack([v_hat, ve])
        C_hat = np.concatenate([C_hat, Ce[None]])
        clk0 = np.vstack([clk0, np.zeros((1, 2))])
        tau0 = np.vstack([tau0, tau_true])
        P0 = np.concatenate([P0, sb.P0])
        sign = np.r_[sign, 1.0 if up_true[2] > 0 else -1.0]
    n_side_wrong = int(np.sum(np.broadcast_to(st.sign, (M,)) != (1.0 if up_true[2] > 0 else -1.0)))
    ekf = InsEkf(tn, L, p_hat, v_hat, C_hat, clk0, P0, tau0, sign, t0_s=t_e)
    # --- main loop --------------------------------------------------------------------------------
    n_imu = int(round(cfg.duration_s / dt))
    rec_every = max(int(round(cfg.record_every_s / dt)), 1)
    n_rec = n_imu // rec_every - n_w0 // rec_every
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
    j = jw  # next measurement
    i_rec = 0
    for c0 in range(n_w0, n_imu, chunk):
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
                _record(ekf, fld, motion, t, M, i_rec, t_rec, err, Pp, nees, var9, nees8, nsq, pcrb, pcrb9)
                i_rec += 1
        if progress:
            progress(f"{(c0 + n) * dt:.0f}/{cfg.duration_s:.0f} s")
    wall = time.perf_counter() - w0
    return InsResult(t_rec, err, Pp, nees, pcrb, wall, cfg.duration_s, M, time.process_time() - c0_cpu, nsq, nees8, var9,
                     pcrb9, t_e, n_win, n_side_wrong)


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
