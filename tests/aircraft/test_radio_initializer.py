"""aircraft/navigator/radio/initializer.py: the start reads broadcasts only (no world module imported,
its inputs are the broadcasts), and starts from a snapshot where the geometry allows one and from a
wide prior where not, the truth within 5 sigma of either."""

from __future__ import annotations

import numpy as np
import pytest

from aircraft.navigator.radio.tuning import Tuning
from radio_support import S001, S003


def test_initializer_never_reads_the_world():
    """Import boundary: the initializer (and the estimators it uses) load without the world side
    (trajectory, simulator, scenarios, nodes); its inputs are broadcasts only."""
    import subprocess
    import sys

    code = ("import sys, aircraft.navigator.radio.initializer; bad = [m for m in sys.modules if m.startswith(("
            "'aircraft.world', 'aircraft.montecarlo', 'aircraft.node', 'aircraft.core', 'aircraft.radio_core', "
            "'aircraft.config', 'net.scenario'))]; "
            "print(bad); sys.exit(1 if bad else 0)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    import inspect

    from aircraft.navigator.radio import initializer

    params = set(inspect.signature(initializer.initial_state).parameters)
    assert params == {"model", "tuning", "pos_m", "cov_m2", "rho_m", "config"}


def test_initializer_snapshot_where_geometry_allows_wide_prior_where_not():
    from aircraft.navigator.radio.initializer import InitConfig, initial_state

    rng = np.random.default_rng(8)
    for stations, p, snap in ((S001, np.array([60.0, 20.0, 40.0]), True),
                              (S001, np.array([2000.0, 300.0, 50.0]), False),
                              (S003, np.array([12000.0, 9000.0, 1000.0]), True)):
        ac_tu = Tuning(sigma_m=0.5)
        rho = np.linalg.norm(p - stations, axis=1) + 17.0 + 0.5 * rng.standard_normal(len(stations))
        for model in ("pr", "tdoa"):
            r = initial_state(model, ac_tu, stations, None, rho)
            assert r.snapshot == snap, (model, p, r.fix_sigma_m)
            e = r.x0[:3] - p
            C = r.P0[:3, :3]
            assert e @ np.linalg.solve(C, e) < 25.0, (model, p, e, r.fix_sigma_m)  # within 5 sigma
            if not snap:
                assert np.sqrt(np.trace(C)) >= np.sqrt(3) * InitConfig().wide_sigma_m - 1e-6
            if model == "pr":
                assert r.x0.size == 8 and r.P0[7, 7] == pytest.approx(ac_tu.p0.drift_m_s**2)
