"""Radio propagation of the air channel (pure): which links exist and how noisy their timing is.

One model for the simulator and the processes (``net/channel.py`` applies it to every reception):

* **Radio horizon** over a smooth Earth of effective radius ``k R_E`` (``k`` = 4/3 for the standard
  atmosphere): two antennas at heights ``h_1``, ``h_2`` above the ground see each other up to
  ``d_h = sqrt(2 k R_E h_1) + sqrt(2 k R_E h_2)`` (ITU-R P.834 / any radio handbook).
* **Link budget**: ``SNR = P_tx + G_tx + G_rx - L(d) - N`` (dB), with the thermal noise
  ``N = -174 dBm/Hz + 10 log10(B) + NF``. Path loss ``L``: free space
  ``20 log10(4 pi d f / c)`` up to the two-ray crossover ``d_c = 4 pi h_1 h_2 / lambda``, beyond it the
  plane-Earth (two-ray ground reflection) law ``40 log10 d - 20 log10(h_1 h_2)`` (Rappaport, *Wireless
  Communications*, eq. 4.52), which is continuous with free space at ``d_c`` up to a constant we keep
  by taking the larger of the two losses. A link exists when the path clears the horizon and the
  post-correlation SNR (``SNR + 10 log10(B T_int)``, the processing gain of a correlator integrating
  ``T_int``) reaches the receiver's detection threshold.
* **Terrain** (optional, ``[radio] terrain``: :mod:`net.terrain`): the straight path between the antennas
  must clear a height grid plus the Earth bulge ``d1 d2 / (2 k R_E)`` (and a fraction of the first Fresnel
  zone) at every sample; without it nothing changes.
* **Timing noise from the SNR**: the Cramer-Rao bound of a time of arrival,
  ``sigma_tau = 1 / (2 pi beta sqrt(2 SNR_post))`` with ``beta = B / sqrt(12)`` the RMS bandwidth of a
  flat spectrum of width ``B`` (Van Trees; Gezici et al. 2005, eq. 3), added in quadrature to the
  hardware floor of the scenario's ``[channel] sigma_d_m``: far links are noisier, near links keep the
  floor.

Distances are the straight-line distance of the emulated (flat) field frame; heights are each
antenna's physical height (its ``z`` in the scenario's physical frame, whatever frame the channel's
positions are in: :meth:`RadioParams.in_frame`) plus the scenario's ``antenna_height_m``, clipped at a minimum
of 0.1 m (an antenna on the ground still radiates). Defaults: a 1 W, 1 GHz ranging radio of 10 MHz
bandwidth, 0 dBi antennas 10 m up, a 10 us correlator and a 12 dB detection threshold: links reach the
26 km horizon, the timing CRLB adds 3.5 cm (one-way, 1 sigma) at 2 km, 0.4 m at 10 km and 2.6 m at
25 km (docs/scenarios.md ``[radio]``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from nav.geometry import SPEED_OF_LIGHT_M_S
from nav.orbits import R_EARTH_MEAN_M as EARTH_RADIUS_M

from . import terrain as _terrain
from .terrain import Terrain

THERMAL_NOISE_DBM_HZ = -174.0
MIN_HEIGHT_M = 0.1


@dataclass(frozen=True)
class RadioParams:
    """The ``[radio]`` section. Units in the names; dB quantities are logarithmic."""

    k_factor: float = 4.0 / 3.0
    antenna_height_m: float = 10.0
    tx_power_dbm: float = 30.0
    antenna_gain_dbi: float = 0.0
    freq_hz: float = 1.0e9
    bandwidth_hz: float = 10.0e6
    noise_figure_db: float = 5.0
    integration_s: float = 1.0e-5
    threshold_db: float = 12.0
    two_ray: bool = True
    # [radio] terrain (net/terrain.py): line-of-sight masking by a height grid; None: a smooth Earth
    terrain: Terrain | None = None
    # [radio] tile_m (net/tiles.py): the side of the wire's nav tiles; None: derived from the link range
    tile_m: float | None = None
    # not scenario keys: the physical up direction in the frame of the positions the channel gets (the
    # network frame) and the physical height of that frame's origin (:meth:`in_frame`)
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    origin_height_m: float = 0.0

    def in_frame(self, R, t_m) -> "RadioParams":
        """These parameters for positions in the network frame ``p_net = R (p_phys - t)``
        (:func:`nav.geometry.to_network_frame`): physical height ``z = R[:, 2] . p_net + t_z``."""
        R, t_m = np.asarray(R, float), np.asarray(t_m, float)
        terrain = None if self.terrain is None else self.terrain.in_frame(R, t_m)
        return replace(self, up=tuple(float(v) for v in R[:, 2]), origin_height_m=float(t_m[2]), terrain=terrain)

    @property
    def wavelength_m(self) -> float:
        return SPEED_OF_LIGHT_M_S / self.freq_hz

    @property
    def noise_dbm(self) -> float:
        """Thermal noise power in the receiver's bandwidth, with its noise figure."""
        return THERMAL_NOISE_DBM_HZ + 10.0 * np.log10(self.bandwidth_hz) + self.noise_figure_db

    @property
    def processing_gain_db(self) -> float:
        return 10.0 * np.log10(self.bandwidth_hz * self.integration_s)

    @cached_property
    def _consts(self) -> tuple:
        """What every link evaluation reads, computed once: ``P_tx + 2 G`` (dB), :attr:`noise_dbm`,
        :attr:`processing_gain_db`, the RMS bandwidth ``beta = B / sqrt(12)`` (Hz) and ``up`` (3,)."""
        return (self.tx_power_dbm + 2.0 * self.antenna_gain_dbi, self.noise_dbm, self.processing_gain_db,
                self.bandwidth_hz / np.sqrt(12.0), np.asarray(self.up))


