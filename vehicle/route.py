"""Map routes (seed 004 eq. 1 and 3): piecewise great circles at constant height, or straight segments.

The map is known to the navigator (it is not truth): both the world and the navigator import this
module. Coordinates are seed 004's Greenwich frame ``(xi, eta, zeta)`` (``eta`` polar, see
:mod:`nav.orbits`).

Great-circle segment (spec Sec. 3.3, constants derived there and checked here)::

    xi   = cos P0 * P * eta - sin P0 * a0 * sqrt(a1 - eta^2)
    zeta = sin P0 * P * eta + cos P0 * a0 * sqrt(a1 - eta^2)

with ``n = A x B``, ``cos P0 = n_xi / rho_n``, ``sin P0 = n_zeta / rho_n``, ``P = -n_eta / rho_n``,
``a0 = +-sqrt(1 + P^2)`` (the sign that reproduces the endpoints), ``a1 = r^2 / (1 + P^2)``.
The paper's factor 2 in the derivative (eq. 3) is wrong; coefficient 1 is used. A segment that
contains the vertex of its great circle (``|eta| = sqrt(a1)``) is refused: split it there.

The filter's along-path coordinate ``q`` is ``eta`` on a great circle and the arc length ``s`` on a
straight segment (spec Sec. 5.3). Everything is vectorized over runs: ``q`` (M,), segment index
``k`` (M,).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nav.orbits import (
    OMEGA_VEC_G,
    R_EARTH_MEAN_M,
    earth_rotation,
    enu_to_ecef,
    enu_rotation,
    gravity,
    gravity_gradient,
    greenwich_from_ecef,
    sphere_point,
)


@dataclass(frozen=True)
class GreatCircle:
    """One constant-height great-circle segment from ``A`` to ``B`` (Greenwich, (3,), |A| = |B| = r)."""

    A: np.ndarray
    B: np.ndarray
    r: float
    P: float
    cP0: float
    sP0: float
    a0: float
    a1: float
    sign: float  # sign of d(eta)/ds from A to B

    @classmethod
    def from_points(cls, A: np.ndarray, B: np.ndarray) -> "GreatCircle":
        A, B = np.asarray(A, float), np.asarray(B, float)
        r = float(np.linalg.norm(A))
        if abs(np.linalg.norm(B) - r) > 1e-6 * r:
            raise ValueError("segment endpoints must be at the same height")
        n = np.cross(A, B)
        rho = float(np.hypot(n[0], n[2]))
        if rho < 1e-9 * float(np.linalg.norm(n)) or np.linalg.norm(n) == 0:
            raise ValueError("equatorial (or degenerate) segment: eta cannot parameterize it")
        cP0, sP0, P = n[0] / rho, n[2] / rho, -n[1] / rho
        wA, wB = -sP0 * A[0] + cP0 * A[2], -sP0 * B[0] + cP0 * B[2]
        if wA * wB < 0:
            raise ValueError("segment passes the vertex of its great circle: split it there")
        a0 = float(np.sign(wA + wB)) * np.sqrt(1.0 + P * P)
        a1 = r * r / (1.0 + P * P)
        return cls(A, B, r, float(P), float(cP0), float(sP0), a0, float(a1), float(np.sign(B[1] - A[1])))

    @property
    def length_m(self) -> float:
        return self.r * float(np.arctan2(np.linalg.norm(np.cross(self.A, self.B)), self.A @ self.B))

    # --- truth-side parameterization by arc length (used by the world) ---
    def arc_frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Unit vectors ``a`` (toward A), ``b`` (in-plane, toward B), normal ``n = a x b``."""
        a = self.A / self.r
        b = self.B - (self.B @ a) * a
        b = b / np.linalg.norm(b)
        return a, b, np.cross(a, b)


@dataclass(frozen=True)
class Straight:
    """Straight segment ``p(s) = A + s u`` (Greenwich), ``s in [0, L]``; ``up`` the body z axis along it."""

    A: np.ndarray
    B: np.ndarray
    up: np.ndarray

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(self.B - self.A))

    @property
    def u(self) -> np.ndarray:
        d = self.B - self.A
        return d / np.linalg.norm(d)


