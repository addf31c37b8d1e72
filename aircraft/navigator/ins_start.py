"""Honest in-flight start of the inertial navigator: LARNS broadcasts and IMU samples only.

The aircraft is already flying when it joins. It listens for a window of ``W`` seconds (default
10 s), keeping the pseudoranges it receives (reception time, broadcast station position and
covariance, pseudorange, variance) and its IMU increments, and then starts its error-state EKF at
the window's end ``t_e`` with a mean and a covariance built from those inputs alone:

1. **Radio fix with motion** (position, velocity, clock). A first guess from the broadcast-only
   initializer (:func:`aircraft.navigator.radio.initializer.snapshot_fix`: multi-start LSQ on the window's first
   cycle), then a Gauss-Newton batch fit of every pseudorange of the window to a constant-acceleration
   track and a two-state clock referenced at ``t_e``:
   ``rho_i = |p_e + v_e tau_i + a tau_i^2 / 2 - s_i| + b_e + d tau_i + noise``, ``tau_i = t_i - t_e``
   (seed 003 eq. 5 with an acceleration term; the broadcast station covariance enters the range
   variance ``sigma_i^2 + u^T P_s u``). The acceleration ``a`` carries a weak manoeuvre prior
   ``N(0, accel_sigma^2 I)``. Both sides of the stations' plane are fitted (a small-height station
   set has a mirror solution) and the lower cost wins; the aircraft flies above the stations, which
   fixes which way the frame's +Z points (``sign``). Covariance ``(H^T W H + Lambda_a)^-1``.
2. **Levelling** (roll, pitch) from the mean specific force of the window expressed in the body
   frame at ``t_e`` (each sample rotated by the integrated gyro increments), matched to the
   navigation-frame specific force ``a^ - g_n(tau^)``: the fitted acceleration is used, so levelling
   works in a turn (the ellipse's 0.17 m/s^2 would otherwise be a 17 mrad level error).
3. **Heading from the track** (TRIAD with the specific force as the primary vector): body x is
   taken along the fitted velocity. This assumes no sideslip and no crab angle (wind), which holds
   for the emulated coordinated flight in still air; the stated uncertainty ``crab_sigma_rad``
   (default 20 mrad: a 1 m/s crosswind at 50 m/s) must be raised where winds blow. Gyrocompassing is
   not possible: the ADIS16480's turn-on and in-run gyro biases (20 and 6.25 deg/h) are of the order
   of Earth rate (15 deg/h) and the emulated world does not rotate.

Covariance ``P0 = A Sigma A^T`` of the error state (``true = nominal + delta``, ``C = exp(phi) C^``),
with ``z = [fit error (11), accel GM bias, accel turn-on bias, accel white-noise mean, gyro GM bias,
gyro turn-on bias (3 each), crab (1), tilt error (2)]``; first-order error model of the levelling:
``phi_level = [w x] (C^ db_a + C^ n_a + da_fit - (W / 2) C^ [f_b x] db_g) / |s| + [w x] (du/dtau) dtau``
(``w`` the unit specific force in the navigation frame, ``|s|`` its magnitude), heading error about
``w``: ``phi_w = e_c . dv_fit / |v_perp| + crab`` (``e_c = w x e_v``). The biases of the EKF's state are
the same biases that acted in the window, so they are correlated with the attitude in ``P0``.

This module never imports the world side; its inputs are message contents and IMU increments.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_triangular

from nav import errorstate as es
from nav.geometry import line_of_sight
from nav.rotations import exp_so3, skew
from nav.strapdown import G0_M_S2

from .radio.initializer import snapshot_fix
from .ins_ekf import InsTuning, tilt_attitude_jacobian

NX = 11  # fit parameters: p (3), v (3), a (3), b, d


@dataclass(frozen=True)
class StartConfig:
    """``window_s``: listening window; ``accel_sigma_m_s2``: manoeuvre prior of the window's constant
    acceleration (per axis); ``crab_sigma_rad``: heading minus course (sideslip + wind crab);
    ``min_meas``: pseudoranges needed in the window (from ``min_stations`` stations);
    ``decide_llr``: the log-likelihood ratio of the two sides of the stations' plane (summed over
    consecutive windows) that decides the side (10: odds of 22000 to 1); ``max_windows``: windows
    after which the likelier side is taken anyway; ``gn_iters``: Gauss-Newton iterations."""

    window_s: float = 10.0
    accel_sigma_m_s2: float = 1.0
    crab_sigma_rad: float = 0.02
    min_meas: int = 30
    min_stations: int = 5
    decide_llr: float = 10.0
    max_windows: int = 60
    gn_iters: int = 12


@dataclass
class RadioFix:
    """Both sides of the stations' plane: ``x`` (M, 2, 11) ``[p_e, v_e, a, b_e, d]`` at ``t_e``, ``P``
    (M, 2, 11, 11) their covariances, ``cost`` (M, 2) their weighted residual sums of squares; side 0
    lies along the plane's normal ``n`` (``n_z > 0``), side 1 against it. ``separated`` (M,): the two
    fits ended on opposite sides (None: all did). A fit started from the mirror guess can cross the
    plane and stop in a poor local fit on the other side: then that window holds no fit of one side
    and no evidence about the side (``llr`` 0), and ``valid`` (M,) is the slot holding a real fit."""

    x: np.ndarray
    P: np.ndarray
    cost: np.ndarray
    separated: np.ndarray | None = None
    valid: np.ndarray | None = None

    def llr(self) -> np.ndarray:
        """Log-likelihood ratio (M,) of side 0 against side 1, ``(cost_1 - cost_0) / 2`` (0 where the two
        fits are not on opposite sides)."""
        d = 0.5 * (self.cost[:, 1] - self.cost[:, 0])
        return d if self.separated is None else np.where(self.separated, d, 0.0)

    def rows(self, sl) -> "RadioFix":
        """The runs ``sl`` (a slice) of this fix."""
        pick = lambda a: None if a is None else a[sl]  # noqa: E731
        return RadioFix(self.x[sl], self.P[sl], self.cost[sl], pick(self.separated), pick(self.valid))


@dataclass
class InsStart:
    """Initial nominal state at ``t_s`` (leading axis M) and prior ``P0`` (M, n, n)."""

    t_s: float
    p: np.ndarray
    v: np.ndarray
    C: np.ndarray
    clock: np.ndarray
    tau: np.ndarray
    P0: np.ndarray
    sign: float
    fix: RadioFix


def _station_plane(stations_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroid (3,) and unit normal (3,) of the best-fit plane of the stations (SVD)."""
    c = stations_m.mean(axis=0)
    _, _, vt = np.linalg.svd(stations_m - c)
    return c, vt[2]


