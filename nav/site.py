"""A field anchored to the Earth (WGS84): the site of a scenario.

Three frames meet here:

* the **field frame** ``f``: the scenario's physical (level) coordinates, metres. It is the local
  East-North-Up frame at the site's origin rotated about Up so that +X points along
  ``azimuth_deg`` (clockwise from north): ``azimuth_deg = 90`` makes +X east and +Y north (ENU
  itself), ``0`` makes +X north and +Y west. +Z is up.
* **ENU** at the origin, and geodetic latitude / longitude / height on WGS84 (via pymap3d).
* the **network frame** ``n`` the stations build from their own ranges (``nav/geometry.py``): a
  rigid motion of the field frame, ``p_n = R (p_f - t)``. :class:`Site` carries that tie (``net_rot``,
  ``net_offset_m``; identity when the caller has none), so the stations' estimates - network
  frame - can be placed on the map.

Pure functions of arrays; shapes ``(..., 3)`` for points, ``(..., 3, 3)`` for covariances.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import numpy as np
import pymap3d


def _rot_enu_from_field(azimuth_deg: float) -> np.ndarray:
    """(3, 3) rotation taking field-frame vectors to ENU at the origin: columns are the field's
    +X (along the azimuth), +Y (90 deg counter-clockwise from +X seen from above) and +Z (up)."""
    a = math.radians(azimuth_deg)
    s, c = math.sin(a), math.cos(a)
    return np.array([[s, -c, 0.0], [c, s, 0.0], [0.0, 0.0, 1.0]])


def _rot_ecef_from_enu(lat_deg, lon_deg) -> np.ndarray:
    """(..., 3, 3) rotation taking ENU vectors at (lat, lon) to ECEF."""
    la, lo = np.radians(np.asarray(lat_deg, float)), np.radians(np.asarray(lon_deg, float))
    sl, cl, so, co = np.sin(la), np.cos(la), np.sin(lo), np.cos(lo)
    z = np.zeros_like(la)
    rows = [[-so, -sl * co, cl * co], [co, -sl * so, cl * so], [z, cl, sl]]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


@dataclass(frozen=True)
class Site:
    """The field's origin on WGS84 (``lat_deg``, ``lon_deg``, ``h_m`` ellipsoidal height), the
    azimuth of its +X axis (degrees clockwise from north) and the tie of the network frame to the
    field frame (``p_n = net_rot @ (p_f - net_offset_m)``; identity / zero by default)."""

    lat_deg: float
    lon_deg: float
    h_m: float = 0.0
    azimuth_deg: float = 90.0
    net_rot: np.ndarray = field(default_factory=lambda: np.eye(3))
    net_offset_m: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        if not -90.0 <= self.lat_deg <= 90.0:
            raise ValueError(f"latitude {self.lat_deg!r} deg (expected -90..90)")
        if not -180.0 <= self.lon_deg <= 180.0:
            raise ValueError(f"longitude {self.lon_deg!r} deg (expected -180..180)")
        object.__setattr__(self, "net_rot", np.asarray(self.net_rot, float).reshape(3, 3))
        object.__setattr__(self, "net_offset_m", np.asarray(self.net_offset_m, float).reshape(3))

    @property
    def origin(self) -> tuple[float, float, float]:
        return (self.lat_deg, self.lon_deg, self.h_m)

    @property
    def rot_enu_from_field(self) -> np.ndarray:
        return _rot_enu_from_field(self.azimuth_deg)

    def with_network(self, rot: np.ndarray, offset_m: np.ndarray) -> "Site":
        """The same site with the network frame tied by ``p_n = rot @ (p_f - offset_m)``."""
        return Site(self.lat_deg, self.lon_deg, self.h_m, self.azimuth_deg, np.asarray(rot, float),
                    np.asarray(offset_m, float))

    # ----------------------------------------------------------------- field frame <-> WGS84
    def frame_to_enu(self, xyz_m) -> np.ndarray:
        """Field-frame points (..., 3) -> ENU at the origin (..., 3), metres."""
        return np.asarray(xyz_m, float) @ self.rot_enu_from_field.T

    def enu_to_frame(self, enu_m) -> np.ndarray:
        return np.asarray(enu_m, float) @ self.rot_enu_from_field

    def frame_to_geodetic(self, xyz_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Field-frame points (..., 3) -> (lat_deg, lon_deg, h_m), each (...)."""
        enu = self.frame_to_enu(xyz_m)
        lat, lon, h = pymap3d.enu2geodetic(enu[..., 0], enu[..., 1], enu[..., 2], self.lat_deg, self.lon_deg,
                                           self.h_m, deg=True)
        return np.asarray(lat, float), np.asarray(lon, float), np.asarray(h, float)

    def geodetic_to_frame(self, lat_deg, lon_deg, h_m) -> np.ndarray:
        """(lat_deg, lon_deg, h_m), each (...) -> field-frame points (..., 3)."""
        e, n, u = pymap3d.geodetic2enu(np.asarray(lat_deg, float), np.asarray(lon_deg, float),
                                       np.asarray(h_m, float), self.lat_deg, self.lon_deg, self.h_m, deg=True)
        return self.enu_to_frame(np.stack(np.broadcast_arrays(e, n, u), axis=-1))

    def frame_cov_to_enu(self, cov_m2, lat_deg=None, lon_deg=None) -> np.ndarray:
        """Field-frame covariances (..., 3, 3) -> ENU (..., 3, 3): a rotation about Up by the azimuth
        (ENU at the origin). Given the point's ``lat_deg`` / ``lon_deg`` (...), the result is in the
        tangent plane at that point (what ``foxglove.LocationFix`` asks for; over a 40 km field the
        two differ by a rotation of at most ~0.2 deg)."""
        M = self.rot_enu_from_field
        if lat_deg is not None:
            M = np.swapaxes(_rot_ecef_from_enu(lat_deg, lon_deg), -1, -2) @ _rot_ecef_from_enu(
                self.lat_deg, self.lon_deg) @ M
        C = np.asarray(cov_m2, float)
        return M @ C @ np.swapaxes(M, -1, -2)

    # ----------------------------------------------------------------- network frame <-> WGS84
    def net_to_frame(self, xyz_n) -> np.ndarray:
        """Network-frame points (..., 3) -> field frame: ``p_f = R^T p_n + t``."""
        return np.asarray(xyz_n, float) @ self.net_rot + self.net_offset_m

    def frame_to_net(self, xyz_f) -> np.ndarray:
        return (np.asarray(xyz_f, float) - self.net_offset_m) @ self.net_rot.T

    def net_to_geodetic(self, xyz_n) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Network-frame points (..., 3) -> (lat_deg, lon_deg, h_m), each (...)."""
        return self.frame_to_geodetic(self.net_to_frame(xyz_n))

    def geodetic_to_net(self, lat_deg, lon_deg, h_m) -> np.ndarray:
        return self.frame_to_net(self.geodetic_to_frame(lat_deg, lon_deg, h_m))

    def net_cov_to_enu(self, cov_m2, lat_deg=None, lon_deg=None) -> np.ndarray:
        """Network-frame covariances (..., 3, 3) -> ENU (at the origin, or at the given point)."""
        R = self.net_rot
        return self.frame_cov_to_enu(R.T @ np.asarray(cov_m2, float) @ R, lat_deg, lon_deg)

    # ----------------------------------------------------------------- recordings
    def to_dict(self) -> dict:
        return {"origin": [self.lat_deg, self.lon_deg, self.h_m], "azimuth_deg": self.azimuth_deg,
                "net_rot": self.net_rot.tolist(), "net_offset_m": self.net_offset_m.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "Site":
        lat, lon, h = (float(v) for v in d["origin"])
        return cls(lat, lon, h, float(d.get("azimuth_deg", 90.0)), np.asarray(d.get("net_rot", np.eye(3)), float),
                   np.asarray(d.get("net_offset_m", np.zeros(3)), float))

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), separators=(",", ":"))

    @classmethod
    def from_json(cls, text: str) -> "Site":
        return cls.from_dict(json.loads(text))


def horizontal_ellipse(cov_en_m2, k_sigma: float = 2.0) -> tuple[float, float, float]:
    """The ``k_sigma`` horizontal error ellipse of an East-North covariance (..., 2, 2) block:
    (semi-major m, semi-minor m, orientation of the major axis in degrees clockwise from north)."""
    C = np.asarray(cov_en_m2, float)[:2, :2]
    C = 0.5 * (C + C.T)
    w, V = np.linalg.eigh(C)
    w = np.maximum(w, 0.0)
    major = V[:, 1]
    az = math.degrees(math.atan2(major[0], major[1])) % 180.0
    return k_sigma * math.sqrt(w[1]), k_sigma * math.sqrt(w[0]), az


def ellipse_ring(site: Site, center_f, cov_en_m2, k_sigma: float = 2.0, n: int = 36) -> np.ndarray:
    """A closed ring (n + 1, 3) of (lon_deg, lat_deg, h_m) approximating the ``k_sigma`` horizontal
    error ellipse of a point ``center_f`` (field frame) with East-North covariance ``cov_en_m2`` (2, 2)
    (ENU at the origin), counter-clockwise (RFC 7946 exterior ring)."""
    a, b, az = horizontal_ellipse(cov_en_m2, k_sigma)
    th = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    ang = math.radians(az)
    major, minor = np.array([math.sin(ang), math.cos(ang)]), np.array([math.cos(ang), -math.sin(ang)])
    # counter-clockwise seen from above (east-north): minor = major rotated -90 deg, so walk -theta
    en = np.outer(a * np.cos(th), major) - np.outer(b * np.sin(th), minor)
    enu0 = site.frame_to_enu(np.asarray(center_f, float))
    enu = np.column_stack([enu0[0] + en[:, 0], enu0[1] + en[:, 1], np.full(n, enu0[2])])
    lat, lon, h = site.frame_to_geodetic(site.enu_to_frame(enu))
    ring = np.column_stack([lon, lat, h])
    return np.vstack([ring, ring[:1]])
