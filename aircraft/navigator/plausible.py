"""Plausibility before trust in the aircraft's navigators: a station's nav broadcast is checked
against the field's physical bounds (``net/plausible.py``: position within the planned deployment
area plus a margin, a positive semi-definite covariance, the clock correction within the oscillator
class, the transmit time near the reception) before the channel layer or any filter takes it in.
The bounds are the navigator configuration's ``field_bounds`` (``aircraft/config.py``): the
operator's deployment plan, a radius and time windows, never a station position. One outside its
bounds is dropped and counted (``implausible_<reason>`` in the core's ``stats``, shown in
``ac_status``), never down-weighted; the filters' integrity (``aircraft/navigator/radio/fde.py``)
then judges what passes. Pure: the radio (``RadioAircraftCore``), inertial and triad cores call
:func:`unusable` (a station's state, then :func:`refuse`) first thing in their ``on_nav``.
"""

from __future__ import annotations

from collections import Counter

from net.plausible import NavBounds, nav_reason

__all__ = ["NavBounds", "USABLE_STATES", "nav_reason", "refuse", "unusable"]

USABLE_STATES = ("frame", "surveying")  # a station's states whose broadcasts a receiver navigates on


def refuse(msg: dict, t_now_s: float, bounds: NavBounds, stats: Counter) -> bool:
    """True if the nav is implausible against the field's ``bounds`` (the navigator configuration's
    ``field_bounds``: the deployment plan, ``aircraft/config.py``): counted in ``stats`` as
    ``implausible_<reason>``, to be dropped."""
    why = nav_reason(msg, t_now_s, bounds)
    if why is None:
        return False
    stats["implausible_" + why] += 1
    return True


def unusable(msg: dict, t_now_s: float, bounds: NavBounds, stats: Counter) -> bool:
    """True if a nav is not one to navigate on: its station not in a :data:`USABLE_STATES` state
    (counted ``nav_unusable_state``) or the nav implausible against ``bounds`` (:func:`refuse`)."""
    if msg.get("state") not in USABLE_STATES:
        stats["nav_unusable_state"] += 1
        return True
    return refuse(msg, t_now_s, bounds, stats)
