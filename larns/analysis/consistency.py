"""Is a recorded estimate as good as its covariance says, and as good as it could be? Pure functions
behind the report's navigation figures (``larns/viz/report.py``): arrays in, arrays and numbers out
(no matplotlib, no I/O).

* horizontal and vertical errors, each with its own sigma (``sigma_h = sqrt(Pxx + Pyy)``,
  ``sigma_v = sqrt(Pzz)``), instead of the 3-D error against a total-covariance bound that the
  vertical dominates;
* the NEES ``e_f^T P_f^-1 e_f`` on each station's free coordinates (``f``: the coordinates its frame
  leaves it, :func:`stations.estimators.free_mask`), summed over the stations at each time with its
  two-sided chi-square band for the summed degrees of freedom;
* the centralized Bayesian CRLB of the survey (:func:`nav.crlb.survey_crlb`, the bound ``larns bench
  survey`` uses) for the ranges the recording shows were measured: each station's nav broadcast
  lists the ranges it measured since its previous nav, so the cumulative counts per link at any time
  are in the recording;
* error ellipses of a 2x2 covariance.

Shapes follow :mod:`larns.analysis.metrics`: tracks ``t_s`` (K,), ``pos_m`` (K, 3), ``cov_m2`` (K, 3, 3).
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from .metrics import hold

def ellipse_probability(k: float) -> float:
    """Probability that a 2-D Gaussian error falls inside its ``k``-sigma ellipse: ``1 - exp(-k^2 / 2)``."""
    return 1.0 - math.exp(-0.5 * k * k)


def ellipse(cov2_m2: np.ndarray, k: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Semi-axes and orientation of the ``k``-sigma ellipses of (..., 2, 2) covariances: ``axes_m``
    (..., 2) (major, minor; negative eigenvalues clipped to 0) and ``angle_rad`` (...) of the major
    axis from +x."""
    C = np.asarray(cov2_m2, float)
    C = 0.5 * (C + np.swapaxes(C, -1, -2))
    w, V = np.linalg.eigh(C)  # ascending
    axes = k * np.sqrt(np.maximum(w[..., ::-1], 0.0))
    return axes, np.arctan2(V[..., 1, 1], V[..., 0, 1])


def hv_errors(track: dict, truth_m) -> dict[str, np.ndarray]:
    """Horizontal and vertical errors against a fixed truth with their own sigmas, each (K,):
    ``eh_m = |e_xy|``, ``sigma_h_m = sqrt(Pxx + Pyy)``, ``ev_m = |e_z|``, ``sigma_v_m = sqrt(Pzz)``."""
    e = np.asarray(track["pos_m"], float) - np.asarray(truth_m, float)
    P = np.asarray(track["cov_m2"], float)
    return {"t_s": np.asarray(track["t_s"], float), "eh_m": np.hypot(e[:, 0], e[:, 1]),
            "sigma_h_m": np.sqrt(np.maximum(P[:, 0, 0] + P[:, 1, 1], 0.0)),
            "ev_m": np.abs(e[:, 2]), "sigma_v_m": np.sqrt(np.maximum(P[:, 2, 2], 0.0))}


def free_axes(cov_m2: np.ndarray) -> np.ndarray:
    """(..., 3) bool: the coordinates an estimate carries, those with a positive variance. A station
    reports exact zeros on the coordinates the founders' frame fixes (station 1: all, 2: y and z,
    3: z) and positive variances on all three once the field carries the datum."""
    c = np.asarray(cov_m2, float)
    return np.diagonal(c[..., :3, :3], axis1=-2, axis2=-1) > 0


def nees_free(track: dict, truth_m, free: np.ndarray | None = None) -> np.ndarray:
    """(K,) NEES ``e_f^T P_f^-1 e_f`` on the free coordinates ``free``: (3,) or (K, 3) bool, default
    each estimate's own (:func:`free_axes`); Cholesky solve; NaN where ``P_f`` is not positive
    definite or nothing is free."""
    from nav.kalman import nees

    e = np.asarray(track["pos_m"], float) - np.asarray(truth_m, float)
    P = np.asarray(track["cov_m2"], float)
    F = free_axes(P) if free is None else np.broadcast_to(np.asarray(free, bool), e.shape)
    out = np.full(e.shape[0], np.nan)
    for k in range(e.shape[0]):
        f = F[k]
        if not f.any():
            continue
        try:
            out[k] = float(nees(e[k][f], P[k][np.ix_(f, f)]))
        except np.linalg.LinAlgError:
            continue
    return out


