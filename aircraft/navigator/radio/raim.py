"""Receiver autonomous integrity monitoring (RAIM) with fault detection and exclusion (pure).

Snapshot weighted least squares on pseudoranges to ground stations, unknowns ``x = [p (3), b]``
(position in the network frame, receiver clock bias in metres):

    rho_i = |p - s_i| + b + e_i,    e_i ~ N(0, sigma_i^2).

* **Detection**: the weighted sum of squared residuals ``SSE = r^T W r`` is chi-square with
  ``m - 4`` degrees of freedom without a fault; a fault is declared when ``SSE > T``,
  ``T = chi2.ppf(1 - p_fa, m - 4)`` (p_fa: false-alarm probability per epoch).
* **Exclusion** (leave-one-out, as RTKLIB's ``raim_fde``): re-solve without each station in turn and
  exclude the one whose removal gives the smallest SSE, if that subset passes the test.
* **Protection levels** (Brown's slope method): station i's slope ``|dpos_h / dSSE^1/2|`` is
  ``sqrt(S_xi^2 + S_yi^2) sigma_i / sqrt(1 - Q_ii)`` with ``S = (H^T W H)^-1 H^T W`` and the residual
  projector's diagonal ``Q_ii``; the bias that is missed with probability ``p_md`` has non-centrality
  ``lambda`` with ``ncx2.cdf(T, m - 4, lambda) = p_md``; ``HPL = max_i slope_h,i sqrt(lambda)`` (VPL
  likewise with the vertical row), a single-fault protection level for integrity risk ``p_md``.

Used by measuring code and tests; ``docs/aircraft.md`` states p_fa and p_md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy.optimize import brentq
from scipy.stats import chi2, ncx2

from nav.geometry import line_of_sight


@dataclass
class RaimResult:
    pos_m: np.ndarray  # (3,)
    clock_m: float
    sse: float
    threshold: float
    dof: int
    fault: bool  # the full set failed the test
    excluded: list[int] = field(default_factory=list)  # station ids excluded
    hpl_m: float = np.inf
    vpl_m: float = np.inf
    available: bool = True  # enough redundancy for detection (m >= 5)


def _wls(S: np.ndarray, rho: np.ndarray, w: np.ndarray, x0: np.ndarray, iters: int = 8):
    """Gauss-Newton WLS for ``[p, b]``. S (m, 3), rho (m,), w (m,) = 1/sigma^2, x0 (4,)."""
    x = x0.astype(float).copy()
    for _ in range(iters):
        r, u = line_of_sight(x[:3], S)
        H = np.hstack([u, np.ones((len(S), 1))])
        res = rho - (r + x[3])
        sw = np.sqrt(w)[:, None]
        dx = np.linalg.lstsq(H * sw, res * sw[:, 0], rcond=None)[0]  # QR/SVD: safe on poor geometry
        x += dx
        if np.max(np.abs(dx)) < 1e-4:
            break
    r, u = line_of_sight(x[:3], S)
    H = np.hstack([u, np.ones((len(S), 1))])
    res = rho - (r + x[3])
    return x, H, res


@lru_cache(maxsize=256)
def _lambda_md(dof: int, T: float, p_md: float) -> float:
    """Non-centrality at which a chi-square(dof) test with threshold T misses with probability p_md."""
    f = lambda lam: ncx2.cdf(T, dof, lam) - p_md  # noqa: E731
    hi = 10.0
    while f(hi) > 0:
        hi *= 2.0
    return float(brentq(f, 1e-9, hi))


def protection_levels(H: np.ndarray, w: np.ndarray, T: float, p_md: float) -> tuple[float, float]:
    """HPL, VPL (m) by the slope method for geometry H (m, 4) and weights w (m,)."""
    m = len(w)
    dof = m - 4
    if dof < 1:
        return np.inf, np.inf
    A = (H.T * w) @ H
    Sx = np.linalg.solve(A, H.T * w)  # (4, m)
    Q = np.eye(m) - H @ Sx  # residual projector
    q = np.clip(np.diag(Q), 1e-12, None)
    sig = 1.0 / np.sqrt(w)
    slope_h = np.hypot(Sx[0], Sx[1]) * sig / np.sqrt(q)
    slope_v = np.abs(Sx[2]) * sig / np.sqrt(q)
    lam = np.sqrt(_lambda_md(dof, T, p_md))
    return float(slope_h.max() * lam), float(slope_v.max() * lam)


def raim_fde(station_ids, stations_m, rho_m, sigma_m, x0, *, p_fa: float = 1e-3, p_md: float = 1e-3,
             max_exclude: int = 1) -> RaimResult:
    """Snapshot RAIM/FDE (see module docstring).

    Parameters
    ----------
    station_ids : (m,) ids. stations_m : (m, 3) broadcast station positions. rho_m : (m,) pseudoranges.
    sigma_m : (m,) or scalar pseudorange sigma (station position uncertainty included by the caller).
    x0 : (4,) start [p, b]. p_fa : false alarms per epoch. p_md : missed-detection probability behind
    the protection levels.
    """
    ids = list(station_ids)
    S = np.asarray(stations_m, float)
    rho = np.asarray(rho_m, float)
    w = 1.0 / np.broadcast_to(np.asarray(sigma_m, float), rho.shape) ** 2
    x, H, res = _wls(S, rho, w, np.asarray(x0, float))
    m = len(rho)
    dof = m - 4
    if dof < 1:
        return RaimResult(x[:3], float(x[3]), 0.0, np.inf, dof, False, available=False)
    T = float(chi2.ppf(1.0 - p_fa, dof))
    sse = float(res @ (w * res))
    hpl, vpl = protection_levels(H, w, T, p_md)
    out = RaimResult(x[:3], float(x[3]), sse, T, dof, sse > T, hpl_m=hpl, vpl_m=vpl)
    if not out.fault or max_exclude < 1 or dof < 2:
        return out
    best = None
    for i in range(m):
        keep = np.arange(m) != i
        xi, Hi, ri = _wls(S[keep], rho[keep], w[keep], x)
        sse_i = float(ri @ (w[keep] * ri))
        if best is None or sse_i < best[0]:
            best = (sse_i, i, xi, Hi, keep)
    sse_i, i, xi, Hi, keep = best
    Ti = float(chi2.ppf(1.0 - p_fa, dof - 1))
    if sse_i > Ti:  # no single exclusion explains it: flag, keep the full solution
        return out
    hpl, vpl = protection_levels(Hi, w[keep], Ti, p_md)
    return RaimResult(xi[:3], float(xi[3]), sse_i, Ti, dof - 1, True, [ids[i]], hpl, vpl)