def clock_window_cov(tau_s: np.ndarray, q_b: float, q_d: float) -> np.ndarray:
    """Covariance (K, K) of the receiver clock's departure from ``b_e + d_e tau`` at ``tau`` (<= 0)
    before the reference: white frequency noise ``q_b`` (random-walk phase, ``q_b min(s_i, s_j)``)
    and random-walk frequency noise ``q_d`` (integrated Brownian motion, ``q_d m^2 (3 M - m) / 6``
    with ``m, M`` the smaller and larger of ``s = -tau``)."""
    sb = -np.asarray(tau_s, float)
    m = np.minimum(sb[:, None], sb[None, :])
    Mx = np.maximum(sb[:, None], sb[None, :])
    return q_b * m + q_d * m * m * (3.0 * Mx - m) / 6.0


def _gauss_newton(x, tau, s, cov, rho, var, Rclk, cfg: StartConfig):
    """Batched generalized Gauss-Newton on the constant-acceleration track (module doc, step 1).

    x (M, 11) start; tau (K,); s (K, 3); cov (K, 3, 3) or None; rho (M, K); var (K,) or (M, K);
    Rclk (K, K) the clock's correlated departure from a line (:func:`clock_window_cov`).
    Returns x, covariance (M, 11, 11), cost (M,) (``nu^T R^-1 nu`` plus the acceleration prior)."""
    M, K = rho.shape
    lam = np.zeros(NX)
    lam[6:9] = 1.0 / cfg.accel_sigma_m_s2**2
    t2 = 0.5 * tau * tau
    Lr = None
    for it in range(cfg.gn_iters + 1):
        pos = x[:, None, 0:3] + x[:, None, 3:6] * tau[:, None] + x[:, None, 6:9] * t2[:, None]
        r, u = line_of_sight(pos, s)
        H = np.concatenate([u, u * tau[:, None], u * t2[:, None], np.ones((M, K, 1)),
                            np.broadcast_to(tau[None, :, None], (M, K, 1))], axis=-1)
        nu = rho - (r + x[:, 9:10] + x[:, 10:11] * tau)
        if cov is None and np.ndim(var) <= 1:  # one noise covariance for every run: one Cholesky factor
            if Lr is None:
                Lr = np.linalg.cholesky(Rclk + np.diag(np.broadcast_to(var, (K,))))
            Y = solve_triangular(Lr, np.concatenate([H, nu[..., None]], axis=-1).transpose(1, 0, 2).reshape(K, -1),
                                 lower=True).reshape(K, M, NX + 1).transpose(1, 0, 2)
        else:
            w = var if cov is None else var + np.einsum("mki,kij,mkj->mk", u, cov, u)
            Lr = np.linalg.cholesky(Rclk + np.broadcast_to(w, (M, K))[..., None] * np.eye(K))
            Y = np.stack([solve_triangular(Lr[i], np.concatenate([H[i], nu[i, :, None]], axis=-1), lower=True)
                          for i in range(M)])
        Hw, nw = Y[..., :NX], Y[..., NX]
        N = np.swapaxes(Hw, -1, -2) @ Hw + np.diag(lam)
        g = np.einsum("mki,mk->mi", Hw, nw) - lam * x
        cost = np.einsum("mk,mk->m", nw, nw) + np.einsum("i,mi,mi->m", lam, x, x)
        Lc = np.linalg.cholesky(N)
        if it == cfg.gn_iters:
            break
        dx = np.linalg.solve(np.swapaxes(Lc, -1, -2), np.linalg.solve(Lc, g[..., None]))[..., 0]
        x = x + dx
    Li = np.linalg.solve(Lc, np.broadcast_to(np.eye(NX), Lc.shape))
    return x, np.swapaxes(Li, -1, -2) @ Li, cost


