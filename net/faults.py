"""Wire faults (network, not air): extra delivery delay, jitter, loss and duplication.

Pure and seeded: the model takes an explicit ``numpy.random.Generator`` and returns the delivery
delays of the copies of one message; the Zenoh node applies them (holding a message back by the
delay, delivering duplicates). A range reply that the wire delays past the end of its slot is then
dropped by the node as late: a lost measurement, exactly as a late reply on air.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scenario import NetFaults


@dataclass
class WireFaults:
    """Per-receiver wire-fault model.

    ``deliveries()`` -> list of delays in seconds (fleet time) of the copies to deliver:
    ``[]`` lost, ``[d]`` normal, ``[d1, d2]`` duplicated. Each delay is
    ``max(0, delay_s + N(0, jitter_s^2))``.
    """

    params: NetFaults
    rng: np.random.Generator

    @property
    def active(self) -> bool:
        p = self.params
        return bool(p.delay_s > 0 or p.jitter_s > 0 or p.loss_prob > 0 or p.dup_prob > 0)

    def _delay(self) -> float:
        p = self.params
        d = p.delay_s
        if p.jitter_s > 0:
            d += float(self.rng.normal(0.0, p.jitter_s))
        return max(0.0, float(d))

    def deliveries(self) -> list[float]:
        p = self.params
        if not self.active:
            return [0.0]
        if p.loss_prob > 0 and self.rng.random() < p.loss_prob:
            return []
        out = [self._delay()]
        if p.dup_prob > 0 and self.rng.random() < p.dup_prob:
            out.append(self._delay())
        return out


def merge_faults(base: NetFaults, delay_s: float | None = None, jitter_s: float | None = None,
                 loss_prob: float | None = None, dup_prob: float | None = None) -> NetFaults:
    """The scenario's faults with command-line overrides (None keeps the scenario value)."""
    def pick(v, d):
        return d if v is None else float(v)
    out = NetFaults(pick(delay_s, base.delay_s), pick(jitter_s, base.jitter_s),
                    pick(loss_prob, base.loss_prob), pick(dup_prob, base.dup_prob))
    if out.delay_s < 0 or out.jitter_s < 0 or not (0 <= out.loss_prob <= 1) or not (0 <= out.dup_prob <= 1):
        raise ValueError(f"invalid network faults {out}")
    return out
