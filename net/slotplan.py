"""Protocol v2 slot capacity (issue 31; docs/protocol.md, "Protocol v2", rule (V8)): does a poll, N
staggered replies and the final fit in one TDMA slot? Pure arithmetic, in ``net`` so the scenario loader
(``net/scenario.py``, ``[tdma] ranging = "poll"``) refuses a plan that cannot fit; ``stations/tdma.py``
re-exports it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from nav.geometry import SPEED_OF_LIGHT_M_S


@dataclass(frozen=True)
class SlotPlan:
    """A protocol v2 slot that fits (offsets from the poll, s): the final's sub-slot, the time the
    slot needs and what is left of it."""

    final_offset_s: float
    needed_s: float
    spare_s: float


def _sig6(x: float, up: bool) -> str:
    """``x`` to 6 significant digits, rounded up or down, so a value quoted as fitting does fit."""
    if x <= 0 or not math.isfinite(x):
        return f"{x:g}"
    unit = 10.0 ** (math.floor(math.log10(x)) - 5)
    return f"{(math.ceil if up else math.floor)(x / unit - (1e-9 if up else -1e-9)) * unit:.6g}"


def _require(ok: bool, key: str, value: float, what: str) -> None:
    if not ok:
        raise ValueError(f"{key}: {value:g} - expected {what}")


def check_slot_plan(slot_s: float, n_responders: int, turnaround_s: float, reply_spacing_s: float,
                    max_range_m: float, frame_s: float, guard_s: float = 0.0) -> SlotPlan:
    """Check that a poll, ``n_responders`` staggered replies and the final fit in one slot, rule (V8).

    With ``tau = max_range_m / c`` (the longest propagation time between two stations that hear
    each other: the field's diameter, or the ``[radio]`` horizon)::

        turnaround_s    >= frame_s                          (reply 0 after the poll's frame)
        reply_spacing_s >= frame_s + 2 tau + 2 guard_s      (no two frames overlap at any receiver,
                                                             the sub-slot windows (V2) are disjoint)
        turnaround_s + N reply_spacing_s + frame_s + tau + guard_s <= slot_s
                                                            (the final, sub-slot N, is heard
                                                             everywhere before the next slot's poll)

    ``frame_s`` is one frame's time on air, ``guard_s`` the margin for slot-timing and clock-rate
    error. Returns the :class:`SlotPlan`; raises ``ValueError`` naming the scenario keys involved
    (``[tdma] slot_s``, ``[channel] turnaround_s``, ``[tdma] reply_spacing_s``, ``[tdma] frame_s``,
    ``[tdma] guard_s``) and what would fit.
    """
    for key, v in (("[tdma] slot_s", slot_s), ("[tdma] reply_spacing_s", reply_spacing_s)):
        _require(math.isfinite(v) and v > 0, key, v, "a number > 0")
    for key, v in (("[channel] turnaround_s", turnaround_s), ("[tdma] frame_s", frame_s),
                   ("[tdma] guard_s", guard_s), ("max_range_m", max_range_m)):
        _require(math.isfinite(v) and v >= 0, key, v, "a number >= 0")
    _require(math.isfinite(n_responders) and float(n_responders).is_integer() and n_responders >= 0, "responders (members but the poller)",
             n_responders, "an integer >= 0")
    n = int(n_responders)
    tol = 1e-12  # a plan that fits exactly is not refused over rounding
    tau = max_range_m / SPEED_OF_LIGHT_M_S
    if turnaround_s < frame_s * (1 - tol):
        raise ValueError(f"[channel] turnaround_s: {turnaround_s:g} s is shorter than one frame "
                         f"([tdma] frame_s {frame_s:g} s): reply 0 would start inside the poll; "
                         f"expected [channel] turnaround_s >= {frame_s:g} s")
    min_spacing = frame_s + 2.0 * tau + 2.0 * guard_s
    if reply_spacing_s < min_spacing * (1 - tol):
        raise ValueError(f"[tdma] reply_spacing_s: {reply_spacing_s:g} s is shorter than one frame plus the "
                         f"round trip at the maximum range plus the guards ([tdma] frame_s {frame_s:g} s + "
                         f"2 x {max_range_m:g} m / c + 2 x [tdma] guard_s {guard_s:g} s = {_sig6(min_spacing, True)} s): "
                         f"replies would overlap; expected [tdma] reply_spacing_s >= {_sig6(min_spacing, True)} s")
    final_offset = turnaround_s + n * reply_spacing_s
    needed = final_offset + frame_s + tau + guard_s
    if needed > slot_s * (1 + tol):
        rest = slot_s - turnaround_s - frame_s - tau - guard_s  # what the N sub-slots may take
        fits = [f"[tdma] slot_s >= {_sig6(needed, True)} s"]
        if n > 0 and rest / n >= min_spacing:
            fits.append(f"[tdma] reply_spacing_s <= {_sig6(rest / n, False)} s")
        fits.append(f"at most {max(0, math.floor(rest / reply_spacing_s + tol))} responders")
        raise ValueError(f"[tdma] slot_s: {slot_s:g} s cannot hold the poll, {n} replies and the final: "
                         f"they need {_sig6(needed, True)} s ([channel] turnaround_s {turnaround_s:g} s + {n} x "
                         f"[tdma] reply_spacing_s {reply_spacing_s:g} s + [tdma] frame_s {frame_s:g} s + "
                         f"{max_range_m:g} m / c + [tdma] guard_s {guard_s:g} s); expected "
                         + ", or ".join(fits))
    return SlotPlan(final_offset_s=final_offset, needed_s=needed, spare_s=slot_s - needed)
