"""Monte Carlo of the triad (seed 002), vectorized over runs: world and navigator joined here only.

World (truth): a flat, non-rotating level frame ``L`` which is the ENU frame at a geodetic origin
(:class:`nav.constellation.EnuFrame`), straight and level flight (spec sec. 1.8:
10 km, 200 m/s), the GPS-like almanac's satellites (ECEF, rotated into ``L``), LARNS ground stations
with a network frame of their own (:func:`nav.geometry.to_network_frame`), the IMU emulator, the
receiver clock (:mod:`aircraft.world.clock`), the baro (:mod:`aircraft.world.baro`).

Measurements (1 Hz, at IMU sample times): satellite pseudoranges ``|p(t) - s(t_tx)| + b + tropo(el)
- c dt_sat(t_tx) + n`` (``t_tx = t - r / c``, the troposphere and the satellite clock removed by the
receiver's broadcast models), ground-station pseudoranges ``|p - g| + b + n`` (the stations keep
satellite time, seed 002), baro altitude. The receiver tracks satellites above the mask.

Navigator start (no truth): a constant-velocity window fix from every satellite above the mask over
the first ``init_window_s`` (the sky is full before the case's degradation starts), a levelling from
the mean specific force and the fix's track (:func:`aircraft.navigator.triad_ekf.initial_fix`,
:func:`start_from_window`). The case's measurement set applies from ``t0 = init_window_s``.

Earth tie: each run draws the stations' self-survey errors (network frame) and the geodetic survey
errors of the tie stations; the navigator fits the tie (:mod:`aircraft.navigator.field_tie`).

The posterior CRLB comes from one extra run appended to the batch (as :mod:`aircraft.montecarlo.ins`): perfect
IMU, clock, baro, noise-free measurements, exact start and stations with the tie covariance of run 0,
so its covariance is the recursion along the true trajectory.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from nav import kalman as kf
from nav.constellation import EnuFrame, gps_like, satellite_elevation_deg
from nav.geometry import to_network_frame

from ..navigator import field_tie as ft
from ..navigator.ins_ekf import InsTuning
from ..navigator.triad_ekf import (Epoch, PaperFilter, PaperTuning, TriadEkf, initial_fix, paper_p0,
                                  start_from_window)
from ..world import baro as wbaro
from ..world import clock as wclock
from ..world import sky
from ..world.imu import ImuEmulator, preset as imu_preset
from ..world.motion import Straight

DEFAULT_STATIONS_M = np.array([[50e3, 50e3, 30.0], [-50e3, -50e3, 10.0], [50e3, -50e3, 50.0], [-50e3, 50e3, 20.0]])


@dataclass
class TriadCase:
    """One Monte Carlo case (defaults: seed spec sec. 1.8 choices, docs/triad.md)."""

    name: str = "4sv"
    n_sv: int = 4
    gs_idx: tuple = ()
    duration_s: float = 2000.0
    runs: int = 100
    seed: int = 2
    imu: str = "navigation"
    imu_rate_hz: float = 10.0
    sigma_sat_m: float = 3.0
    sigma_gs_m: float = 5.0
    mask_deg: float = 10.0
    lat_deg: float = 55.75
    lon_deg: float = 37.62
    altitude_m: float = 10_000.0
    speed_m_s: float = 200.0
    heading_deg: float = 0.0  # track angle from east, counter-clockwise
    start_m: tuple = (-50e3, 0.0)
    epoch_t0_s: float = 3000.0  # almanac time of the flight's start (all times are almanac times)
    stations_m: np.ndarray = field(default_factory=lambda: DEFAULT_STATIONS_M.copy())
    tie: str = "survey"  # "survey" (Procrustes fit on tie stations) or "perfect" (yardstick)
    tie_idx: tuple = (0, 1, 2)
    sigma_n_m: float = 0.5  # self-survey error per coordinate (seed 000: below sigma_d)
    sigma_tie_m: tuple = (0.05, 0.05, 0.1)  # geodetic survey (E, N, U)
    init_window_s: float = 10.0
    baro: wbaro.BaroModel = field(default_factory=wbaro.BaroModel)
    clock: wclock.ClockModel = field(default_factory=wclock.ClockModel)
    paper: PaperTuning = field(default_factory=PaperTuning)
    use_baro: bool = True
    station_states: bool = True  # our filter estimates the ranged stations' tie errors (else: white)
    pcrb: bool = True
    paper_filter: bool = True


@dataclass
class TriadResult:
    t_s: np.ndarray  # (K,) record times from t0
    err_m: np.ndarray  # (M, K, 3) ours
    P_pos: np.ndarray  # (M, K, 3, 3)
    nees_pos: np.ndarray  # (M, K) 3 dof
    pcrb_pos: np.ndarray | None  # (K, 3, 3)
    err_paper_m: np.ndarray | None
    P_paper: np.ndarray | None
    nees_paper: np.ndarray | None
    sat_ids: np.ndarray
    stats: dict
    wall_s: float
    init_sigma_m: float

    def rms_radial(self, err=None) -> np.ndarray:
        e = self.err_m if err is None else err
        return np.sqrt(np.mean(np.sum(e**2, axis=-1), axis=0))


def _world_sky(case, alm, frame, t_ep, p_tr, M, rng):
    """The sky: visible satellites (N,), the case's satellites, receiver clocks (K, M, 2) and pseudoranges
    (K, MM, N), NaN when below the mask; the last run noise-free when ``case.pcrb``."""
    T0, W = case.epoch_t0_s, case.init_window_s
    K = t_ep.size
    e0, _ = alm.ecef(T0 + W)
    el0 = satellite_elevation_deg(frame.from_ecef(e0), p_tr[int(W)][None, :])
    visible = np.flatnonzero(el0 >= case.mask_deg)
    case_ids = visible[np.argsort(-el0[visible])][: case.n_sv]
    _, r_all, el_all, ttx_all = sky.satellites_seen(alm, frame, p_tr, t_ep, visible)
    clk = wclock.sample(case.clock, t_ep, M, rng)  # (K, M, 2)
    clean = sky.clean_pseudorange_m(alm, visible, r_all, el_all, ttx_all)  # (K, N)
    rho_sat = clean[:, None, :] + clk[:, :, 0:1] + case.sigma_sat_m * rng.standard_normal((K, M, visible.size))
    tracked = el_all >= case.mask_deg
    if case.pcrb:
        rho_sat = np.concatenate([rho_sat, clean[:, None, :]], axis=1)
    rho_sat = np.where(tracked[:, None, :], rho_sat, np.nan)  # (K, MM, N)
    return visible, case_ids, clk, rho_sat


def _world_ground_ranges(case, p_tr, clk, M, rng):
    """Indices (j,) of the ranged ground stations and their pseudoranges (K, MM, j)."""
    K = p_tr.shape[0]
    g_true = np.asarray(case.stations_m, float)
    gidx = np.asarray(case.gs_idx, dtype=int)
    r_g = np.linalg.norm(p_tr[:, None, :] - g_true[None, gidx], axis=-1)  # (K, j)
    rho_gs = r_g[:, None, :] + clk[:, :, 0:1] + case.sigma_gs_m * rng.standard_normal((K, M, gidx.size))
    if case.pcrb:
        rho_gs = np.concatenate([rho_gs, r_g[:, None, :]], axis=1)
    return gidx, rho_gs


def _world_ties(case, frame, M, rng) -> ft.FieldTie:
    """The field ties of all runs (stacked; the truth appended when ``case.pcrb``)."""
    g_true = np.asarray(case.stations_m, float)
    pn_true, _, _ = to_network_frame(g_true, z_ref=min(3, len(g_true) - 1))
    tidx = np.asarray(case.tie_idx, dtype=int)
    lat_t, lon_t, h_t = frame.to_geodetic(g_true[tidx])
    # survey errors are drawn whatever the tie mode, so a perfect tie sees the same world otherwise
    pn_err = case.sigma_n_m * rng.standard_normal((M,) + pn_true.shape)
    geo_err = np.asarray(case.sigma_tie_m) * rng.standard_normal((M, tidx.size, 3))
    ties = []
    for m in range(M):
        if case.tie == "perfect":
            ties.append(ft.perfect(g_true))
            continue
        surveyed = frame.from_geodetic(lat_t, lon_t, h_t) + geo_err[m]
        ties.append(ft.tie(pn_true + pn_err[m], case.sigma_n_m, tidx, surveyed, np.asarray(case.sigma_tie_m)))
    if case.pcrb:
        ties.append(ft.FieldTie(g_true, ties[0].cov_m2, np.eye(3), np.zeros(3), ties[0].cov_full_m2))
    return ft.stack(ties)


def _start_filters(case, pre, alm, frame, x, cov, f_mean, cost, tie_all, t0_s):
    """Our filter and (``case.paper_filter``, else None) the paper's, started from the window's fix."""
    tn = InsTuning.from_preset(pre, q_b=case.clock.q_b_m2_s, q_d=case.clock.q_d_m2_s3,
                               sigma_baro_m=case.baro.sigma_m, sigma_baro_bias_m=case.baro.sigma_bias_m,
                               tc_baro_s=case.baro.tc_s, max_prop_s=1.0)
    st = start_from_window(tn, x, cov, f_mean, cost, 0)
    ekf = TriadEkf(tn, alm, frame, st.p, st.v, st.C, st.clk, st.P0, case.sigma_sat_m, case.mask_deg, t0_s,
                   stations=tie_all if case.station_states else None)
    paper = None
    if case.paper_filter:
        paper = PaperFilter(tn, case.paper, alm, frame, st.p, st.v, st.C, st.clk, paper_p0(st.P_pvc, case.paper, tn),
                            case.sigma_sat_m, case.mask_deg, t0_s)
    return ekf, paper


def _epoch_update(ekf, paper, ep, stats) -> None:
    """One epoch's update of the filters; our filter's counts added to ``stats``."""
    for f in (ekf, paper) if paper else (ekf,):
        s = f.epoch(ep)
        if f is ekf:
            for key in stats:
                stats[key] += s[key]


def _record_buffers(M, n_rec):
    """Empty position errors (M, n_rec, 3), covariances (M, n_rec, 3, 3) and NEES (M, n_rec)."""
    return np.empty((M, n_rec, 3)), np.empty((M, n_rec, 3, 3)), np.empty((M, n_rec))


def _record(f, pt, M, i, err, Pp, nees) -> None:
    """Position error, covariance and NEES of filter ``f``'s first ``M`` runs into column ``i``."""
    e = f.p[:M] - pt
    err[:, i] = e
    Pp[:, i] = f.P[:M, :3, :3]
    nees[:, i] = kf.nees(e, Pp[:, i])