def radio_fix(t_rx_s: np.ndarray, stations_m: np.ndarray, station_cov_m2: np.ndarray | None, rho_m: np.ndarray,
              var_m2, t_e_s: float, sigma_m: float, cfg: StartConfig, q_b: float = 0.0, q_d: float = 0.0,
              guess: np.ndarray | None = None) -> RadioFix:
    """Position, velocity, acceleration and clock at ``t_e`` from the window's pseudoranges.

    Parameters
    ----------
    t_rx_s : (K,) reception times (receiver time scale). stations_m : (K, 3) broadcast positions.
    station_cov_m2 : (K, 3, 3) broadcast covariances or None. rho_m : (M, K) pseudoranges (M runs).
    var_m2 : (K,) or (M, K) range noise variances (without the station term). t_e_s : reference time.
    sigma_m : range sigma for the first-guess snapshot fix. q_b, q_d : the receiver clock's noise
    (m^2/s, m^2/s^3): its departure from a line over the window is correlated measurement noise.
    guess : (M, 11) first guess (e.g. the previous window's fit moved on); default the initializer's
    snapshot of the window's first second.
    """
    t = np.asarray(t_rx_s, float)
    s = np.asarray(stations_m, float)
    rho = np.atleast_2d(np.asarray(rho_m, float))
    M, K = rho.shape
    tau = t - t_e_s
    # first guess: the broadcast-only initializer's multi-start snapshot on the first cycle
    if guess is None:
        first = _first_cycle(t)
        c_first = None if station_cov_m2 is None else station_cov_m2[first]
        x0 = np.zeros((M, NX))
        for m in range(M):
            fix, _, _, _ = snapshot_fix("pr", s[first], c_first, rho[m, first], sigma_m, floor_z_m=None)
            x0[m, 0:3] = fix[:3]
            x0[m, 9] = fix[3]
    else:
        x0 = np.array(guess, dtype=float)
    # velocity guess from the range rates is left to Gauss-Newton (ranges are nearly linear in v)
    var = np.asarray(var_m2, float)
    c, nrm = _station_plane(s)
    nrm = nrm if nrm[2] >= 0 else -nrm
    mir = x0.copy()
    mir[:, 0:3] -= 2.0 * ((x0[:, 0:3] - c) @ nrm)[:, None] * nrm  # the mirror track: position,
    mir[:, 3:6] -= 2.0 * (x0[:, 3:6] @ nrm)[:, None] * nrm  # velocity and acceleration reflected
    mir[:, 6:9] -= 2.0 * (x0[:, 6:9] @ nrm)[:, None] * nrm
    Rclk = clock_window_cov(tau, q_b, q_d)
    xa, Pa, ca = _gauss_newton(x0, tau, s, station_cov_m2, rho, var, Rclk, cfg)
    xb, Pb, cb = _gauss_newton(mir, tau, s, station_cov_m2, rho, var, Rclk, cfg)
    a_up = ((xa[:, 0:3] - c) @ nrm >= 0)  # whether the first solution lies on side 0
    b_up = ((xb[:, 0:3] - c) @ nrm >= 0)
    x = np.where(a_up[:, None, None], np.stack([xa, xb], 1), np.stack([xb, xa], 1))
    P = np.where(a_up[:, None, None, None], np.stack([Pa, Pb], 1), np.stack([Pb, Pa], 1))
    cost = np.where(a_up[:, None], np.stack([ca, cb], 1), np.stack([cb, ca], 1))
    return RadioFix(x, P, cost, a_up != b_up, np.where(a_up, 0, 1))