def _norm(v: np.ndarray) -> np.ndarray:
    """``np.linalg.norm(v, axis=-1)`` (...) of vectors ``v`` (..., 3): its own operations without its
    argument handling."""
    return np.sqrt(np.add.reduce(v * v, axis=-1))


def _heights(pos_m, params: RadioParams) -> np.ndarray:
    """Antenna heights (...) above the ground of positions (..., 3) in the parameters' frame."""
    z = np.asarray(pos_m, float) @ params._consts[4] + params.origin_height_m
    return np.maximum(z + params.antenna_height_m, MIN_HEIGHT_M)


def horizon_m(h1_m, h2_m, k_factor: float = 4.0 / 3.0) -> np.ndarray:
    """Radio horizon (...) between antennas at heights ``h1_m``, ``h2_m`` (...) above a smooth Earth."""
    ke = 2.0 * k_factor * EARTH_RADIUS_M
    return np.sqrt(ke * np.maximum(h1_m, 0.0)) + np.sqrt(ke * np.maximum(h2_m, 0.0))


def path_loss_db(d_m, h1_m, h2_m, params: RadioParams) -> np.ndarray:
    """Path loss (...) in dB at distance ``d_m``: free space, and beyond the two-ray crossover the
    plane-Earth law (the larger of the two, so the loss never drops with distance)."""
    d = np.maximum(np.asarray(d_m, float), 1e-3)
    fspl = 20.0 * np.log10(4.0 * np.pi * d / params.wavelength_m)
    if not params.two_ray:
        return fspl
    plane = 40.0 * np.log10(d) - 20.0 * np.log10(np.asarray(h1_m, float) * np.asarray(h2_m, float))
    return np.maximum(fspl, plane)


def link_snr_db(d_m, h1_m, h2_m, params: RadioParams) -> np.ndarray:
    """Post-correlation SNR (...) dB of a link of length ``d_m`` between antennas at ``h1_m``, ``h2_m``:
    the link budget ``P_tx + G_tx + G_rx - L(d) - N`` plus the processing gain."""
    gain_db, noise_dbm, gain_pg_db = params._consts[:3]
    return gain_db - path_loss_db(d_m, h1_m, h2_m, params) - noise_dbm + gain_pg_db


