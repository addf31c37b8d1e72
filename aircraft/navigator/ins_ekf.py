"""Closed-loop error-state EKF: strapdown INS tightly coupled with LARNS pseudoranges (``ins-ekf``).

The nominal state (position, velocity, attitude ``C_nb``, bias estimates, frame tilt, receiver
clock) is integrated by :mod:`nav.strapdown` at the IMU rate from bias-corrected increments; the
error state (:class:`nav.errorstate.ErrorLayout`) carries the covariance. Each received pseudorange is
one scalar update at its exact reception time ``t_rx``: it is applied at the first IMU sample
``t_k >= t_rx`` with the nominal position interpolated back under the mechanization's own
constant-acceleration-per-step model, ``p(t_rx) = p_k - v_k T + a_k T^2 / 2`` (``T = t_k - t_rx``,
``a_k = (v_k - v_{k-1}) / dt``), clock ``b(t_rx) = b_k - d_k T``, Jacobian ``[u, -T u, 0..., 1, -T]``.
After every update the error estimate is fed back into the nominal state and reset to zero
(closed loop; the reset Jacobian is the identity to first order for the left attitude error).

Heading consistency (``InsTuning.jac_force_tc_s``, docs/ins.md): the specific force in the attitude
column of ``F`` (``-[f^_n x]``) is low-passed with that time constant. The nominal ``f^_n = C^ f^_b``
carries ``g0`` times the level error, which jumps with every level correction (about 0.01 m/s^2 per
mrad, against the 0.1-0.2 m/s^2 of horizontal specific force that alone makes the heading
observable); linearizing at those jumps makes the nearly unobservable heading look observable (the
EKF's false observability, first-estimate-Jacobian family of remedies). Measured: with the true
level error removed from ``f^_n`` the filter's heading covariance follows its posterior CRLB; with
the jump-free, low-passed ``f^_n`` it does too (the filter's heading NEES stays near 1 over the lap
instead of reaching 10). The posterior CRLB run uses the same low-passed force along the truth.

Everything is vectorized over a leading axis of ``M`` runs (one aircraft is ``M = 1``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nav import errorstate as es
from nav import strapdown as sd
from nav.geometry import line_of_sight
from nav.kalman import scalar_update
from nav.rotations import exp_so3, skew


JAC_FORCE_TC_S = 20.0  # the inertial aircraft's low-pass of f^_n in the Jacobian (module doc)


@dataclass(frozen=True)
class InsTuning:
    """The filter's model of its IMU and clock (from the IMU preset's datasheet figures), priors."""

    dt_s: float
    vrw: float
    arw: float
    sigma_gm_a: float
    tc_a_s: float
    sigma_gm_g: float
    tc_g_s: float
    turn_on_a: float
    turn_on_g: float
    q_b: float = 0.0
    q_d: float = 0.0
    sigma_range_m: float = 0.9
    p0_pos_m: float = 10.0
    p0_vel_m_s: float = 0.5
    p0_level_rad: float = 1e-3
    p0_yaw_rad: float = 1e-2
    p0_clock_m: float = 100.0
    p0_drift_m_s: float = 1.0
    p0_tilt_rad: float = 5e-3
    sigma_baro_m: float = 10.0  # baro white noise (used when the layout carries the baro bias)
    sigma_baro_bias_m: float = 20.0  # stationary sigma of the baro bias (Gauss-Markov)
    tc_baro_s: float = 600.0
    max_prop_s: float = 0.1  # longest covariance step without a measurement
    jac_force_tc_s: float = 0.0  # low-pass time constant of f^_n in F's attitude column (0: the interval's own)

    @classmethod
    def from_preset(cls, p, **kw) -> "InsTuning":
        """Tuning from an :class:`aircraft.world.imu.ImuPreset`-like object (duck-typed: the navigator
        only reads the datasheet numbers, never an emulator's draws). Scale-factor errors are not
        states: their effect at 1 g (``sf * g0``) is folded into the turn-on accelerometer bias prior,
        and ``sf`` times the largest expected rate (0.05 rad/s) into the gyro's."""
        return cls(dt_s=1.0 / p.rate_hz, vrw=p.vrw_m_s_sqrt_s, arw=p.arw_rad_sqrt_s,
                   sigma_gm_a=p.accel_gm_sigma, tc_a_s=p.accel_tc_s, sigma_gm_g=p.gyro_gm_sigma, tc_g_s=p.gyro_tc_s,
                   turn_on_a=float(np.hypot(p.accel_turn_on_m_s2, p.accel_sf * sd.G0_M_S2)),
                   turn_on_g=float(np.hypot(p.gyro_turn_on_rad_s, p.gyro_sf * 0.05)), **kw)

    def qc(self, L: es.ErrorLayout) -> np.ndarray:
        return es.q_matrix(L, self.vrw, self.arw, self.sigma_gm_a, self.tc_a_s, self.sigma_gm_g, self.tc_g_s,
                           self.q_b, self.q_d, self.sigma_baro_bias_m, self.tc_baro_s)


def tilt_attitude_jacobian(tau: np.ndarray, sign) -> np.ndarray:
    """Attitude error (..., 3, 2) that levelling against the nominal up ``u(tau^)`` leaves when the
    true tilt is ``tau^ + dtau``: ``phi = [u x] (du/dtau) dtau``."""
    u = es.up_vector(tau, sign)
    du = -es.gravity_jacobian(tau, sign, 1.0)  # d u / d tau
    return skew(u) @ du


def initial_covariance(L: es.ErrorLayout, tn: InsTuning, tau: np.ndarray, sign) -> np.ndarray:
    """Prior ``P0`` (n, n): fix, alignment (levelling + heading from the track), biases, tilt, clock.
    The attitude error's level part is correlated with the tilt error (:func:`tilt_attitude_jacobian`)."""
    P = np.zeros((L.n, L.n))
    P[L.P, L.P] = tn.p0_pos_m**2 * np.eye(3)
    P[L.V, L.V] = tn.p0_vel_m_s**2 * np.eye(3)
    # alignment error: level (about the horizontal axes) and heading (about up) in the nav frame
    u = es.up_vector(np.asarray(tau, float), sign)
    Pu = np.outer(u, u)
    P[L.ATT, L.ATT] = tn.p0_level_rad**2 * (np.eye(3) - Pu) + tn.p0_yaw_rad**2 * Pu
    P[L.BA, L.BA] = tn.sigma_gm_a**2 * np.eye(3)
    P[L.BG, L.BG] = tn.sigma_gm_g**2 * np.eye(3)
    if L.turn_on:
        P[L.BAC, L.BAC] = tn.turn_on_a**2 * np.eye(3)
        P[L.BGC, L.BGC] = tn.turn_on_g**2 * np.eye(3)
    if L.tilt:
        J = tilt_attitude_jacobian(np.asarray(tau, float), sign)
        St = tn.p0_tilt_rad**2 * np.eye(2)
        P[L.TILT, L.TILT] = St
        P[L.ATT, L.ATT] += J @ St @ J.T
        P[L.ATT, L.TILT] = J @ St
        P[L.TILT, L.ATT] = (J @ St).T
    if L.clock:
        c = L.CLK.start
        P[c, c] = tn.p0_clock_m**2
        P[c + 1, c + 1] = tn.p0_drift_m_s**2
    if L.baro:
        P[L.BARO, L.BARO] = tn.sigma_baro_bias_m**2
    return P


class InsEkf:
    """Batched closed-loop error-state EKF (M runs).

    Parameters
    ----------
    tn : InsTuning. L : ErrorLayout.
    p_m, v_m_s : (M, 3) initial nominal position/velocity; C_nb : (M, 3, 3); clock : (M, 2) ``[b, d]``.
    P0 : (n, n) or (M, n, n). tau : (M, 2) nominal tilt; sign : +-1 (scalar or (M,)), which way the
    frame's +Z points (from the aircraft's own fix: the aircraft flies above the stations). t0_s : time of the state.
    """

    def __init__(self, tn: InsTuning, L: es.ErrorLayout, p_m, v_m_s, C_nb, clock, P0, tau, sign, t0_s: float = 0.0):
        M = np.asarray(p_m).shape[0]
        self.tn, self.L, self.M = tn, L, M
        self.p = np.array(p_m, dtype=float)
        self.v = np.array(v_m_s, dtype=float)
        self.v_prev = self.v.copy()
        self.C = np.array(C_nb, dtype=float)
        self.clk = np.array(clock, dtype=float) if clock is not None else np.zeros((M, 2))
        self.tau = np.array(tau, dtype=float)
        self.sign = np.asarray(sign, dtype=float)  # scalar, or (M,) when runs decided differently
        self.ba = np.zeros((M, 3))
        self.bg = np.zeros((M, 3))
        self.bac = np.zeros((M, 3))
        self.bgc = np.zeros((M, 3))
        self.bh = np.zeros(M)  # baro bias estimate (m), used when the layout carries it
        self.P = np.broadcast_to(np.asarray(P0, dtype=float), (M, L.n, L.n)).copy()
        self.t_s = float(t0_s)
        self.t_prop = self.t_s
        self.Qc = tn.qc(L)
        self._g = es.gravity(self.tau, self.sign)
        self._dth_prev = np.zeros((M, 3))
        self._dv_prev = np.zeros((M, 3))
        self._Csum = np.zeros((M, 3, 3))
        self._fsum = np.zeros((M, 3))
        self.f_jac = None  # the f^_n of the last F (M, 3): low-passed when tn.jac_force_tc_s > 0
        self.n_updates = 0

    # -- IMU ------------------------------------------------------------------------------------
    def imu(self, dth: np.ndarray, dv: np.ndarray) -> None:
        """One IMU sample: increments (M, 3) over ``[t, t + dt]``."""
        dt = self.tn.dt_s
        dth = dth - (self.bg + self.bgc) * dt
        dv = dv - (self.ba + self.bac) * dt
        phi, dvr = sd.coning_sculling(self._dth_prev, self._dv_prev, dth, dv)
        dv_n = np.einsum("...ij,...j->...i", self.C, dvr)
        self._Csum += self.C
        self._fsum += dv_n
        self.v_prev = self.v
        v_new = self.v + dv_n + self._g * dt
        self.p = self.p + 0.5 * (self.v + v_new) * dt
        self.v = v_new
        self.C = self.C @ exp_so3(phi)
        self._dth_prev, self._dv_prev = dth, dv
        self.t_s += dt

    # -- covariance -----------------------------------------------------------------------------
    def propagate(self) -> None:
        """Covariance (and the nominal clock and Gauss-Markov bias means) to the current time."""
        T = self.t_s - self.t_prop
        if T <= 0:
            return
        tn, L = self.tn, self.L
        nsteps = max(round(T / tn.dt_s), 1)
        Cm = self._Csum / nsteps
        fm = self._fsum / T
        if tn.jac_force_tc_s > 0.0 and self.f_jac is not None:
            fm = self.f_jac + min(T / tn.jac_force_tc_s, 1.0) * (fm - self.f_jac)
        self.f_jac = fm
        Gt = es.gravity_jacobian(self.tau, self.sign) if L.tilt else None
        F = es.f_matrix(L, Cm, fm, Gt, tn.tc_a_s, tn.tc_g_s, tn.tc_baro_s)
        Phi, Qd = es.discretize(F, self.Qc, T)
        self.P = es.propagate(self.P, Phi, Qd)
        self.last_phi = Phi
        self.clk[:, 0] += self.clk[:, 1] * T
        self.ba *= np.exp(-T / tn.tc_a_s)
        self.bg *= np.exp(-T / tn.tc_g_s)
        self.bh *= np.exp(-T / tn.tc_baro_s)
        self._Csum[:] = 0.0
        self._fsum[:] = 0.0
        self.t_prop = self.t_s

    def maybe_propagate(self) -> None:
        if self.t_s - self.t_prop >= self.tn.max_prop_s - 1e-9:
            self.propagate()

    # -- measurements ---------------------------------------------------------------------------
    def position_at(self, t_s: float) -> np.ndarray:
        """Nominal position (M, 3) at ``t_s`` inside the last IMU step (constant acceleration per step)."""
        T = self.t_s - t_s
        a = (self.v - self.v_prev) / self.tn.dt_s
        return self.p - self.v * T + 0.5 * a * T * T

    def predict_range(self, t_rx_s: float, station_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predicted pseudorange (M,) at ``t_rx`` (within the last IMU step) and its Jacobian (M, n)."""
        return Pseudorange(np.asarray(station_m, dtype=float), t_rx_s).predict(self)

    def update(self, model, z: np.ndarray, var_m2, active: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
        """Scalar update with a measurement model object (``model.predict(ekf) -> (pred (M,), H (M, n))``),
        measured values ``z`` (M,), variance ``var_m2`` (scalar or (M,)); ``active`` (M,) bool selects the
        runs that use it. Returns the innovation and its variance."""
        self.propagate()
        pred, H = model.predict(self)
        nu = np.asarray(z, dtype=float) - pred
        dx, Pn, s = scalar_update(self.P, H, var_m2, nu)
        if active is not None:
            dx = np.where(active[:, None], dx, 0.0)
            Pn = np.where(active[:, None, None], Pn, self.P)
        self.P = Pn
        self.inject(dx)
        self.n_updates += 1
        return nu, s

    def pseudorange(self, t_rx_s: float, station_m, rho_m: np.ndarray, var_m2=None,
                    active: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Scalar update with pseudoranges ``rho_m`` (M,) received at ``t_rx`` (in the last IMU step).

        ``var_m2``: range variance (scalar or (M,)), default ``sigma_range^2``.
        """
        if not (self.t_s - self.tn.dt_s - 1e-9 <= t_rx_s <= self.t_s + 1e-9):
            raise ValueError(f"reception time {t_rx_s} not inside the last IMU step ending {self.t_s}")
        var = self.tn.sigma_range_m**2 if var_m2 is None else var_m2
        return self.update(Pseudorange(np.asarray(station_m, dtype=float), t_rx_s), rho_m, var, active)

    def inject(self, dx: np.ndarray) -> None:
        """Closed loop: add the error estimate (M, n) to the nominal state and reset it to zero."""
        L = self.L
        self.p = self.p + dx[:, L.P]
        self.v = self.v + dx[:, L.V]
        self.v_prev = self.v_prev + dx[:, L.V]
        self.C = exp_so3(dx[:, L.ATT]) @ self.C
        self.ba = self.ba + dx[:, L.BA]
        self.bg = self.bg + dx[:, L.BG]
        if L.turn_on:
            self.bac = self.bac + dx[:, L.BAC]
            self.bgc = self.bgc + dx[:, L.BGC]
        if L.tilt:
            self.tau = self.tau + dx[:, L.TILT]
            self._g = es.gravity(self.tau, self.sign)
        if L.clock:
            self.clk = self.clk + dx[:, L.CLK]
        if L.baro:
            self.bh = self.bh + dx[:, L.BARO.start]

    def estimate(self) -> dict:
        """Current estimate: position, velocity, attitude (roll, pitch, yaw of ``C_nb``), covariances."""
        from nav.rotations import euler_from_dcm

        L = self.L
        return {"t_s": self.t_s, "pos_m": self.p.copy(), "vel_m_s": self.v.copy(),
                "att_rad": euler_from_dcm(self.C), "cov_pos_m2": self.P[:, L.P, L.P].copy(),
                "clock_m": self.clk[:, 0].copy() if L.clock else None, "tilt": self.tau.copy()}


@dataclass(frozen=True)
class Pseudorange:
    """Pseudorange to a station received at ``t_rx_s``: ``|p(t_rx) - s| + b(t_rx)`` (seed 002 eq. 6,
    seed 001 eq. 13). Jacobian ``[u, -T u, 0 ..., 1, -T]`` with ``T = t_k - t_rx``."""

    station_m: np.ndarray
    t_rx_s: float

    def predict(self, ekf: "InsEkf") -> tuple[np.ndarray, np.ndarray]:
        L = ekf.L
        T = ekf.t_s - self.t_rx_s
        r, u = line_of_sight(ekf.position_at(self.t_rx_s), self.station_m)
        H = np.zeros((ekf.M, L.n))
        H[:, L.P] = u
        H[:, L.V] = -T * u
        pred = r
        if L.clock:
            c = L.CLK.start
            H[:, c] = 1.0
            H[:, c + 1] = -T
            pred = r + ekf.clk[:, 0] - ekf.clk[:, 1] * T
        return pred, H


@dataclass(frozen=True)
class PositionComponent:
    """A linear position measurement ``e^T p(t_s)`` (a height from a barometer along the up
    direction ``e``, or one axis of an external fix); Jacobian ``[e, -T e, 0 ...]``."""

    e: np.ndarray
    t_s: float

    def predict(self, ekf: "InsEkf") -> tuple[np.ndarray, np.ndarray]:
        L = ekf.L
        T = ekf.t_s - self.t_s
        H = np.zeros((ekf.M, L.n))
        H[:, L.P] = self.e
        H[:, L.V] = -T * self.e
        return ekf.position_at(self.t_s) @ self.e, H


@dataclass(frozen=True)
class BaroAltitude:
    """Barometric altitude ``e^T p(t_s) + h0 + b_h`` (seed spec sec. 1.3: the baro measurement with a
    Gauss-Markov bias state): ``e`` the physical up direction in the navigation frame, ``h0_m`` the
    altitude of the frame's origin. Jacobian ``[e, -T e, 0 ..., 1 (baro bias)]``."""

    e: np.ndarray
    t_s: float
    h0_m: float = 0.0

    def predict(self, ekf: "InsEkf") -> tuple[np.ndarray, np.ndarray]:
        L = ekf.L
        pred, H = PositionComponent(self.e, self.t_s).predict(ekf)
        if L.baro:
            H[:, L.BARO.start] = 1.0
            pred = pred + ekf.bh
        return pred + self.h0_m, H
