"""Continuous-discrete total-state EKFs of seed 004 (eqs. 2, 4, 6, 9; spec Sec. 3.4-3.6), as they
should have been written.

* :class:`MapFilter` - the map-constrained ("orthodromic") model: ``x = [vec(D), q, V]`` (11 states)
  with ``q = eta`` on great circles (``q = s`` on straight field segments), optionally the receiver
  clock ``[b, d]`` (13 states).
* :class:`FreeFilter` - the unconstrained model ``x = [vec(D), p_I, v_I]`` (15, or 17 with clock).

``D`` maps body to inertial axes (``D' = D [w x]``, eq. 2), ``vec`` is column-major. Between radio
epochs an extended Kalman-Bucy filter on the odometer runs (eq. 6), integrated by RK4 on state and
covariance with the IMU and odometer samples held over the step; covariance symmetrized each step.
At an epoch the mean and covariance are handed over to a discrete pseudorange + Doppler update
(eq. 9, Joseph form, satellite/station rows only: the odometer is used once, continuously), then
``D`` is re-orthonormalized (polar decomposition) and its 9x9 covariance block projected on the
tangent space ``{vec(D [dtheta x])}``. Corrections to the paper: coefficient 1 (not 2) in eq. 3 and
the odometer function, ``G D`` (not ``G D^T``), noise intensities in ``dR/dt``, ``r = R_E + h``.

Vectorized over M runs: ``x`` (M, n), ``P`` (M, n, n). Inputs per step: gyro ``w`` (M, 3) with the
known offset removed by the caller (``Z_d - m_d``), specific force ``f`` (M, 3), odometer ``z`` (M,).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nav.geometry import line_of_sight
from nav.kalman import gain, joseph, nis, symmetrize
from nav.orbits import OMEGA_VEC_G, earth_rotation, gravity, gravity_gradient
from vehicle.navigator.fused import rk4_fused, speed_factor_one
from vehicle.route import Route

_E = np.zeros((3, 3, 3))  # _E[k] = [e_k x]
_E[0, 1, 2], _E[0, 2, 1] = -1.0, 1.0
_E[1, 0, 2], _E[1, 2, 0] = 1.0, -1.0
_E[2, 0, 1], _E[2, 1, 0] = -1.0, 1.0
_WE = np.einsum("kij,k->ij", _E, OMEGA_VEC_G)  # [w_e x] in Greenwich axes


def skew(w: np.ndarray) -> np.ndarray:
    """``[w x]`` (..., 3, 3)."""
    return np.einsum("kij,...k->...ij", _E, w)


def xi_matrix(Dt: np.ndarray) -> np.ndarray:
    """``Xi(D)`` (M, 9, 3) of eq. 2: columns ``vec(D [e_k x])`` (body-frame attitude directions).

    ``Dt`` is ``D^T`` (M, 3, 3), i.e. the state's ``vec(D)`` reshaped row-major.
    """
    T = -np.matmul(_E[None], Dt[:, None])  # (M, k, 3, 3) = (D [e_k x])^T
    return np.swapaxes(T.reshape(Dt.shape[0], 3, 9), 1, 2)


def inertial_dirs(Dt: np.ndarray) -> np.ndarray:
    """``J`` (M, 9, 3): columns ``vec([e_k x] D)`` (inertial-frame attitude directions)."""
    T = -np.matmul(Dt[:, None], _E[None])  # ([e_k x] D)^T = -D^T [e_k x]
    return np.swapaxes(T.reshape(Dt.shape[0], 3, 9), 1, 2)


# -[w x] (x) I3 on vec(D^T) row-major: F[3i+j, 3k+j] = -W[i, k] (entries of W = [w x], off-diagonal)
_KR, _KC, _KW, _KS = [], [], [], []
for _i in range(3):
    for _k in range(3):
        for _j in range(3):
            _c = int(np.flatnonzero(_E[:, _i, _k])[0]) if np.any(_E[:, _i, _k]) else -1
            if _c >= 0:
                _KR.append(3 * _i + _j)
                _KC.append(3 * _k + _j)
                _KW.append(_c)
                _KS.append(-_E[_c, _i, _k])
_KR, _KC, _KW, _KS = (np.array(a) for a in (_KR, _KC, _KW, _KS))


def polar(Dt: np.ndarray) -> np.ndarray:
    """Nearest rotation (polar decomposition) of each (3, 3) matrix."""
    U, _, Vt = np.linalg.svd(Dt)
    return U @ Vt


@dataclass(frozen=True)
class Intensities:
    """Continuous-time noise intensities used by the filter: gyro (rad^2/s), accelerometer (m^2/s^3),
    odometer (m^2/s), clock ``q_b`` (m^2/s) and ``q_d`` (m^2/s^3)."""

    gyro: float
    accel: float
    odometer: float
    q_b: float = 0.04
    q_d: float = 1e-4


class _Base:
    n: int
    clock: bool
    ib: int

    def __init__(self, x0, P0, noise: Intensities, odometer: bool = True, k_odo: float = 1.0):
        self.x = np.array(x0, dtype=float)
        self.P = symmetrize(np.array(P0, dtype=float))
        self.noise = noise
        self.odometer = odometer
        self.k_odo = k_odo
        self.last_nis = None
        self.Pxc = None  # (M, n, c) cross-covariance with the consider parameters (Schmidt), if any

    # ------------------------------------------------------------------ continuous part (eq. 6)
    def step(self, t: float, dt: float, w: np.ndarray, f: np.ndarray, z: np.ndarray | None) -> None:
        """One RK4 step of the Kalman-Bucy filter on [t, t + dt] (inputs held over the step).

        While the odometer gain is stiff (``H P H^T / r * dt > 0.5``, only in the first instants
        after a wide ``P(0)``, since the odometer is far better than the initial velocity prior) the
        step is split into equal RK4 substeps; otherwise it is one RK4 step of ``dt``.
        """
        if self.odometer and z is not None:
            stiff = self._stiffness(t, dt)
            if stiff > 0.5:
                n_sub = int(np.ceil(stiff / 0.5))
                h = dt / n_sub
                for j in range(n_sub):
                    self._rk4(t + j * h, h, w, f, z)
                self.after_step()
                return
        self._rk4(t, dt, w, f, z)
        self.after_step()

    def _stiffness(self, t: float, dt: float) -> float:
        """Largest ``H P H^T / r * dt`` of the odometer over the runs."""
        return float(np.max(self.odo_hph(t, self.P))) / self.noise.odometer * dt

    def _rk4(self, t, dt, w, f, z) -> None:
        x, P = self.x, self.P
        n = x.shape[1]
        if self.Pxc is not None:  # [P | Pxc]: the consider columns follow F (and the odometer gain), eq. 6
            P = np.concatenate([P, self.Pxc], axis=2)
        # gyro noise block F1 Q F1^T = q_g Xi Xi^T, evaluated once per step at the step's start
        Xi = xi_matrix(x[:, :9].reshape(-1, 3, 3))
        self._Qd = self.noise.gyro * (Xi @ np.swapaxes(Xi, 1, 2))
        h2 = 0.5 * dt
        k1x, k1P = self.deriv(t, x, P, w, f, z)
        k2x, k2P = self.deriv(t + h2, x + h2 * k1x, P + h2 * k1P, w, f, z)
        k3x, k3P = self.deriv(t + h2, x + h2 * k2x, P + h2 * k2P, w, f, z)
        k4x, k4P = self.deriv(t + dt, x + dt * k3x, P + dt * k3P, w, f, z)
        s = dt / 6.0
        self.x = x + s * (k1x + 2.0 * (k2x + k3x) + k4x)
        Pn = P + s * (k1P + 2.0 * (k2P + k3P) + k4P)
        if self.Pxc is not None:
            self.Pxc = Pn[:, :, n:]
            Pn = Pn[:, :, :n]
        self.P = 0.5 * (Pn + np.swapaxes(Pn, 1, 2))

    def after_step(self) -> None:
        pass

    def _att(self, x, P, w):
        """Attitude part shared by both models: xdot[:9], FP[:9] and the gyro noise block."""
        M, nc = P.shape[0], P.shape[2]
        Dt = x[:, :9].reshape(M, 3, 3)
        W = skew(w)
        xd = np.empty_like(x)
        xd[:, :9] = np.matmul(W, Dt).reshape(M, 9)
        np.negative(xd[:, :9], out=xd[:, :9])
        FP = np.empty_like(P)
        FP[:, :9, :] = np.matmul(W, P[:, :9, :].reshape(M, 3, 3 * nc)).reshape(M, 9, nc)
        np.negative(FP[:, :9, :], out=FP[:, :9, :])
        return Dt, xd, FP, self._Qd

    def _clock_rows(self, x, P, xd, FP) -> None:
        """Receiver clock ``b' = d``, ``d' = 0`` (+ noise in :meth:`_finish`), if the model has it."""
        if self.clock:
            b = self.ib
            xd[:, b] = x[:, b + 1]
            xd[:, b + 1] = 0.0
            FP[:, b, :] = P[:, b + 1, :]
            FP[:, b + 1, :] = 0.0

    def _finish(self, xd, FP, Qd, PH, innov, HZc=None):
        """``P' = F P + P F^T + Q - P H^T H P / r`` (on ``[P | Pxc]``: ``F Pxc - P H^T H Pxc / r``)."""
        n = xd.shape[1]
        if FP.shape[2] > n:
            Pd = FP.copy()
            Pd[:, :, :n] += np.swapaxes(FP[:, :, :n], 1, 2)
            if PH is not None:
                HZ = np.concatenate([PH, HZc], axis=1)
        else:
            Pd = FP + np.swapaxes(FP, 1, 2)
            HZ = PH
        Pd[:, :9, :9] += Qd
        if self.clock:
            Pd[:, self.ib, self.ib] += self.noise.q_b
            Pd[:, self.ib + 1, self.ib + 1] += self.noise.q_d
        if PH is not None:
            r = self.noise.odometer
            xd += PH * (innov / r)[:, None]
            Pd -= PH[:, :, None] * HZ[:, None, :] / r
        return xd, Pd

    # ------------------------------------------------------------------ discrete part (eq. 9)
    def update(self, t: float, src_pos, src_vel, rho, rate, var_rho, var_rate, use_rate: bool = True,
               src_cov=None) -> None:
        """Pseudorange (+ Doppler) update at an epoch, Joseph form; emitters (N, 3) or (M, N, 3).

        ``src_cov`` (N, 3, 3) or (M, N, 3, 3): the emitters' own broadcast position covariance (LARNS
        stations). Their position errors are then *consider* parameters (Schmidt-Kalman): constant,
        not estimated, their cross-covariance ``Pxc`` with the state carried through the continuous
        part and the updates, so an error that is the same at every epoch is not averaged away as
        white noise. ``var_rho`` is then the range noise alone. The emitters must be the same, in
        the same order, at every epoch.
        """
        x, P = self.x, self.P
        M, n = x.shape
        pos, vel, Jp, Jv = self.geometry(t, x)
        r, u = line_of_sight(src_pos, pos[:, None, :])  # u: receiver -> emitter
        wv = np.asarray(src_vel, float) - vel[:, None, :]
        rr = np.einsum("mni,mni->mn", u, wv)
        H_rho = -u @ Jp
        hz, Hs, zs, Rs = [r], [H_rho], [rho], [np.broadcast_to(var_rho, r.shape)]
        if self.clock:
            H_rho[:, :, self.ib] = 1.0
            hz[0] = r + x[:, self.ib, None]
        if use_rate:
            H_rate = ((rr[..., None] * u - wv) / r[..., None]) @ Jp - u @ Jv
            hr = rr
            if self.clock:
                H_rate[:, :, self.ib + 1] = 1.0
                hr = rr + x[:, self.ib + 1, None]
            hz.append(hr)
            Hs.append(H_rate)
            zs.append(rate)
            Rs.append(np.broadcast_to(var_rate, rr.shape))
        H = np.concatenate(Hs, axis=1)
        nu = np.concatenate(zs, axis=1) - np.concatenate(hz, axis=1)
        Rd = np.concatenate(Rs, axis=1)
        c = 0
        if src_cov is not None:
            P, H, c = self._consider(P, H, u, wv, r, rr, src_cov, use_rate)
        Ht = np.swapaxes(H, 1, 2)
        PHt = P @ Ht
        S = H @ PHt
        S[:, np.arange(S.shape[1]), np.arange(S.shape[1])] += Rd
        S = symmetrize(S)
        K = gain(PHt[:, :n], S)
        self.x = x + np.einsum("mij,mj->mi", K, nu)
        if c:  # Schmidt: zero gain rows for the consider parameters, Joseph form on the augmented P
            K = np.concatenate([K, np.zeros((M, c, K.shape[2]))], axis=1)
        Pn = joseph(P, K, H, Rd, diagonal=True)
        self.P = Pn[:, :n, :n] if c else Pn
        if c:
            self.Pxc = Pn[:, :n, n:]
        self.last_nis = nis(nu, S)
        self.last_nis_dof = nu.shape[1]
        self.orthonormalize()

    def _consider(self, P, H, u, wv, r, rr, src_cov, use_rate):
        """Augmented ``[[P, Pxc], [Pxc^T, Pcc]]`` (M, n+c, n+c) and ``[H, Hc]`` for the emitters' positions."""
        M, N = u.shape[:2]
        n = P.shape[1]
        c = 3 * N
        cov = np.broadcast_to(np.asarray(src_cov, float), (M, N, 3, 3))
        Pcc = np.zeros((M, c, c))
        Hc = np.zeros((M, H.shape[1], c))
        for s in range(N):
            Pcc[:, 3 * s:3 * s + 3, 3 * s:3 * s + 3] = cov[:, s]
            Hc[:, s, 3 * s:3 * s + 3] = u[:, s]  # d rho / d p_s
            if use_rate:  # d (u . w) / d p_s = (w - u (u . w)) / r
                Hc[:, N + s, 3 * s:3 * s + 3] = (wv[:, s] - u[:, s] * rr[:, s, None]) / r[:, s, None]
        if self.Pxc is None:
            self.Pxc = np.zeros((M, n, c))
        elif self.Pxc.shape[2] != c:
            raise ValueError(f"src_cov: {N} emitters, but the consider block holds {self.Pxc.shape[2] // 3}")
        Pa = np.concatenate([np.concatenate([P, self.Pxc], axis=2),
                             np.concatenate([np.swapaxes(self.Pxc, 1, 2), Pcc], axis=2)], axis=1)
        return Pa, np.concatenate([H, Hc], axis=2), c

    def orthonormalize(self) -> None:
        """Polar re-orthonormalization of D and projection of its covariance on the tangent space."""
        M, n = self.x.shape
        Dt = polar(self.x[:, :9].reshape(M, 3, 3))
        self.x[:, :9] = Dt.reshape(M, 9)
        Xi = xi_matrix(Dt)
        T = np.broadcast_to(np.eye(n), (M, n, n)).copy()
        T[:, :9, :9] = 0.5 * (Xi @ np.swapaxes(Xi, 1, 2))
        self.P = symmetrize(T @ self.P @ np.swapaxes(T, 1, 2))
        if self.Pxc is not None:
            self.Pxc = T @ self.Pxc

    # ------------------------------------------------------------------ outputs
    def D(self) -> np.ndarray:
        """Body -> inertial direction cosines (M, 3, 3)."""
        M = self.x.shape[0]
        return np.swapaxes(self.x[:, :9].reshape(M, 3, 3), 1, 2)

    def error_state_cov(self) -> np.ndarray:
        """Covariance of ``[e_I (3), rest of the state]`` (M, n - 6, n - 6) (attitude as 3 angles)."""
        M, n = self.x.shape
        J = inertial_dirs(self.x[:, :9].reshape(M, 3, 3))
        T = np.zeros((M, n - 6, n))
        T[:, :3, :9] = 0.5 * np.swapaxes(J, 1, 2)
        T[:, 3:, 9:] = np.eye(n - 9)
        return T @ self.P @ np.swapaxes(T, 1, 2)