def nees_band(dof: np.ndarray | float, p: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """Two-sided probability-``p`` band of ``NEES / dof`` for a chi-square with ``dof`` degrees of
    freedom (elementwise; NaN where ``dof`` is 0)."""
    from scipy.stats import chi2

    d = np.asarray(dof, float)
    with np.errstate(all="ignore"):
        dd = np.where(d > 0, d, np.nan)
        return chi2.ppf(0.5 * (1 - p), dd) / dd, chi2.ppf(0.5 * (1 + p), dd) / dd


def nees_curve(tracks: dict[int, dict], truths: dict[int, Any], grid: np.ndarray, p: float = 0.95) -> dict[str, Any]:
    """The stations' NEES on their free coordinates (each estimate's own, :func:`free_axes`) on a time
    grid (each station's last estimate at or before each grid time): ``per_station`` {id: (G,) NEES /
    dof}, ``normalized`` (G,) = sum of NEES / sum of dof over the stations with an estimate, ``dof``
    (G,) that sum, and the band ``lo`` / ``hi`` (G,) of :func:`nees_band` - exact if the stations'
    errors were independent (they share the frame's modes, so the band is the reference a consistent
    filter is held to, not a strict test)."""
    S = np.zeros(grid.size)
    D = np.zeros(grid.size)
    per = {}
    for sid, tr in tracks.items():
        t = np.asarray(tr["t_s"], float)
        q = hold(t, nees_free(tr, truths[sid]), grid)
        n = hold(t, free_axes(tr["cov_m2"]).sum(axis=-1).astype(float), grid)
        ok = np.isfinite(q) & (n > 0)
        if not ok.any():
            continue
        with np.errstate(all="ignore"):
            per[sid] = np.where(ok, q / n, np.nan)
        S[ok] += q[ok]
        D[ok] += n[ok]
    with np.errstate(all="ignore"):
        norm = np.where(D > 0, S / D, np.nan)
    lo, hi = nees_band(D, p)
    return {"grid_s": grid, "per_station": per, "normalized": norm, "dof": D, "lo": lo, "hi": hi, "p": p}


def nees_numbers(c: dict[str, Any]) -> dict[str, Any]:
    """Summary of :func:`nees_curve`: the final normalized NEES with its dof and band, its mean over
    the second half of the grid and the share of grid times inside the band."""
    n, lo, hi = c["normalized"], c["lo"], c["hi"]
    ok = np.isfinite(n) & np.isfinite(lo)
    if not ok.any():
        return {}
    k = np.flatnonzero(ok)
    half = k[k >= k[0] + (k[-1] - k[0]) // 2]
    return {"final": float(n[k[-1]]), "dof": int(c["dof"][k[-1]]), "band": [float(lo[k[-1]]), float(hi[k[-1]])],
            "probability": c["p"], "mean_second_half": float(np.mean(n[half])),
            "inside_band_pct": float(100.0 * np.mean((n[ok] >= lo[ok]) & (n[ok] <= hi[ok])))}


# --------------------------------------------------------------------------- survey CRLB from the record

def range_events(navs: dict[int, Sequence[dict]]) -> np.ndarray:
    """(m, 3) rows ``[t_s, initiator, peer]`` of every range listed in the recorded nav broadcasts
    (``navs``: station id -> its nav messages; each nav's ``ranges`` rows are ``[peer, range_m, t_s,
    ...]``), sorted by time; a range repeated in two recorded copies of one nav counts once."""
    seen = set()
    for sid, msgs in navs.items():
        for nav in msgs:
            for r in nav.get("ranges") or ():
                seen.add((float(r[2]), int(sid), int(r[0])))
    if not seen:
        return np.zeros((0, 3))
    return np.array(sorted(seen), float)


def final_events(journals: dict[int, Any]) -> np.ndarray:
    """(k, 3) rows ``[t_s, member, poller]`` of protocol v2's finals each member took, sorted by time:
    a poller's nav in the member's recorded journal whose final lists the member's reply as heard
    (``poll.rx``). ``journals``: station id -> :class:`larns.log.series.Journal`. With the poller's
    reply rows of :func:`range_events` these make :func:`nav.crlb.poll_exchange_counts`' 4/3 per
    exchange closed by its final (a final heard outside its window, which the member drops, still
    counts here: the bound is then slightly low)."""
    rows = set()
    for sid, j in journals.items():
        for _, entries in j.inputs.values():
            for e in entries:
                if e[0] != "m" or not isinstance(e[2], dict) or e[2].get("kind") != "nav":
                    continue
                pf = e[2].get("poll")
                if pf and any(int(p) == sid for p, _ in pf.get("rx", ())):
                    rows.add((float(e[1]), int(sid), int(e[2]["src"])))
    return np.array(sorted(rows), float) if rows else np.zeros((0, 3))


def survey_crlb_curve(ids: Sequence[int], truth_m: np.ndarray, events: np.ndarray, grid: np.ndarray,
                      sigma_d_m: float, free: np.ndarray, sigma0_m: np.ndarray,
                      finals: np.ndarray | None = None) -> np.ndarray:
    """Per grid time, the bound covariances (G, n, 3, 3) of :func:`nav.crlb.survey_crlb` for the
    ranges measured until then (``events`` from :func:`range_events`, one range each; ``finals`` from
    :func:`final_events`, the third of a range each (:data:`nav.crlb.POLL_EXCHANGE_INFO`); ids not in
    ``ids`` ignored), ``truth_m`` (n, 3) in the network frame, ``free`` (n, 3), ``sigma0_m`` (n,) each
    station's prior sigma (0 or inf: none). NaN where the information is singular (a station not yet
    located)."""
    from nav.crlb import POLL_EXCHANGE_INFO, survey_crlb

    index = {sid: i for i, sid in enumerate(ids)}
    n = len(ids)
    rows = [(t, a, b, 1.0) for t, a, b in events]
    rows += [(t, a, b, POLL_EXCHANGE_INFO - 1.0) for t, a, b in (finals if finals is not None else ())]
    ev = sorted((r for r in rows if int(r[1]) in index and int(r[2]) in index), key=lambda r: r[0])
    out = np.full((grid.size, n, 3, 3), np.nan)
    counts = np.zeros((n, n))
    k = 0
    for g, t in enumerate(grid):
        while k < len(ev) and ev[k][0] <= t:
            counts[index[int(ev[k][1])], index[int(ev[k][2])]] += ev[k][3]
            k += 1
        try:
            out[g] = survey_crlb(truth_m, counts, sigma_d_m, free, sigma0_m)
        except np.linalg.LinAlgError:
            continue
    return out


def crlb_horizontal_rms(bound: np.ndarray, rows: Sequence[int]) -> np.ndarray:
    """(G,) ``sqrt(mean over rows of (var x + var y))`` of :func:`survey_crlb_curve`'s bounds: the
    smallest RMS horizontal error any estimator could have over those stations."""
    b = bound[:, list(rows)]
    with np.errstate(all="ignore"):
        return np.sqrt(np.mean(b[..., 0, 0] + b[..., 1, 1], axis=1))


def rms_horizontal(tracks: dict[int, dict], truths: dict[int, Any], grid: np.ndarray) -> np.ndarray:
    """(G,) RMS over the stations of the horizontal error of each one's last estimate at or before
    each grid time (the quantity :func:`crlb_horizontal_rms` bounds)."""
    H = np.full((len(tracks), grid.size), np.nan)
    for i, (sid, s) in enumerate(tracks.items()):
        e = np.asarray(s["pos_m"], float) - np.asarray(truths[sid], float)
        H[i] = hold(np.asarray(s["t_s"], float), np.hypot(e[:, 0], e[:, 1]), grid)
    with np.errstate(all="ignore"):
        return np.sqrt(np.nanmean(H**2, axis=0))