@dataclass
class Route:
    """A homogeneous chain of segments (all great circles or all straight)."""

    kind: str  # "great_circle" | "straight"
    segments: list
    speeds_m_s: list[float] = field(default_factory=list)  # cruise speed per leg (truth plan)
    name: str = "route"

    def __post_init__(self) -> None:
        if self.kind not in ("great_circle", "straight"):
            raise ValueError(f"route kind must be great_circle or straight, got {self.kind!r}")
        if not self.segments:
            raise ValueError("a route needs at least two map points")
        K = len(self.segments)
        if self.kind == "great_circle":
            S = self.segments
            self._tab = {k: np.array([getattr(s, k) for s in S]) for k in ("P", "cP0", "sP0", "a0", "a1", "sign", "r")}
            self._q0 = np.array([s.A[1] for s in S])
            self._q1 = np.array([s.B[1] for s in S])
        else:
            self._A = np.array([s.A for s in self.segments])
            self._u = np.array([s.u for s in self.segments])
            self._q0 = np.zeros(K)
            self._q1 = np.array([s.length_m for s in self.segments])
            self._tab = {"sign": np.ones(K)}

    @property
    def n_segments(self) -> int:
        return len(self.segments)

    # ------------------------------------------------------------------ navigator-side (vectorized)
    def q_start(self, k) -> np.ndarray:
        return self._q0[k]

    def q_end(self, k) -> np.ndarray:
        return self._q1[k]

    def fwd_sign(self, k) -> np.ndarray:
        """+1 if ``q`` grows in the direction of travel on segment ``k``."""
        return self._tab["sign"][k]

    def pos(self, q: np.ndarray, k: np.ndarray, deriv: int = 2):
        """Greenwich position (M, 3) and its first and second derivatives in ``q`` (eq. 1, 3)."""
        q = np.asarray(q, float)
        if self.kind == "straight":
            A, u = self._A[k], self._u[k]
            p = A + q[..., None] * u
            return p, u, np.zeros_like(u)
        t = self._tab
        P, c, s_, a0, a1 = t["P"][k], t["cP0"][k], t["sP0"][k], t["a0"][k], t["a1"][k]
        root = np.sqrt(np.maximum(a1 - q * q, 1e-6 * a1))
        w = a0 * root
        dw = -a0 * q / root
        ddw = -a0 * a1 / root**3
        p = np.stack([c * P * q - s_ * w, q, s_ * P * q + c * w], axis=-1)
        dp = np.stack([c * P - s_ * dw, np.ones_like(q), s_ * P + c * dw], axis=-1)
        ddp = np.stack([-s_ * ddw, np.zeros_like(q), c * ddw], axis=-1)
        return p, dp, ddp

    def speed_factor(self, q, k) -> np.ndarray:
        """``|dp/dq|``: on a great circle ``sqrt(1 + P^2 + a0^2 eta^2 / (a1 - eta^2))`` (corrected eq. 5)."""
        if self.kind == "straight":
            return np.ones_like(np.asarray(q, float))
        t = self._tab
        P, a0, a1 = t["P"][k], t["a0"][k], t["a1"][k]
        return np.sqrt(1.0 + P * P + a0 * a0 * q * q / np.maximum(a1 - q * q, 1e-6 * a1))

    def speed_factor_d(self, q, k) -> tuple[np.ndarray, np.ndarray]:
        """``|dp/dq|`` and its derivative in ``q`` (the odometer function's eta-dependence)."""
        q = np.asarray(q, float)
        if self.kind == "straight":
            return np.ones_like(q), np.zeros_like(q)
        t = self._tab
        P, a0, a1 = t["P"][k], t["a0"][k], t["a1"][k]
        den = np.maximum(a1 - q * q, 1e-6 * a1)
        sf = np.sqrt(1.0 + P * P + a0 * a0 * q * q / den)
        return sf, a0 * a0 * a1 * q / (den * den * sf)

    def accel_axis_inertial(self, t_s: float, k: np.ndarray) -> np.ndarray:
        """Inertial unit vector ``a`` (M, 3) with ``q'' = a^T D f + gamma(q)``.

        Great circle: the polar axis ``e_eta`` (``e_2^T G = e_2^T``, spec Sec. 3.4). Straight: ``G^T(t) u``.
        """
        if self.kind == "great_circle":
            return _E_ETA  # broadcasts against (M, 3)
        return self._u[k] @ earth_rotation(t_s)  # (G^T u)^T = u^T G

    def gamma(self, q, k) -> tuple[np.ndarray, np.ndarray]:
        """Gravity (and, on a straight segment, centrifugal) term of ``q''`` and its derivative in ``q``.

        Great circle: ``-mu eta / r^3`` (the polar component of central gravity; no Coriolis or
        centrifugal term along the rotation axis). Straight: ``u^T (g(p) - w x (w x p))`` (the Coriolis
        term vanishes because the velocity is along ``u``).
        """
        from nav.orbits import MU_EARTH_M3_S2

        q = np.asarray(q, float)
        if self.kind == "great_circle":
            r3 = self._tab["r"][k] ** 3
            return -MU_EARTH_M3_S2 * q / r3, -MU_EARTH_M3_S2 / r3
        u = self._u[k]
        p = self._A[k] + q[..., None] * u
        W = _skew(OMEGA_VEC_G)
        WW = W @ W
        g_eff = gravity(p) - p @ WW.T
        dg = gravity_gradient(p) - WW
        return np.einsum("...i,...i->...", u, g_eff), np.einsum("...i,...ij,...j->...", u, dg, u)

    def next_segment(self, q, k) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Runs whose ``q`` passed the end of their segment move to the next one.

        Returns ``(q_new, k_new, scale, switched)``: ``q_new = q0' + scale (q - q1)`` and the velocity
        ``V' = scale V`` with ``scale = |dp/dq|_old / |dp/dq|_new`` at the node and the forward signs,
        so the along-track position and speed are continuous.
        """
        q, k = np.asarray(q, float), np.asarray(k)
        last = k >= self.n_segments - 1
        over = (q - self._q1[k]) * self.fwd_sign(k) > 0
        sw = over & ~last
        if not np.any(sw):
            return q, k, np.ones_like(q), sw
        kn = np.where(sw, k + 1, k)
        sf_old = self.speed_factor(self._q1[k], k) * self.fwd_sign(k)
        sf_new = self.speed_factor(self._q0[kn], kn) * self.fwd_sign(kn)
        scale = np.where(sw, sf_old / sf_new, 1.0)
        qn = np.where(sw, self._q0[kn] + scale * (q - self._q1[k]), q)
        return qn, kn, scale, sw


_E_ETA = np.array([[0.0, 1.0, 0.0]])


def _skew(w: np.ndarray) -> np.ndarray:
    w = np.asarray(w, float)
    Z = np.zeros(w.shape[:-1] + (3, 3))
    Z[..., 0, 1], Z[..., 0, 2] = -w[..., 2], w[..., 1]
    Z[..., 1, 0], Z[..., 1, 2] = w[..., 2], -w[..., 0]
    Z[..., 2, 0], Z[..., 2, 1] = -w[..., 1], w[..., 0]
    return Z


# ---------------------------------------------------------------------------------------- builders
def great_circle_route(points_deg, height_m: float = 100.0, speeds_m_s=None, radius_m: float = R_EARTH_MEAN_M,
                       geodetic: bool = True, name: str = "route") -> Route:
    """Route through map points ``[(lat, lon), ...]`` at constant ``height_m`` on the map sphere."""
    pts = [greenwich_from_ecef(sphere_point(la, lo, radius_m + height_m, geodetic)) for la, lo in points_deg]
    segs = [GreatCircle.from_points(a, b) for a, b in zip(pts[:-1], pts[1:])]
    return Route("great_circle", segs, _speeds(speeds_m_s, len(segs)), name)


def straight_route(points_m, origin_deg, rot_frame_to_enu=None, speeds_m_s=None, name: str = "route") -> Route:
    """Route of straight segments through points (n, 3) of a local field frame.

    ``origin_deg = (lat, lon, h)`` ties the frame's origin to WGS-84; ``rot_frame_to_enu`` (3, 3)
    rotates frame vectors into the local ENU (identity: the frame is ENU). Body ``z`` is the local
    vertical at the origin.
    """
    P = np.asarray(points_m, float)
    R = np.eye(3) if rot_frame_to_enu is None else np.asarray(rot_frame_to_enu, float)
    lat, lon, h = origin_deg
    enu = P @ R.T
    pts = greenwich_from_ecef(enu_to_ecef(enu, lat, lon, h))
    up = greenwich_from_ecef(enu_rotation(lat, lon)[2])
    segs = []
    for a, b in zip(pts[:-1], pts[1:]):
        d = b - a
        if abs(d @ up) > 1e-3 * np.linalg.norm(d):
            raise ValueError("straight route segments must be level (constant height)")
        segs.append(Straight(a, b, up))
    return Route("straight", segs, _speeds(speeds_m_s, len(segs)), name)


def _speeds(speeds, n: int) -> list[float]:
    if speeds is None:
        return [20.0] * n
    if np.isscalar(speeds):
        return [float(speeds)] * n
    speeds = [float(v) for v in speeds]
    if len(speeds) != n:
        raise ValueError(f"route: {len(speeds)} speeds for {n} legs (speeds_m_s needs one per leg)")
    return speeds


def load_route(path: str | Path) -> Route:
    """Read a route file: TOML (``[route]`` table) or GeoJSON (a LineString). See docs/scenarios.md."""
    import json
    import tomllib

    path = Path(path)
    text = path.read_text()
    if path.suffix.lower() in (".geojson", ".json"):
        return route_from_geojson(json.loads(text), name=path.stem)
    raw = tomllib.loads(text)
    if "route" not in raw:
        raise ValueError(f"{path}: no [route] table")
    return route_from_dict(raw["route"], name=path.stem)


def route_from_dict(r: dict, name: str = "route") -> Route:
    kind = str(r.get("kind", "great_circle"))
    if kind == "great_circle":
        if "points_deg" not in r:
            raise ValueError("route.points_deg: list of [lat, lon] map points is required")
        return great_circle_route(r["points_deg"], float(r.get("height_m", 100.0)), r.get("speeds_m_s"),
                                  geodetic=bool(r.get("geodetic", True)), name=name)
    if kind == "straight":
        for key in ("points_m", "origin_deg"):
            if key not in r:
                raise ValueError(f"route.{key} is required for a straight route")
        return straight_route(r["points_m"], r["origin_deg"], r.get("rot_frame_to_enu"), r.get("speeds_m_s"), name)
    raise ValueError(f"route.kind must be great_circle or straight, got {kind!r}")


def route_from_geojson(doc: dict, name: str = "route") -> Route:
    """GeoJSON LineString (``[lon, lat(, h)]``; a Feature or FeatureCollection holding one) as great circles.

    The height is the first point's third coordinate (default 100 m); ``properties.speeds_m_s`` sets
    the leg speeds.
    """
    props = {}
    if doc.get("type") == "FeatureCollection":
        lines = [f for f in doc.get("features", []) if f.get("geometry", {}).get("type") == "LineString"]
        if not lines:
            raise ValueError("GeoJSON: no LineString feature")
        doc = lines[0]
    if doc.get("type") == "Feature":
        props = doc.get("properties") or {}
        doc = doc.get("geometry", {})
    if doc.get("type") != "LineString":
        raise ValueError("GeoJSON: expected a LineString")
    co = doc["coordinates"]
    h = float(co[0][2]) if len(co[0]) > 2 else 100.0
    return great_circle_route([(c[1], c[0]) for c in co], h, props.get("speeds_m_s"), name=name)
