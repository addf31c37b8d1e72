"""The single-run fast path of the map filter (fused RK4 on ``[P | x]``) equals the batched path."""

from __future__ import annotations

import numpy as np
import pytest

from vehicle import sim
from vehicle.navigator.cdekf import MapFilter
from vehicle.route import great_circle_route


@pytest.mark.parametrize("clock", [False, True])
def test_single_run_fast_path_equals_reference(monkeypatch, clock):
    """Same seed, one run, 6 s with radio epochs and a 2 s outage: the fast path and the batched
    reference agree to round-off (including the stiff odometer sub-steps of the first instants)."""
    route = great_circle_route([(47.23, 39.72), (47.40, 39.80)], 100.0, [20.0])
    case = dict(route=route, duration_s=6.0, outage_s=(2.0, 4.0), runs=1, seed=4,
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


_KERNEL_RUN = """
import sys, numpy as np
from vehicle import sim
from vehicle.navigator import fused
from vehicle.route import great_circle_route
assert fused.COMPILED == (sys.argv[1] == "on"), fused.COMPILED
route = great_circle_route([(47.23, 39.72), (47.40, 39.80)], 100.0, [20.0])
for clock in (False, True):
    r = sim.run(sim.Case(route=route, duration_s=6.0, outage_s=(2.0, 4.0), runs=1, seed=4,
                         clock_states=clock, clock_in_measurements=clock))
    np.save(sys.argv[2] + f"_{clock}.npy", np.stack([r.err_pos, r.sig_pos, r.err_att, r.sig_att]))
"""


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_compiled_kernel_equals_numpy_kernel(tmp_path):
    """The fused RK4 kernel compiled by numba (the bench's path) gives the NumPy kernel's numbers to
    round-off (bit for bit on this machine), with and without clock states."""
    import os
    import subprocess
    import sys

    pytest.importorskip("numba")
    out = {}
    for jit in ("on", "off"):
        env = {**os.environ, "LARNS_JIT": jit}
        p = subprocess.run([sys.executable, "-c", _KERNEL_RUN, jit, str(tmp_path / jit)], env=env,
                           capture_output=True, text=True, timeout=240)
        assert p.returncode == 0, p.stderr[-2000:]
    for clock in (False, True):
        a, b = (np.load(tmp_path / f"{j}_{clock}.npy") for j in ("on", "off"))
        assert np.isfinite(a).all()
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-10)


def test_station_consider_with_zero_covariance_equals_plain_update():
    """Schmidt consider block with a zero broadcast covariance changes nothing (same x, P to round-off);
    with the real covariance the cross-covariance is carried and the position variance grows."""
    from vehicle import field

    _, phys, _, R, t = field.field_layout("seed000")
    froute, _ = field.field_route(phys, R, t, speed_m_s=10.0)
    base = dict(route=froute, duration_s=2.0, outage_s=None, runs=2, radio="stations",
                stations_g=field.stations_greenwich(phys), sigma_rho_m=0.5, sigma_rate_m_s=0.15,
                clock_states=True, clock_in_measurements=True, seed=3)
    a = sim.run(sim.Case(**base, station_sigma_m=0.0, station_consider=True))
    b = sim.run(sim.Case(**base, station_sigma_m=0.0, station_consider=False))
    np.testing.assert_allclose(a.err_pos, b.err_pos, atol=1e-9)
    np.testing.assert_allclose(a.sig_pos, b.sig_pos, rtol=1e-9)
    c = sim.run(sim.Case(**base, station_sigma_m=0.2, station_consider=True))
    assert np.all(np.linalg.norm(c.sig_pos[:, -1], axis=-1) > 1.1 * np.linalg.norm(a.sig_pos[:, -1], axis=-1))


def test_free_filter_forward_odometer_function_and_jacobian():
    """The free model's odometer ``k (D e_1)^T (v_I - w_e x p_I)`` equals the truth's forward speed and
    its Jacobian (``P H^T`` with ``P = I``) equals central differences."""
    from vehicle.navigator.cdekf import FreeFilter, Intensities
    from vehicle.world import truth as wt

    route = great_circle_route([(47.23, 39.72), (47.40, 39.80)], 100.0, [20.0])
    tr = wt.sample(route, wt.speed_plan(route), np.array([0.0, 7.3]))
    case = sim.Case(route=route, runs=1, filter="free")
    x = sim.true_state(case, tr, 1)
    f = FreeFilter(x[None], np.eye(15)[None], Intensities(0.0, 0.0, 1.0), k_odo=1.0)
    I = np.eye(15)[None]
    H, _, innov = f._odo_forward(x[None], I, np.zeros(1))
    assert -innov[0] == pytest.approx(tr.speed[1], rel=1e-9)

    def h(y):
        return -f._odo_forward(y[None], I, np.zeros(1))[2][0]

    eps = np.r_[np.full(9, 1e-6), np.full(6, 1e-3)]
    Hn = np.array([(h(x + e) - h(x - e)) / (2 * e[i]) for i, e in enumerate(np.diag(eps))])
    np.testing.assert_allclose(H[0], Hn, rtol=1e-6, atol=1e-8)
