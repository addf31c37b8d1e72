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


def nees_band(n: int, dof: int = 3, p: float = 0.95) -> tuple[float, float]:
    """Two-sided ``p`` band of the mean of ``n`` independent NEES samples of ``dof`` degrees of freedom:
    ``chi2.ppf((1 -+ p) / 2, n dof) / n``."""
    from scipy.stats import chi2

    return (float(chi2.ppf(0.5 * (1 - p), n * dof) / n), float(chi2.ppf(0.5 * (1 + p), n * dof) / n))  # n may be fractional


def aircraft_accuracy(track: dict, truth: dict, t_from_s: float = 30.0, t_to_s: float | None = None,
                      sample_s: float = 1.0) -> dict[str, Any]:
    """A navigator's accuracy from its recording: horizontal error ``e_h`` of every estimate against
    the interpolated truth; the first estimate's time; the first times from which ``e_h`` stays below
    10 m and 3 m; the largest ``e_h`` in ``[t_from_s, t_to_s]`` and the last; the 3-D position NEES
    ``e^T P^-1 e`` averaged over that window sampled once per ``sample_s`` (about one TDMA cycle apart)
    with the band of :func:`nees_band` for the *effective* number of independent samples: a filter's
    consecutive errors are correlated, so ``n_eff = n (1 - rho) / (1 + rho)`` with ``rho`` the lag-1
    autocorrelation of the NEES series (AR(1)); whether every estimate was finite."""
    t = np.asarray(track["t_s"], float)
    out: dict[str, Any] = {"n": int(t.size), "finite": bool(np.all(np.isfinite(track["pos_m"]))
                                                           and np.all(np.isfinite(track["cov_m2"])))}
    if not t.size:
        return out
    e = track["pos_m"] - interp_truth(truth, t)
    eh = np.hypot(e[:, 0], e[:, 1])
    t_to = float(t[-1]) if t_to_s is None else float(t_to_s)
    win = (t >= t_from_s) & (t <= t_to)
    out.update(first_t_s=float(t[0]), t_10m_s=first_time_staying_below(t, eh, 10.0),
               t_3m_s=first_time_staying_below(t, eh, 3.0), final_t_s=float(t[-1]), final_eh_m=float(eh[-1]),
               final_ev_m=float(abs(e[-1, 2])),
               final_sigma_h_m=float(np.sqrt(max(track["cov_m2"][-1, 0, 0] + track["cov_m2"][-1, 1, 1], 0.0))))
    if np.any(win):
        out["max_eh_window_m"] = float(eh[win].max())
        grid = np.arange(t_from_s, t_to + 1e-9, sample_s)
        k = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, t.size - 1)
        k = np.unique(k[t[k] >= t_from_s])
        P = track["cov_m2"][k]
        try:
            q = np.einsum("ki,ki->k", e[k], np.linalg.solve(P, e[k][..., None])[..., 0])
        except np.linalg.LinAlgError:
            q = np.full(k.size, np.inf)
        rho = float(np.corrcoef(q[:-1], q[1:])[0, 1]) if q.size > 3 and np.all(np.isfinite(q)) and np.std(q) > 0 else 0.0
        rho = min(max(rho, 0.0), 0.99) if np.isfinite(rho) else 0.0
        n_eff = max(1.0, q.size * (1.0 - rho) / (1.0 + rho))
        out.update(nees_mean=float(np.mean(q)), nees_n=int(k.size), nees_n_eff=float(n_eff),
                   nees_band=nees_band(n_eff))
    return out


def tdma_numbers(requests: Sequence[tuple], replies: set) -> dict[str, Any]:
    """Exchanges recorded (``(stamp_s, initiator, responder, seq, cycle)``: a range request, or a
    poll's member) and how many were answered (``(initiator, responder, seq)`` in ``replies``); per
    initiator (``by_station``): its exchanges answered and its polls answered by every member named
    (``complete_pct``; with the addressed exchange each request is a poll of one)."""
    n_ans = sum(1 for r in requests if (r[1], r[2], r[3]) in replies)
    polls: dict[tuple[int, int], list[bool]] = {}
    for r in requests:
        polls.setdefault((r[1], r[3]), []).append((r[1], r[2], r[3]) in replies)
    by: dict[int, list[int]] = {}
    for (src, _), ok in polls.items():
        n = by.setdefault(src, [0, 0, 0, 0])  # polls, complete, exchanges, answered
        n[0] += 1
        n[1] += all(ok)
        n[2] += len(ok)
        n[3] += sum(ok)
    return {"requests": len(requests), "answered": n_ans, "answered_pct": 100.0 * n_ans / len(requests),
            "by_station": {src: {"polls": n[0], "complete_pct": 100.0 * n[1] / n[0],
                                 "answered_pct": 100.0 * n[3] / n[2]} for src, n in sorted(by.items())}}


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
    pseudorange filters' own model (CV + clock offset/drift, ``aircraft.navigator.radio.tuning.Tuning``) for the
    sequential TDMA measurements: one scalar pseudorange per nav broadcast ``(t_true_s, sender
    pos_m)`` from the sender's true position, along the true track. Returns (times, sqrt of the
    position-bound trace)."""
    from aircraft.navigator.radio import models as mdl
    from nav.pcrb import pcrb_step

    navs = [n for n in navs if truth is not None and truth["t_s"][0] - 1.0 <= n[0] <= truth["t_s"][-1]]
    if truth is None or len(navs) < 8:
        return None
    layout = mdl.StateLayout("pr", drift=True)
    n = layout.n
    P = tuning.prior_cov(layout)
    t_prev = navs[0][0]
    ts, out = [], []
    for t, pos in navs:
        dt = max(t - t_prev, 0.0)
        t_prev = t
        X = np.zeros(n)
        X[:3] = interp_truth(truth, np.array([t]))[0]
        H = mdl.jac_pr(X, np.asarray(pos, float)[None])  # (1, n)
        F, Q = ((mdl.cv_transition(n, dt), mdl.cv_noise(n, dt, tuning.q_acc, tuning.q_clock, tuning.q_drift))
                if dt > 0 else (None, None))
        P = pcrb_step(P, H.T @ H / tuning.sigma_m**2, F, Q)
        ts.append(t)
        out.append(sigma_m(P))
    return np.array(ts), np.array(out)