def _first_cycle(t_s: np.ndarray, span_s: float = 1.0) -> np.ndarray:
    """Indices of the measurements of the window's first ``span_s`` (about one working cycle; at
    least four), for the snapshot first guess."""
    n = max(int(np.count_nonzero(t_s <= t_s[0] + span_s)), min(4, len(t_s)))
    return np.arange(n)


def window_specific_force(dth: np.ndarray, dv: np.ndarray) -> np.ndarray:
    """Mean specific force (M, 3) over the window, in the body frame at its end.

    dth, dv : (N, M, 3) gyro and accelerometer increments of the window. Each increment is rotated
    by the integrated gyro from its step to the window's end (``C_k = C_{k-1} exp(dth_k)`` relative
    to the body at the window's start, then ``C_N^T sum C_{k-1} dv_k``)."""
    N, M, _ = dth.shape
    C = np.broadcast_to(np.eye(3), (M, 3, 3)).copy()
    acc = np.zeros((M, 3))
    for k in range(N):
        Cn = C @ exp_so3(dth[k])
        acc += np.einsum("mij,mj->mi", 0.5 * (C + Cn), dv[k])
        C = Cn
    return np.einsum("mji,mj->mi", C, acc) / (N * 1.0)


def triad(f_b: np.ndarray, s_n: np.ndarray, v_n: np.ndarray) -> np.ndarray:
    """Attitude ``C_nb`` (M, 3, 3) with ``C f_b`` along ``s_n`` exactly and body x in the plane of
    ``s_n`` and ``v_n`` (TRIAD, the specific force as the primary vector)."""
    def frame(a, b):
        t1 = a / np.linalg.norm(a, axis=-1, keepdims=True)
        t2 = np.cross(a, b)
        t2 /= np.linalg.norm(t2, axis=-1, keepdims=True)
        return np.stack([t1, t2, np.cross(t1, t2)], axis=-1)

    ex = np.broadcast_to([1.0, 0.0, 0.0], f_b.shape)
    return frame(s_n, v_n) @ np.swapaxes(frame(f_b, ex), -1, -2)


