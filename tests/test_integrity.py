"""Issue 14: NLOS-robust survey, scenario faults, station-side integrity."""

from __future__ import annotations

import numpy as np
import pytest

from net.scenario import load
from stations.estimators import DistributedMap
from stations.sim import Simulator


def _solve_case(robust, outlier_m: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    truth = np.array([300.0, 400.0, 20.0])
    peers = {2: [1000.0, 0, 0], 3: [200.0, 900.0, 0], 4: [700.0, 800.0, 60.0], 5: [-300.0, 600.0, 30.0],
             6: [900.0, 500.0, -20.0], 7: [-100.0, -200.0, 10.0]}
    est = DistributedMap(8, truth + rng.normal(0, 3.0, 3), np.eye(3) * 9.0, 0.5, robust=robust)
    for pid, p in peers.items():
        p = np.asarray(p)
        est.on_peer(pid, p, np.eye(3) * 0.01)
        for _ in range(6):
            est.on_range(pid, np.linalg.norm(truth - p) + rng.normal(0, 0.5), 0.0, True, None, None)
        est.refresh()
    est.on_range(4, np.linalg.norm(truth - np.asarray(peers[4])) + outlier_m, 0.0, True, None, None)
    for _ in range(3):
        est._dirty = True
        est.refresh()
    return est, truth


def test_single_outlier_range_is_down_weighted():
    rob, truth = _solve_case("tukey", 25.0)
    pla, _ = _solve_case(None, 25.0)
    ranges, w = rob.link_ranges(4)
    assert len(ranges) == 7 and w[-1] == 0.0 and np.all(w[:-1] > 0.5)
    e_rob = np.linalg.norm((rob.pos_m - truth)[:2])
    e_pla = np.linalg.norm((pla.pos_m - truth)[:2])
    clean, _ = _solve_case("tukey", 0.0)
    assert e_rob < 0.5 and e_pla > 2 * e_rob
    assert np.linalg.norm((rob.pos_m - clean.pos_m)[:2]) < 0.05  # the outlier changed (almost) nothing


def test_robust_equals_plain_on_clean_data():
    """Seeded: on clean ranges the robust dmap's estimates match plain dmap-ls within a fraction of sigma_d."""
    d_h, e_rob, e_pla = [], [], []
    for seed in (3, 4):
        scn = load("seed000", seed=seed)
        out = {}
        for est in ("dmap", "dmap-ls"):
            r = Simulator(scn, estimator=est).run(30.0, [30.0])
            out[est] = r.pos_m[0, 3:] - r.truth_m[3:]
        d_h.append(np.hypot(*(out["dmap"] - out["dmap-ls"])[:, :2].T))
        e_rob.append(np.hypot(*out["dmap"][:, :2].T))
        e_pla.append(np.hypot(*out["dmap-ls"][:, :2].T))
    d_h = np.concatenate(d_h)
    assert np.sqrt((d_h**2).mean()) < 0.1  # sigma_d = 0.5 m
    rms = lambda e: np.sqrt((np.concatenate(e) ** 2).mean())
    assert rms(e_rob) < 1.2 * rms(e_pla)
