"""Wire-fault model: seeded, honest rates (binomial tolerances), delays never negative."""

from __future__ import annotations

import numpy as np
import pytest

from net.faults import WireFaults, merge_faults
from net.scenario import NetFaults


def test_inactive_is_identity():
    wf = WireFaults(NetFaults(), np.random.default_rng(0))
    assert not wf.active and wf.deliveries() == [0.0]


def test_rates_and_delays():
    n = 20000
    wf = WireFaults(NetFaults(delay_s=0.002, jitter_s=0.001, loss_prob=0.1, dup_prob=0.05),
                    np.random.default_rng(1))
    outs = [wf.deliveries() for _ in range(n)]
    lost = sum(1 for o in outs if not o)
    dup = sum(1 for o in outs if len(o) == 2)
    # 4-sigma binomial bands
    assert abs(lost - 0.1 * n) < 4 * np.sqrt(n * 0.1 * 0.9)
    kept = n - lost
    assert abs(dup - 0.05 * kept) < 4 * np.sqrt(kept * 0.05 * 0.95)
    d = np.array([x for o in outs for x in o])
    assert d.min() >= 0.0
    assert d.mean() == pytest.approx(0.002, abs=1e-4)
    assert d.std() == pytest.approx(0.001, rel=0.1)


def test_seeded_reproducible():
    p = NetFaults(delay_s=0.001, jitter_s=0.001, loss_prob=0.2, dup_prob=0.2)
    a = [WireFaults(p, np.random.default_rng(5)).deliveries() for _ in range(1)]
    w1, w2 = WireFaults(p, np.random.default_rng(5)), WireFaults(p, np.random.default_rng(5))
    assert [w1.deliveries() for _ in range(100)] == [w2.deliveries() for _ in range(100)]
    assert a


def test_merge_overrides_and_validation():
    base = NetFaults(delay_s=0.01, loss_prob=0.1)
    m = merge_faults(base, jitter_s=0.002)
    assert m == NetFaults(delay_s=0.01, jitter_s=0.002, loss_prob=0.1, dup_prob=0.0)
    with pytest.raises(ValueError):
        merge_faults(base, loss_prob=1.5)
