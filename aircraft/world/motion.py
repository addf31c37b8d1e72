"""6-DOF truth trajectories with attitude, angular rate and specific force (world side only).

Physics: flat, non-rotating Earth, uniform gravity ``g_L = [0, 0, -g0]`` in a *level* frame ``L``
(x, y horizontal, z up, origin and azimuth those of the scenario's physical coordinates). Body axes:
x forward, y left, z up. Flight is coordinated: the body x axis is along the velocity and the
specific force has no lateral (body y) component, so the bank angle follows from the turn.

A motion gives, at any times ``t`` (T,): position, velocity and acceleration in ``L`` (analytic),
the attitude ``C_Lb`` (from velocity and specific force), the body angular rate ``w_b`` (central
difference of the attitude, Richardson-extrapolated) and the specific force ``f_b``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nav.rotations import exp_so3, log_so3
from nav.strapdown import G0_M_S2

G_L = np.array([0.0, 0.0, -G0_M_S2])
_GL3 = (np.array([0.5 - np.sqrt(15.0) / 10.0, 0.5, 0.5 + np.sqrt(15.0) / 10.0]),
        np.array([5.0, 8.0, 5.0]) / 18.0)  # 3-point Gauss-Legendre on [0, 1]


class Motion:
    """Base class: subclasses implement :meth:`pva` (positions, velocities, accelerations (T, 3))."""

    yaw0_rad: float = 0.0  # heading when the velocity vanishes (hover)

    def pva(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        raise NotImplementedError

    def attitude(self, t_s: np.ndarray) -> np.ndarray:
        """Body-to-level DCM ``C_Lb`` (T, 3, 3) of coordinated flight."""
        _, v, a = self.pva(t_s)
        f = a - G_L
        speed = np.linalg.norm(v, axis=-1)
        hov = speed < 1e-6
        x = np.where(hov[:, None], np.array([np.cos(self.yaw0_rad), np.sin(self.yaw0_rad), 0.0]),
                     v / np.where(hov, 1.0, speed)[:, None])
        y = np.cross(f, x)
        y /= np.linalg.norm(y, axis=-1)[:, None]
        z = np.cross(x, y)
        return np.stack([x, y, z], axis=-1)

    def body_rates(self, t_s: np.ndarray, h_s: float = 2e-4) -> tuple[np.ndarray, np.ndarray]:
        """Angular rate ``w_b`` (T, 3) and specific force ``f_b`` (T, 3) in the body frame."""
        t_s = np.asarray(t_s, dtype=float)
        # central differences of the attitude at h and 2h, Richardson-combined: O(h^4) truncation
        # (the relative rotation C(t-h)^T C(t+h) is in body axes; its BCH error is O(h^3))
        w1 = log_so3(np.swapaxes(self.attitude(t_s - h_s), -1, -2) @ self.attitude(t_s + h_s)) / (2.0 * h_s)
        w2 = log_so3(np.swapaxes(self.attitude(t_s - 2 * h_s), -1, -2) @ self.attitude(t_s + 2 * h_s)) / (4.0 * h_s)
        w = (4.0 * w1 - w2) / 3.0
        C = self.attitude(t_s)
        _, _, a = self.pva(t_s)
        f_b = np.einsum("tji,tj->ti", C, a - G_L)
        return w, f_b

    def increments(self, t0_s: float, dt_s: float, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Exact IMU increments over ``[t0 + k dt, t0 + (k+1) dt]``, k < n: ``int w_b``, ``int f_b`` (n, 3).

        3-point Gauss-Legendre quadrature per interval (exact to O(dt^6) for smooth motion).
        """
        nodes, wts = _GL3
        tk = t0_s + dt_s * np.arange(n)
        t = (tk[:, None] + dt_s * nodes[None, :]).ravel()
        w, f = self.body_rates(t)
        w = w.reshape(n, 3, 3)
        f = f.reshape(n, 3, 3)
        return dt_s * np.einsum("q,nqi->ni", wts, w), dt_s * np.einsum("q,nqi->ni", wts, f)


