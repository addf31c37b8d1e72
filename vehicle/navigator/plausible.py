"""Plausibility before trust in the vehicle (issue 32 item 1): a station's nav broadcast is checked
against physical bounds (``net/plausible.py``) before the vehicle's channel layer or its filter takes
it in; one outside them is dropped and counted (``implausible_<reason>`` in the core's ``stats``),
never down-weighted. The field's extent is the vehicle's own map: a station it hears lies within
``MARGIN_M`` of the mapped route (the init record's route, in the network frame); the clock bounds
are the loosest oscillator class the stations accept. Pure.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from net.plausible import NavBounds, bounds_for, cov_ok, nav_reason

#: a station the vehicle hears is at most this far beyond the route's extent from the network origin
#: (a radio range; seed000's stations lie within 1.2 km of a route that crosses the field)
MARGIN_M = 5000.0


def route_net_m(record: dict) -> np.ndarray:
    """The route's points (n, 3) in the network frame (``enu = A p_n + b``, ``A`` orthogonal)."""
    A = np.asarray(record["net_to_enu"], float)
    b = np.asarray(record["net_offset_m"], float)
    return (np.asarray(record["route_enu_m"], float) - b) @ A


def bounds_of(record: dict) -> NavBounds:
    """The route's extent from the network origin plus :data:`MARGIN_M` (cached per route)."""
    pts = route_net_m(record)
    far = np.zeros((1, 3))
    far[0, 0] = float(np.max(np.linalg.norm(pts, axis=1))) + MARGIN_M - 1000.0  # (bounds_for adds 1 km)
    return bounds_for(far)


def refuse(msg: dict, t_now_s: float, record: dict, stats: Counter) -> bool:
    """True if the nav is implausible: counted in ``stats`` as ``implausible_<reason>``, to be dropped."""
    why = nav_reason(msg, t_now_s, bounds_of(record))
    if why is None:
        return False
    stats["implausible_" + why] += 1
    return True


def measurement_reason(pos_n, cov_n, clock_var_m2: float, rho_m: float, rate_m_s: float,
                       bound: NavBounds) -> str | None:
    """Why one navigator input (a journal ``m`` entry) is unusable, or None: a finite position within
    the bounds, a PSD bounded covariance, a finite non-negative clock variance, finite range and rate."""
    p = np.asarray(pos_n, float)
    if p.shape != (3,) or not np.all(np.isfinite(p)) or float(np.linalg.norm(p)) > bound.pos_m:
        return "pos"
    if not cov_ok(cov_n, bound.var_m2):
        return "cov"
    if not (np.isfinite(clock_var_m2) and 0.0 <= clock_var_m2 <= (299792458.0 * bound.clock_offset_s) ** 2):
        return "clock"
    if not (np.isfinite(rho_m) and np.isfinite(rate_m_s)):
        return "range"
    return None