def simulate(case: TriadCase, progress=None) -> TriadResult:
    """Run ``case`` (module doc)."""
    rng = np.random.default_rng([case.seed, 2002, case.runs])
    M = case.runs
    pre = imu_preset(case.imu).with_(rate_hz=case.imu_rate_hz)
    dt = 1.0 / case.imu_rate_hz
    steps_per_epoch = int(round(case.imu_rate_hz))
    frame = EnuFrame(case.lat_deg, case.lon_deg, 0.0)
    alm = gps_like()
    hd = np.radians(case.heading_deg)
    T0 = case.epoch_t0_s
    motion = Straight(np.array([case.start_m[0], case.start_m[1], case.altitude_m]),
                      case.speed_m_s * np.array([np.cos(hd), np.sin(hd), 0.0]), T0)
    W = case.init_window_s
    t_end = W + case.duration_s
    t_ep = T0 + np.arange(0.0, t_end + 1e-9, 1.0)  # epochs
    p_tr = motion.pva(t_ep)[0]
    visible, case_ids, clk, rho_sat = _world_sky(case, alm, frame, t_ep, p_tr, M, rng)
    gidx, rho_gs = _world_ground_ranges(case, p_tr, clk, M, rng)
    tie_all = _world_ties(case, frame, M, rng).subset(gidx)
    # --- world: baro, IMU ------------------------------------------------------------------------
    baro = wbaro.sample(case.baro, p_tr[:, 2] + frame.h_m, t_ep, M, rng)
    if case.pcrb:
        baro = np.concatenate([baro, p_tr[:, 2:3] + frame.h_m], axis=1)
    imu = ImuEmulator(pre, M, rng)
    n_imu = int(round(t_end / dt))

    def increments(i0, n):
        dth_t, dv_t = motion.increments(T0 + i0 * dt, dt, n)
        g, a = imu.measure(dth_t, dv_t)
        if case.pcrb:
            g = np.concatenate([g, dth_t[:, None, :]], axis=1)
            a = np.concatenate([a, dv_t[:, None, :]], axis=1)
        return g, a

    # --- navigator start ---------------------------------------------------------------------------
    nW = int(round(W / dt))
    g_w, a_w = increments(0, nW)
    f_mean = a_w.sum(axis=0) / W
    kW = int(round(W)) + 1
    rho_w = np.swapaxes(rho_sat[:kW], 0, 1)  # (MM, kW, N)
    x, cov, cost = initial_fix(alm, frame, t_ep[:kW], visible, rho_w, case.sigma_sat_m, T0 + W)
    ekf, paper = _start_filters(case, pre, alm, frame, x, cov, f_mean, cost, tie_all, T0 + W)
    # --- main loop --------------------------------------------------------------------------------
    col = {int(s): i for i, s in enumerate(visible)}
    cidx = np.array([col[int(s)] for s in case_ids], dtype=int)
    n_rec = int(round(case.duration_s))
    t_rec = np.empty(n_rec)
    err, Pp, nees = _record_buffers(M, n_rec)
    pcrb = np.empty((n_rec, 3, 3)) if case.pcrb else None
    errp, Ppp, neesp = _record_buffers(M, n_rec) if paper else (None, None, None)
    stats = {"sat_used": 0, "sat_masked": 0, "gs_used": 0}
    w0 = time.perf_counter()
    chunk = 100 * steps_per_epoch
    i_rec = 0
    for c0 in range(nW, n_imu, chunk):
        n = min(chunk, n_imu - c0)
        g_m, a_m = increments(c0, n)
        for i in range(n):
            for f in (ekf, paper) if paper else (ekf,):
                f.imu(g_m[i], a_m[i])
            if (c0 + i + 1) % steps_per_epoch:
                continue
            k = (c0 + i + 1) // steps_per_epoch
            rs = rho_sat[k][:, cidx]
            ok = np.all(np.isfinite(rs[:M]), axis=0)  # tracked by the receiver (the same sky for every run)
            ep = Epoch(t_ep[k], case_ids[ok], rs[:, ok], tie_all, rho_gs[k], case.sigma_gs_m,
                       baro[k] if case.use_baro else None)
            _epoch_update(ekf, paper, ep, stats)
            pt = p_tr[k]
            t_rec[i_rec] = t_ep[k] - T0 - W
            _record(ekf, pt, M, i_rec, err, Pp, nees)
            if case.pcrb:
                pcrb[i_rec] = ekf.P[M, :3, :3]
            if paper:
                _record(paper, pt, M, i_rec, errp, Ppp, neesp)
            i_rec += 1
        if progress:
            progress(f"{case.name}: {(c0 + n) * dt - W:.0f}/{case.duration_s:.0f} s")
    init_sigma = float(np.sqrt(np.mean(np.trace(cov[:M, :3, :3], axis1=-2, axis2=-1))))
    return TriadResult(t_rec[:i_rec], err[:, :i_rec], Pp[:, :i_rec], nees[:, :i_rec],
                       pcrb[:i_rec] if case.pcrb else None, errp[:, :i_rec] if paper else None,
                       Ppp[:, :i_rec] if paper else None, neesp[:, :i_rec] if paper else None,
                       case_ids, stats, time.perf_counter() - w0, init_sigma)