@dataclass(frozen=True)
class Link:
    """One link's physics: ``exists`` (...) bool, post-correlation ``snr_db`` (...) and the one-way
    timing sigma of the SNR's CRLB ``sigma_crlb_s`` (...) (inf where no link)."""

    exists: np.ndarray
    snr_db: np.ndarray
    sigma_crlb_s: np.ndarray


def link(tx_pos_m, rx_pos_m, params: RadioParams) -> Link:
    """The link between positions ``tx_pos_m`` (..., 3) and ``rx_pos_m`` (..., 3) of the physical frame."""
    tx, rx = np.asarray(tx_pos_m, float), np.asarray(rx_pos_m, float)
    d = _norm(rx - tx)
    h1, h2 = _heights(tx, params), _heights(rx, params)
    snr_db = link_snr_db(d, h1, h2, params)
    exists = (d <= horizon_m(h1, h2, params.k_factor)) & (snr_db >= params.threshold_db)
    if params.terrain is not None:  # line of sight over the terrain
        exists = _line_of_sight(tx, rx, exists, params)
    sigma = np.where(exists, toa_crlb_s(snr_db, params), np.inf)
    return Link(exists=np.asarray(exists), snr_db=np.asarray(snr_db), sigma_crlb_s=np.asarray(sigma))


def may_link(pos_m, params: RadioParams | None, slack: float = 1e-6) -> np.ndarray:
    """(n, n) bool, ``[i, j]``: whether the horizon and the link budget can let :func:`link` from position
    ``i`` to position ``j`` of ``pos_m`` (n, 3) exist, with a relative slack on the distance and an
    absolute one (dB) on the SNR far above rounding: every pair :func:`link` lets exist is in it (the
    terrain is not looked at), so a caller tests only these pairs one by one. All True without ``[radio]``."""
    pos = np.asarray(pos_m, float)
    n = len(pos)
    if params is None:
        return np.ones((n, n), bool)
    d = np.linalg.norm(pos[:, None, :] - pos[None, :, :], axis=-1)
    h = _heights(pos, params)
    h1, h2 = h[:, None], h[None, :]
    snr_db = link_snr_db(d, h1, h2, params)
    return (d <= horizon_m(h1, h2, params.k_factor) * (1.0 + slack)) & (snr_db >= params.threshold_db - slack)


def _line_of_sight(tx, rx, exists, params: RadioParams) -> np.ndarray:
    """``exists`` (...) and the terrain's line of sight (:func:`net.terrain.clear`), evaluated only where the
    horizon and the budget let the link exist."""
    tx, rx = np.broadcast_arrays(tx, rx)
    out = np.broadcast_to(np.asarray(exists, bool), tx.shape[:-1]).copy()
    if out.any():
        out[out] = _terrain.clear(tx[out], rx[out], params.terrain, params.k_factor, params.wavelength_m,
                                  params.antenna_height_m)
    return out


def toa_crlb_s(snr_db, params: RadioParams) -> np.ndarray:
    """One-way TOA Cramer-Rao bound (...) s at post-correlation SNR ``snr_db`` (...):
    ``1 / (2 pi beta sqrt(2 SNR))``, ``beta = B / sqrt(12)`` (flat spectrum)."""
    beta = params._consts[3]
    snr = 10.0 ** (np.asarray(snr_db, float) / 10.0)
    return 1.0 / (2.0 * np.pi * beta * np.sqrt(2.0 * snr))


