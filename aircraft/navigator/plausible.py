"""Plausibility before trust in the aircraft's navigators: a station's nav
broadcast is checked against the field's physical bounds (``net/plausible.py``: position within
the field's extent plus a margin, a positive semi-definite covariance, the clock correction within
the oscillator class, the transmit time near the reception) before the channel layer or any filter
takes it in. One outside its bounds is dropped and counted (``implausible_<reason>`` in the core's
``stats``, shown in ``ac_status``), never down-weighted; the filters' integrity (``aircraft/navigator/radio/fde.py``)
then judges what passes. Pure: the radio (``RadioAircraftCore``), inertial and triad cores call
:func:`unusable` (a station's state, then :func:`refuse`) first thing in their ``on_nav``.
"""

from __future__ import annotations

from collections import Counter

from net.plausible import NavBounds, bounds_for, nav_reason

__all__ = ["NavBounds", "USABLE_STATES", "bounds_of", "nav_reason", "refuse", "unusable"]

USABLE_STATES = ("frame", "surveying")  # a station's states whose broadcasts a receiver navigates on


def bounds_of(ac, clock=None) -> NavBounds:
    """The bounds of the aircraft's field: its scenario's stations (``ac.stations_m``, network frame)
    and, when given, the stations' oscillator class ``clock`` (``scn.clock``; without it the loosest
    class the stations accept)."""
    if clock is None:
        return bounds_for(ac.stations_m)
    return bounds_for(ac.stations_m, clock.offset_s, clock.freq_sigma)


def refuse(msg: dict, t_now_s: float, ac, stats: Counter, clock=None) -> bool:
    """True if the nav is implausible: counted in ``stats`` as ``implausible_<reason>``, to be dropped."""
    why = nav_reason(msg, t_now_s, bounds_of(ac, clock))
    if why is None:
        return False
    stats["implausible_" + why] += 1
    return True


def unusable(msg: dict, t_now_s: float, ac, stats: Counter) -> bool:
    """True if a nav is not one to navigate on: its station not in a :data:`USABLE_STATES` state
    (counted ``nav_unusable_state``) or the nav implausible (:func:`refuse`)."""
    if msg.get("state") not in USABLE_STATES:
        stats["nav_unusable_state"] += 1
        return True
    return refuse(msg, t_now_s, ac, stats)
