"""IMU emulator (world side): gyro and accelerometer triads producing delta-angle / delta-velocity
increments at the IMU rate, with the usual error budget, seeded per aircraft.

Per axis and run (increment over ``dt``, true increments ``dth``/``dv`` from :mod:`aircraft.world.motion`):

* white noise: angle random walk ``arw`` (rad/sqrt(s)) and velocity random walk ``vrw``
  (m/s/sqrt(s)): ``N(0, arw^2 dt)`` per increment;
* bias instability: a first-order Gauss-Markov bias with correlation time ``tc`` whose Allan-deviation
  peak equals the datasheet's in-run bias stability ``bi`` (``sigma_gm = bi / GM_ADEV_PEAK``);
* turn-on bias: a random constant per run (``turn_on``);
* scale factor: a random constant per run (``sf``, dimensionless).

``measured = (1 + sf) true + (turn_on + b_gm) dt + white``.

Presets (docs/ins.md cites the sources): ``adis16480`` (Analog Devices ADIS16480 datasheet figures:
gyro in-run bias stability 6.25 deg/h, ARW 0.3 deg/sqrt(h); accelerometer in-run bias stability
0.1 mg, VRW 0.029 m/s/sqrt(h)); ``tactical`` (1 deg/h, 0.05 deg/sqrt(h), 50 ug, 0.01 m/s/sqrt(h)) and
``navigation`` (0.01 deg/h, 0.002 deg/sqrt(h), 10 ug, 0.002 m/s/sqrt(h)) grades.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.signal import lfilter

DEG = np.pi / 180.0
HOUR = 3600.0
MG = 9.80665e-3


def gm_allan_var(tau_s: np.ndarray, sigma: float, tc_s: float) -> np.ndarray:
    """Allan variance of a first-order Gauss-Markov process (variance ``sigma^2``, time constant ``tc``)."""
    x = np.asarray(tau_s, dtype=float) / tc_s
    return sigma**2 / x**2 * (2.0 * x - 3.0 + 4.0 * np.exp(-x) - np.exp(-2.0 * x))


def _peak() -> float:
    x = np.logspace(-2, 3, 20001)
    return float(np.sqrt(gm_allan_var(x, 1.0, 1.0).max()))


GM_ADEV_PEAK = _peak()  # max Allan deviation of a unit GM process (~0.62)


@dataclass(frozen=True)
class ImuPreset:
    name: str
    rate_hz: float
    arw_rad_sqrt_s: float
    vrw_m_s_sqrt_s: float
    gyro_bi_rad_s: float  # in-run bias stability (Allan floor)
    accel_bi_m_s2: float
    gyro_tc_s: float
    accel_tc_s: float
    gyro_turn_on_rad_s: float
    accel_turn_on_m_s2: float
    gyro_sf: float
    accel_sf: float

    @property
    def gyro_gm_sigma(self) -> float:
        return self.gyro_bi_rad_s / GM_ADEV_PEAK

    @property
    def accel_gm_sigma(self) -> float:
        return self.accel_bi_m_s2 / GM_ADEV_PEAK

    def with_(self, **kw) -> "ImuPreset":
        return replace(self, **kw)


PRESETS: dict[str, ImuPreset] = {
    # Analog Devices ADIS16480 datasheet (Rev. G, Table 1): gyro in-run bias stability 6.25 deg/h,
    # ARW 0.3 deg/sqrt(h); accelerometer in-run bias stability 0.1 mg, VRW 0.029 m/s/sqrt(h).
    # Turn-on bias and scale factor: the residual after a calibration at the start (docs/ins.md).
    "adis16480": ImuPreset("adis16480", 100.0, 0.3 * DEG / np.sqrt(HOUR), 0.029 / np.sqrt(HOUR),
                           6.25 * DEG / HOUR, 0.1 * MG, 300.0, 300.0,
                           20.0 * DEG / HOUR, 1.0 * MG, 1e-3, 1e-3),
    "tactical": ImuPreset("tactical", 100.0, 0.05 * DEG / np.sqrt(HOUR), 0.01 / np.sqrt(HOUR),
                          1.0 * DEG / HOUR, 0.05 * MG, 600.0, 600.0,
                          3.0 * DEG / HOUR, 0.3 * MG, 1e-4, 1e-4),
    "navigation": ImuPreset("navigation", 100.0, 0.002 * DEG / np.sqrt(HOUR), 0.002 / np.sqrt(HOUR),
                            0.01 * DEG / HOUR, 0.01 * MG, 3600.0, 3600.0,
                            0.02 * DEG / HOUR, 0.03 * MG, 1e-5, 1e-5),
}


def preset(name: str) -> ImuPreset:
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown IMU preset {name!r}; choose from {sorted(PRESETS)}") from None


class ImuEmulator:
    """Error model state for ``runs`` IMUs (turn-on bias, scale factor, Gauss-Markov bias), seeded.

    :meth:`measure` turns true increments (K, 3) into measured ones (K, runs, 3), continuing the
    Gauss-Markov states across calls (so a flight can be emulated chunk by chunk).
    """

    def __init__(self, p: ImuPreset, runs: int, rng: np.random.Generator):
        self.p = p
        self.runs = runs
        self.rng = rng
        self.dt_s = 1.0 / p.rate_hz
        self.gyro_turn_on = rng.normal(0.0, p.gyro_turn_on_rad_s, (runs, 3))
        self.accel_turn_on = rng.normal(0.0, p.accel_turn_on_m_s2, (runs, 3))
        self.gyro_sf = rng.normal(0.0, p.gyro_sf, (runs, 3))
        self.accel_sf = rng.normal(0.0, p.accel_sf, (runs, 3))
        self.gyro_gm = rng.normal(0.0, p.gyro_gm_sigma, (runs, 3))
        self.accel_gm = rng.normal(0.0, p.accel_gm_sigma, (runs, 3))

    def _gm(self, state: np.ndarray, sigma: float, tc: float, K: int) -> tuple[np.ndarray, np.ndarray]:
        """K samples (K, runs, 3) of the AR(1) bias starting after ``state``; returns samples, last."""
        a = np.exp(-self.dt_s / tc)
        w = self.rng.standard_normal((K,) + state.shape) * sigma * np.sqrt(1.0 - a * a)
        zi = (a * state)[None]
        y, _ = lfilter([1.0], [1.0, -a], w, axis=0, zi=zi)
        return y, y[-1]

    def measure(self, dth: np.ndarray, dv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Measured increments (K, runs, 3) from true ones (K, 3) (or (K, runs, 3))."""
        K = dth.shape[0]
        p, dt = self.p, self.dt_s
        bg, self.gyro_gm = self._gm(self.gyro_gm, p.gyro_gm_sigma, p.gyro_tc_s, K)
        ba, self.accel_gm = self._gm(self.accel_gm, p.accel_gm_sigma, p.accel_tc_s, K)
        dth = np.broadcast_to(dth[:, None, :] if dth.ndim == 2 else dth, (K, self.runs, 3))
        dv = np.broadcast_to(dv[:, None, :] if dv.ndim == 2 else dv, (K, self.runs, 3))
        g = ((1.0 + self.gyro_sf) * dth + (self.gyro_turn_on + bg) * dt
             + p.arw_rad_sqrt_s * np.sqrt(dt) * self.rng.standard_normal((K, self.runs, 3)))
        a = ((1.0 + self.accel_sf) * dv + (self.accel_turn_on + ba) * dt
             + p.vrw_m_s_sqrt_s * np.sqrt(dt) * self.rng.standard_normal((K, self.runs, 3)))
        return g, a


