"""stations/tdma.py: slot arithmetic every station does on its own clock (no clock master)."""

from __future__ import annotations

import numpy as np
import pytest

from stations.tdma import TdmaPlan

PLAN = TdmaPlan(cycle_s=1.0, slot_s=0.01)


def test_slots_per_cycle_and_default_slot():
    assert PLAN.slots_per_cycle == 100
    assert TdmaPlan(0.5, 0.01).slots_per_cycle == 50
    assert [PLAN.default_slot(i) for i in (1, 2, 100, 101, 250)] == [0, 1, 99, 0, 49]


def test_slot_start():
    assert PLAN.slot_start_s(0, 0) == 0.0
    assert PLAN.slot_start_s(3, 7) == pytest.approx(3.07)


@pytest.mark.parametrize("cycle, slot", [(0, 0), (0, 99), (5, 42), (1234, 1), (86399, 99)])
def test_locate_inverts_slot_start_inside_the_slot(cycle, slot):
    t0 = PLAN.slot_start_s(cycle, slot)
    for frac in (0.0, 0.3, 0.999):
        assert PLAN.locate(t0 + frac * PLAN.slot_s) == (cycle, slot)


def test_locate_never_returns_a_slot_past_the_cycle():
    # float rounding just below a cycle boundary must not yield slot 100 of a 100-slot cycle
    c, s = PLAN.locate(np.nextafter(1.0, 0.0))
    assert (c, s) in ((0, 99), (1, 0))
    assert 0 <= s < PLAN.slots_per_cycle


def test_next_slot_start_is_strictly_after_and_the_first_one():
    rng = np.random.default_rng(5)
    for after in rng.uniform(-2.0, 500.0, 300):
        slot = int(rng.integers(0, 100))
        cycle, t = PLAN.next_slot_start(slot, after)
        assert t > after
        assert t == PLAN.slot_start_s(cycle, slot)
        assert cycle >= 0
        # the one before it is not after ``after`` (it is the first), unless it would be negative
        if cycle > 0:
            assert PLAN.slot_start_s(cycle - 1, slot) <= after


def test_next_slot_start_exactly_at_a_slot_start_goes_to_the_next_cycle():
    assert PLAN.next_slot_start(7, PLAN.slot_start_s(4, 7)) == (5, PLAN.slot_start_s(5, 7))
    assert PLAN.next_slot_start(0, -5.0) == (0, 0.0)  # before the epoch: the first cycle
