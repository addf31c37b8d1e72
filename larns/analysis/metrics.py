"""The report's numbers as pure functions of series (arrays in, numbers out; no matplotlib, no I/O).

Station tracks are dicts of arrays as :meth:`larns.log.series.StationSeries.track` returns them
(``t_s`` (K,), ``pos_m`` (K, 3), ``cov_m2`` (K, 3, 3), ``n_updates`` (K,)); clock series are rows
``[t_s, error_ns, sigma_ns]`` (:meth:`~larns.log.series.StationSeries.clock`); aircraft truth is
``{"t_s", "pos_m", "vel_m_s"}`` (:meth:`~larns.log.series.AircraftSeries.truth_track`).
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from ..log.series import sigma_m


def hold(t_s: np.ndarray, values: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """(len(grid),) the last of ``values`` at or before each grid time (NaN before the first)."""
    out = np.full(grid.size, np.nan)
    k = np.searchsorted(t_s, grid, side="right") - 1
    ok = k >= 0
    out[ok] = values[k[ok]]
    return out


def error_and_bound(track: dict, truth_m) -> tuple[np.ndarray, np.ndarray]:
    """(K,) error norms against a fixed truth and (K,) 3-sigma bounds ``3 sqrt(trace P)``."""
    e = np.linalg.norm(track["pos_m"] - np.asarray(truth_m, float), axis=-1)
    return e, 3.0 * sigma_m(track["cov_m2"])


def inside_fraction(err: np.ndarray, bound: np.ndarray) -> float:
    """Fraction of samples with ``err <= bound`` (NaN for none)."""
    return float(np.mean(err <= bound)) if err.size else math.nan


def station_numbers(track: dict, truth_m, frame: bool = False) -> dict[str, Any]:
    """Final error, final 3-sigma bound, fraction inside 3 sigma, counts. A frame station (the
    origin: zero covariance by definition) has bound 0 and no fraction."""
    e, b = error_and_bound(track, truth_m)
    return {"final_err_m": float(e[-1]), "final_bound3_m": 0.0 if frame else float(b[-1]),
            "inside_3sigma": math.nan if frame else inside_fraction(e, b), "n_estimates": int(e.size),
            "n_updates": int(track["n_updates"][-1])}


def first_time_staying_below(grid: np.ndarray, values: np.ndarray, threshold: float) -> float | None:
    """The first grid time from which every finite value stays below ``threshold`` (None if the
    last finite value is not below it). NaN (no estimate yet) neither breaks nor starts a stay."""
    ok = np.isfinite(values)
    above = np.where(ok & (values >= threshold))[0]
    start = above[-1] + 1 if above.size else 0
    below = np.where(ok[start:])[0]
    return float(grid[start + below[0]]) if below.size else None


def survey_convergence(tracks: dict[int, dict], truths: dict[int, Any], n_grid: int = 200
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Mean and max horizontal error and mean horizontal 1-sigma over the stations on a common grid
    (each station's last estimate at or before the grid time): ``(grid, mean_h, max_h, mean_s)``."""
    t_end = max(v["t_s"][-1] for v in tracks.values())
    t_beg = min(v["t_s"][0] for v in tracks.values())
    grid = np.linspace(t_beg, t_end, n_grid)
    H = np.full((len(tracks), n_grid), np.nan)
    S = np.full((len(tracks), n_grid), np.nan)
    for i, (sid, s) in enumerate(tracks.items()):
        eh = np.linalg.norm((s["pos_m"] - truths[sid])[:, :2], axis=-1)
        sh = np.sqrt(np.maximum(s["cov_m2"][:, 0, 0] + s["cov_m2"][:, 1, 1], 0.0))
        H[i] = hold(s["t_s"], eh, grid)
        S[i] = hold(s["t_s"], sh, grid)
    with np.errstate(all="ignore"):
        return grid, np.nanmean(H, axis=0), np.nanmax(H, axis=0), np.nanmean(S, axis=0)


def second_half_errors(tracks: dict[int, dict], truths: dict[int, Any], free_z) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal errors of all stations and vertical errors of those with ``free_z(id)`` over the
    second half of each station's track."""
    eh, ev = [], []
    for sid, s in tracks.items():
        half = s["t_s"] >= s["t_s"][0] + 0.5 * (s["t_s"][-1] - s["t_s"][0])
        e = (s["pos_m"] - truths[sid])[half]
        eh.append(np.linalg.norm(e[:, :2], axis=-1))
        if free_z(sid):
            ev.append(e[:, 2])
    return np.concatenate(eh), (np.concatenate(ev) if ev else np.zeros(0))


def histogram_numbers(eh: np.ndarray, ev: np.ndarray) -> dict[str, Any]:
    return {"horizontal_rms_m": float(np.sqrt(np.mean(eh**2))),
            "vertical_rms_m": float(np.sqrt(np.mean(ev**2))) if ev.size else math.nan,
            "samples": int(eh.size)}


def sync_curves(series: dict[int, np.ndarray], n_grid: int = 200) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """RMS clock error over the stations and their mean 1-sigma on a common grid: ``(grid, rms, sig)``."""
    t_end = max(r[-1, 0] for r in series.values())
    t_beg = min(r[0, 0] for r in series.values())
    grid = np.linspace(t_beg, t_end, n_grid)
    E = np.full((len(series), grid.size), np.nan)
    S = np.full((len(series), grid.size), np.nan)
    for i, r in enumerate(series.values()):
        E[i], S[i] = hold(r[:, 0], r[:, 1], grid), hold(r[:, 0], r[:, 2], grid)
    with np.errstate(all="ignore"):
        return grid, np.sqrt(np.nanmean(E**2, axis=0)), np.nanmean(S, axis=0)


