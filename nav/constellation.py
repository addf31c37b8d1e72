"""Satellite constellations from an almanac at a fixed epoch (GPS-like and GLONASS-like).

An :class:`Almanac` holds Keplerian elements per satellite at ``t = 0`` (the scenario's epoch) and
the broadcast clock polynomial. Positions and velocities come from the two-body model
(:mod:`nav.orbits`), Earth-fixed. Seed 002 asks for a GPS-like almanac, seed 004 (spec Sec. 3.9)
for a GLONASS-like one: 24 satellites in 3 planes, 19 100 km altitude, 64.8 deg, circular.

Error terms offered to the world (the estimators never call them with truth):
* ``clock_m``: the satellite clock offset ``c (af0 + af1 t)`` (the broadcast correction removes it
  up to a residual the caller draws);
* :func:`tropo_delay_m`: a simple troposphere, 2.4 m at zenith with a ``1 / sin(el)`` mapping.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .geometry import SPEED_OF_LIGHT_M_S
from .orbits import WGS84_A_M, eci_to_ecef, elevation_deg, enu_rotation, kepler_eci


@dataclass(frozen=True)
class Almanac:
    """Keplerian elements (N,) at ``t = 0``; angles in radians; ``af0_s``, ``af1`` clock polynomial."""

    name: str
    prn: np.ndarray
    a_m: np.ndarray
    e: np.ndarray
    inc_rad: np.ndarray
    raan_rad: np.ndarray
    argp_rad: np.ndarray
    m0_rad: np.ndarray
    af0_s: np.ndarray
    af1: np.ndarray

    @property
    def n(self) -> int:
        return int(self.prn.size)

    def eci(self, t_s) -> tuple[np.ndarray, np.ndarray]:
        """Inertial position, velocity (..., N, 3) at times ``t_s`` (...)."""
        t = np.asarray(t_s, float)[..., None]
        return kepler_eci(self.a_m, self.e, self.inc_rad, self.raan_rad, self.argp_rad, self.m0_rad, t)

    def ecef(self, t_s) -> tuple[np.ndarray, np.ndarray]:
        """Earth-fixed position and velocity relative to the Earth (..., N, 3)."""
        p, v = self.eci(t_s)
        return eci_to_ecef(p, v, np.asarray(t_s, float)[..., None])

    def clock_m(self, t_s) -> np.ndarray:
        """Satellite clock offset in metres ``c (af0 + af1 t)`` (..., N)."""
        t = np.asarray(t_s, float)[..., None]
        return SPEED_OF_LIGHT_M_S * (self.af0_s + self.af1 * t)

    def visible(self, rx_ecef: np.ndarray, t_s: float, mask_deg: float = 10.0) -> np.ndarray:
        """Indices of the satellites above ``mask_deg`` at the receiver (ECEF (3,)) at ``t_s``."""
        p, _ = self.ecef(t_s)
        return np.flatnonzero(elevation_deg(p, rx_ecef) >= mask_deg)


def walker(name: str, total: int, planes: int, phasing: int, altitude_m: float, inc_deg: float,
           raan0_deg: float = 0.0, m0_deg: float = 0.0, rng: np.random.Generator | None = None,
           clock_sigma_s: float = 1e-4, drift_sigma: float = 1e-11) -> Almanac:
    """Walker delta constellation ``total/planes/phasing`` on circular orbits.

    The clock polynomial is drawn from ``rng`` (a fixed default stream keeps the almanac a constant).
    """
    rng = rng or np.random.default_rng(4)
    per = total // planes
    if per * planes != total:
        raise ValueError("total must be a multiple of planes")
    j = np.repeat(np.arange(planes), per)
    k = np.tile(np.arange(per), planes)
    raan = np.radians(raan0_deg) + 2.0 * np.pi * j / planes
    m0 = np.radians(m0_deg) + 2.0 * np.pi * k / per + 2.0 * np.pi * phasing * j / total
    z = np.zeros(total)
    return Almanac(
        name=name, prn=np.arange(1, total + 1), a_m=np.full(total, WGS84_A_M + altitude_m), e=z,
        inc_rad=np.full(total, np.radians(inc_deg)), raan_rad=raan, argp_rad=z.copy(), m0_rad=m0,
        af0_s=clock_sigma_s * rng.standard_normal(total), af1=drift_sigma * rng.standard_normal(total),
    )


def glonass_like() -> Almanac:
    """24 satellites, 3 planes, 19 100 km, 64.8 deg, circular (Walker 24/3/1)."""
    return walker("glonass-like", 24, 3, 1, 19_100e3, 64.8)


def gps_like() -> Almanac:
    """24 satellites, 6 planes, 20 180 km, 55 deg, circular (Walker 24/6/1)."""
    return walker("gps-like", 24, 6, 1, 20_180e3, 55.0, raan0_deg=17.0, m0_deg=11.0)


CONSTELLATIONS = {"glonass": glonass_like, "gps": gps_like}


def tropo_delay_m(el_deg: np.ndarray, zenith_m: float = 2.4) -> np.ndarray:
    """Simple troposphere: ``zenith / sin(el)`` (el clipped at 3 deg)."""
    return zenith_m / np.sin(np.radians(np.maximum(np.asarray(el_deg, float), 3.0)))


# --------------------------------------------------------------------------- the local frame of a sky
@dataclass(frozen=True)
class EnuFrame:
    """ENU frame at a WGS-84 origin (deg, deg, m): ``p_L = R (p_ecef - o)`` (pymap3d for the origin)."""

    lat_deg: float
    lon_deg: float
    h_m: float = 0.0

    @cached_property
    def R(self) -> np.ndarray:
        """ECEF -> ENU rotation (3, 3) at the origin (computed once per frame, read-only)."""
        r = enu_rotation(self.lat_deg, self.lon_deg)
        r.setflags(write=False)
        return r

    @cached_property
    def origin_ecef(self) -> np.ndarray:
        import pymap3d

        o = np.array(pymap3d.geodetic2ecef(self.lat_deg, self.lon_deg, self.h_m), dtype=float)
        o.setflags(write=False)
        return o

    def from_ecef(self, p_ecef: np.ndarray) -> np.ndarray:
        """ECEF points (..., 3) -> local (..., 3)."""
        return (np.asarray(p_ecef, float) - self.origin_ecef) @ self.R.T

    def from_geodetic(self, lat_deg, lon_deg, h_m) -> np.ndarray:
        """Geodetic points (...,) -> local (..., 3) (pymap3d)."""
        import pymap3d

        e, n, u = pymap3d.geodetic2enu(lat_deg, lon_deg, h_m, self.lat_deg, self.lon_deg, self.h_m)
        return np.stack([np.asarray(e, float), np.asarray(n, float), np.asarray(u, float)], axis=-1)

    def to_geodetic(self, p_m: np.ndarray):
        import pymap3d

        p = np.asarray(p_m, float)
        return pymap3d.enu2geodetic(p[..., 0], p[..., 1], p[..., 2], self.lat_deg, self.lon_deg, self.h_m)


def local_up(frame_p_m: np.ndarray) -> np.ndarray:
    """Approximate local vertical (..., 3) at local positions (spherical Earth of the WGS-84 radius)."""
    c = np.asarray(frame_p_m, float) + np.array([0.0, 0.0, WGS84_A_M])
    return c / np.linalg.norm(c, axis=-1, keepdims=True)


def satellite_elevation_deg(sat_m: np.ndarray, p_m: np.ndarray) -> np.ndarray:
    """Elevation (deg) of satellites (..., 3) seen from ``p_m`` (..., 3), both local."""
    d = np.asarray(sat_m, float) - np.asarray(p_m, float)
    u = d / np.linalg.norm(d, axis=-1, keepdims=True)
    return np.degrees(np.arcsin(np.clip(np.sum(u * local_up(p_m), axis=-1), -1.0, 1.0)))