@dataclass
class Hover(Motion):
    point_m: np.ndarray
    yaw0_rad: float = 0.0

    def pva(self, t_s):
        t_s = np.asarray(t_s, dtype=float)
        p = np.broadcast_to(np.asarray(self.point_m, float), (t_s.size, 3)).copy()
        return p, np.zeros_like(p), np.zeros_like(p)


@dataclass
class Ellipse(Motion):
    """Ellipse (seed 003 sec. 4) counter-clockwise at a constant parameter rate (speed ~ constant),
    optionally with a sinusoidal climb/descent ``height + amp sin(2 pi t / period)``.

    ``rate = 2 pi speed / perimeter`` (Ramanujan), so one lap takes ``perimeter / speed``; a circle is
    ``a == b``. Heights are above the level plane ``z = 0`` of ``L``.
    """

    centre_m: tuple[float, float]
    semi_axes_m: tuple[float, float]
    height_m: float
    speed_m_s: float
    start_angle_rad: float = np.pi
    climb_amp_m: float = 0.0
    climb_period_s: float = 600.0

    @property
    def perimeter_m(self) -> float:
        a, b = self.semi_axes_m
        h = 3.0 * ((a - b) / (a + b)) ** 2
        return float(np.pi * (a + b) * (1.0 + h / (10.0 + np.sqrt(4.0 - h))))

    @property
    def lap_s(self) -> float:
        return self.perimeter_m / self.speed_m_s

    def pva(self, t_s):
        t_s = np.asarray(t_s, dtype=float)
        a, b = self.semi_axes_m
        r = 2.0 * np.pi * self.speed_m_s / self.perimeter_m
        th = self.start_angle_rad + r * t_s
        c, s = np.cos(th), np.sin(th)
        w = 2.0 * np.pi / self.climb_period_s
        A = self.climb_amp_m
        p = np.column_stack([self.centre_m[0] + a * c, self.centre_m[1] + b * s, self.height_m + A * np.sin(w * t_s)])
        v = np.column_stack([-a * r * s, b * r * c, A * w * np.cos(w * t_s)])
        acc = np.column_stack([-a * r * r * c, -b * r * r * s, -A * w * w * np.sin(w * t_s)])
        return p, v, acc


@dataclass
class Straight(Motion):
    """Straight and level (or any constant-velocity) flight ``p0 + v (t - t0)`` (seed 002 spec sec. 1.8)."""

    p0_m: np.ndarray
    v_m_s: np.ndarray
    t0_s: float = 0.0

    def pva(self, t_s):
        t_s = np.asarray(t_s, dtype=float)
        v = np.broadcast_to(np.asarray(self.v_m_s, float), (t_s.size, 3)).copy()
        return np.asarray(self.p0_m, float) + (t_s - self.t0_s)[:, None] * v, v, np.zeros_like(v)


class AtRest(Motion):
    """Test motions at a fixed point (subclasses give the attitude)."""

    def pva(self, t_s):
        t_s = np.asarray(t_s, dtype=float)
        z = np.zeros((t_s.size, 3))
        return z, z.copy(), z.copy()


@dataclass
class Coning(AtRest):
    """Classical coning at a fixed point (test motion): ``C_Lb(t) = exp([a (cos wt, sin wt, 0) x])``
    with half-angle ``a`` and frequency ``w``; the body sits at rest (specific force ``-C^T g``).

    Closed form of the body rate is not needed: the attitude itself is the reference.
    """

    half_angle_rad: float
    freq_rad_s: float

    def attitude(self, t_s):
        t_s = np.asarray(t_s, dtype=float)
        ph = self.half_angle_rad * np.column_stack([np.cos(self.freq_rad_s * t_s), np.sin(self.freq_rad_s * t_s),
                                                    np.zeros(t_s.size)])
        return exp_so3(ph)


@dataclass
class ConstantRate(AtRest):
    """Rotation at a constant body rate ``w_b`` about a fixed axis, at rest (test motion):
    ``C_Lb(t) = C0 exp([w t x])``."""

    rate_rad_s: np.ndarray
    C0: np.ndarray | None = None

    def attitude(self, t_s):
        t_s = np.asarray(t_s, dtype=float)
        C0 = np.eye(3) if self.C0 is None else self.C0
        return C0 @ exp_so3(np.asarray(self.rate_rad_s, float) * t_s[:, None])
