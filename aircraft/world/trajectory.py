"""True aircraft trajectories (emulator side only; estimators never see them).

All functions return a :class:`Track` sampled at the given times, positions in the network frame.
Heights: seed 001 does not give the height of its points; by default the aircraft sits on a
3 degree glide path toward the centre of the station circle, ``h = d * tan(3 deg)`` with ``d`` the
horizontal distance of the (start) point from the centre (:func:`glide_height`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GLIDE_DEG = 3.0


@dataclass
class Track:
    """Sampled truth: ``t_s`` (T,), ``pos_m`` (T, 3), ``vel_m_s`` (T, 3)."""

    t_s: np.ndarray
    pos_m: np.ndarray
    vel_m_s: np.ndarray

    def at(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity at an arbitrary time: linear interpolation between samples, the
        arithmetic of ``numpy.interp`` (``(y1 - y0) / (t1 - t0) * (t - t0) + y0``; held at the ends) on
        the six columns at once."""
        t = self.t_s
        if not t[0] < t_s < t[-1]:
            p = np.array([np.interp(t_s, t, self.pos_m[:, i]) for i in range(3)])
            v = np.array([np.interp(t_s, t, self.vel_m_s[:, i]) for i in range(3)])
            return p, v
        pv = self.__dict__.get("_pv")
        if pv is None:  # the samples side by side, (T, 6), built on first use
            pv = self.__dict__["_pv"] = np.concatenate([self.pos_m, self.vel_m_s], axis=1)
        j = int(np.searchsorted(t, t_s, "right")) - 1
        y0 = pv[j]
        y = (pv[j + 1] - y0) / (t[j + 1] - t[j]) * (t_s - t[j]) + y0
        return y[:3], y[3:]


def glide_height(distance_m: float | np.ndarray, glide_deg: float = GLIDE_DEG) -> np.ndarray | float:
    """Height on a glide path of ``glide_deg`` toward the centre: ``d * tan(glide)``."""
    return np.asarray(distance_m, dtype=float) * np.tan(np.radians(glide_deg))


def hover(t_s: np.ndarray, point_m: np.ndarray) -> Track:
    """Hover at ``point_m`` (3,) (seed 001 trajectory no. 1)."""
    t_s = np.asarray(t_s, dtype=float)
    pos = np.broadcast_to(np.asarray(point_m, dtype=float), (t_s.size, 3)).copy()
    return Track(t_s, pos, np.zeros_like(pos))