class MapFilter(_Base):
    """Map-constrained total-state filter: ``[vec(D), q, V (, b, d)]`` on a known route."""

    def __init__(self, route: Route, x0, P0, seg0, noise: Intensities, clock: bool = False,
                 odometer: bool = True, k_odo: float = 1.0):
        self.route = route
        self.clock = clock
        self.n = 13 if clock else 11
        self.ib = 11
        self.seg = np.array(seg0, dtype=int)
        super().__init__(x0, P0, noise, odometer, k_odo)
        if self.x.shape[-1] != self.n:
            raise ValueError(f"MapFilter expects {self.n} states, got {self.x.shape[-1]}")

    def deriv(self, t, x, P, w, f, z):
        r = self.route
        k = self.seg
        Dt, xd, FP, Qd = self._att(x, P, w)
        q, V = x[:, 9], x[:, 10]
        a = r.accel_axis_inertial(t, k)
        gam, dgam = r.gamma(q, k)
        xd[:, 9] = V
        xd[:, 10] = (f * (Dt @ a[:, :, None])[:, :, 0]).sum(axis=1) + gam
        FP[:, 9, :] = P[:, 10, :]
        c = (f[:, :, None] * a[:, None, :]).reshape(-1, 1, 9)  # kron(f, a): d(a^T D f)/d vec(D)
        FP[:, 10, :] = (c @ P[:, :9, :])[:, 0] + dgam[:, None] * P[:, 9, :]
        Qd_v = self.noise.accel
        self._clock_rows(x, P, xd, FP)
        PH = innov = None
        if self.odometer and z is not None:
            sf, dsf = r.speed_factor_d(q, k)
            ks = self.k_odo * r.fwd_sign(k)
            h = ks * V * sf
            n = x.shape[1]
            PH = P[:, :, 9] * (ks * V * dsf)[:, None] + P[:, :, 10] * (ks * sf)[:, None]
            HZc = P[:, 9, n:] * (ks * V * dsf)[:, None] + P[:, 10, n:] * (ks * sf)[:, None]
            innov = z - h
        xd, Pd = self._finish(xd, FP, Qd, PH, innov, None if PH is None else HZc)
        Pd[:, 10, 10] += Qd_v
        return xd, Pd

    #: yaw rate (rad/s) above which the vehicle is taken to be turning in place at a map node
    TURN_RATE_RAD_S = 0.02
    #: along-track sigma (m) of the node pseudo-measurement ("turns happen at map nodes")
    NODE_SIGMA_M = 0.5
    #: how far (m, plus 3 sigma) from the node a turn is accepted as the node's turn
    NODE_GATE_M = 20.0

    def step(self, t, dt, w, f, z) -> None:
        """Kalman-Bucy step; a turn in place near a map node snaps the along-track state to the node.

        Map matching: the route's legs are joined at nodes where the vehicle stops and turns in place
        (the world's speed plan). When the gyro shows a yaw rate above ``TURN_RATE_RAD_S`` while the
        estimate is within ``NODE_GATE_M`` + 3 sigma of the end of its leg, the node is applied as a
        pseudo-measurement ``q = q_end`` (sigma ``NODE_SIGMA_M`` along track, Joseph form) and the
        filter moves to the next leg. Without this, the estimate would linger a metre or two on the
        old leg's extension while the vehicle sets off on the new one.
        """
        super().step(t, dt, w, f, z)
        r = self.route
        if r.n_segments < 2:
            return
        k = self.seg
        q1 = r.q_end(k)
        sf, _ = r.speed_factor_d(q1, k)
        dist = np.abs(self.x[:, 9] - q1) / sf
        sig = np.sqrt(np.maximum(self.P[:, 9, 9], 0.0)) / sf
        turning = (np.abs(w[:, 2]) > self.TURN_RATE_RAD_S) & (k < r.n_segments - 1) & (dist < self.NODE_GATE_M + 3 * sig)
        if not np.any(turning):
            return
        m = np.flatnonzero(turning)
        x, P = self.x[m], self.P[m]
        R = (self.NODE_SIGMA_M * sf[m]) ** 2
        PH = P[:, :, 9]
        Kg = PH / (P[:, 9, 9] + R)[:, None]
        x = x + Kg * (q1[m] - x[:, 9])[:, None]
        IKH = np.broadcast_to(np.eye(self.n), P.shape).copy()
        IKH[:, :, 9] -= Kg
        P = IKH @ P @ np.swapaxes(IKH, 1, 2) + R[:, None, None] * Kg[:, :, None] * Kg[:, None, :]
        # move to the next leg: along-track offset from the node and speed carried over
        kn = k[m] + 1
        sf_old = sf[m] * r.fwd_sign(k[m])
        sf_new = r.speed_factor(r.q_start(kn), kn) * r.fwd_sign(kn)
        scale = sf_old / sf_new
        x[:, 9] = r.q_start(kn) + scale * (x[:, 9] - q1[m])
        x[:, 10] *= scale
        T = np.ones((m.size, self.n))
        T[:, 9] = scale
        T[:, 10] = scale
        self.x[m] = x
        self.P[m] = symmetrize(P * T[:, :, None] * T[:, None, :])
        if self.Pxc is not None:
            self.Pxc[m] = (IKH @ self.Pxc[m]) * T[:, :, None]
        self.seg = self.seg.copy()
        self.seg[m] = kn

    def odo_hph(self, t, P) -> np.ndarray:
        sf, _ = self.route.speed_factor_d(self.x[:, 9], self.seg)
        return (self.k_odo * sf) ** 2 * P[:, 10, 10]

    # ------------------------------------------------------------------ single-run fast path
    #: use the single-run fast path (one run on a great-circle route); same equations as :meth:`deriv`
    fast: bool = True

    def _one_run(self) -> bool:
        return self.fast and self.x.shape[0] == 1 and self.route.kind == "great_circle" and self.Pxc is None

    def _gc_consts(self) -> tuple[float, float, float, float, float]:
        """``(P, a0, a1, -mu/r^3, sign)`` of the current segment as Python floats."""
        k = int(self.seg[0])
        cache = self.__dict__.setdefault("_gc_cache", {})
        if k not in cache:
            from nav.orbits import MU_EARTH_M3_S2

            tab = self.route._tab
            cache[k] = (float(tab["P"][k]), float(tab["a0"][k]), float(tab["a1"][k]),
                        -MU_EARTH_M3_S2 / float(tab["r"][k]) ** 3, float(tab["sign"][k]))
        return cache[k]

    def _stiffness(self, t: float, dt: float) -> float:
        if self._one_run():
            P, a0, a1, _, _ = self._gc_consts()
            sf, _ = speed_factor_one(float(self.x[0, 9]), P, a0, a1)
            return (self.k_odo * sf) ** 2 * float(self.P[0, 10, 10]) / self.noise.odometer * dt
        return super()._stiffness(t, dt)

    def _rk4(self, t, dt, w, f, z) -> None:
        if self._one_run():
            self._rk4_one(dt, w[0], f[0], None if (z is None or not self.odometer) else float(z[0]))
        else:
            super()._rk4(t, dt, w, f, z)

    def _rk4_one(self, dt: float, w: np.ndarray, f: np.ndarray, z: float | None) -> None:
        """One RK4 step of :meth:`deriv` for a single run on a great circle, fused on ``Z = [P | x]``.

        On a great circle ``a = e_eta`` and ``gamma = (-mu / r^3) q`` are constant/linear, so the
        drift is ``x' = F x`` with the covariance's ``F`` (held over the step with the inputs). Each
        RK4 stage is one product ``[F; H] [P | x]``, giving ``F P``, ``F x`` and the odometer's
        ``H P = (P H^T)^T`` at once (``H`` evaluated at the stage's state), and one outer product
        for ``-P H^T H P / r`` and ``+P H^T nu / r``; the four stages run in one kernel
        (:func:`vehicle.navigator.fused.rk4_fused`, compiled when numba is installed). Equal to the
        batched path within round-off (tests/vehicle/test_vehicle_filter_fast.py).
        """
        n = self.n
        c = self._gc_consts()
        Qm, FH, Z, KK = self._one_buffers()
        Z[:, :n] = self.P[0]
        Z[:, n] = self.x[0]
        XiT = (_E @ self.x[0, :9].reshape(3, 3)).reshape(3, 9)  # -Xi^T (xi_matrix for one run)
        np.matmul(XiT.T, XiT, out=Qm[:9, :9])
        Qm[:9, :9] *= self.noise.gyro
        odo = z is not None
        FH[_KR, _KC] = _KS * w[_KW]
        FH[10, 1:9:3] = f  # kron(f, e_eta)
        FH[10, 9] = c[3]
        rk4_fused(Z, KK, FH, Qm, n + 1 if odo else n, dt, z if odo else 0.0, self.k_odo * c[4],
                  1.0 / math.sqrt(self.noise.odometer), c[0], c[1], c[2])
        self.P = Z[None, :, :n].copy()
        self.x = Z[None, :, n].copy()

    def _one_buffers(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The single-run step's work arrays, kept between steps: ``Q`` (n, n) with its constant part
        (accelerometer, clock) set once, ``[F; H]`` (n + 1, n) with its constant entries set once
        (the rest is overwritten every step), ``Z = [P | x]`` (n, n + 1) and the kernel's stage
        work space (4, n + 1, n + 1)."""
        buf = self.__dict__.get("_one_buf")
        if buf is None:
            n = self.n
            FH = np.zeros((n + 1, n))
            FH[9, 10] = 1.0
            if self.clock:
                FH[self.ib, self.ib + 1] = 1.0
            buf = self._one_buf = (self._Qconst(), FH, np.empty((n, n + 1)), np.empty((4, n + 1, n + 1)))
        return buf

    def _Qconst(self) -> np.ndarray:
        """Constant part of the process noise (accelerometer, clock), a fresh (n, n) array."""
        Q0 = self.__dict__.get("_Q0")
        if Q0 is None:
            Q0 = np.zeros((self.n, self.n))
            Q0[10, 10] = self.noise.accel
            if self.clock:
                Q0[self.ib, self.ib] = self.noise.q_b
                Q0[self.ib + 1, self.ib + 1] = self.noise.q_d
            self._Q0 = Q0
        return Q0.copy()

    def after_step(self) -> None:
        if self.route.n_segments > 1:
            q, k, scale, sw = self.route.next_segment(self.x[:, 9], self.seg)
            if np.any(sw):
                self.x[:, 9] = q
                self.x[:, 10] *= scale
                self.seg = k
                T = np.ones((self.x.shape[0], self.n))
                T[:, 9] = scale
                T[:, 10] = scale
                self.P = self.P * T[:, :, None] * T[:, None, :]
                if self.Pxc is not None:
                    self.Pxc = self.Pxc * T[:, :, None]

    def geometry(self, t, x):
        """Greenwich position and velocity (M, 3) and their Jacobians (M, 3, n)."""
        M = x.shape[0]
        p, dp, ddp = self.route.pos(x[:, 9], self.seg)
        V = x[:, 10]
        Jp = np.zeros((M, 3, self.n))
        Jv = np.zeros((M, 3, self.n))
        Jp[:, :, 9] = dp
        Jv[:, :, 9] = V[:, None] * ddp
        Jv[:, :, 10] = dp
        return p, V[:, None] * dp, Jp, Jv

    def pos_vel(self, t):
        p, v, _, _ = self.geometry(t, self.x)
        return p, v


class FreeFilter(_Base):
    """Unconstrained total-state filter ``[vec(D), p_I, v_I (, b, d)]`` (15 or 17 states)."""

    def __init__(self, x0, P0, noise: Intensities, clock: bool = False, odometer: bool = True, k_odo: float = 1.0):
        self.clock = clock
        self.n = 17 if clock else 15
        self.ib = 15
        super().__init__(x0, P0, noise, odometer, k_odo)
        if self.x.shape[-1] != self.n:
            raise ValueError(f"FreeFilter expects {self.n} states, got {self.x.shape[-1]}")

    def odo_hph(self, t, P) -> np.ndarray:
        G = earth_rotation(t)
        _, vg, _, _ = self.geometry(t, self.x)
        e = (vg / np.maximum(np.linalg.norm(vg, axis=-1, keepdims=True), 1e-3)) @ G  # inertial direction of H_v
        return self.k_odo**2 * np.einsum("mi,mij,mj->m", e, P[:, 12:15, 12:15], e)

    def deriv(self, t, x, P, w, f, z):
        M, n = x.shape
        nc = P.shape[2]
        Dt, xd, FP, Qd = self._att(x, P, w)
        p, v = x[:, 9:12], x[:, 12:15]
        xd[:, 9:12] = v
        xd[:, 12:15] = (f[:, None, :] @ Dt)[:, 0] + gravity(p)
        FP[:, 9:12, :] = P[:, 12:15, :]
        FP[:, 12:15, :] = (f[:, None, :] @ P[:, :9, :].reshape(M, 3, 3 * nc)).reshape(M, 3, nc) \
            + gravity_gradient(p) @ P[:, 9:12, :]
        self._clock_rows(x, P, xd, FP)
        PH = innov = None
        if self.odometer and z is not None and self.odo_model == "forward":
            PH, HZc, innov = self._odo_forward(x, P, z)
        elif self.odometer and z is not None:
            G = earth_rotation(t)
            vg = v @ G.T - (p @ G.T) @ _WE.T
            sp = np.linalg.norm(vg, axis=-1)
            e = vg / sp[:, None]
            Hv = self.k_odo * e @ G
            Hp = -self.k_odo * e @ (_WE @ G)
            PH = np.einsum("mij,mj->mi", P[:, :, 9:12], Hp) + np.einsum("mij,mj->mi", P[:, :, 12:15], Hv)
            HZc = np.einsum("mj,mjk->mk", Hp, P[:, 9:12, n:]) + np.einsum("mj,mjk->mk", Hv, P[:, 12:15, n:])
            innov = z - self.k_odo * sp
        xd, Pd = self._finish(xd, FP, Qd, PH, innov, None if PH is None else HZc)
        Pd[:, 12:15, 12:15] += self.noise.accel * np.eye(3)
        return xd, Pd

    #: odometer function of the free model: "forward" = k (D e_1)^T (v_I - w_e x p_I), the Earth-relative
    #: velocity along the body's forward axis (what a wheel measures); "speed" = k |v_G| (the old form,
    #: whose curvature |dv_perp|^2 / (2 |v|) across the track biases the 0.001 m/s-per-second odometer)
    odo_model = "forward"

    def _odo_forward(self, x, P, z):
        n = x.shape[1]
        k = self.k_odo
        d1 = x[:, 0:3]  # D e_1 (vec(D) column-major)
        vr = x[:, 12:15] - x[:, 9:12] @ _WE.T
        Hd, Hv, Hp = k * vr, k * d1, -k * (d1 @ _WE)
        PH = (np.einsum("mij,mj->mi", P[:, :, 0:3], Hd) + np.einsum("mij,mj->mi", P[:, :, 9:12], Hp)
              + np.einsum("mij,mj->mi", P[:, :, 12:15], Hv))
        HZc = (np.einsum("mj,mjk->mk", Hd, P[:, 0:3, n:]) + np.einsum("mj,mjk->mk", Hp, P[:, 9:12, n:])
               + np.einsum("mj,mjk->mk", Hv, P[:, 12:15, n:]))
        return PH, HZc, z - k * np.einsum("mi,mi->m", d1, vr)

    def geometry(self, t, x):
        M = x.shape[0]
        G = earth_rotation(t)
        pg = x[:, 9:12] @ G.T
        vg = x[:, 12:15] @ G.T - pg @ _WE.T
        Jp = np.zeros((M, 3, self.n))
        Jv = np.zeros((M, 3, self.n))
        Jp[:, :, 9:12] = G
        Jv[:, :, 9:12] = -_WE @ G
        Jv[:, :, 12:15] = G
        return pg, vg, Jp, Jv

    def pos_vel(self, t):
        p, v, _, _ = self.geometry(t, self.x)
        return p, v
