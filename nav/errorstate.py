"""Error-state (indirect) Kalman filter machinery for a strapdown INS in a local Cartesian frame
(pure math, vectorized over leading run axes).

Error convention (seed 002 sec. 1.5 uses ``nominal - true``; here ``true = nominal + delta``):
``p = p^ + dp``, ``v = v^ + dv``, ``C_nb = exp([phi x]) C^_nb`` (navigation-frame attitude error),
``b = b^ + db`` for every bias, ``tau = tau^ + dtau`` for the frame tilt, ``[b, d] = [b^, d^] + dclk``
for the receiver clock (range units).

Continuous error dynamics (flat non-rotating frame, :mod:`nav.strapdown`), with ``f^_n = C^ f^_b``
the navigation-frame specific force and ``G_tau = d g_n / d tau``:

    dp'   = dv
    dv'   = -[f^_n x] phi - C^ (dba + dbac) + G_tau dtau - C^ n_a
    phi'  = -C^ (dbg + dbgc) - C^ n_g
    dba'  = -dba / T_a + w_a          dbg' = -dbg / T_g + w_g      (Gauss-Markov, in-run)
    dbac' = 0                         dbgc' = 0                    (turn-on, random constants)
    dtau' = 0
    db'   = dd + w_b                  dd' = w_d                    (receiver clock)
    dbh'  = -dbh / T_h + w_h                                       (baro bias, optional)

Gravity with tilt: the physical "up" direction in the navigation frame is
``u(tau) = s [tau_1, tau_2, sqrt(1 - tau_1^2 - tau_2^2)]`` (``s = +-1`` fixes which way +Z points,
decided once from the aircraft's own fix) and ``g_n = -g0 u(tau)``.

Discretization over an interval ``T`` with the interval-mean ``F`` (``C^`` and ``f^_n`` averaged over the
IMU samples): ``Phi = I + F T + (F T)^2 / 2 + (F T)^3 / 6`` (the p-v-phi-bias chain is nilpotent of
order 4; the Gauss-Markov diagonal's truncation error is ``(T/T_c)^4 / 24``) and
``Q_d = Q T + (F Q + Q F^T) T^2 / 2 + (F^2 Q + 2 F Q F^T + Q F^2T) T^3 / 6`` (Van Loan's series).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .strapdown import G0_M_S2


@dataclass(frozen=True)
class ErrorLayout:
    """Named slices of the error state: 15 core states + optional turn-on biases, tilt, clock, baro bias."""

    turn_on: bool = True
    tilt: bool = True
    clock: bool = True
    baro: bool = False

    @property
    def P(self):
        return slice(0, 3)

    @property
    def V(self):
        return slice(3, 6)

    @property
    def ATT(self):
        return slice(6, 9)

    @property
    def BA(self):
        return slice(9, 12)

    @property
    def BG(self):
        return slice(12, 15)

    @property
    def BAC(self):
        return slice(15, 18) if self.turn_on else None

    @property
    def BGC(self):
        return slice(18, 21) if self.turn_on else None

    @property
    def TILT(self):
        if not self.tilt:
            return None
        i = 21 if self.turn_on else 15
        return slice(i, i + 2)

    @property
    def CLK(self):
        if not self.clock:
            return None
        i = 15 + 6 * self.turn_on + 2 * self.tilt
        return slice(i, i + 2)

    @property
    def BARO(self):
        if not self.baro:
            return None
        i = 15 + 6 * self.turn_on + 2 * self.tilt + 2 * self.clock
        return slice(i, i + 1)

    @property
    def n(self) -> int:
        return 15 + 6 * self.turn_on + 2 * self.tilt + 2 * self.clock + self.baro

    def names(self) -> list[str]:
        out = [f"{a}_{x}" for a in ("p", "v", "phi", "ba", "bg") for x in "xyz"]
        if self.turn_on:
            out += [f"{a}_{x}" for a in ("bac", "bgc") for x in "xyz"]
        if self.tilt:
            out += ["tau_1", "tau_2"]
        if self.clock:
            out += ["clk_b", "clk_d"]
        if self.baro:
            out += ["baro_b"]
        return out


def up_vector(tau: np.ndarray, sign: float | np.ndarray) -> np.ndarray:
    """Physical up direction in the navigation frame (..., 3) from the tilt ``tau`` (..., 2)."""
    tau = np.asarray(tau, dtype=float)
    n3 = np.sqrt(np.maximum(1.0 - np.einsum("...i,...i->...", tau, tau), 0.0))
    return np.asarray(sign, dtype=float)[..., None] * np.concatenate([tau, n3[..., None]], axis=-1)


def gravity(tau: np.ndarray, sign: float | np.ndarray, g0: float = G0_M_S2) -> np.ndarray:
    """Gravity ``g_n = -g0 u(tau)`` (..., 3)."""
    return -g0 * up_vector(tau, sign)


def gravity_jacobian(tau: np.ndarray, sign: float | np.ndarray, g0: float = G0_M_S2) -> np.ndarray:
    """``d g_n / d tau`` (..., 3, 2)."""
    tau = np.asarray(tau, dtype=float)
    n3 = np.sqrt(np.maximum(1.0 - np.einsum("...i,...i->...", tau, tau), 1e-12))
    J = np.zeros(tau.shape[:-1] + (3, 2))
    J[..., 0, 0] = 1.0
    J[..., 1, 1] = 1.0
    J[..., 2, 0] = -tau[..., 0] / n3
    J[..., 2, 1] = -tau[..., 1] / n3
    return -g0 * np.asarray(sign, dtype=float)[..., None, None] * J


def _skew(w):
    S = np.zeros(w.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -w[..., 2], w[..., 1]
    S[..., 1, 0], S[..., 1, 2] = w[..., 2], -w[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -w[..., 1], w[..., 0]
    return S


def f_matrix(L: ErrorLayout, C_mean: np.ndarray, f_n_mean: np.ndarray, G_tau: np.ndarray | None,
             tc_a_s: float, tc_g_s: float, tc_baro_s: float = np.inf) -> np.ndarray:
    """Continuous error-dynamics matrix (..., n, n) (module docstring), interval-mean ``C^`` (..., 3, 3)
    and ``f^_n`` (..., 3); ``G_tau`` (..., 3, 2) when the layout carries the tilt; ``tc_baro_s`` the
    baro bias correlation time when it carries the baro bias."""
    F = np.zeros(C_mean.shape[:-2] + (L.n, L.n))
    F[..., L.P, L.V] = np.eye(3)
    F[..., L.V, L.ATT] = -_skew(f_n_mean)
    F[..., L.V, L.BA] = -C_mean
    F[..., L.ATT, L.BG] = -C_mean
    F[..., L.BA, L.BA] = -np.eye(3) / tc_a_s
    F[..., L.BG, L.BG] = -np.eye(3) / tc_g_s
    if L.turn_on:
        F[..., L.V, L.BAC] = -C_mean
        F[..., L.ATT, L.BGC] = -C_mean
    if L.tilt:
        F[..., L.V, L.TILT] = G_tau
    if L.clock:
        c = L.CLK.start
        F[..., c, c + 1] = 1.0
    if L.baro:
        F[..., L.BARO, L.BARO] = -1.0 / tc_baro_s
    return F


def q_matrix(L: ErrorLayout, vrw: float, arw: float, sigma_gm_a: float, tc_a_s: float,
             sigma_gm_g: float, tc_g_s: float, q_b: float = 0.0, q_d: float = 0.0,
             sigma_baro_bias_m: float = 0.0, tc_baro_s: float = np.inf) -> np.ndarray:
    """Continuous process-noise density (n, n). White accelerometer/gyro noise is isotropic, so
    ``C^ Q C^T = Q`` and the density does not depend on the attitude."""
    Q = np.zeros((L.n, L.n))
    Q[L.V, L.V] = vrw**2 * np.eye(3)
    Q[L.ATT, L.ATT] = arw**2 * np.eye(3)
    Q[L.BA, L.BA] = 2.0 * sigma_gm_a**2 / tc_a_s * np.eye(3)
    Q[L.BG, L.BG] = 2.0 * sigma_gm_g**2 / tc_g_s * np.eye(3)
    if L.clock:
        c = L.CLK.start
        Q[c, c] = q_b
        Q[c + 1, c + 1] = q_d
    if L.baro:
        Q[L.BARO, L.BARO] = 2.0 * sigma_baro_bias_m**2 / tc_baro_s
    return Q


def discretize(F: np.ndarray, Qc: np.ndarray, T: float) -> tuple[np.ndarray, np.ndarray]:
    """Transition ``Phi`` and process noise ``Q_d`` over ``T`` (module docstring); (..., n, n)."""
    n = F.shape[-1]
    FT = F * T
    FT2 = FT @ FT
    Phi = np.eye(n) + FT + FT2 / 2.0 + FT2 @ FT / 6.0
    FQ = F @ Qc
    FQt = np.swapaxes(FQ, -1, -2)
    F2Q = F @ FQ
    Qd = (Qc * T + (FQ + FQt) * (T * T / 2.0)
          + (F2Q + np.swapaxes(F2Q, -1, -2) + 2.0 * FQ @ np.swapaxes(F, -1, -2)) * (T**3 / 6.0))
    return Phi, 0.5 * (Qd + np.swapaxes(Qd, -1, -2))


def propagate(P: np.ndarray, Phi: np.ndarray, Qd: np.ndarray) -> np.ndarray:
    """``Phi P Phi^T + Q_d``, symmetrized; (..., n, n)."""
    Pn = Phi @ P @ np.swapaxes(Phi, -1, -2) + Qd
    return 0.5 * (Pn + np.swapaxes(Pn, -1, -2))
