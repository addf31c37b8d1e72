"""Truth motion along a map route: speed plan with accelerations and stops, attitude along the track,
analytic angular rate and specific force (spec Sec. 3.9 "body attitude", Sec. 5.2).

Body axes: x along the track, z up (radial on the map sphere, the local vertical on a straight
field route), y = z x x (left). On a great circle the track frame turns about the circle's normal at
``s' / r`` (pitch rate), so ``w_gb^b = (0, s'/r, 0)``; at a map node the vehicle stops and turns in
place about z with a smooth yaw profile. With ``G`` the Earth rotation (:mod:`nav.orbits`):

* ``D = G(t)^T C_gb`` (body -> inertial, the filter's direction cosines),
* ``w_ib^b = C_gb^T w_e + w_gb^b``,
* ``f^b = C_gb^T (a_G + 2 w_e x v_G + w_e x (w_e x p_G) - g(p_G))`` with central gravity.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nav.orbits import OMEGA_VEC_G, earth_rotation, gravity
from vehicle.route import Route


@dataclass
class Phase:
    t0: float
    t1: float
    seg: int
    s0: float
    v0: float
    acc: float
    turn: float = 0.0  # heading change (rad) for a turn-in-place phase, 0 otherwise


@dataclass
class TruthSamples:
    """Truth at times ``t_s`` (T,): Greenwich p, v, a (T, 3); ``C_gb`` (T, 3, 3); ``D`` (T, 3, 3);
    ``w_ib_b``, ``f_b`` (T, 3); segment ``seg`` (T,), along-track ``s`` (T,), forward speed ``speed`` (T,)."""

    t_s: np.ndarray
    p_g: np.ndarray
    v_g: np.ndarray
    a_g: np.ndarray
    C_gb: np.ndarray
    D: np.ndarray
    w_ib_b: np.ndarray
    f_b: np.ndarray
    seg: np.ndarray
    s: np.ndarray
    speed: np.ndarray


def speed_plan(route: Route, v_start_m_s: float | None = None, accel_m_s2: float = 0.5,
               turn_s: float = 10.0, stop_at_end: bool = True) -> list[Phase]:
    """Phases of constant along-track acceleration (and turn-in-place phases at the nodes).

    Leg ``k`` runs at ``route.speeds_m_s[k]``; the vehicle starts at ``v_start_m_s`` (default: the
    first leg's speed, i.e. already moving), stops at every inner node, turns in place over ``turn_s``
    and sets off again; at the last node it stops if ``stop_at_end`` (else it keeps going).
    """
    phases: list[Phase] = []
    t = 0.0
    K = route.n_segments
    v_in = route.speeds_m_s[0] if v_start_m_s is None else float(v_start_m_s)
    for k, seg in enumerate(route.segments):
        L, V = seg.length_m, route.speeds_m_s[k]
        v_out = 0.0 if (k < K - 1 or stop_at_end) else V
        d1 = abs(V * V - v_in * v_in) / (2 * accel_m_s2)
        d2 = (V * V - v_out * v_out) / (2 * accel_m_s2)
        if d1 + d2 > L:
            raise ValueError(f"leg {k + 1} ({L:.0f} m) is too short for its speed changes at {accel_m_s2} m/s^2")
        s = 0.0
        if d1 > 0:
            dt = abs(V - v_in) / accel_m_s2
            phases.append(Phase(t, t + dt, k, s, v_in, np.sign(V - v_in) * accel_m_s2))
            t, s = t + dt, d1
        dc = L - d1 - d2
        if dc > 0:
            phases.append(Phase(t, t + dc / V, k, s, V, 0.0))
            t, s = t + dc / V, s + dc
        if d2 > 0:
            dt = (V - v_out) / accel_m_s2
            phases.append(Phase(t, t + dt, k, s, V, -accel_m_s2))
            t, s = t + dt, L
        if k < K - 1:
            psi = _turn_angle(route, k)
            phases.append(Phase(t, t + turn_s, k, L, 0.0, 0.0, turn=psi))
            t += turn_s
        v_in = 0.0
    # after the route: stand still (or cruise on, which extends the last segment's geometry)
    last = route.segments[-1]
    vend = 0.0 if stop_at_end else route.speeds_m_s[-1]
    phases.append(Phase(t, np.inf, K - 1, last.length_m, vend, 0.0))
    return phases


def _frame(route: Route, k: int, s: np.ndarray):
    """Position, unit tangent, body z and track-frame pitch-rate factor (1/r or 0) at arc length s."""
    seg = route.segments[k]
    if route.kind == "great_circle":
        a, b, n = seg.arc_frame()
        th = s / seg.r
        c, sn = np.cos(th)[:, None], np.sin(th)[:, None]
        pu = c * a + sn * b
        tang = -sn * a + c * b
        return seg.r * pu, tang, pu, 1.0 / seg.r
    p = seg.A + s[:, None] * seg.u
    T = np.broadcast_to(seg.u, p.shape)
    Z = np.broadcast_to(seg.up, p.shape)
    return p, T, Z, 0.0


def _turn_angle(route: Route, k: int) -> float:
    L = route.segments[k].length_m
    _, t_old, z, _ = _frame(route, k, np.array([L]))
    _, t_new, _, _ = _frame(route, k + 1, np.array([0.0]))
    t_old, t_new, z = t_old[0], t_new[0], z[0]
    return float(np.arctan2(np.cross(t_old, t_new) @ z, t_old @ t_new))


def sample(route: Route, phases: list[Phase], t_s: np.ndarray) -> TruthSamples:
    """Truth at the times ``t_s`` (T,), vectorized per phase."""
    t_s = np.asarray(t_s, float)
    T = t_s.size
    p, v, a = np.zeros((T, 3)), np.zeros((T, 3)), np.zeros((T, 3))
    C = np.zeros((T, 3, 3))
    w_gb = np.zeros((T, 3))
    seg, s_out, spd = np.zeros(T, int), np.zeros(T), np.zeros(T)
    starts = np.array([ph.t0 for ph in phases])
    idx = np.searchsorted(starts, t_s, side="right") - 1
    if np.any(idx < 0):
        raise ValueError("times before the start of the plan")
    for j in np.unique(idx):
        ph = phases[j]
        m = idx == j
        tau = t_s[m] - ph.t0
        k = ph.seg
        if ph.turn == 0.0:
            s = ph.s0 + ph.v0 * tau + 0.5 * ph.acc * tau**2
            sd = ph.v0 + ph.acc * tau
            pos, tang, z, kap = _frame(route, k, s)
            p[m], v[m] = pos, sd[:, None] * tang
            # along-track acceleration plus the centripetal term of the great circle
            a[m] = ph.acc * tang - (kap * sd**2)[:, None] * z
            x = tang
            w_gb[m, 1] = kap * sd
        else:
            dur = ph.t1 - ph.t0
            u = tau / dur
            psi = ph.turn * (u - np.sin(2 * np.pi * u) / (2 * np.pi))
            psid = ph.turn / dur * (1.0 - np.cos(2 * np.pi * u))
            s, sd = np.full(tau.shape, ph.s0), np.zeros(tau.shape)
            pos, t_old, z, _ = _frame(route, k, s)
            p[m] = pos
            x = np.cos(psi)[:, None] * t_old + np.sin(psi)[:, None] * np.cross(z, t_old)
            w_gb[m, 2] = psid
        y = np.cross(z, x)
        C[m] = np.stack([x, y, z], axis=-1)
        seg[m], s_out[m], spd[m] = k, s, sd
    w_e = OMEGA_VEC_G
    G = earth_rotation(t_s)
    D = np.swapaxes(G, -1, -2) @ C
    w_ib = np.einsum("tji,j->ti", C, w_e) + w_gb
    acc_i = a + 2.0 * np.cross(w_e, v) + np.cross(w_e, np.cross(w_e, p)) - gravity(p)
    f_b = np.einsum("tji,tj->ti", C, acc_i)
    return TruthSamples(t_s, p, v, a, C, D, w_ib, f_b, seg, s_out, spd)
