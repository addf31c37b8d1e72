"""A LARNS field for the vehicle: the scenario's stations placed on the Earth and a straight route
through the field (spec Sec. 5.3: satellites replaced by stations, great circle by a straight
segment at constant height).

The stations' network frame is tied to the local level (ENU at ``origin_deg``) by the map: the map of
the field gives the route in the network frame together with the frame's rotation to ENU, as the
survey that made the map measured it (its error is not modelled here).
"""

from __future__ import annotations

import numpy as np

from nav.geometry import to_network_frame
from nav.orbits import enu_to_ecef, greenwich_from_ecef
from vehicle.route import Route, straight_route

DEFAULT_ORIGIN = (47.23, 39.72, 0.0)  # the field near Rostov-on-Don, like seed 004's route


def field_layout(scenario="seed000"):
    """Physical (local-level) station positions (n, 3) and the network frame ``(pos_net, R, t)``;
    ``scenario`` a name / TOML path or a loaded :class:`net.scenario.Scenario`."""
    from net.scenario import load, order_for_frame, random_layout

    sc = load(scenario) if isinstance(scenario, str) else scenario
    lay = sc.raw.get("layout", {})
    if "stations" in sc.raw:
        phys = np.array([[float(v) for v in s["pos_m"]] for s in sc.raw["stations"]])
    else:  # the same draw as net.scenario.from_dict
        rng = np.random.default_rng(sc.seed)
        phys = random_layout(rng, int(lay.get("n", 10)), tuple(lay.get("area_m", (2000.0, 2000.0, 80.0))),
                             float(lay.get("min_separation_m", 100.0)))
        phys = phys[order_for_frame(phys)]
    zi = sc.ids.index(sc.z_ref) if sc.z_ref in sc.ids else 3
    pos, R, t = to_network_frame(phys, z_ref=zi)
    return sc, phys, pos, R, t


def field_route(phys: np.ndarray, R: np.ndarray, t: np.ndarray, speed_m_s: float = 5.0, height_m: float = 20.0,
                before_m: float = 1500.0, after_m: float = 1500.0, origin_deg=DEFAULT_ORIGIN) -> tuple[Route, np.ndarray]:
    """A level straight route west -> east through the middle of the field, given in the network frame.

    Returns the route and the route's map points in the network frame (2, 3).
    """
    lo, hi = phys.min(axis=0), phys.max(axis=0)
    y = 0.5 * (lo[1] + hi[1])
    enu = np.array([[lo[0] - before_m, y, height_m], [hi[0] + after_m, y, height_m]])
    pts_net = (enu - t) @ R.T
    # network frame -> ENU: enu = pts_net @ R + t (rotation R^T, offset t)
    route = straight_route(pts_net @ R + t, origin_deg, None, [speed_m_s], name="larns-field")
    return route, pts_net


def stations_greenwich(phys: np.ndarray, origin_deg=DEFAULT_ORIGIN) -> np.ndarray:
    """Station positions (n, 3) in the Greenwich frame."""
    lat, lon, h = origin_deg
    return greenwich_from_ecef(enu_to_ecef(phys, lat, lon, h))
