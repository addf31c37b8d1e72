"""Keplerian orbits, Earth rotation and geodesy helpers shared by the aircraft and the vehicle.

Frames
------
* ECEF: the usual Earth-fixed frame (X toward (0 N, 0 E), Z polar). Geodetic conversions use
  `pymap3d <https://github.com/geospace-code/pymap3d>`_ on WGS-84.
* Greenwich ``(xi, eta, zeta)`` of seed 004 (Sec. 3.2 of the spec): the same Earth-fixed frame with
  the axes renamed so that ``eta`` is the polar axis: ``xi = Y_ecef, eta = Z_ecef, zeta = X_ecef``
  (a cyclic permutation, so right-handed and cross products are preserved).
* Inertial ``I``: coincides with Greenwich at ``t = 0``; ``p_G = G(Omega t) p_I`` with seed 004's
  ``G(a) = [[cos a, 0, -sin a], [0, 1, 0], [sin a, 0, cos a]]`` (Earth spinning at +Omega about eta).

Gravity is the spherical central field ``-mu p / |p|^3`` (seed 004 uses ``g = mu / r^2``).
"""

from __future__ import annotations

import numpy as np

MU_EARTH_M3_S2 = 3.986004418e14
OMEGA_EARTH_RAD_S = 7.2921151467e-5
R_EARTH_MEAN_M = 6_371_000.0  # radius of the map sphere (seed 004's "Earth sphere")
WGS84_A_M = 6_378_137.0

# Greenwich (xi, eta, zeta) <-> ECEF (X, Y, Z): xi = Y, eta = Z, zeta = X
_G_FROM_ECEF = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
OMEGA_VEC_G = np.array([0.0, OMEGA_EARTH_RAD_S, 0.0])  # Earth rate in Greenwich axes


def greenwich_from_ecef(v: np.ndarray) -> np.ndarray:
    """ECEF vectors (..., 3) -> Greenwich (xi, eta, zeta) (..., 3)."""
    return np.asarray(v, dtype=float) @ _G_FROM_ECEF.T


def ecef_from_greenwich(v: np.ndarray) -> np.ndarray:
    """Greenwich (xi, eta, zeta) vectors (..., 3) -> ECEF (..., 3)."""
    return np.asarray(v, dtype=float) @ _G_FROM_ECEF


def earth_rotation(t_s: np.ndarray | float) -> np.ndarray:
    """Seed 004's ``G(Omega t)`` (..., 3, 3): inertial -> Greenwich."""
    a = OMEGA_EARTH_RAD_S * np.asarray(t_s, dtype=float)
    c, s = np.cos(a), np.sin(a)
    G = np.zeros(a.shape + (3, 3))
    G[..., 0, 0] = c
    G[..., 0, 2] = -s
    G[..., 1, 1] = 1.0
    G[..., 2, 0] = s
    G[..., 2, 2] = c
    return G


def gravity(p_m: np.ndarray) -> np.ndarray:
    """Central gravity ``-mu p / |p|^3`` (..., 3) in any Earth-centred frame."""
    p = np.asarray(p_m, dtype=float)
    r = np.linalg.norm(p, axis=-1, keepdims=True)
    return -MU_EARTH_M3_S2 * p / r**3


def gravity_gradient(p_m: np.ndarray) -> np.ndarray:
    """``d g / d p = -mu / r^3 (I - 3 p p^T / r^2)`` (..., 3, 3)."""
    p = np.asarray(p_m, dtype=float)
    r = np.linalg.norm(p, axis=-1)[..., None, None]
    u = p[..., :, None] / r
    return -MU_EARTH_M3_S2 / r**3 * (np.eye(3) - 3.0 * u * np.swapaxes(u, -1, -2))


def sphere_point(lat_deg: float, lon_deg: float, radius_m: float, geodetic: bool = True) -> np.ndarray:
    """A map point on the sphere of ``radius_m``, ECEF (3,).

    With ``geodetic`` (default) the map's WGS-84 latitude/longitude is converted by pymap3d and the
    point is taken along the direction of the ellipsoid point (so the geocentric latitude is kept);
    otherwise lat/lon are read as spherical (geocentric) angles.
    """
    if geodetic:
        import pymap3d

        x, y, z = pymap3d.geodetic2ecef(lat_deg, lon_deg, 0.0)
        d = np.array([x, y, z], dtype=float)
        return radius_m * d / np.linalg.norm(d)
    la, lo = np.radians(lat_deg), np.radians(lon_deg)
    return radius_m * np.array([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)])