def omega_schedule(
    rng: np.random.Generator, duration_s: float, omega_max_rad_s: float, segment_s: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """Piecewise-constant jumping angular velocity: segment start times (K,) and rates (K,).

    Segment lengths uniform in ``segment_s``, rates uniform in ``[-omega_max, omega_max]``.
    """
    starts, rates, t = [], [], 0.0
    while t < duration_s:
        starts.append(t)
        rates.append(rng.uniform(-omega_max_rad_s, omega_max_rad_s))
        t += rng.uniform(*segment_s)
    return np.array(starts), np.array(rates)


def coordinated_turn(
    t_s: np.ndarray, start_m: np.ndarray, speed_m_s: float, heading_rad: float,
    seg_start_s: np.ndarray, seg_omega_rad_s: np.ndarray,
) -> Track:
    """Horizontal coordinated turn with piecewise-constant angular velocity (seed 001 traj. no. 2).

    Exact integration of the turn model of seed 001 (the ``F_1(omega)`` matrix) inside each segment;
    constant speed and height.
    """
    t_s = np.asarray(t_s, dtype=float)
    # heading and position at each segment start
    K = len(seg_start_s)
    p0 = np.zeros((K, 2))
    psi0 = np.zeros(K)
    p, psi = np.asarray(start_m, dtype=float)[:2].copy(), float(heading_rad)
    for k in range(K):
        p0[k], psi0[k] = p, psi
        if k + 1 < K:
            p, psi = _turn_step(p, psi, speed_m_s, seg_omega_rad_s[k], seg_start_s[k + 1] - seg_start_s[k])
    k = np.clip(np.searchsorted(seg_start_s, t_s, side="right") - 1, 0, K - 1)
    tau = t_s - seg_start_s[k]
    xy, psi_t = _turn_step(p0[k], psi0[k], speed_m_s, seg_omega_rad_s[k], tau)
    pos = np.column_stack([xy, np.full(t_s.size, float(start_m[2]))])
    vel = np.column_stack([speed_m_s * np.cos(psi_t), speed_m_s * np.sin(psi_t), np.zeros(t_s.size)])
    return Track(t_s, pos, vel)


def _turn_step(p, psi, v, w, tau):
    """Advance (position (...,2), heading) by ``tau`` at speed ``v`` and rate ``w`` (exact arc)."""
    p = np.asarray(p, dtype=float)
    w = np.asarray(w, dtype=float)
    tau = np.asarray(tau, dtype=float)
    small = np.abs(w) < 1e-9
    ws = np.where(small, 1.0, w)
    dx = np.where(small, v * tau * np.cos(psi), v / ws * (np.sin(psi + w * tau) - np.sin(psi)))
    dy = np.where(small, v * tau * np.sin(psi), -v / ws * (np.cos(psi + w * tau) - np.cos(psi)))
    return p + np.stack([dx, dy], axis=-1), psi + w * tau


def ellipse(
    t_s: np.ndarray, centre_m: np.ndarray, semi_axes_m: tuple[float, float], height_m: float,
    speed_m_s: float, start_angle_rad: float = np.pi,
) -> Track:
    """Ellipse at constant height, counter-clockwise at (nearly) constant speed (seed 003, sec. 4).

    The parameter advances at ``speed / mean radius`` so one lap takes ``perimeter / speed``
    (Ramanujan's perimeter); the speed varies mildly along the ellipse.
    """
    t_s = np.asarray(t_s, dtype=float)
    a, b = semi_axes_m
    h = 3.0 * ((a - b) / (a + b)) ** 2
    perim = np.pi * (a + b) * (1.0 + h / (10.0 + np.sqrt(4.0 - h)))
    rate = 2.0 * np.pi * speed_m_s / perim
    th = start_angle_rad + rate * t_s
    c = np.asarray(centre_m, dtype=float)
    pos = np.column_stack([c[0] + a * np.cos(th), c[1] + b * np.sin(th), np.full(t_s.size, height_m)])
    vel = np.column_stack([-a * rate * np.sin(th), b * rate * np.cos(th), np.zeros(t_s.size)])
    return Track(t_s, pos, vel)


def from_config(cfg: dict, t_s: np.ndarray, centre_m: np.ndarray, height_m: float | None = None) -> Track:
    """Build a track from a scenario's ``[aircraft.trajectory]`` table (see docs/aircraft.md).

    ``height_m`` overrides the height rule; otherwise ``height_m`` from the table, else the glide path.
    """
    kind = cfg.get("kind", "hover")
    centre_m = np.asarray(centre_m, dtype=float)
    if kind in ("hover", "turn"):
        d = float(cfg.get("distance_m", 1000.0))
        az = np.radians(float(cfg.get("azimuth_deg", 0.0)))
        h = height_m if height_m is not None else cfg.get("height_m")
        h = float(glide_height(d)) if h is None else float(h)
        start = centre_m + np.array([d * np.cos(az), d * np.sin(az), 0.0])
        start[2] = centre_m[2] + h
        if kind == "hover":
            return hover(t_s, start)
        rng = np.random.default_rng(int(cfg.get("seed", 1)))
        starts, rates = omega_schedule(rng, float(t_s[-1]) + 1.0, float(cfg.get("omega_max_rad_s", 0.05)),
                                       tuple(cfg.get("segment_s", (5.0, 15.0))))
        heading = az + np.radians(float(cfg.get("heading_deg", 90.0)))
        return coordinated_turn(t_s, start, float(cfg.get("speed_m_s", 30.0)), heading, starts, rates)
    if kind == "ellipse":
        h = height_m if height_m is not None else float(cfg.get("height_m", 1000.0))
        return ellipse(t_s, cfg.get("centre_m", centre_m[:2]), tuple(cfg["semi_axes_m"]), centre_m[2] * 0 + h,
                       float(cfg.get("speed_m_s", 44.0)), np.radians(float(cfg.get("start_angle_deg", 180.0))))
    raise ValueError(f"unknown trajectory kind {kind!r} (hover, turn, ellipse)")