class ImuBlocks:
    """An IMU's increments step by step, emulated in fixed blocks of ``block`` steps: block ``b``
    from its own generator ``default_rng(key + [b])``, so step ``k`` is the same whatever steps were
    asked for before it (a live process and its replay agree). ``sample(k, dt_s)`` -> (gyro (3,),
    accel (3,)) increments of step ``k`` of length ``dt_s``."""

    def __init__(self, imu: ImuEmulator, motion, key: list[int], block: int = 100):
        self.imu, self.motion, self.key, self.block = imu, motion, list(key), int(block)
        self._id = -1
        self._gyro = self._accel = None

    def sample(self, k: int, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        b, i = divmod(int(k), self.block)
        if b != self._id:
            dth, dv = self.motion.increments(b * self.block * dt_s, dt_s, self.block)
            self.imu.rng = np.random.default_rng(self.key + [b])
            self._gyro, self._accel = self.imu.measure(dth, dv)
            self._id = b
        return self._gyro[i], self._accel[i]


def allan_dev(rate: np.ndarray, dt_s: float, m: np.ndarray) -> np.ndarray:
    """Overlapping Allan deviation of a rate series (N,) at cluster sizes ``m`` (L,) -> (L,)."""
    theta = np.concatenate([[0.0], np.cumsum(rate) * dt_s])
    out = []
    for mm in np.asarray(m, dtype=int):
        d = theta[2 * mm:] - 2.0 * theta[mm:-mm] + theta[: -2 * mm]
        out.append(np.sqrt(np.mean(d * d) / (2.0 * (mm * dt_s) ** 2)))
    return np.array(out)
