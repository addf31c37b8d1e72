"""nav/site.py: field frame <-> WGS84 (pymap3d), covariance to ENU, the network tie."""

import math

import numpy as np
import pymap3d
import pytest

from nav.geometry import to_network_frame
from nav.site import Site, ellipse_ring, horizontal_ellipse


@pytest.mark.parametrize("origin", [(48.8566, 2.3522, 35.0), (-33.9, 151.2, 0.0), (69.6, -140.0, 1200.0)])
@pytest.mark.parametrize("azimuth_deg", [90.0, 0.0, 37.5, -120.0])
def test_round_trip_40_km_below_1_mm(origin, azimuth_deg):
    site = Site(*origin, azimuth_deg=azimuth_deg)
    rng = np.random.default_rng(5)
    xyz = rng.uniform([-20e3, -20e3, -100.0], [20e3, 20e3, 3000.0], (500, 3))
    lat, lon, h = site.frame_to_geodetic(xyz)
    assert lat.shape == (500,)
    back = site.geodetic_to_frame(lat, lon, h)
    assert np.max(np.linalg.norm(back - xyz, axis=-1)) < 1e-3
    # vectorized over any leading shape
    lat2, _, _ = site.frame_to_geodetic(xyz.reshape(25, 20, 3))
    assert lat2.shape == (25, 20) and np.allclose(lat2.ravel(), lat)


def test_azimuth_orients_the_axes():
    o = (48.8566, 2.3522, 35.0)
    east = Site(*o, azimuth_deg=90.0).frame_to_enu([1000.0, 0.0, 0.0])
    assert np.allclose(east, [1000.0, 0.0, 0.0])
    north = Site(*o, azimuth_deg=0.0).frame_to_enu([[1000.0, 0.0, 0.0], [0.0, 1000.0, 0.0]])
    assert np.allclose(north, [[0.0, 1000.0, 0.0], [-1000.0, 0.0, 0.0]])  # +X north, +Y west
    # +X along azimuth 0 moves north on the ellipsoid: latitude up, longitude unchanged
    lat, lon, h = Site(*o, azimuth_deg=0.0).frame_to_geodetic([1000.0, 0.0, 0.0])
    assert lat > o[0] and abs(lon - o[1]) < 1e-9
    # against pymap3d directly
    e, n, u = pymap3d.geodetic2enu(lat, lon, h, *o)
    assert np.allclose([e, n, u], [0.0, 1000.0, 0.0], atol=1e-6)


def test_cov_to_enu_is_the_rotation_about_up():
    site = Site(10.0, 20.0, 0.0, azimuth_deg=30.0)
    C = np.diag([4.0, 1.0, 9.0])
    E = site.frame_cov_to_enu(C)
    # field +X (variance 4) lies along azimuth 30: in ENU, the major axis points 30 deg east of north
    w, V = np.linalg.eigh(E[:2, :2])
    assert np.allclose(w, [1.0, 4.0])
    assert math.isclose(abs(math.degrees(math.atan2(V[0, 1], V[1, 1]))) % 180.0, 30.0, abs_tol=1e-9)
    assert E[2, 2] == pytest.approx(9.0) and np.allclose(E[:2, 2], 0.0)
    # batch of covariances, and the tangent plane at a point 20 km away stays within 0.2 deg
    Es = site.frame_cov_to_enu(np.stack([C, 2 * C]))
    assert np.allclose(Es[1], 2 * E)
    lat, lon, _ = site.frame_to_geodetic([20e3, 0.0, 0.0])
    El = site.frame_cov_to_enu(C, lat, lon)
    assert np.allclose(np.trace(El), 14.0) and np.allclose(El, E, atol=0.05)


def test_network_tie_places_the_network_frame():
    rng = np.random.default_rng(1)
    phys = rng.uniform([0, 0, 0], [2000, 2000, 80], (6, 3))
    net, R, t = to_network_frame(phys)
    site = Site(48.8566, 2.3522, 35.0, 90.0).with_network(R, t)
    lat, lon, h = site.net_to_geodetic(net)
    lat0, lon0, h0 = site.frame_to_geodetic(phys)
    assert np.allclose(lat, lat0, atol=1e-12) and np.allclose(h, h0, atol=1e-6)
    assert np.max(np.abs(site.geodetic_to_net(lat, lon, h) - net)) < 1e-6
    # a covariance along network +X is along 1->2 on the ground
    C = np.diag([1.0, 0.0, 0.0])
    E = site.net_cov_to_enu(C)
    d = (phys[1] - phys[0]) / np.linalg.norm(phys[1] - phys[0])
    assert np.allclose(E, np.outer(d, d), atol=1e-12)
    # JSON round trip (recording metadata)
    again = Site.from_json(site.to_json())
    assert np.allclose(again.net_rot, R) and again.origin == site.origin


def test_two_sigma_ellipse_ring():
    site = Site(0.0, 0.0, 0.0)
    cov = np.array([[4.0, 0.0], [0.0, 1.0]])  # sigma 2 m east, 1 m north
    a, b, az = horizontal_ellipse(cov)
    assert (a, b, az) == pytest.approx((4.0, 2.0, 90.0))
    ring = ellipse_ring(site, [0.0, 0.0, 0.0], cov, n=8)
    assert ring.shape == (9, 3) and np.array_equal(ring[0], ring[-1])
    enu = site.frame_to_enu(site.geodetic_to_frame(ring[:, 1], ring[:, 0], ring[:, 2]))
    assert np.allclose((enu[:, 0] / 4.0) ** 2 + (enu[:, 1] / 2.0) ** 2, 1.0, atol=1e-6)
    # counter-clockwise (positive shoelace area)
    x, y = enu[:, 0], enu[:, 1]
    assert 0.5 * np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]) > 0


def test_bad_origin():
    with pytest.raises(ValueError, match="latitude"):
        Site(91.0, 0.0)
