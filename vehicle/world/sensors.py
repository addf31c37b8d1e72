"""Vehicle sensors on the truth: white-noise IMU (both readings of seed 004's intensities), odometer
with a scale factor, 2-state receiver clock, satellite and LARNS-station pseudoranges and Dopplers.

Noise conventions (spec Sec. 3.8 item 1): seed 004 gives each sensor's noise as a number ``x``
"(x)^2 s". ``"psd"`` reads it as a power spectral density ``q = x^2`` (per-sample sigma at the step
``dt`` is ``x / sqrt(dt)``); ``"per_sample"`` reads ``x`` as the per-sample sigma at ``dt``
(intensity ``x^2 dt``). Everything is vectorized over ``M`` Monte Carlo runs with explicit
generators.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nav.constellation import Almanac, tropo_delay_m
from nav.orbits import ecef_from_greenwich, elevation_deg, greenwich_from_ecef

CONVENTIONS = ("psd", "per_sample")

# seed 004 Sec. 3.7 (spec): the numbers x of "(x)^2 s"
PAPER_NOISE = {"gyro_rad_s": 1e-4, "accel_m_s2": 1e-5, "odometer_m_s": 1e-2}


def per_sample_sigma(x: float, convention: str, dt_s: float) -> float:
    """Per-sample standard deviation at step ``dt_s`` of a white noise given as ``x`` (see module doc)."""
    if convention not in CONVENTIONS:
        raise ValueError(f"noise convention must be one of {CONVENTIONS}, got {convention!r}")
    return x if convention == "per_sample" else x / np.sqrt(dt_s)


def intensity(x: float, convention: str, dt_s: float) -> float:
    """Continuous-time intensity (PSD) of the same noise: ``x^2`` (psd) or ``x^2 dt`` (per_sample)."""
    return per_sample_sigma(x, convention, dt_s) ** 2 * dt_s


@dataclass(frozen=True)
class ImuSpec:
    """White gyro / accelerometer noise and the known mean gyro offset ``m_d`` (subtracted by the navigator)."""

    gyro: float = PAPER_NOISE["gyro_rad_s"]
    accel: float = PAPER_NOISE["accel_m_s2"]
    convention: str = "per_sample"
    gyro_offset_rad_s: float = np.radians(0.01) / 3600.0  # m_d, known

    def sample(self, w_ib_b: np.ndarray, f_b: np.ndarray, runs: int, dt_s: float,
               rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Gyro and accelerometer outputs (T, M, 3) for truth samples (T, 3)."""
        T = w_ib_b.shape[0]
        sg = per_sample_sigma(self.gyro, self.convention, dt_s)
        sa = per_sample_sigma(self.accel, self.convention, dt_s)
        gyro = w_ib_b[:, None, :] + self.gyro_offset_rad_s + sg * rng.standard_normal((T, runs, 3))
        acc = f_b[:, None, :] + sa * rng.standard_normal((T, runs, 3))
        return gyro, acc


@dataclass(frozen=True)
class OdometerSpec:
    """``z = k (1 + scale_error) s' + w``: signed forward speed with the nominal scale factor ``k``."""

    sigma: float = PAPER_NOISE["odometer_m_s"]
    convention: str = "per_sample"
    k: float = 1.0
    scale_error: float = 0.0

    def sample(self, speed_m_s: np.ndarray, runs: int, dt_s: float, rng: np.random.Generator) -> np.ndarray:
        s = per_sample_sigma(self.sigma, self.convention, dt_s)
        T = speed_m_s.shape[0]
        return self.k * (1.0 + self.scale_error) * speed_m_s[:, None] + s * rng.standard_normal((T, runs))


