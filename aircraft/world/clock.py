"""Receiver clock of the aircraft (world side): a two-state random-walk clock in range units.

``b`` (m, ``c dtau``) and ``d = db/dt`` (m/s):  ``db = d dt + w_b``, ``dd = w_d`` with white
frequency noise ``q_b`` (m^2/s) and random-walk frequency noise ``q_d`` (m^2/s^3) (TCXO defaults of
the seed spec sec. 1.4: ``q_b = c^2 h0 / 2``, ``q_d = 2 pi^2 c^2 h_-2``). Sampled exactly at the given
times (the discrete process has covariance ``[[q_b T + q_d T^3/3, q_d T^2/2], [q_d T^2/2, q_d T]]``).

:class:`ReceiverClock`: the deterministic clock of seed 001 (a constant frequency offset), the radio
aircraft's true clock (``[aircraft]`` ``df_hz``, ``lambda_m``, ``tau0_s``; the live node and the Monte Carlo).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nav.geometry import SPEED_OF_LIGHT_M_S

H0 = 2e-19
HM2 = 2e-20


@dataclass(frozen=True)
class ClockModel:
    q_b_m2_s: float = SPEED_OF_LIGHT_M_S**2 * H0 / 2.0
    q_d_m2_s3: float = 2.0 * np.pi**2 * SPEED_OF_LIGHT_M_S**2 * HM2
    b0_sigma_m: float = 100.0
    d0_sigma_m_s: float = 1.0


def clock_noise(model: ClockModel, T: float) -> np.ndarray:
    """Discrete process noise (2, 2) over ``T`` seconds."""
    qb, qd = model.q_b_m2_s, model.q_d_m2_s3
    return np.array([[qb * T + qd * T**3 / 3.0, qd * T**2 / 2.0], [qd * T**2 / 2.0, qd * T]])


def sample(model: ClockModel, t_s: np.ndarray, runs: int, rng: np.random.Generator) -> np.ndarray:
    """Clock states at increasing times ``t_s`` (T,) for ``runs`` runs: (T, runs, 2) ``[b, d]``."""
    t_s = np.asarray(t_s, dtype=float)
    x = np.stack([rng.normal(0.0, model.b0_sigma_m, runs), rng.normal(0.0, model.d0_sigma_m_s, runs)], axis=-1)
    out = np.empty((t_s.size, runs, 2))
    tp = t_s[0]
    for k, t in enumerate(t_s):
        T = t - tp
        if T > 0:
            L = np.linalg.cholesky(clock_noise(model, T))
            x = np.column_stack([x[:, 0] + x[:, 1] * T, x[:, 1]]) + rng.standard_normal((runs, 2)) @ L.T
        out[k] = x
        tp = t
    return out


@dataclass(frozen=True)
class ReceiverClock:
    """Receiver clock model of seed 001: ``dtau(t) = df * lambda * t / c + tau0``.

    ``df_hz`` carrier frequency offset, ``lambda_m`` carrier wavelength, ``tau0_s`` initial offset.
    The paper's values ``df = 20 Hz``, ``lambda = 0.03 m``, ``tau0 = 0`` give 0.6 m/s of range drift.
    """

    df_hz: float = 20.0
    lambda_m: float = 0.03
    tau0_s: float = 0.0

    @property
    def drift_m_s(self) -> float:
        return self.df_hz * self.lambda_m

    def bias_m(self, t_s: np.ndarray | float) -> np.ndarray:
        """Clock offset in range units ``c * dtau(t)``; same shape as ``t_s``."""
        return self.drift_m_s * np.asarray(t_s, dtype=float) + SPEED_OF_LIGHT_M_S * self.tau0_s
