"""CRLB maps of one TDMA cycle (seed 003, eqs. 1-7): the bounds on a grid and their summary by
distance from the station area (numbers only: the figure is :func:`larns.viz.crlb.plot_maps`, the
command ``larns crlb`` is :mod:`larns.commands.crlb`)."""

from __future__ import annotations

import numpy as np


def compute(stations_m, height_m, sigma_m, t_rel_s, velocity_m_s, params, clock, extent, step):
    """Bounds on a grid: returns x (nx,), y (ny,), horiz (ny, nx), vert (ny, nx), dist_area (ny, nx)."""
    from nav.pcrb import crlb_cycle, fisher_cycle

    x = np.arange(extent[0], extent[1] + 0.5 * step, step)
    y = np.arange(extent[2], extent[3] + 0.5 * step, step)
    X, Y = np.meshgrid(x, y)
    r0 = np.stack([X, Y, np.full_like(X, height_m)], axis=-1)
    J = fisher_cycle(r0, np.asarray(velocity_m_s, float), stations_m, t_rel_s, sigma_m,
                     clock=clock, velocity=(params == "posvel"))
    b = crlb_cycle(J)
    lo, hi = stations_m[:, :2].min(axis=0), stations_m[:, :2].max(axis=0)
    dx = np.maximum(np.maximum(lo[0] - X, X - hi[0]), 0.0)
    dy = np.maximum(np.maximum(lo[1] - Y, Y - hi[1]), 0.0)
    return x, y, b["horiz_m"], b["vert_m"], np.hypot(dx, dy)


def summary(horiz, vert, dist, bands=((0, 0), (0, 10e3), (10e3, 20e3), (20e3, 30e3))):
    """Median / min / max bounds inside the station area (0, 0) and in distance bands from it."""
    out = []
    for a, b in bands:
        m = (dist == 0) if b == 0 else (dist > a) & (dist <= b)
        if not np.any(m):
            continue
        h, v = horiz[m], vert[m]
        out.append({"band_km": [a / 1e3, b / 1e3], "horiz_median_m": float(np.median(h)),
                    "horiz_min_m": float(np.min(h)), "horiz_max_m": float(np.max(h)),
                    "vert_median_m": float(np.median(v)), "vert_min_m": float(np.min(v)),
                    "vert_max_m": float(np.max(v)), "points": int(m.sum())})
    return out
