"""The triad (seed 002): strapdown INS + barometric altimeter + satellite and LARNS pseudoranges in one
tightly coupled error-state filter with one receiver clock (navigator side: no truth, no world).

Frame: the navigation frame is a local level frame tied to the Earth, ENU at a chosen geodetic origin
(:class:`EnuFrame`); satellites come from the broadcast almanac (:mod:`nav.constellation`) in ECEF
and are rotated/translated into it, ground stations come from the field's Earth tie
(:mod:`aircraft.navigator.field_tie`). A pseudorange is invariant under that rigid transform, so the
flat-frame mechanization of :mod:`nav.strapdown` serves as is (docs/triad.md lists what the
flat, non-rotating frame neglects; the world emulates the same physics).

Two filters:

* :class:`TriadEkf` (ours): :class:`aircraft.navigator.ins_ekf.InsEkf` with the layout
  ``p, v, phi, ba, bg, bac, bgc, clk_b, clk_d, baro_b`` (24 states). One epoch's satellite and
  ground-station pseudoranges (seed 002 eq. 6, each with its own variance) and the baro altitude are
  one measurement batch with a diagonal ``R``, applied as sequential scalar Joseph updates (exact for a
  diagonal ``R`` in the linear case, tests/aircraft/test_triad.py). Satellites below the elevation mask (seen
  from the nominal position) are dropped and counted; the state never depends on which satellites
  are tracked, so a satellite rising or setting only changes the rows of ``H``.
* :class:`PaperFilter`: the seed spec's reconstruction of the paper's 11-state kinematic error filter
  (sec. 1.4): ``[dp, db, dv, dd, da]`` (kept internally as ``p, v, b, d, a`` so the clock pair is
  contiguous) plus the baro bias the spec's sec. 1.8 adds for the baro measurement (12 states). The
  error of the INS acceleration is a Gauss-Markov process with ``sigma_a``, ``T_a``; attitude is not
  a state, so the strapdown's attitude is never corrected (its effect is what ``da`` absorbs).
  Closed loop: position, velocity, clock and the acceleration correction are fed back (sec. 1.5 item 8).

Error convention (as :mod:`nav.errorstate`): ``true = nominal + delta`` (the paper's ``dx = x~ - x``
with the opposite sign).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nav import errorstate as es
from nav.constellation import Almanac, EnuFrame, satellite_elevation_deg, tropo_delay_m
from nav.geometry import SPEED_OF_LIGHT_M_S, line_of_sight
from nav.kalman import chol_solve, symmetrize
from nav.rotations import dcm_from_euler, euler_from_dcm
from nav.strapdown import G0_M_S2

from .ins_ekf import BaroAltitude, InsEkf, InsTuning, Pseudorange, initial_covariance

TRIAD_LAYOUT = es.ErrorLayout(turn_on=True, tilt=False, clock=True, baro=True)


@dataclass(frozen=True)
class TriadLayout(es.ErrorLayout):
    """:class:`nav.errorstate.ErrorLayout` plus the position errors of ``stations`` ranged ground
    stations (random constants, 3 each, after every other state)."""

    stations: int = 0

    @property
    def base_n(self) -> int:
        return es.ErrorLayout.n.fget(self)

    def GS(self, j: int) -> slice:
        i = self.base_n + 3 * j
        return slice(i, i + 3)

    @property
    def n(self) -> int:
        return self.base_n + 3 * self.stations
UP = np.array([0.0, 0.0, 1.0])


def satellites_at_transmission(alm: Almanac, frame: EnuFrame, ids: np.ndarray, t_rx_s: float,
                               rho_m: np.ndarray, clock_m: np.ndarray) -> np.ndarray:
    """Local satellite positions (M, k, 3) at their transmission times ``t_rx - (rho - b^) / c``.

    ``rho_m`` (M, k) measured pseudoranges, ``clock_m`` (M,) the nominal receiver clock. The Earth is
    not rotated during the signal's flight (the world's frame is Earth-fixed and non-rotating too)."""
    t_tx = t_rx_s - (rho_m - clock_m[:, None]) / SPEED_OF_LIGHT_M_S  # (M, k)
    p, _ = alm.ecef(t_tx)  # (M, k, N, 3): all satellites at each column's time
    idx = np.asarray(ids)
    sel = p[:, np.arange(idx.size), idx, :]  # (M, k, 3)
    return frame.from_ecef(sel)


def broadcast_corrections_m(alm: Almanac, ids: np.ndarray, t_rx_s: float, sat_m: np.ndarray,
                            p_m: np.ndarray) -> np.ndarray:
    """What the receiver subtracts from a satellite pseudorange (M, k): the troposphere model at the
    nominal elevation minus the broadcast satellite clock ``c (af0 + af1 t)``."""
    el = satellite_elevation_deg(sat_m, p_m[:, None, :])
    return tropo_delay_m(el) - alm.clock_m(t_rx_s)[..., np.asarray(ids)]


@dataclass
class Epoch:
    """One measurement epoch at an IMU sample time ``t_s``.

    ``sat_ids`` (k,) almanac indices, ``sat_rho_m`` (M, k); ``gs`` the ground stations in the local
    frame (a :class:`aircraft.navigator.field_tie.FieldTie`, arrays (M, j, ...)), ``gs_rho_m`` (M, j),
    ``gs_sigma_m`` their noise (the tie's covariance is added per update); ``baro_m`` (M,) or None."""

    t_s: float
    sat_ids: np.ndarray
    sat_rho_m: np.ndarray
    gs: object = None
    gs_rho_m: np.ndarray | None = None
    gs_sigma_m: float = 5.0
    baro_m: np.ndarray | None = None


class TriadMixin:
    """The epoch update shared by both filters (they differ in state and dynamics, not in measurements)."""

    alm: Almanac
    frame: EnuFrame
    sigma_sat_m: float
    mask_deg: float

    def epoch(self, ep: Epoch) -> dict:
        """Apply one epoch (module doc). Returns counts: ``sat_used``, ``sat_masked`` (per run summed),
        ``gs_used``."""
        self.propagate()
        stats = {"sat_used": 0, "sat_masked": 0, "gs_used": 0}
        k = len(ep.sat_ids)
        if k:
            sat = satellites_at_transmission(self.alm, self.frame, ep.sat_ids, ep.t_s, ep.sat_rho_m, self.clk[:, 0])
            z = ep.sat_rho_m - broadcast_corrections_m(self.alm, ep.sat_ids, ep.t_s, sat, self.p)
            el = satellite_elevation_deg(sat, self.p[:, None, :])
            for i in range(k):
                ok = el[:, i] >= self.mask_deg
                stats["sat_masked"] += int(np.sum(~ok))
                stats["sat_used"] += int(np.sum(ok))
                if ok.any():
                    self.update(Pseudorange(sat[:, i], ep.t_s), z[:, i], self.sigma_sat_m**2, None if ok.all() else ok)
        if ep.gs_rho_m is not None and ep.gs_rho_m.shape[-1]:
            if getattr(self, "gs", None) is not None:  # the filter's own station states
                for j in range(ep.gs_rho_m.shape[-1]):
                    self.update(StationPseudorange(j, ep.t_s), ep.gs_rho_m[:, j], ep.gs_sigma_m**2)
                    stats["gs_used"] += self.M
            else:  # the tie's share as white range noise
                var = ep.gs.range_var_m2(self.p, ep.gs_sigma_m)  # (M, j) at the nominal before the batch
                for j in range(ep.gs_rho_m.shape[-1]):
                    self.update(Pseudorange(ep.gs.stations_m[:, j], ep.t_s), ep.gs_rho_m[:, j], var[:, j])
                    stats["gs_used"] += self.M
        if ep.baro_m is not None:
            self.update(BaroAltitude(UP, ep.t_s, self.frame.h_m), ep.baro_m, self.tn.sigma_baro_m**2)
        return stats


class TriadEkf(TriadMixin, InsEkf):
    """Our triad filter (module doc): :class:`InsEkf` on :data:`TRIAD_LAYOUT` in a :class:`EnuFrame`.

    Parameters as :class:`InsEkf` (``tau`` zero and ``sign`` +1: the ENU frame is level by
    construction; ``P0`` over :data:`TRIAD_LAYOUT`) plus the almanac, frame, satellite pseudorange
    sigma and elevation mask; ``stations``: the ranged ground stations from the Earth tie
    (:class:`aircraft.navigator.field_tie.FieldTie` with arrays (M, j, ...)): their position errors
    become states with the tie's joint covariance as the prior (the epoch's ground pseudoranges are in
    this order). Without it the ground stations are taken from each epoch with the white treatment."""

    def __init__(self, tn: InsTuning, alm: Almanac, frame: EnuFrame, p_m, v_m_s, C_nb, clock, P0,
                 sigma_sat_m: float = 3.0, mask_deg: float = 10.0, t0_s: float = 0.0, stations=None):
        M = np.asarray(p_m).shape[0]
        j = 0 if stations is None else stations.stations_m.shape[-2]
        L = TriadLayout(turn_on=True, tilt=False, clock=True, baro=True, stations=j)
        nb = L.base_n
        P = np.zeros((M, L.n, L.n))
        P[:, :nb, :nb] = np.broadcast_to(np.asarray(P0, float), (M, nb, nb))
        self.gs = None
        if j:
            P[:, nb:, nb:] = np.broadcast_to(stations.cov_full_m2, (M, 3 * j, 3 * j))
        super().__init__(tn, L, p_m, v_m_s, C_nb, clock, P, np.zeros((M, 2)), 1.0, t0_s)
        if j:
            self.gs = np.broadcast_to(np.asarray(stations.stations_m, float), (M, j, 3)).copy()
        self.alm, self.frame, self.sigma_sat_m, self.mask_deg = alm, frame, sigma_sat_m, mask_deg

    def inject(self, dx: np.ndarray) -> None:
        super().inject(dx)
        if self.gs is not None:
            self.gs = self.gs + dx[:, self.L.base_n:].reshape(self.gs.shape)


@dataclass(frozen=True)
class StationPseudorange:
    """Pseudorange to the filter's ground station ``j`` (its nominal position ``ekf.gs[:, j]``):
    :class:`Pseudorange` plus ``-u`` on that station's position-error states."""

    j: int
    t_rx_s: float

    def predict(self, ekf: "TriadEkf") -> tuple[np.ndarray, np.ndarray]:
        pred, H = Pseudorange(ekf.gs[:, self.j], self.t_rx_s).predict(ekf)
        H[:, ekf.L.GS(self.j)] = -H[:, ekf.L.P]
        return pred, H


# --- the paper's filter ---------------------------------------------------------------------------


@dataclass(frozen=True)
class PaperLayout:
    """Seed 002's 11-element error state ``[dp, dv, db, dd, da]`` + baro bias (paper order
    ``x, y, z, tau, x', y', z', tau', a``: permutation ``[0, 1, 2, 6, 3, 4, 5, 7, 8, 9, 10]``)."""

    clock: bool = True
    baro: bool = True
    tilt: bool = False
    turn_on: bool = False
    P = slice(0, 3)
    V = slice(3, 6)
    CLK = slice(6, 8)
    ACC = slice(8, 11)
    BARO = slice(11, 12)
    n = 12


@dataclass(frozen=True)
class PaperTuning:
    """The paper filter's model (spec sec. 1.4 defaults): INS acceleration error GM ``sigma_a`` (m/s^2),
    ``T_a`` (s); clock, baro and priors come from the :class:`InsTuning` it shares with ours."""

    sigma_a_m_s2: float = 2e-3
    tc_a_s: float = 300.0


def paper_matrices(pt: PaperTuning, tn: InsTuning) -> tuple[np.ndarray, np.ndarray]:
    """Continuous ``A`` and ``Q`` (12, 12) of spec sec. 1.4 (``A = [[0 I 0],[0 0 G],[0 0 -I/T_a]]``)."""
    L = PaperLayout()
    A = np.zeros((L.n, L.n))
    A[L.P, L.V] = np.eye(3)
    A[L.V, L.ACC] = np.eye(3)
    A[L.ACC, L.ACC] = -np.eye(3) / pt.tc_a_s
    A[6, 7] = 1.0
    A[11, 11] = -1.0 / tn.tc_baro_s
    Q = np.zeros((L.n, L.n))
    Q[L.ACC, L.ACC] = 2.0 * pt.sigma_a_m_s2**2 / pt.tc_a_s * np.eye(3)
    Q[6, 6], Q[7, 7] = tn.q_b, tn.q_d
    Q[11, 11] = 2.0 * tn.sigma_baro_bias_m**2 / tn.tc_baro_s
    return A, Q


class PaperFilter(TriadMixin, InsEkf):
    """The paper's kinematic error filter (module doc) on the same strapdown nominal as ours.

    ``P0`` (M, 12, 12) or (12, 12) in :class:`PaperLayout` order."""

    def __init__(self, tn: InsTuning, pt: PaperTuning, alm: Almanac, frame: EnuFrame, p_m, v_m_s, C_nb,
                 clock, P0, sigma_sat_m: float = 3.0, mask_deg: float = 10.0, t0_s: float = 0.0):
        M = np.asarray(p_m).shape[0]
        L0 = es.ErrorLayout(turn_on=False, tilt=False, clock=True, baro=True)
        super().__init__(tn, L0, p_m, v_m_s, C_nb, clock, np.zeros((L0.n, L0.n)), np.zeros((M, 2)), 1.0, t0_s)
        self.L = PaperLayout()
        self.pt = pt
        self.A, self.Qc = paper_matrices(pt, tn)
        self.P = np.broadcast_to(np.asarray(P0, float), (M, 12, 12)).copy()
        self.acc_n = np.zeros((M, 3))  # estimated INS acceleration error (navigation frame)
        self.alm, self.frame, self.sigma_sat_m, self.mask_deg = alm, frame, sigma_sat_m, mask_deg

    def imu(self, dth: np.ndarray, dv: np.ndarray) -> None:
        # the navigation-frame acceleration correction as a body-frame accelerometer correction
        self.ba = np.einsum("mji,mj->mi", self.C, self.acc_n)
        super().imu(dth, dv)

    def propagate(self) -> None:
        T = self.t_s - self.t_prop
        if T <= 0:
            return
        Phi, Qd = es.discretize(self.A, self.Qc, T)
        self.P = es.propagate(self.P, Phi, Qd)
        self.clk[:, 0] += self.clk[:, 1] * T
        self.acc_n *= np.exp(-T / self.pt.tc_a_s)
        self.bh *= np.exp(-T / self.tn.tc_baro_s)
        self._Csum[:] = 0.0
        self._fsum[:] = 0.0
        self.t_prop = self.t_s

    def inject(self, dx: np.ndarray) -> None:
        L = self.L
        self.p = self.p + dx[:, L.P]
        self.v = self.v + dx[:, L.V]
        self.v_prev = self.v_prev + dx[:, L.V]
        self.clk = self.clk + dx[:, L.CLK]
        self.acc_n = self.acc_n - dx[:, L.ACC]  # true accel = nominal + da: subtract less, i.e. correct by -da
        self.bh = self.bh + dx[:, 11]


def paper_p0(P_pvc: np.ndarray, pt: PaperTuning, tn: InsTuning) -> np.ndarray:
    """Paper-filter prior (M, 12, 12) from the initializer's ``[p, v, b, d]`` covariance (M, 8, 8)."""
    M = P_pvc.shape[0]
    P0 = np.zeros((M, 12, 12))
    P0[:, :8, :8] = P_pvc
    P0[:, 8:11, 8:11] = pt.sigma_a_m_s2**2 * np.eye(3)
    P0[:, 11, 11] = tn.sigma_baro_bias_m**2
    return P0


# --- start: a window fix from the full sky and a levelling -------------------------------------------


@dataclass
class TriadStart:
    """Initial nominal states (M, ...) and the prior; ``P_pvc`` (M, 8, 8) the fix's ``[p, v, b, d]``
    covariance; ``cost`` (M,) the fix's weighted residual sum of squares; ``dof`` its degrees of freedom."""

    p: np.ndarray
    v: np.ndarray
    C: np.ndarray
    clk: np.ndarray
    P0: np.ndarray
    P_pvc: np.ndarray
    cost: np.ndarray
    dof: int


def window_fix(t_s: np.ndarray, sat_m: np.ndarray, z_m: np.ndarray, sigma_m: float, t_ref_s: float,
               iters: int = 10) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Constant-velocity pseudorange LSQ over a short window (seed 001 eqs. 14-16 with a velocity and a
    clock drift): ``z_k = |p + v (t_k - t_ref) - s_k| + b + d (t_k - t_ref)``.

    Parameters
    ----------
    t_s : (K,) epoch times. sat_m : (M, K, N, 3) satellite positions (local). z_m : (M, K, N) corrected
    pseudoranges (NaN: not received). sigma_m : noise. t_ref_s : time of the solution.

    Returns
    -------
    x : (M, 8) ``[p, v, b, d]`` at ``t_ref``; cov : (M, 8, 8) ``(G^T G)^-1 sigma^2``; cost : (M,).
    """
    M = z_m.shape[0]
    dt = (np.asarray(t_s, float) - t_ref_s)[None, :, None, None]
    ok = np.isfinite(z_m)
    z = np.where(ok, z_m, 0.0)
    x = np.zeros((M, 8))
    x[:, 2] = 1e4  # above the ground: the far root is at the satellites' side of the Earth
    for _ in range(iters):
        p = x[:, None, None, :3] + x[:, None, None, 3:6] * dt
        r, u = line_of_sight(p, sat_m)
        G = np.concatenate([u, u * dt, np.ones_like(r)[..., None], dt[..., 0][..., None] * np.ones_like(r)[..., None]],
                           axis=-1)  # (M, K, N, 8)
        res = np.where(ok, z - (r + x[:, None, None, 6:7][..., 0] + x[:, None, None, 7:8][..., 0] * dt[..., 0]), 0.0)
        G = np.where(ok[..., None], G, 0.0).reshape(M, -1, 8)
        N = symmetrize(np.swapaxes(G, -1, -2) @ G)
        dx = chol_solve(N, np.einsum("mki,mk->mi", G, res.reshape(M, -1))[..., None])[..., 0]
        x = x + dx
        if np.all(np.abs(dx) < 1e-4):
            break
    cov = sigma_m**2 * chol_solve(N, np.broadcast_to(np.eye(8), N.shape).copy())
    return x, symmetrize(cov), np.sum(res**2, axis=(1, 2)) / sigma_m**2


def levelled_attitude(f_b_mean: np.ndarray, v_m_s: np.ndarray) -> np.ndarray:
    """``C_nb`` (M, 3, 3) from the mean specific force (M, 3) over a window (roll, pitch) and the fix's
    velocity (heading = track: the aircraft flies without sideslip)."""
    f = np.asarray(f_b_mean, float)
    roll = np.arctan2(f[:, 1], f[:, 2])
    pitch = np.arctan2(-f[:, 0], np.hypot(f[:, 1], f[:, 2]))
    yaw = np.arctan2(v_m_s[:, 1], v_m_s[:, 0])
    return dcm_from_euler(roll, pitch, yaw)


def start_from_window(tn: InsTuning, x: np.ndarray, cov: np.ndarray, f_b_mean: np.ndarray, cost: np.ndarray,
                      dof: int, level_floor_rad: float = 2e-5) -> TriadStart:
    """Our filter's start from :func:`window_fix` and :func:`levelled_attitude`.

    Prior: the fix's ``[p, v, b, d]`` covariance (with its cross terms); the level attitude error is
    the one the accelerometer biases leave in the levelling, ``phi = A C^ (dba + dbac)`` with
    ``A = [[0, -1/g, 0], [1/g, 0, 0], [0, 0, 0]]`` (so ``-[f_n x] phi - C^ db`` has no horizontal part),
    carried with its correlation to the biases, plus a floor ``level_floor_rad``; heading
    ``sigma_v_cross / speed``; biases and baro bias from the tuning."""
    L = TRIAD_LAYOUT
    M = x.shape[0]
    v = x[:, 3:6]
    C = levelled_attitude(f_b_mean, v)
    P0 = np.broadcast_to(initial_covariance(L, tn, np.zeros(2), 1.0), (M, L.n, L.n)).copy()
    idx = np.r_[0:3, 3:6, L.CLK.start, L.CLK.start + 1]
    P0[:, idx[:, None], idx[None, :]] = cov
    speed = np.linalg.norm(v[:, :2], axis=-1)
    cross = np.stack([-v[:, 1], v[:, 0], np.zeros(M)], axis=-1) / np.maximum(speed, 1.0)[:, None]
    var_cross = np.einsum("mi,mij,mj->m", cross, cov[:, 3:6, 3:6], cross)
    sig_yaw = np.sqrt(var_cross) / np.maximum(speed, 1.0)
    A = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]) / G0_M_S2
    J = A @ C  # (M, 3, 3): phi = J (dba + dbac)
    Sa, Sc = tn.sigma_gm_a**2 * np.eye(3), tn.turn_on_a**2 * np.eye(3)
    P0[:, L.ATT, L.ATT] = J @ (Sa + Sc) @ np.swapaxes(J, -1, -2) + level_floor_rad**2 * np.diag([1.0, 1.0, 0.0])
    P0[:, 8, 8] += np.maximum(sig_yaw, 1e-4) ** 2
    P0[:, L.ATT, L.BA] = J @ Sa
    P0[:, L.BA, L.ATT] = np.swapaxes(J @ Sa, -1, -2)
    P0[:, L.ATT, L.BAC] = J @ Sc
    P0[:, L.BAC, L.ATT] = np.swapaxes(J @ Sc, -1, -2)
    return TriadStart(x[:, :3], v, C, x[:, 6:8], P0, cov, cost, dof)


def turn_corrected(st: TriadStart, w_z_rad_s: float, window_s: float, att_sigma_rad: float) -> TriadStart:
    """The start of one run (``st``, M = 1) corrected for a coordinated turn seen by the window's mean
    yaw rate ``w_z_rad_s`` (gyro, body z ~ up), in place.

    The levelling reads no bank in a coordinated turn (the specific force stays on the body z axis) and
    the constant-velocity fix's track is the mid-window one: the bank ``-atan(V w / g)`` is added and the
    heading and the velocity are turned by ``w W / 2``. Both assume a steady turn over the window; the
    attitude prior is widened by ``att_sigma_rad`` per axis to cover what that misses."""
    speed = float(np.linalg.norm(st.v[0, :2]))
    roll, pitch, yaw = euler_from_dcm(st.C[0])
    dpsi = w_z_rad_s * window_s / 2
    st.C[0] = dcm_from_euler(roll - np.arctan(speed * w_z_rad_s / G0_M_S2), pitch, yaw + dpsi)
    c, s_ = np.cos(dpsi), np.sin(dpsi)
    st.v[0, :2] = np.array([[c, -s_], [s_, c]]) @ st.v[0, :2]
    att = TRIAD_LAYOUT.ATT
    st.P0[:, att, att] += np.diag([att_sigma_rad**2] * 3)
    return st


def initial_fix(alm: Almanac, frame: EnuFrame, t_s: np.ndarray, ids: np.ndarray, rho_m: np.ndarray,
                sigma_m: float, t_ref_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`window_fix` from raw pseudoranges (M, K, N) of satellites ``ids`` (N,) (NaN: not tracked):
    satellite positions at transmission, broadcast clock removed; a first fix, then the troposphere
    model at the fix's elevations and a second fix."""
    M, K, N = rho_m.shape
    sat = np.stack([satellites_at_transmission(alm, frame, ids, t, np.nan_to_num(rho_m[:, k], nan=2.2e7), np.zeros(M))
                    for k, t in enumerate(t_s)], axis=1)  # (M, K, N, 3)
    clk = np.stack([alm.clock_m(t)[np.asarray(ids)] for t in t_s])  # (K, N)
    z = rho_m + clk[None]
    x, cov, cost = window_fix(t_s, sat, z, sigma_m, t_ref_s)
    p = x[:, None, None, :3] + x[:, None, None, 3:6] * (np.asarray(t_s) - t_ref_s)[None, :, None, None]
    z2 = z - tropo_delay_m(satellite_elevation_deg(sat, p))
    return window_fix(t_s, sat, z2, sigma_m, t_ref_s)
