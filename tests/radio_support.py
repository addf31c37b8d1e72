"""Shared by the radio navigator's tests in tests/aircraft/ (test_radio_models.py, test_radio_lsq.py,
test_radio_tracker.py, test_radio_pcrb.py, test_radio_initializer.py): the station positions of
seed001 and seed003 and a central-difference Jacobian."""

from __future__ import annotations

import numpy as np

from net.scenario import load

S001 = load("seed001").pos_m
S003 = load("seed003").pos_m


def fd_jac(f, x, eps=1e-5):
    cols = []
    for i in range(x.shape[-1]):
        d = np.zeros_like(x)
        d[..., i] = eps
        cols.append((f(x + d) - f(x - d)) / (2 * eps))
    return np.stack(cols, axis=-1)
