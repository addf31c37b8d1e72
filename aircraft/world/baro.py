"""Barometric altimeter (world side): altitude plus a Gauss-Markov bias plus white noise.

``h_baro = h_true + b + n`` with ``b`` a first-order Gauss-Markov process (stationary ``sigma_bias_m``,
correlation time ``tc_s``: the slowly changing difference between the pressure altitude and the
geometric one) and ``n ~ N(0, sigma_m^2)`` per sample. Defaults from the seed spec sec. 1.8:
sigma 10 m at 1 Hz, bias 20 m with 600 s. Sampled exactly at the given times.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class BaroModel:
    sigma_m: float = 10.0
    sigma_bias_m: float = 20.0
    tc_s: float = 600.0


def sample(model: BaroModel, h_true_m: np.ndarray, t_s: np.ndarray, runs: int,
           rng: np.random.Generator) -> np.ndarray:
    """Baro readings (T, runs) at increasing times ``t_s`` (T,) of the true altitudes ``h_true_m`` (T,)."""
    t_s = np.asarray(t_s, dtype=float)
    b = rng.normal(0.0, model.sigma_bias_m, runs)
    out = np.empty((t_s.size, runs))
    tp = t_s[0]
    for k, t in enumerate(t_s):
        a = np.exp(-(t - tp) / model.tc_s)
        b = a * b + model.sigma_bias_m * np.sqrt(1.0 - a * a) * rng.standard_normal(runs)
        out[k] = h_true_m[k] + b + model.sigma_m * rng.standard_normal(runs)
        tp = t
    return out