def range_var_m2(pos_a_m, pos_b_m, params: RadioParams | None, sigma_d_m: float):
    """Variance (...) m^2 of a two-way range between stations at ``pos_a_m``, ``pos_b_m`` (..., 3)
    (estimates: this is what a station weights its ranges with, not truth), in the parameters' frame.

    The channel times each leg with sigma ``hypot(sqrt(2) sigma_d / c, sigma_crlb)``
    (:class:`net.channel.AirChannel`) and a range is ``c / 2`` times the sum of the two legs, so its
    variance is ``sigma_d^2 + c^2 sigma_crlb^2 / 2``. A range that was measured came over a link at or
    above the detection threshold: the SNR is taken at least there (an estimated geometry can put it
    below). Without ``[radio]`` (``params`` None): ``sigma_d^2``, a scalar."""
    if params is None:
        return float(sigma_d_m) ** 2
    a, b = np.asarray(pos_a_m, float), np.asarray(pos_b_m, float)
    if a.shape == b.shape == (3,):
        var = _pair_range_var_m2(a, b, params, sigma_d_m)
        if var is not None:
            return var
    d = _norm(a - b)
    snr_db = link_snr_db(d, _heights(a, params), _heights(b, params), params)
    crlb_m = SPEED_OF_LIGHT_M_S * toa_crlb_s(np.maximum(snr_db, params.threshold_db), params)
    return float(sigma_d_m) ** 2 + 0.5 * crlb_m**2


def _pair_range_var_m2(a: np.ndarray, b: np.ndarray, params: RadioParams, sigma_d_m: float):
    """:func:`range_var_m2` of one pair ``a``, ``b`` (3,) without small arrays: the same operations in the
    same order on floats (the norm's sum as numpy reduces three terms; ``log10`` and the powers on numpy
    scalars, as there), so the same value; None where a coordinate is not finite (then the arrays)."""
    ax, ay, az = a.tolist()
    bx, by, bz = b.tolist()
    if not math.isfinite(ax + ay + az + bx + by + bz):
        return None
    gain_db, noise_dbm, gain_pg_db, beta, up = params._consts
    dx, dy, dz = ax - bx, ay - by, az - bz
    d = max(math.sqrt((dx * dx + dy * dy) + dz * dz), 1e-3)
    h1 = max(float(a @ up) + params.origin_height_m + params.antenna_height_m, MIN_HEIGHT_M)
    h2 = max(float(b @ up) + params.origin_height_m + params.antenna_height_m, MIN_HEIGHT_M)
    loss_db = 20.0 * float(np.log10(4.0 * np.pi * d / params.wavelength_m))
    if params.two_ray:
        loss_db = max(loss_db, 40.0 * float(np.log10(d)) - 20.0 * float(np.log10(h1 * h2)))
    snr_db = max(gain_db - loss_db - noise_dbm + gain_pg_db, params.threshold_db)
    snr = 10.0 ** np.float64(snr_db / 10.0)
    crlb_m = SPEED_OF_LIGHT_M_S * (1.0 / (2.0 * np.pi * beta * math.sqrt(2.0 * snr)))
    return float(sigma_d_m) ** 2 + 0.5 * np.float64(crlb_m) ** 2


def radio_dict(params: RadioParams | None) -> dict | None:
    """The parameters as a plain dict (a station core's journaled config), or None."""
    if params is None:
        return None
    return {f.name: (list(getattr(params, f.name)) if f.name == "up" else getattr(params, f.name))
            for f in fields(params) if f.name not in ("terrain", "tile_m")}  # ranges are weighted without them


def radio_from_dict(d: dict | None) -> RadioParams | None:
    """Inverse of :func:`radio_dict`."""
    if d is None:
        return None
    return RadioParams(**{k: (tuple(v) if k == "up" else v) for k, v in d.items()})


def max_range_m(params: RadioParams, h1_m: float, h2_m: float) -> float:
    """The longest link between antennas at ``h1_m`` and ``h2_m`` (the horizon or the SNR, whichever
    is shorter), by bisection on the monotone path loss."""
    lo, hi = 1.0, float(horizon_m(h1_m, h2_m, params.k_factor))

    def ok(d: float) -> bool:
        return float(link_snr_db(d, h1_m, h2_m, params)) >= params.threshold_db

    if ok(hi):
        return hi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo


POSITIVE = ("k_factor", "freq_hz", "bandwidth_hz", "integration_s", "tile_m")


TERRAIN_KEYS = ("terrain", "fresnel_clearance")


