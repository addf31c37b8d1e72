"""The single-run fast path of the map filter (fused RK4 on ``[P | x]``) equals the batched path."""

from __future__ import annotations

import numpy as np
import pytest

from vehicle import sim
from vehicle.navigator.cdekf import MapFilter
from vehicle.route import great_circle_route


@pytest.mark.parametrize("clock", [False, True])
def test_single_run_fast_path_equals_reference(monkeypatch, clock):
    """Same seed, one run, 12 s with radio epochs and a 3 s outage: the fast path and the batched
    reference agree to round-off (including the stiff odometer sub-steps of the first instants)."""
    route = great_circle_route([(47.23, 39.72), (47.40, 39.80)], 100.0, [20.0])
    case = dict(route=route, duration_s=12.0, outage_s=(5.0, 8.0), runs=1, seed=4,
                clock_states=clock, clock_in_measurements=clock)
    res = {}
    for fast in (True, False):
        monkeypatch.setattr(MapFilter, "fast", fast)
        res[fast] = sim.run(sim.Case(**case))
    a, b = res[True], res[False]
    assert np.isfinite(a.err_pos).all()
    for k, tol in (("err_pos", 1e-7), ("err_vel", 1e-10), ("err_att", 1e-12), ("sig_pos", 1e-9),
                   ("sig_vel", 1e-12), ("sig_att", 1e-13)):
        x, y = getattr(a, k), getattr(b, k)
        np.testing.assert_allclose(x, y, rtol=1e-9, atol=tol, err_msg=k)
    np.testing.assert_allclose(a.nees, b.nees, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(a.nis[:, 1:][np.isfinite(b.nis[:, 1:])], b.nis[:, 1:][np.isfinite(b.nis[:, 1:])],
                               rtol=1e-7)