@dataclass(frozen=True)
class ClockSpec:
    """Receiver clock in metres: offset ``b`` and drift ``d``; white frequency noise ``q_b`` (m^2/s) and
    drift random walk ``q_d`` (m^2/s^3); initial spreads ``sigma_b0``, ``sigma_d0``."""

    sigma_b0_m: float = 100.0
    sigma_d0_m_s: float = 1.0
    q_b: float = 0.04
    q_d: float = 1e-4

    def sample(self, t_s: np.ndarray, runs: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Clock offset and drift (T, M) on the grid ``t_s`` (exact discretization of the 2-state model)."""
        T = t_s.size
        b, d = np.empty((T, runs)), np.empty((T, runs))
        b[0] = self.sigma_b0_m * rng.standard_normal(runs)
        d[0] = self.sigma_d0_m_s * rng.standard_normal(runs)
        dts = np.diff(t_s)
        for i, h in enumerate(dts):
            Q = np.array([[self.q_b * h + self.q_d * h**3 / 3, self.q_d * h**2 / 2], [self.q_d * h**2 / 2, self.q_d * h]])
            w = rng.standard_normal((runs, 2)) @ np.linalg.cholesky(Q).T
            b[i + 1] = b[i] + h * d[i] + w[:, 0]
            d[i + 1] = d[i] + w[:, 1]
        return b, d


@dataclass
class RadioEpochs:
    """Radio data at epochs: for each epoch ``i`` emitters' Greenwich positions/velocities (N_i, 3) as
    broadcast, pseudoranges and Dopplers (M, N_i) and their variances (N_i,)."""

    t_s: np.ndarray
    src_pos: list
    src_vel: list
    rho: list
    rate: list
    var_rho: list
    var_rate: list
    ids: list
    src_cov: np.ndarray | None = None  # (N, 3, 3) emitters' broadcast position covariance (stations)


def satellite_epochs(alm: Almanac, truth, epoch_idx: np.ndarray, runs: int, rng: np.random.Generator,
                     sigma_rho_m: float = 15.0, sigma_rate_m_s: float = 0.5, mask_deg: float = 10.0,
                     clock: tuple[np.ndarray, np.ndarray] | None = None, tropo: bool = False,
                     sat_clock_residual_m: float = 0.0, max_sats: int | None = None) -> RadioEpochs:
    """Satellite pseudoranges/Dopplers at truth samples ``epoch_idx`` (instantaneous geometry, Earth-fixed).

    ``clock``: the receiver clock (b, d) (T, M) to include (None: the paper's clock-free model).
    ``tropo`` adds :func:`nav.constellation.tropo_delay_m`; ``sat_clock_residual_m`` a constant
    per-run, per-satellite residual of the broadcast clock correction. Visibility (mask) is decided
    on the truth - by the world, as a receiver's tracking loops would.
    """
    out = RadioEpochs(truth.t_s[epoch_idx], [], [], [], [], [], [], [])
    resid = sat_clock_residual_m * rng.standard_normal((runs, alm.n))
    for i in epoch_idx:
        t = truth.t_s[i]
        pe, ve = alm.ecef(t)
        p_rx = ecef_from_greenwich(truth.p_g[i])
        el = elevation_deg(pe, p_rx)
        vis = np.flatnonzero(el >= mask_deg)
        if max_sats is not None:
            vis = vis[np.argsort(-el[vis])[:max_sats]]
        sp, sv = greenwich_from_ecef(pe[vis]), greenwich_from_ecef(ve[vis])
        d = sp - truth.p_g[i]
        r = np.linalg.norm(d, axis=-1)
        u = d / r[:, None]
        rate = np.einsum("ni,ni->n", u, sv - truth.v_g[i])
        rho = np.broadcast_to(r, (runs, vis.size)).copy()
        rr = np.broadcast_to(rate, (runs, vis.size)).copy()
        if clock is not None:
            rho += clock[0][i][:, None]
            rr += clock[1][i][:, None]
        if tropo:
            rho += tropo_delay_m(el[vis])
        rho += resid[:, vis]
        rho += sigma_rho_m * rng.standard_normal(rho.shape)
        rr += sigma_rate_m_s * rng.standard_normal(rr.shape)
        out.src_pos.append(sp)
        out.src_vel.append(sv)
        out.rho.append(rho)
        out.rate.append(rr)
        out.var_rho.append(np.full(vis.size, sigma_rho_m**2))
        out.var_rate.append(np.full(vis.size, sigma_rate_m_s**2))
        out.ids.append(alm.prn[vis])
    return out


def station_epochs(stations_g: np.ndarray, station_cov_m2: float, truth, epoch_idx: np.ndarray, runs: int,
                   rng: np.random.Generator, sigma_rho_m: float, sigma_rate_m_s: float,
                   clock: tuple[np.ndarray, np.ndarray] | None, consider: bool = False) -> tuple[RadioEpochs, np.ndarray]:
    """LARNS stations' nav broadcasts: pseudoranges and carrier pseudorange rates at the vehicle.

    Stations (N, 3) Greenwich are static; each run's broadcast positions carry a survey error
    ``N(0, station_cov_m2 I)`` drawn once per run. Returns the epochs (``src_pos`` per run: (M, N, 3))
    and the broadcast positions (M, N, 3). Each station broadcasts its position covariance
    (``src_cov`` (N, 3, 3)). ``consider=False``: the navigator is to treat it as white range noise
    (``var_rho = sigma^2 + station_cov_m2``, which is wrong: the error is constant per run);
    ``consider=True``: ``var_rho`` is the range noise alone and the navigator takes the stations'
    positions as Schmidt consider parameters with the broadcast covariance.
    """
    N = stations_g.shape[0]
    bcast = stations_g[None] + np.sqrt(station_cov_m2) * rng.standard_normal((runs, N, 3))
    out = RadioEpochs(truth.t_s[epoch_idx], [], [], [], [], [], [], [])
    out.src_cov = np.broadcast_to(station_cov_m2 * np.eye(3), (N, 3, 3))
    for i in epoch_idx:
        d = stations_g - truth.p_g[i]
        r = np.linalg.norm(d, axis=-1)
        u = d / r[:, None]
        rate = -u @ truth.v_g[i]
        rho = np.broadcast_to(r, (runs, N)).copy()
        rr = np.broadcast_to(rate, (runs, N)).copy()
        if clock is not None:
            rho += clock[0][i][:, None]
            rr += clock[1][i][:, None]
        rho += sigma_rho_m * rng.standard_normal(rho.shape)
        rr += sigma_rate_m_s * rng.standard_normal(rr.shape)
        out.src_pos.append(bcast)
        out.src_vel.append(np.zeros((N, 3)))
        out.rho.append(rho)
        out.rate.append(rr)
        out.var_rho.append(np.full(N, sigma_rho_m**2 + (0.0 if consider else station_cov_m2)))
        out.var_rate.append(np.full(N, sigma_rate_m_s**2))
        out.ids.append(np.arange(1, N + 1))
    return out, bcast