def enu_to_ecef(enu_m: np.ndarray, lat_deg: float, lon_deg: float, h_m: float) -> np.ndarray:
    """Local ENU points (..., 3) at a WGS-84 origin -> ECEF (..., 3) (pymap3d)."""
    import pymap3d

    e = np.asarray(enu_m, dtype=float)
    x, y, z = pymap3d.enu2ecef(e[..., 0], e[..., 1], e[..., 2], lat_deg, lon_deg, h_m)
    return np.stack([np.asarray(x, float), np.asarray(y, float), np.asarray(z, float)], axis=-1)


def enu_rotation(lat_deg: float, lon_deg: float) -> np.ndarray:
    """Rotation (3, 3) with ``v_enu = R v_ecef`` at geodetic (lat, lon)."""
    la, lo = np.radians(lat_deg), np.radians(lon_deg)
    sl, cl, so, co = np.sin(la), np.cos(la), np.sin(lo), np.cos(lo)
    return np.array([[-so, co, 0.0], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl]])


def elevation_deg(sat_ecef: np.ndarray, rx_ecef: np.ndarray) -> np.ndarray:
    """Elevation (deg) of satellites (..., 3) above the receiver's geodetic horizon (pymap3d)."""
    import pymap3d

    lat, lon, h = pymap3d.ecef2geodetic(*np.asarray(rx_ecef, dtype=float))
    s = np.asarray(sat_ecef, dtype=float)
    _, el, _ = pymap3d.ecef2aer(s[..., 0], s[..., 1], s[..., 2], lat, lon, h)
    return np.asarray(el, dtype=float)


def solve_kepler(M: np.ndarray, e: np.ndarray, iters: int = 8) -> np.ndarray:
    """Eccentric anomaly ``E - e sin E = M`` by Newton's method (elementwise)."""
    E = np.array(M, dtype=float, copy=True)
    for _ in range(iters):
        E = E - (E - e * np.sin(E) - M) / (1.0 - e * np.cos(E))
    return E


def kepler_eci(a_m, e, inc_rad, raan_rad, argp_rad, m0_rad, t_s) -> tuple[np.ndarray, np.ndarray]:
    """Two-body position and velocity in an Earth-centred inertial frame (Z polar).

    Elements broadcast against each other (e.g. satellites (N,) against times (T, 1)); ``m0_rad`` is
    the mean anomaly at ``t = 0``. Returns ``pos_m, vel_m_s`` of shape (..., 3).
    """
    a, e = np.asarray(a_m, float), np.asarray(e, float)
    n = np.sqrt(MU_EARTH_M3_S2 / a**3)
    M = np.asarray(m0_rad, float) + n * np.asarray(t_s, float)
    E = solve_kepler(M, e)
    cE, sE = np.cos(E), np.sin(E)
    b = a * np.sqrt(1.0 - e**2)
    x, y = a * (cE - e), b * sE  # perifocal
    Edot = n / (1.0 - e * cE)
    vx, vy = -a * sE * Edot, b * cE * Edot
    co, so = np.cos(raan_rad), np.sin(raan_rad)
    cw, sw = np.cos(argp_rad), np.sin(argp_rad)
    ci, si = np.cos(inc_rad), np.sin(inc_rad)
    # columns of R3(-raan) R1(-i) R3(-argp): perifocal P and Q axes
    P = np.stack([co * cw - so * sw * ci, so * cw + co * sw * ci, sw * si], axis=-1)
    Q = np.stack([-co * sw - so * cw * ci, -so * sw + co * cw * ci, cw * si], axis=-1)
    pos = x[..., None] * P + y[..., None] * Q
    vel = vx[..., None] * P + vy[..., None] * Q
    return pos, vel


def eci_to_ecef(pos_m: np.ndarray, vel_m_s: np.ndarray, t_s) -> tuple[np.ndarray, np.ndarray]:
    """Rotate inertial (Z polar, aligned with ECEF at t = 0) to ECEF; velocity relative to the Earth."""
    th = OMEGA_EARTH_RAD_S * np.asarray(t_s, float)
    c, s = np.cos(th), np.sin(th)
    x = c * pos_m[..., 0] + s * pos_m[..., 1]
    y = -s * pos_m[..., 0] + c * pos_m[..., 1]
    vx = c * vel_m_s[..., 0] + s * vel_m_s[..., 1] + OMEGA_EARTH_RAD_S * y
    vy = -s * vel_m_s[..., 0] + c * vel_m_s[..., 1] - OMEGA_EARTH_RAD_S * x
    pos = np.stack([x, y, pos_m[..., 2]], axis=-1)
    vel = np.stack([vx, vy, vel_m_s[..., 2]], axis=-1)
    return pos, vel