def start_covariance(L: es.ErrorLayout, tn: InsTuning, fixP: np.ndarray, C: np.ndarray, f_b: np.ndarray,
                     s_n: np.ndarray, v_n: np.ndarray, tau: np.ndarray, sign: float, window_s: float,
                     crab_sigma_rad: float) -> np.ndarray:
    """``P0`` (M, n, n) = ``A Sigma A^T`` (module doc). fixP (M, 11, 11) radio fix covariance; C (M, 3, 3)
    the start attitude; f_b (M, 3) window-mean specific force (body); s_n (M, 3) its navigation-frame
    match ``a^ - g_n``; v_n (M, 3) start velocity; tau (M, 2) nominal tilt."""
    M = C.shape[0]
    smag = np.linalg.norm(s_n, axis=-1)
    wv = s_n / smag[:, None]
    Wx = skew(wv) / smag[:, None, None]  # (M, 3, 3)
    vperp = v_n - np.einsum("mi,mi->m", v_n, wv)[:, None] * wv
    vp = np.linalg.norm(vperp, axis=-1)
    ec = np.cross(wv, vperp / vp[:, None])
    nz = NX + 3 * 5 + 1 + 2
    iA, iAC, iN, iG, iGC, iCR, iT = NX, NX + 3, NX + 6, NX + 9, NX + 12, NX + 15, NX + 16
    S = np.zeros((M, nz, nz))
    S[:, :NX, :NX] = fixP
    for i0, var in ((iA, tn.sigma_gm_a**2), (iAC, tn.turn_on_a**2), (iN, tn.vrw**2 / window_s),
                    (iG, tn.sigma_gm_g**2), (iGC, tn.turn_on_g**2)):
        S[:, i0:i0 + 3, i0:i0 + 3] = var * np.eye(3)
    S[:, iCR, iCR] = crab_sigma_rad**2
    S[:, iT:iT + 2, iT:iT + 2] = tn.p0_tilt_rad**2 * np.eye(2)
    A = np.zeros((M, L.n, nz))
    A[:, L.P, 0:3] = np.eye(3)
    A[:, L.V, 3:6] = np.eye(3)
    att = L.ATT.start
    WC = Wx @ C
    A[:, L.ATT, 6:9] = Wx  # fitted acceleration error
    for i0 in (iA, iAC, iN):
        A[:, L.ATT, i0:i0 + 3] = WC
    Gb = -0.5 * window_s * WC @ skew(f_b)  # gyro bias rotating the window's samples
    for i0 in (iG, iGC):
        A[:, L.ATT, i0:i0 + 3] = Gb
    # heading about w: velocity error across the track and the crab angle
    A[:, att:att + 3, 3:6] += wv[:, :, None] * (ec / vp[:, None])[:, None, :]
    A[:, att:att + 3, iCR] = wv
    A[:, L.BA, iA:iA + 3] = np.eye(3)
    A[:, L.BG, iG:iG + 3] = np.eye(3)
    if L.turn_on:
        A[:, L.BAC, iAC:iAC + 3] = np.eye(3)
        A[:, L.BGC, iGC:iGC + 3] = np.eye(3)
    else:  # no turn-on states: their part is folded into the GM states' error
        A[:, L.BA, iAC:iAC + 3] = np.eye(3)
        A[:, L.BG, iGC:iGC + 3] = np.eye(3)
    if L.tilt:
        A[:, L.ATT, iT:iT + 2] = tilt_attitude_jacobian(tau, sign) * (G0_M_S2 / smag)[:, None, None]
        A[:, L.TILT, iT:iT + 2] = np.eye(2)
    if L.clock:
        c = L.CLK.start
        A[:, c, 9] = 1.0
        A[:, c + 1, 10] = 1.0
    P = A @ S @ np.swapaxes(A, -1, -2)
    return 0.5 * (P + np.swapaxes(P, -1, -2))