def sync_numbers(series: dict[int, np.ndarray], rms: np.ndarray, after_s: float = 60.0) -> dict[str, Any]:
    late = np.concatenate([r[r[:, 0] >= after_s, 1] for r in series.values()])
    return {"final_rms_ns": float(rms[-1]), "stations": len(series),
            "max_abs_ns_after_60s": float(np.max(np.abs(late))) if late.size else None,
            "rms_ns_after_60s": float(np.sqrt(np.mean(late**2))) if late.size else None}


def interp_truth(tr: dict, t_s: np.ndarray) -> np.ndarray:
    """Aircraft truth at times ``t_s`` (linear interpolation per axis); (K, 3)."""
    return np.stack([np.interp(t_s, tr["t_s"], tr["pos_m"][:, i]) for i in range(3)], axis=-1)


def aircraft_numbers(track: dict, truth: dict) -> tuple[np.ndarray, dict[str, Any]]:
    """(K,) error norms of one algorithm against the interpolated truth, and its numbers (final,
    RMS after the first 10 % of the estimates)."""
    e = np.linalg.norm(track["pos_m"] - interp_truth(truth, track["t_s"]), axis=-1)
    tail = e[len(e) // 10:]
    return e, {"n": int(e.size), "final_err_m": float(e[-1]),
               "rms_err_m": float(np.sqrt(np.mean(tail**2))) if tail.size else math.nan}


def tdma_numbers(requests: Sequence[tuple], replies: set) -> dict[str, Any]:
    """Range requests recorded and how many were answered (a reply with the request's seq)."""
    n_ans = sum(1 for r in requests if (r[1], r[2], r[3]) in replies)
    return {"requests": len(requests), "answered": n_ans, "answered_pct": 100.0 * n_ans / len(requests)}


# --------------------------------------------------------------------------- aircraft bounds

def aircraft_crlb(truth: dict, stations_m: dict[int, Any], slots: dict[int, int], tdma: tuple[float, float],
                  sigma_m_: float, n_points: int = 150) -> tuple[np.ndarray, np.ndarray] | None:
    """One-cycle CRLB of the position (pseudoranges, unknown clock offset; seed 003 eq. 7) along the
    true track, with the stations at their true positions and their TDMA slot offsets ``slot *
    slot_s`` (``slots``: the slot each station reported). The velocity is a parameter too when one
    cycle has >= 8 stations (else known: one cycle cannot observe it). ``tdma`` = (cycle_s, slot_s)."""
    from nav.pcrb import crlb_cycle, fisher_cycle

    if truth is None or not stations_m or truth["t_s"].size < 2:
        return None
    ids = sorted(stations_m)
    S = np.array([stations_m[i] for i in ids], float)
    cycle_s, slot_s = tdma
    t_rel = np.array([(slots[i] * slot_s) % cycle_s for i in ids])
    k = np.unique(np.linspace(0, truth["t_s"].size - 1, n_points).astype(int))
    J = fisher_cycle(truth["pos_m"][k], truth["vel_m_s"][k], S, t_rel, sigma_m_, clock=True, velocity=len(ids) >= 8)
    return truth["t_s"][k], crlb_cycle(J)["total_m"]


def aircraft_pcrb(truth: dict, navs: Sequence[tuple[float, Any]], tuning) -> tuple[np.ndarray, np.ndarray] | None:
    """Posterior CRLB (``nav.pcrb.pcrb_step``, Tichavsky et al. 1998 in covariance form) of the
    pseudorange filters' own model (CV + clock offset/drift, ``aircraft.estimators.Tuning``) for the
    sequential TDMA measurements: one scalar pseudorange per nav broadcast ``(t_true_s, sender
    pos_m)`` from the sender's true position, along the true track. Returns (times, sqrt of the
    position-bound trace)."""
    from aircraft import models as mdl
    from nav.pcrb import pcrb_step

    navs = [n for n in navs if truth is not None and truth["t_s"][0] - 1.0 <= n[0] <= truth["t_s"][-1]]
    if truth is None or len(navs) < 8:
        return None
    layout = mdl.StateLayout("pr", drift=tuning.drift_state)
    n = layout.n
    P = tuning.p0(layout)
    t_prev = navs[0][0]
    ts, out = [], []
    for t, pos in navs:
        dt = max(t - t_prev, 0.0)
        t_prev = t
        X = np.zeros(n)
        X[:3] = interp_truth(truth, np.array([t]))[0]
        H = mdl.jac_pr(X, np.asarray(pos, float)[None])  # (1, n)
        F, Q = (mdl.cv_transition(n, dt), mdl.cv_noise(n, dt, tuning.q_acc, tuning.q_clock, tuning.q_drift,
                                                       tuning.q_acc_z)) if dt > 0 else (None, None)
        P = pcrb_step(P, H.T @ H / tuning.sigma_m**2, F, Q)
        ts.append(t)
        out.append(sigma_m(P))
    return np.array(ts), np.array(out)
