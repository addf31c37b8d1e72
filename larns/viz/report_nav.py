"""The report's navigation figures (``larns report``, :mod:`larns.viz.report`): what a navigation
engineer checks first. Numbers come from :mod:`larns.analysis.consistency` (pure); this module only
draws them and returns the numbers for ``report.json``.

* ``station_map.png`` - plan (x, y) of the true and estimated stations with their 2-sigma horizontal
  error ellipses from the recorded covariance (offsets and ellipses magnified by a stated factor: the
  errors are centimetres to metres on a kilometre field), and beside it the final horizontal errors
  whitened by their own covariance against the 1-, 2- and 3-sigma circles;
* ``station_errors.png`` - per station, the horizontal error against ``2 sigma_h = 2 sqrt(Pxx + Pyy)``
  and the vertical error against ``2 sigma_z`` in separate panels;
* ``station_nees.png`` - NEES on the free coordinates over time with its chi-square band (dof and
  probability stated);
* ``aircraft_sigma.png`` - per aircraft algorithm, horizontal and vertical errors against their own
  2-sigma and the NEES with its per-sample band; ``aircraft_track.png`` - the tracks in plan.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ..analysis import consistency as C
from ..analysis import metrics as M

K_SIGMA = 2.0  # the ellipses and bounds drawn: 2 sigma


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(plt, fig, path: Path, tight: bool = True) -> None:
    if tight:
        fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def free_of(d: dict, sid: int) -> np.ndarray:
    """(3,) bool: the coordinates station ``sid`` has in the founders' frame (a founder 1-3 fewer; a
    station that joined a running field - ``join`` in its init record - all three): the unknowns of
    the survey's CRLB. (What an estimate carries at a given time is its covariance's business,
    :func:`larns.analysis.consistency.free_axes`.)"""
    from stations.estimators import free_mask

    init = d.get("inits", {}).get(sid)
    joined = bool(init and init.get("cfg", {}).get("join"))
    return free_mask(sid, founder=not joined)


def _magnification(span_m: float, biggest_m: float) -> float:
    """A 1-2-5 factor that draws ``biggest_m`` at about 6 % of ``span_m`` (1 if it already shows)."""
    if biggest_m <= 0 or not math.isfinite(biggest_m):
        return 1.0
    want = 0.06 * span_m / biggest_m
    if want <= 1:
        return 1.0
    e = 10 ** math.floor(math.log10(want))
    return float(max(m * e for m in (1, 2, 5) if m * e <= want))


def _ellipse_patch(center, axes, angle, **kw):
    from matplotlib.patches import Ellipse

    return Ellipse(center, 2 * axes[0], 2 * axes[1], angle=math.degrees(angle), fill=False, **kw)


def fig_station_map(d: dict, path: Path) -> dict[str, Any]:
    """Plan map of the final estimates (see the module doc); returns per station the final horizontal
    error, the 2-sigma ellipse (semi-axes, orientation) and whether the error is inside it, and the
    magnification used."""
    plt = _plt()
    st = {k: v for k, v in d["stations"].items() if v["truth_m"] is not None}
    if not st:
        return {}
    ids = sorted(st)
    T = np.array([st[i]["truth_m"] for i in ids], float)
    E = np.array([st[i]["pos_m"][-1] for i in ids], float)
    P2 = np.array([st[i]["cov_m2"][-1][:2, :2] for i in ids], float)
    axes, ang = C.ellipse(P2, K_SIGMA)
    err = E[:, :2] - T[:, :2]
    span = float(np.ptp(T[:, :2], axis=0).max()) or 1.0
    mag = _magnification(span, float(max(np.max(axes[:, 0]), np.max(np.hypot(*err.T)))))
    fig, (a, b) = plt.subplots(1, 2, figsize=(13, 6), gridspec_kw={"width_ratios": [1.6, 1]})
    for name, tr in sorted(d.get("ac_truth", {}).items()):
        a.plot(tr["pos_m"][:, 0], tr["pos_m"][:, 1], color="0.75", lw=0.8, zorder=0, label=f"aircraft {name} (truth)")
    a.plot(T[:, 0], T[:, 1], "^", color="tab:green", ms=8, label="true position")
    Em = T[:, :2] + mag * err
    a.plot(Em[:, 0], Em[:, 1], "o", color="tab:blue", ms=4, label=f"estimate (offset x{mag:g})")
    out: dict[str, Any] = {"magnification": mag, "sigma": K_SIGMA, "probability": C.ellipse_probability(K_SIGMA),
                           "stations": {}}
    W = []
    for k, sid in enumerate(ids):
        a.plot([T[k, 0], Em[k, 0]], [T[k, 1], Em[k, 1]], color="tab:blue", lw=0.8)
        if axes[k, 0] > 0:
            a.add_patch(_ellipse_patch(Em[k], mag * axes[k], ang[k], color="tab:red", lw=1.0))
        a.annotate(f"{sid}", T[k, :2], textcoords="offset points", xytext=(6, 6), fontsize=9)
        w = _whiten(err[k], P2[k], C.free_axes(st[sid]["cov_m2"][-1])[:2])
        out["stations"][sid] = {"eh_m": float(np.hypot(*err[k])), "semi_major_m": float(axes[k, 0]),
                                "semi_minor_m": float(axes[k, 1]), "angle_deg": float(math.degrees(ang[k])),
                                "inside": None if w is None else bool(np.hypot(*w) <= K_SIGMA)}
        if w is not None:
            W.append((sid, w))
    a.plot([], [], color="tab:red", lw=1.0, label=f"{K_SIGMA:g}-sigma horizontal ellipse "
                                                   f"({100 * out['probability']:.1f} %, x{mag:g})")
    a.set_aspect("equal", adjustable="datalim")
    a.set_xlabel("x, m (network frame)")
    a.set_ylabel("y, m (network frame)")
    a.set_title(f"Stations in plan at the end of the run; offsets and ellipses magnified x{mag:g}", fontsize=9)
    a.grid(True, alpha=0.3)
    a.legend(fontsize=8, loc="best")
    _whitened_panel(b, W)
    _save(plt, fig, path)
    return out


def _whiten(e2: np.ndarray, P2: np.ndarray, free2: np.ndarray) -> np.ndarray | None:
    """The horizontal error in units of its own covariance (``L^-1 e`` with ``L L^T = P`` on the free
    horizontal axes; a constrained axis stays 0), or None if nothing is free or P is singular."""
    f = np.asarray(free2, bool)
    if not f.any():
        return None
    try:
        L = np.linalg.cholesky(P2[np.ix_(f, f)])
    except np.linalg.LinAlgError:
        return None
    w = np.zeros(2)
    w[: int(f.sum())] = np.linalg.solve(L, e2[f])
    return w


def _whitened_panel(b, W) -> None:
    th = np.linspace(0, 2 * np.pi, 200)
    for k in (1, 2, 3):
        b.plot(k * np.cos(th), k * np.sin(th), color="tab:red" if k == K_SIGMA else "0.6",
               lw=1.2 if k == K_SIGMA else 0.7, ls="-" if k == K_SIGMA else "--",
               label=f"{k} sigma ({100 * C.ellipse_probability(k):.1f} %)")
    for sid, w in W:
        b.plot(w[0], w[1], "o", color="tab:blue", ms=4)
        b.annotate(str(sid), w, textcoords="offset points", xytext=(4, 4), fontsize=8)
    lim = max(3.5, max((float(np.abs(w).max()) for _, w in W), default=0.0) * 1.15)
    b.set_xlim(-lim, lim)
    b.set_ylim(-lim, lim)
    b.set_aspect("equal")
    b.set_xlabel("whitened horizontal error, sigma units")
    b.set_ylabel("sigma units")
    b.set_title("Final horizontal errors in their own covariance\n(on the axes each station estimates)", fontsize=9)
    b.grid(True, alpha=0.3)
    b.legend(fontsize=8, loc="upper right")


def fig_station_errors(d: dict, path: Path) -> dict[int, dict]:
    """Per station (the origin has zero error and zero covariance: numbers only), horizontal and
    vertical error each against its own 2-sigma, in separate panels; returns
    :func:`larns.analysis.metrics.station_numbers` plus the final horizontal / vertical errors and
    sigmas and the shares inside 2 sigma."""
    plt = _plt()
    st = {k: v for k, v in d["stations"].items() if v["truth_m"] is not None}
    out: dict[int, dict] = {}
    for sid in [k for k, v in st.items() if v["state"] == "frame"]:
        s = st.pop(sid)
        out[sid] = M.station_numbers(s, s["truth_m"], frame=True)
    if not st:
        return out
    n = len(st)
    fig, axes = plt.subplots(n, 2, figsize=(10, 1.7 * n + 1.0), squeeze=False, sharex=True)
    for row, (sid, s) in zip(axes, sorted(st.items())):
        hv = C.hv_errors(s, s["truth_m"])
        free = C.free_axes(s["cov_m2"][-1])
        out[sid] = {**M.station_numbers(s, s["truth_m"]), **_hv_numbers(hv, free)}
        _hv_panel(row[0], hv["t_s"], hv["eh_m"], hv["sigma_h_m"], "horizontal")
        if free[2]:
            _hv_panel(row[1], hv["t_s"], hv["ev_m"], hv["sigma_v_m"], "vertical")
        else:
            row[1].text(0.5, 0.5, "z fixed by the founders' frame (no vertical error)", ha="center", va="center",
                        transform=row[1].transAxes, fontsize=8, color="0.4")
            row[1].set_yticks([])
        row[0].set_ylabel(f"station {sid}\nm", fontsize=8)
    axes[0, 0].set_title(f"horizontal |e_xy| and {K_SIGMA:g} sigma_h = {K_SIGMA:g} sqrt(Pxx + Pyy)", fontsize=9)
    axes[0, 1].set_title(f"vertical |e_z| and {K_SIGMA:g} sigma_z = {K_SIGMA:g} sqrt(Pzz)", fontsize=9)
    for ax in (axes[0, 0], next((a for a in axes[:, 1] if a.lines), None)):
        if ax is not None:
            ax.legend(fontsize=7, loc="upper right")
    for ax in axes[-1]:
        ax.set_xlabel("fleet time, s")
    fig.suptitle("Station errors against their own sigma (network frame)", fontsize=10)
    h = fig.get_figheight()  # fixed margins (tight_layout over 2 n panels takes seconds)
    fig.subplots_adjust(left=0.09, right=0.98, top=1 - 0.75 / h, bottom=0.5 / h, hspace=0.25, wspace=0.15)
    _save(plt, fig, path, tight=False)
    return out


def _hv_panel(ax, t, e, s, what: str) -> None:
    ax.semilogy(t, np.maximum(e, 1e-3), lw=1.0, color="tab:blue", label=f"|{what} error|")
    ax.semilogy(t, np.maximum(K_SIGMA * s, 1e-3), lw=1.0, ls="--", color="tab:red", label=f"{K_SIGMA:g} sigma")
    ax.grid(True, which="both", alpha=0.3)
    ax.tick_params(labelsize=7)


def _hv_numbers(hv: dict, free: np.ndarray) -> dict[str, Any]:
    out = {"final_eh_m": float(hv["eh_m"][-1]), "final_sigma_h_m": float(hv["sigma_h_m"][-1]),
           "inside_2sigma_h": float(np.mean(hv["eh_m"] <= K_SIGMA * hv["sigma_h_m"]))}
    if free[2]:
        out.update(final_ev_m=float(hv["ev_m"][-1]), final_sigma_v_m=float(hv["sigma_v_m"][-1]),
                   inside_2sigma_v=float(np.mean(hv["ev_m"] <= K_SIGMA * hv["sigma_v_m"])))
    return out


def fig_nees(d: dict, st: dict[int, dict], grid: np.ndarray, path: Path, p: float = 0.95) -> dict[str, Any]:
    """NEES of the surveying stations ``st`` over ``grid`` (:func:`larns.analysis.consistency.nees_curve`)
    with its band; returns :func:`~larns.analysis.consistency.nees_numbers`."""
    c = C.nees_curve(st, {k: v["truth_m"] for k, v in st.items()}, grid, p)
    num = C.nees_numbers(c)
    if not num:
        return {}
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 4.4))
    for sid, q in sorted(c["per_station"].items()):
        ax.plot(grid, q, lw=0.6, alpha=0.45)
    ax.plot(grid, c["normalized"], "k", lw=1.6, label="all stations: sum NEES / sum dof")
    ax.fill_between(grid, c["lo"], c["hi"], color="tab:green", alpha=0.2,
                    label=f"{100 * p:g} % two-sided chi-square band, dof {num['dof']}")
    ax.axhline(1.0, color="tab:green", lw=0.8)
    ax.set_yscale("log")
    ax.set_xlabel("fleet time, s")
    ax.set_ylabel("NEES / dof (1 = consistent)")
    ax.set_title(f"Station NEES on the coordinates each estimates (thin: each station / its dof; at the end dof "
                 f"{num['dof']} over {len(c['per_station'])} stations;\nband exact for independent station errors)",
                 fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    _save(plt, fig, path)
    return num


# --------------------------------------------------------------------------- survey CRLB

def survey_bound(d: dict, st: dict[int, dict], grid: np.ndarray) -> np.ndarray | None:
    """(G,) CRLB of the RMS horizontal error over the surveying stations ``st`` for the ranges the
    recorded navs list and, with the poll, the finals the members took (``d["finals"]``: 4/3 of a range
    per exchange closed by its final, as ``larns bench survey``'s bound;
    :func:`larns.analysis.consistency.survey_crlb_curve`), stations at their true positions, each
    station's prior from its init record; None without the range noise (no journal recorded) or
    truth."""
    init = d.get("init")
    sig_d = (init or {}).get("cfg", {}).get("sigma_d_m")
    truth = {k: v["truth_m"] for k, v in d["stations"].items() if v["truth_m"] is not None}
    if not sig_d or len(truth) < 3 or not st:
        return None
    ids = sorted(truth)
    sigma0 = []
    for sid in ids:
        c = (d.get("inits", {}).get(sid) or {}).get("init_cov_m2")
        sigma0.append(math.sqrt(max(np.max(np.diag(np.asarray(c, float))), 0.0)) if c is not None else math.inf)
    ev = C.range_events(d.get("nav_msgs", {}))
    if not len(ev):
        return None
    b = C.survey_crlb_curve(ids, np.array([truth[i] for i in ids], float), ev, grid, float(sig_d),
                            np.array([free_of(d, i) for i in ids]), np.array(sigma0), d.get("finals"))
    return C.crlb_horizontal_rms(b, [ids.index(i) for i in sorted(st)])


# --------------------------------------------------------------------------- aircraft

def fig_aircraft_sigma(d: dict, path: Path) -> dict[str, Any]:
    """Per aircraft and algorithm: horizontal and vertical error against 2 sigma, and the NEES (3 dof)
    with its per-sample band; returns the shares inside 2 sigma and the NEES numbers of
    :func:`larns.analysis.metrics.aircraft_accuracy`."""
    rows = [(n, a, tr) for n in sorted(d["aircraft"]) for a, tr in sorted(d["aircraft"][n].items())
            if d["ac_truth"].get(n) is not None and len(tr["t_s"])]
    if not rows:
        return {}
    from scipy.stats import chi2

    plt = _plt()
    lo, hi = chi2.ppf(0.025, 3) / 3, chi2.ppf(0.975, 3) / 3
    fig, axes = plt.subplots(len(rows), 3, figsize=(14, 2.6 * len(rows) + 0.8), squeeze=False)
    out: dict[str, Any] = {}
    for ax, (name, algo, tr) in zip(axes, rows):
        truth = d["ac_truth"][name]
        e = tr["pos_m"] - M.interp_truth(truth, tr["t_s"])
        P = tr["cov_m2"]
        sh = np.sqrt(np.maximum(P[:, 0, 0] + P[:, 1, 1], 0.0))
        sv = np.sqrt(np.maximum(P[:, 2, 2], 0.0))
        eh, ev = np.hypot(e[:, 0], e[:, 1]), np.abs(e[:, 2])
        _hv_panel(ax[0], tr["t_s"], eh, sh, "horizontal")
        _hv_panel(ax[1], tr["t_s"], ev, sv, "vertical")
        q = C.nees_free({"t_s": tr["t_s"], "pos_m": e, "cov_m2": P}, np.zeros(3), np.ones(3, bool)) / 3  # all 3 free
        ax[2].semilogy(tr["t_s"], q, lw=0.7, color="k", label="NEES / 3")
        ax[2].axhspan(lo, hi, color="tab:green", alpha=0.2, label="95 % band of one sample (chi-square, 3 dof)")
        ax[2].grid(True, which="both", alpha=0.3)
        ax[2].tick_params(labelsize=7)
        ax[0].set_ylabel(f"{name} {algo}\nm", fontsize=8)
        acc = M.aircraft_accuracy(tr, truth)
        out.setdefault(name, {})[algo] = {
            "inside_2sigma_h": float(np.mean(eh <= K_SIGMA * sh)), "inside_2sigma_v": float(np.mean(ev <= K_SIGMA * sv)),
            **{k: acc.get(k) for k in ("nees_mean", "nees_n", "nees_n_eff", "nees_band", "max_eh_window_m")}}
    axes[0, 0].set_title(f"horizontal |e_xy| and {K_SIGMA:g} sigma_h", fontsize=9)
    axes[0, 1].set_title(f"vertical |e_z| and {K_SIGMA:g} sigma_z", fontsize=9)
    axes[0, 2].set_title("position NEES / dof (dof 3)", fontsize=9)
    axes[0, 0].legend(fontsize=7)
    axes[0, 2].legend(fontsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("fleet time, s")
    fig.suptitle("Aircraft errors against their own sigma (network frame)", fontsize=10)
    _save(plt, fig, path)
    return out


def fig_aircraft_track(d: dict, path: Path, after_s: float = 30.0) -> dict[str, Any]:
    """Plan of each aircraft's true and estimated tracks over the true stations, and beside it each
    algorithm's horizontal error (estimate minus the interpolated truth) from ``after_s`` on (the whole
    run if shorter) with the 2-sigma ellipse of its mean covariance there; returns per algorithm the
    horizontal error's mean and RMS over that window and the share inside each estimate's own 2-sigma
    ellipse."""
    names = [n for n in sorted(d["aircraft"]) if d["ac_truth"].get(n) is not None]
    if not names:
        return {}
    plt = _plt()
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(14, 6.5), gridspec_kw={"width_ratios": [1.2, 1]})
    S = np.array([v for v in d["truth"].values()], float).reshape(-1, 3)
    if len(S):
        ax.plot(S[:, 0], S[:, 1], "^", color="tab:green", ms=8, label="stations (truth)")
        for sid, p in d["truth"].items():
            ax.annotate(str(sid), p[:2], textcoords="offset points", xytext=(5, 5), fontsize=8)
    out: dict[str, Any] = {}
    for name in names:
        tr = d["ac_truth"][name]
        ax.plot(tr["pos_m"][:, 0], tr["pos_m"][:, 1], "k-", lw=1.6, label=f"{name} truth")
        ax.plot(tr["pos_m"][0, 0], tr["pos_m"][0, 1], "ko", ms=5)
        for algo, a in sorted(d["aircraft"][name].items()):
            if len(a["t_s"]):
                line, = ax.plot(a["pos_m"][:, 0], a["pos_m"][:, 1], lw=0.8, alpha=0.8, label=f"{name} {algo}")
                out.setdefault(name, {})[algo] = _error_cloud(bx, a, tr, after_s, line.get_color(), f"{name} {algo}")
    # the view: stations and true tracks with a margin (a first estimate far off is clipped)
    P = np.vstack([S[:, :2]] + [d["ac_truth"][n]["pos_m"][:, :2] for n in names])
    lo, hi = P.min(axis=0), P.max(axis=0)
    c, half = 0.5 * (lo + hi), 0.55 * max(float(np.max(hi - lo)), 100.0)
    ax.set_xlim(c[0] - half, c[0] + half)
    ax.set_ylim(c[1] - half, c[1] + half)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x, m (network frame)")
    ax.set_ylabel("y, m (network frame)")
    ax.set_title("Aircraft tracks in plan (dot: start; far estimates clipped)", fontsize=9)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    bx.plot([0], [0], "k+", ms=12)
    bx.set_aspect("equal", adjustable="datalim")
    bx.set_xlabel("x error, m")
    bx.set_ylabel("y error, m")
    bx.set_title(f"Horizontal error from {after_s:g} s on, with the {K_SIGMA:g}-sigma ellipse of the mean "
                 f"covariance\n({100 * C.ellipse_probability(K_SIGMA):.1f} % if the covariance is right)", fontsize=9)
    bx.grid(True, alpha=0.3)
    bx.legend(fontsize=8)
    _save(plt, fig, path)
    return out


def _error_cloud(bx, a: dict, truth: dict, after_s: float, color, label: str) -> dict[str, Any]:
    t = np.asarray(a["t_s"], float)
    win = t >= min(after_s, t[len(t) // 2])
    e = (a["pos_m"] - M.interp_truth(truth, t))[win, :2]
    P = a["cov_m2"][win][:, :2, :2]
    bx.plot(e[:, 0], e[:, 1], ".", ms=3, color=color, alpha=0.6, label=label)
    ax_, ang = C.ellipse(P.mean(axis=0), K_SIGMA)
    bx.add_patch(_ellipse_patch((0.0, 0.0), ax_, ang, color=color, lw=1.2))
    inside = [bool(w is not None and np.hypot(*w) <= K_SIGMA) for w in (_whiten(e[k], P[k], np.ones(2, bool))
                                                                          for k in range(len(e)))]
    return {"from_s": float(t[win][0]), "samples": int(win.sum()), "mean_eh_m": float(np.mean(np.hypot(*e.T))),
            "rms_eh_m": float(np.sqrt(np.mean(np.sum(e**2, axis=1)))),
            "inside_2sigma_ellipse": float(np.mean(inside)) if inside else None}