def start(L: es.ErrorLayout, tn: InsTuning, fix: RadioFix, side: np.ndarray, dth, dv, t_e_s: float,
          cfg: StartConfig | None = None, tau_nominal: np.ndarray | None = None) -> InsStart:
    """The navigator's start at ``t_e`` from a window's radio fix and IMU increments (module doc).

    Parameters
    ----------
    L, tn : the EKF's layout and tuning. fix : :func:`radio_fix` of the window ending at ``t_e``.
    side : (M,) 0/1, the side of the stations' plane decided (:class:`SideTest`); the aircraft flies
    above the stations, so that side is physically up and fixes which way +Z points.
    dth, dv : (N, M, 3) the window's IMU increments, the last one ending at ``t_e``.
    tau_nominal : (2,) nominal frame tilt (default 0: the frame assumed level; the tilt states and
    ``P0`` carry the difference).
    """
    cfg = cfg or StartConfig()
    side = np.asarray(side, dtype=int)
    M = side.shape[0]
    x = fix.x[np.arange(M), side]
    Pf = fix.P[np.arange(M), side]
    sign = np.where(side == 0, 1.0, -1.0)  # side 0 lies along n (n_z > 0): there +Z points up
    tau = np.broadcast_to(np.zeros(2) if tau_nominal is None else tau_nominal, (M, 2)).copy()
    g_n = es.gravity(tau, sign)
    s_n = x[:, 6:9] - g_n
    f_b = window_specific_force(np.asarray(dth, float), np.asarray(dv, float)) / tn.dt_s
    v = x[:, 3:6]
    C = triad(f_b, s_n, v)
    P0 = start_covariance(L, tn, Pf, C, f_b, s_n, v, tau, sign, dth.shape[0] * tn.dt_s, cfg.crab_sigma_rad)
    return InsStart(float(t_e_s), x[:, 0:3].copy(), v.copy(), C, x[:, 9:11].copy(), tau, P0,
                    sign if M > 1 else float(sign[0]), fix)


class SideTest:
    """Which side of the stations' plane the aircraft is on, from consecutive windows: the summed
    log-likelihood ratio of the two sides' fits (a sequential probability ratio test; the windows'
    data are disjoint). A small-height station set (the text's: 30-50 m out of plane) separates the
    sides by a few units of LLR per 10 s at 250 m and by tens at 1000 m."""

    def __init__(self, cfg: StartConfig, M: int):
        self.cfg = cfg
        self.llr = np.zeros(M)
        self.windows = 0
        self.separated = np.ones(M, dtype=bool)  # whether the latest window fitted both sides

    def add(self, fix: RadioFix) -> None:
        self.llr = self.llr + fix.llr()
        self.windows += 1
        if fix.separated is not None:
            self.separated = np.asarray(fix.separated, dtype=bool)[: self.llr.shape[0]]

    def decided(self) -> np.ndarray:
        """(M,) bool: decided on a window that fitted both sides (the start uses its fit of the side
        decided), or out of windows (then the likelier side is taken)."""
        return ((np.abs(self.llr) >= self.cfg.decide_llr) & self.separated) | (self.windows >= self.cfg.max_windows)

    def side(self) -> np.ndarray:
        return np.where(self.llr >= 0.0, 0, 1)


def moved_on(fix: RadioFix, side: np.ndarray, dt_s: float) -> np.ndarray:
    """First guess (M, 11) for the next window: the decided-so-far side's fit moved on by ``dt_s``
    (where the window did not fit both sides: the one real fit)."""
    if fix.separated is not None:
        side = np.where(fix.separated[: side.shape[0]], side, fix.valid[: side.shape[0]])
    x = fix.x[np.arange(side.shape[0]), side].copy()
    x[:, 0:3] += x[:, 3:6] * dt_s + 0.5 * x[:, 6:9] * dt_s**2
    x[:, 3:6] += x[:, 6:9] * dt_s
    x[:, 9] += x[:, 10] * dt_s
    return x


def enough(t_rx_s, station_ids, cfg: StartConfig) -> bool:
    """Whether a window's pseudoranges (reception times, sender ids) suffice for :func:`start`."""
    return len(t_rx_s) >= cfg.min_meas and len(set(station_ids)) >= cfg.min_stations
