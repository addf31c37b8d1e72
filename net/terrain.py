"""Terrain for the radio's line-of-sight masking (pure): a height grid and the test of a straight path.

A scenario's ``[radio] terrain = "FILE"`` names a TOML file beside it (relative to the scenario file)::

    origin_m = [-8000.0, -8000.0]   # physical x, y (m) of heights_m[0][0]
    spacing_m = [500.0, 500.0]      # grid step along x and y (m); one number for both
    heights_m = [[...], [...], ...] # ny rows of nx heights (m): heights_m[j][i] at (x0 + i dx, y0 + j dy)

in the scenario's physical frame (that of ``[[stations]] pos_m``, ``z`` up). Between the nodes the height
is bilinear; outside the grid it is 0 m (the smooth Earth).

**Line of sight** (:func:`clear`): the straight path between the two antennas (each at its physical
position plus ``antenna_height_m`` up, the heights :mod:`net.radio` uses) is sampled at ``n - 1`` interior points
``s = 1/n .. (n-1)/n``, ``n = ceil(horizontal length / (half the finer grid spacing))``; at a sample at fractions ``d1 = s d`` and ``d2 = (1 - s) d`` of the path
length ``d`` the obstacle is the terrain plus the Earth-curvature bulge of the effective radius ``k R_E``,
``d1 d2 / (2 k R_E)``, plus ``fresnel_clearance`` times the first Fresnel zone's radius
``sqrt(lambda d1 d2 / d)`` (default 0: pure geometric line of sight). The link is clear when the path is
at or above the obstacle at every sample. Over a flat grid at 0 m the bulge alone blocks exactly the links
beyond the smooth-Earth horizon (the parabolic Earth's tangent), which :func:`net.radio.link` already
drops: flat terrain changes no link.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from nav.orbits import R_EARTH_MEAN_M as EARTH_RADIUS_M

from .sidefile import read_beside

#: samples (links x points) evaluated at once: bounds the memory of a bulk evaluation
CHUNK_SAMPLES = 1_000_000


@dataclass(frozen=True, eq=False)
class Terrain:
    """A height grid in the physical frame and the physical frame of the positions it will be given.

    ``heights_m`` (ny, nx): height at ``(origin_m[0] + i spacing_m[0], origin_m[1] + j spacing_m[1])`` is
    ``heights_m[j, i]``. ``R``, ``t_m``: positions ``p`` (..., 3) handed to :func:`clear` are in the frame
    ``p = R (p_phys - t)`` (None: physical), so ``p_phys = p @ R + t``. Compared by identity."""

    origin_m: tuple[float, float]
    spacing_m: tuple[float, float]
    heights_m: np.ndarray
    fresnel_clearance: float = 0.0
    source: str = ""
    R: np.ndarray | None = None
    t_m: np.ndarray | None = None

    def in_frame(self, R, t_m) -> "Terrain":
        """This grid for positions in the network frame ``p_net = R (p_phys - t)``."""
        return replace(self, R=np.asarray(R, float), t_m=np.asarray(t_m, float))

    @property
    def shape(self) -> tuple[int, int]:
        return self.heights_m.shape

    def describe(self) -> str:
        ny, nx = self.shape
        return (f"terrain {self.source or '(grid)'} ({nx} x {ny} at {self.spacing_m[0]:g} x {self.spacing_m[1]:g} m "
                f"from ({self.origin_m[0]:g}, {self.origin_m[1]:g}), {self.heights_m.min():g}.."
                f"{self.heights_m.max():g} m), fresnel_clearance {self.fresnel_clearance:g}")


def height_at(terrain: Terrain, x_m, y_m) -> np.ndarray:
    """Bilinear terrain height (...) m at physical ``x_m``, ``y_m`` (...); 0 outside the grid."""
    x = (np.asarray(x_m, float) - terrain.origin_m[0]) / terrain.spacing_m[0]
    y = (np.asarray(y_m, float) - terrain.origin_m[1]) / terrain.spacing_m[1]
    ny, nx = terrain.shape
    inside = (x >= 0.0) & (x <= nx - 1) & (y >= 0.0) & (y <= ny - 1)
    i = np.clip(np.floor(x), 0, nx - 2).astype(int)
    j = np.clip(np.floor(y), 0, ny - 2).astype(int)
    fx, fy = np.clip(x - i, 0.0, 1.0), np.clip(y - j, 0.0, 1.0)
    h = terrain.heights_m
    z = ((1 - fx) * (1 - fy) * h[j, i] + fx * (1 - fy) * h[j, i + 1]
         + (1 - fx) * fy * h[j + 1, i] + fx * fy * h[j + 1, i + 1])
    return np.where(inside, z, 0.0)


def _clear_rows(a, b, terrain: Terrain, k_factor: float, wavelength_m: float, n: int) -> np.ndarray:
    """Line of sight (m,) between physical antenna positions ``a``, ``b`` (m, 3) at ``n - 1`` interior samples."""
    s = np.arange(1, n) / n                                      # (n-1,)
    p = a[:, None, :] + s[None, :, None] * (b - a)[:, None, :]   # (m, n-1, 3) points of the path
    d = np.linalg.norm(b - a, axis=-1)[:, None]                  # (m, 1)
    d1d2 = s * (1.0 - s) * d**2                                  # (m, n-1)
    obstacle = height_at(terrain, p[..., 0], p[..., 1]) + d1d2 / (2.0 * k_factor * EARTH_RADIUS_M)
    if terrain.fresnel_clearance > 0:
        obstacle = obstacle + terrain.fresnel_clearance * np.sqrt(wavelength_m * d1d2 / np.maximum(d, 1e-9))
    return np.all(p[..., 2] >= obstacle, axis=-1)


def clear(tx_pos_m, rx_pos_m, terrain: Terrain, k_factor: float, wavelength_m: float,
          antenna_height_m: float) -> np.ndarray:
    """Whether the path between ``tx_pos_m`` and ``rx_pos_m`` (..., 3) (the terrain's frame, :meth:`Terrain.in_frame`;
    antennas ``antenna_height_m`` above them) clears terrain, Earth bulge and Fresnel clearance: bool (...)."""
    tx, rx = np.broadcast_arrays(np.asarray(tx_pos_m, float), np.asarray(rx_pos_m, float))
    shape = tx.shape[:-1]
    up = np.array([0.0, 0.0, antenna_height_m])
    R = np.eye(3) if terrain.R is None else terrain.R
    t = np.zeros(3) if terrain.t_m is None else terrain.t_m
    a = tx.reshape(-1, 3) @ R + t + up
    b = rx.reshape(-1, 3) @ R + t + up
    step = 0.5 * min(terrain.spacing_m)
    dh = np.hypot(*(b - a)[:, :2].T)
    out = np.ones(len(a), bool)
    if len(a) == 0:
        return out.reshape(shape)
    n = np.maximum(np.ceil(dh / step), 1).astype(int)  # each link its own samples: results do not depend on the batch
    for n_k in np.unique(n):
        idx = np.flatnonzero(n == n_k)
        m = max(1, CHUNK_SAMPLES // int(n_k))
        for c in range(0, len(idx), m):
            sel = idx[c:c + m]
            out[sel] = _clear_rows(a[sel], b[sel], terrain, k_factor, wavelength_m, int(n_k))
    return out.reshape(shape)


def load(name: str, base_dir: Path | None, fresnel_clearance: float, error) -> Terrain:
    """The terrain file ``name`` (relative to ``base_dir``, the scenario's folder); ``error(message)`` makes the
    loader's one-line error (``[radio] terrain: FILE: what is wrong (expected ...)``)."""
    w = "[radio] terrain"
    grid = "a terrain grid TOML file with origin_m, spacing_m, heights_m"
    path, doc = read_beside(name, base_dir, w, tomllib.loads, "TOML", grid, grid, error)
    unknown = sorted(set(doc) - {"origin_m", "spacing_m", "heights_m"})
    if unknown:
        raise error(f"{w}: {path}: unknown key {unknown[0]} (expected origin_m, spacing_m, heights_m)")
    origin = _numbers(doc.get("origin_m"), 2, f"{w}: {path}: origin_m", "[x_m, y_m]", error)
    sp = doc.get("spacing_m")
    spacing = _numbers([sp, sp] if _is_number(sp) else sp, 2, f"{w}: {path}: spacing_m",
                       "a number > 0 or [dx_m, dy_m]", error)
    if min(spacing) <= 0:
        raise error(f"{w}: {path}: spacing_m: got {sp!r} (expected a number > 0 or [dx_m, dy_m] > 0)")
    return Terrain(origin_m=origin, spacing_m=spacing, heights_m=_grid(doc.get("heights_m"), f"{w}: {path}", error),
                   fresnel_clearance=float(fresnel_clearance), source=str(name))


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and bool(np.isfinite(v))


def _numbers(v, n: int, where: str, expected: str, error) -> tuple[float, ...]:
    if not isinstance(v, list) or len(v) != n or not all(_is_number(x) for x in v):
        raise error(f"{where}: got {v!r} (expected {expected})")
    return tuple(float(x) for x in v)


def _grid(rows, where: str, error) -> np.ndarray:
    expected = "heights_m: a list of >= 2 rows of >= 2 finite heights in m, all rows of one length"
    if not isinstance(rows, list) or len(rows) < 2 or not all(isinstance(r, list) for r in rows):
        raise error(f"{where}: heights_m: got {type(rows).__name__} (expected {expected})")
    lengths = {len(r) for r in rows}
    if len(lengths) != 1 or min(lengths) < 2:
        raise error(f"{where}: heights_m: rows of lengths {sorted(lengths)} (expected {expected})")
    for j, r in enumerate(rows):
        for i, x in enumerate(r):
            if not _is_number(x):
                raise error(f"{where}: heights_m[{j}][{i}]: got {x!r} (expected a finite height in m)")
    return np.asarray(rows, float)
