"""stations/tdma.py check_slot_plan: poll + N replies + final fit in one slot (protocol v2, issue 31,
rule (V8) of docs/protocol.md), or the plan is refused with the scenario keys named."""

from __future__ import annotations

import re

import pytest

from nav.geometry import SPEED_OF_LIGHT_M_S as C
from stations.tdma import SlotPlan, check_slot_plan

OK = dict(slot_s=0.01, n_responders=9, turnaround_s=1e-3, reply_spacing_s=500e-6, max_range_m=3000.0, frame_s=200e-6)


def test_a_plan_that_fits_passes_with_its_numbers():
    plan = check_slot_plan(**OK)
    assert isinstance(plan, SlotPlan)
    assert plan.final_offset_s == pytest.approx(1e-3 + 9 * 500e-6)
    assert plan.needed_s == pytest.approx(plan.final_offset_s + 200e-6 + 3000.0 / C)
    assert plan.spare_s == pytest.approx(0.01 - plan.needed_s) and plan.spare_s > 0


def test_a_plan_that_fits_exactly_passes():
    needed = 1e-3 + 9 * 500e-6 + 200e-6 + 3000.0 / C + 1e-6
    assert check_slot_plan(**{**OK, "slot_s": needed, "guard_s": 1e-6}).spare_s == pytest.approx(0.0, abs=1e-15)


def test_too_many_replies_for_the_slot_is_refused_naming_the_keys_and_what_fits():
    with pytest.raises(ValueError) as e:
        check_slot_plan(**{**OK, "n_responders": 29})
    msg = str(e.value)
    assert msg.startswith("[tdma] slot_s:")
    assert "[tdma] reply_spacing_s" in msg and "[channel] turnaround_s" in msg
    need = 1e-3 + 29 * 500e-6 + 200e-6 + 3000.0 / C
    spacing = (0.01 - 1e-3 - 200e-6 - 3000.0 / C) / 29
    slot_fit = float(re.search(r"\[tdma\] slot_s >= ([0-9.e-]+) s", msg).group(1))
    spacing_fit = float(re.search(r"\[tdma\] reply_spacing_s <= ([0-9.e-]+) s", msg).group(1))
    assert slot_fit == pytest.approx(need, rel=1e-5) and slot_fit >= need
    assert spacing_fit == pytest.approx(spacing, rel=1e-5) and spacing_fit <= spacing
    assert "at most 17 responders" in msg
    # each alternative the message names does fit, as quoted (rounded the safe way)
    check_slot_plan(**{**OK, "n_responders": 29, "slot_s": slot_fit})
    check_slot_plan(**{**OK, "n_responders": 29, "reply_spacing_s": spacing_fit})
    check_slot_plan(**{**OK, "n_responders": 17})
    with pytest.raises(ValueError):
        check_slot_plan(**{**OK, "n_responders": 18})


def test_a_reply_spacing_shorter_than_a_frame_plus_the_round_trip_is_refused():
    min_spacing = 200e-6 + 2 * 3000.0 / C + 2 * 1e-6
    with pytest.raises(ValueError, match=r"^\[tdma\] reply_spacing_s: .*expected \[tdma\] reply_spacing_s >= "):
        check_slot_plan(**{**OK, "reply_spacing_s": min_spacing - 1e-9, "guard_s": 1e-6})
    check_slot_plan(**{**OK, "reply_spacing_s": min_spacing, "guard_s": 1e-6})
    # the maximum range alone can break it: a 30 km radio horizon needs 200 us of round trip
    with pytest.raises(ValueError, match=r"\[tdma\] reply_spacing_s"):
        check_slot_plan(**{**OK, "max_range_m": 30e3, "frame_s": 0.0, "reply_spacing_s": 150e-6})


def test_a_turnaround_shorter_than_the_poll_frame_is_refused():
    with pytest.raises(ValueError, match=r"^\[channel\] turnaround_s: .*expected \[channel\] turnaround_s >= 0.0002 s"):
        check_slot_plan(**{**OK, "turnaround_s": 100e-6})


@pytest.mark.parametrize("key, name, bad", [
    ("slot_s", "[tdma] slot_s", 0.0), ("reply_spacing_s", "[tdma] reply_spacing_s", -1.0),
    ("turnaround_s", "[channel] turnaround_s", float("nan")), ("frame_s", "[tdma] frame_s", -1e-6),
    ("max_range_m", "max_range_m", float("inf")), ("n_responders", "responders", 2.5),
    ("n_responders", "responders", -1), ("n_responders", "responders", float("nan")),
])
def test_malformed_numbers_are_refused_by_key(key, name, bad):
    with pytest.raises(ValueError, match=r"^" + name.replace("[", r"\[").replace("]", r"\]")):
        check_slot_plan(**{**OK, key: bad})


def test_no_responders_is_a_poll_and_a_final():
    plan = check_slot_plan(**{**OK, "n_responders": 0})
    assert plan.final_offset_s == pytest.approx(1e-3)


def test_the_running_default_plan_holds_a_ten_station_field():
    """Today's 10 ms slot with its 1 ms turnaround holds a 10-station v2 exchange at modest spacing."""
    check_slot_plan(slot_s=0.01, n_responders=9, turnaround_s=1e-3, reply_spacing_s=300e-6,
                    max_range_m=26e3, frame_s=100e-6, guard_s=1e-6)
