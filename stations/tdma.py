"""TDMA plan: cycles of equal slots from a common epoch (t = 0 in fleet time).

Each station computes slot boundaries itself from its own clock; there is no clock master.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

# protocol v2 slot capacity (issue 31): the scenario loader checks it, so it lives in net
from net.slotplan import SlotPlan, check_slot_plan  # noqa: F401  (re-exported)


@dataclass(frozen=True)
class TdmaPlan:
    cycle_s: float = 1.0
    slot_s: float = 0.01

    @property
    def slots_per_cycle(self) -> int:
        return int(round(self.cycle_s / self.slot_s))

    def slot_start_s(self, cycle: int, slot: int) -> float:
        return cycle * self.cycle_s + slot * self.slot_s

    def locate(self, t_s: float) -> tuple[int, int]:
        """(cycle, slot) containing time ``t_s``."""
        cycle = math.floor(t_s / self.cycle_s + 1e-12)
        slot = int((t_s - cycle * self.cycle_s) / self.slot_s + 1e-9)
        return cycle, min(slot, self.slots_per_cycle - 1)

    def next_slot_start(self, slot: int, after_s: float) -> tuple[int, float]:
        """First start of ``slot`` strictly after ``after_s``: (cycle, t_s)."""
        cycle = math.floor((after_s - slot * self.slot_s) / self.cycle_s) + 1
        cycle = max(cycle, 0)
        t = self.slot_start_s(cycle, slot)
        while t <= after_s:
            cycle += 1
            t = self.slot_start_s(cycle, slot)
        prev = cycle - 1
        if prev >= 0 and self.slot_start_s(prev, slot) > after_s:
            return prev, self.slot_start_s(prev, slot)
        return cycle, t

    def default_slot(self, station_id: int) -> int:
        return (station_id - 1) % self.slots_per_cycle