def _parse_terrain(table: dict, error, base_dir: Path | None, load_terrain: bool) -> Terrain | None:
    """``[radio] terrain`` (a grid file, relative to ``base_dir``) and ``fresnel_clearance`` (net/terrain.py)."""
    name, f = table.get("terrain"), table.get("fresnel_clearance", 0.0)
    if name is None:
        if "fresnel_clearance" in table:
            raise error("[radio] fresnel_clearance: without [radio] terrain (expected a terrain grid file too)")
        return None
    if not isinstance(name, str) or not name:
        raise error(f"[radio] terrain: got {name!r} (expected the path of a terrain grid TOML file)")
    if isinstance(f, bool) or not isinstance(f, (int, float)) or not np.isfinite(f) or f < 0:
        raise error(f"[radio] fresnel_clearance: got {f!r} (expected a number >= 0: the fraction of the first "
                    "Fresnel zone kept clear)")
    return _terrain.load(name, base_dir, float(f), error) if load_terrain else None


def parse(table: dict, error, base_dir: str | Path | None = None, load_terrain: bool = True) -> RadioParams | None:
    """``RadioParams`` of a scenario's ``[radio]`` table (None: no table, every station hears every
    other at any distance). ``error(message)`` raises the loader's one-line error. ``[radio] terrain``
    is read relative to ``base_dir`` (the scenario file's folder), not at all with ``load_terrain`` False."""
    if table is None:
        return None
    if not isinstance(table, dict):
        raise error("[radio]: expected a table")
    known = [f.name for f in fields(RadioParams) if f.name not in ("up", "origin_height_m", "terrain")]
    known += list(TERRAIN_KEYS)
    for key in table:
        if key not in known:
            raise error(f"[radio] {key}: unknown key (expected one of {', '.join(known)})")
    terrain = _parse_terrain(table, error, None if base_dir is None else Path(base_dir), load_terrain)
    values = {}
    for key, v in table.items():
        if key in TERRAIN_KEYS:
            continue
        if key == "two_ray":
            if not isinstance(v, bool):
                raise error(f"[radio] two_ray: {v!r} is not a boolean (expected true or false)")
            values[key] = v
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
            raise error(f"[radio] {key}: {v!r} is not a number (expected a finite number)")
        if key in POSITIVE and v <= 0:
            raise error(f"[radio] {key}: {v!r} (expected > 0)")
        if key == "antenna_height_m" and v < 0:
            raise error(f"[radio] antenna_height_m: {v!r} (expected >= 0)")
        values[key] = float(v)
    return RadioParams(**values, terrain=terrain)


def reception_sigma_m(tx_pos_m, rx_pos_m, params: RadioParams | None, floor_m: float) -> float | None:
    """One-way timing sigma (range units, m) of one reception from ``tx_pos_m`` (3,) at ``rx_pos_m``
    (3,), both in the parameters' frame: the receiver's floor ``floor_m`` in quadrature with ``c`` x
    the link's TOA CRLB; ``None`` where the link does not exist (beyond the horizon or the budget).
    Without a ``[radio]`` section (``params`` None) every link exists with the floor.

    This is the one channel model of a user receiver (the aircraft's and the vehicle's world sides);
    the stations' two-way legs get theirs in :class:`net.channel.AirChannel`."""
    if params is None:
        return float(floor_m)
    air = link(tx_pos_m, rx_pos_m, params)
    if not bool(air.exists):
        return None
    return float(np.hypot(floor_m, SPEED_OF_LIGHT_M_S * float(air.sigma_crlb_s)))


def link_var_m2(sigma_m: float, floor_m: float) -> float:
    """The part of a reception's timing variance above the receiver's nominal floor, ``sigma^2 -
    floor^2`` (m^2): a white range variance the navigator adds to its nominal one. A receiver knows it
    from the SNR it measures (its C/N0 estimate), so the navigator gets no truth from it."""
    return max(float(sigma_m) ** 2 - float(floor_m) ** 2, 0.0)
