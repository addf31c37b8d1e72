"""`larns report run.mcap -o DIR`: PNG figures and a Markdown summary from a recording alone.

Everything is computed from the log: station estimates against the station truth topics, aircraft
estimates against the aircraft truth topic, the TDMA timeline from the recorded range requests and
replies, loss from sequence gaps and latency from ``log_time - publish_time``. A recording killed
with SIGKILL works too (stream-read up to the damage).

Figures (``DIR/*.png``):

* ``station_errors.png`` - per station: error norm and the 3-sigma bound ``3 sqrt(trace P)`` vs time;
* ``survey_convergence.png`` - mean and max horizontal error over the surveying stations vs time
  (seed 000, fig. 3), with the mean 1-sigma horizontal bound;
* ``survey_histograms.png`` - histograms of horizontal and vertical errors over the second half of
  the run (seed 000, figs. 4 and 5);
* ``aircraft_errors.png`` - aircraft error per algorithm vs time with the posterior CRLB of the
  pseudorange filters' model for the recorded sequence of broadcasts, and the one-cycle snapshot
  CRLB (seed 003 eq. 7, ``nav.pcrb``) along the true track (if aircraft topics are present);
* ``tdma_timeline.png`` - who ranged whom when (first cycles; green = answered, red = no reply
  recorded) and the exchange count matrix over the whole run;
* ``network.png`` - message loss per kind (sequence gaps) and latency distributions per kind;
* ``sync_errors.png`` - each station's clock error against network time (estimate minus truth of the
  same stamp, ns) vs time with the RMS over the stations and the mean 1-sigma bound (docs/sync.md).

``DIR/report.md`` summarizes the numbers and embeds the figures; ``DIR/report.json`` holds them.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any, Sequence

import numpy as np


# --------------------------------------------------------------------------- data extraction

def extract(logs) -> dict[str, Any]:
    """Decoded time series from recorded wire messages (fleet time axis in seconds)."""
    from .mcaputil import merge
    from net import messages as M

    msgs = merge(logs)
    ep = logs[0].epoch_unix_s if logs else None
    speed = logs[0].speed if logs else 1.0
    t0_ns = msgs[0].log_time if msgs else 0

    def fleet(ns: int) -> float:
        return (ns * 1e-9 - ep) * speed if ep is not None else (ns - t0_ns) * 1e-9

    est: dict[int, list] = defaultdict(list)
    truth: dict[int, list[float]] = {}
    ac_est: dict[tuple[str, str], list] = defaultdict(list)
    ac_truth: dict[str, list] = defaultdict(list)
    reqs: list[tuple] = []
    rsps: set[tuple] = set()
    init_cfg: dict[int, dict] = {}
    lat: dict[str, list[float]] = defaultdict(list)
    navs: list[tuple[float, list[float]]] = []
    for m in msgs:
        if m.encoding != "msgpack":
            continue
        try:
            msg, phy = M.decode(m.data)
        except M.MessageError:
            continue
        k = msg["kind"]
        if k == "nav" and phy is not None and msg["state"] in ("frame", "surveying"):
            navs.append((phy["t_true_s"], phy["pos_m"]))
        if m.publish_time != m.log_time:
            lat[k].append((m.log_time - m.publish_time) * 1e-6)
        if k == "estimate":
            est[msg["src"]].append((msg["t_s"], msg["pos_m"], msg["cov_m2"], msg["n_updates"], msg["state"],
                                    fleet(m.log_time)))
        elif k == "truth":
            truth[msg["src"]] = msg["pos_m"]
        elif k == "ac_estimate":
            ac_est[(msg["src"], msg["algo"])].append((msg["t_s"], msg["pos_m"], msg["cov_m2"]))
        elif k == "ac_truth":
            ac_truth[msg["src"]].append((msg["t_s"], msg["pos_m"], msg.get("vel_m_s")))
        elif k == "range_req":
            reqs.append((msg["stamp_s"], msg["src"], msg["dst"], msg["seq"], msg["cycle"]))
        elif k == "range_rsp":
            rsps.add((msg["dst"], msg["src"], msg["req_seq"]))
        elif k == "core_init":
            init_cfg.setdefault(msg["src"], msg["record"])
    stations = {}
    for sid, rows in sorted(est.items()):
        rows.sort(key=lambda r: r[0])
        stations[sid] = {"t_s": np.array([r[0] for r in rows]), "pos_m": np.array([r[1] for r in rows], float),
                         "cov_m2": np.array([r[2] for r in rows], float), "n_updates": np.array([r[3] for r in rows]),
                         "state": rows[-1][4], "truth_m": np.asarray(truth[sid], float) if sid in truth else None}
    aircraft = {}
    for (name, algo), rows in sorted(ac_est.items()):
        rows.sort(key=lambda r: r[0])
        aircraft.setdefault(name, {})[algo] = {"t_s": np.array([r[0] for r in rows]),
                                               "pos_m": np.array([r[1] for r in rows], float),
                                               "cov_m2": np.array([r[2] for r in rows], float)}
    ac_tr = {}
    for name, rows in ac_truth.items():
        rows.sort(key=lambda r: r[0])
        ac_tr[name] = {"t_s": np.array([r[0] for r in rows]), "pos_m": np.array([r[1] for r in rows], float),
                       "vel_m_s": np.array([r[2] if r[2] is not None else [0.0, 0.0, 0.0] for r in rows], float)}
    return {"stations": stations, "aircraft": aircraft, "ac_truth": ac_tr, "reqs": reqs, "rsps": rsps,
            "init": init_cfg, "latency_ms": lat, "truth": truth, "navs": sorted(navs)}


def interp_truth(tr: dict, t_s: np.ndarray) -> np.ndarray:
    """Aircraft truth at times ``t_s`` (linear interpolation per axis); (K, 3)."""
    return np.stack([np.interp(t_s, tr["t_s"], tr["pos_m"][:, i]) for i in range(3)], axis=-1)


# --------------------------------------------------------------------------- figures

def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _hold(t_s: np.ndarray, values: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """(len(grid),) the last of ``values`` at or before each grid time (NaN before the first)."""
    out = np.full(grid.size, np.nan)
    k = np.searchsorted(t_s, grid, side="right") - 1
    ok = k >= 0
    out[ok] = values[k[ok]]
    return out


def _save_log_plot(plt, fig, ax, ylabel: str, title: str, path: Path) -> None:
    """Log y axis, labels, grid, legend; write the PNG and close the figure."""
    ax.set_yscale("log")
    ax.set_xlabel("fleet time, s")
    ax.set_ylabel(ylabel)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def fig_station_errors(d: dict, path: Path) -> dict[int, dict]:
    plt = _plt()
    st = {k: v for k, v in d["stations"].items() if v["truth_m"] is not None}
    out: dict[int, dict] = {}
    for sid in [k for k, v in st.items() if v["state"] == "frame"]:  # the origin: zero error, zero covariance
        s = st.pop(sid)
        out[sid] = {"final_err_m": float(np.linalg.norm(s["pos_m"][-1] - s["truth_m"])), "final_bound3_m": 0.0,
                    "inside_3sigma": math.nan, "n_estimates": int(len(s["t_s"])),
                    "n_updates": int(s["n_updates"][-1])}
    if not st:
        return out
    n = len(st)
    cols = min(3, n)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 2.8 * rows), squeeze=False, sharex=True)
    for ax, (sid, s) in zip(axes.flat, st.items()):
        e = np.linalg.norm(s["pos_m"] - s["truth_m"], axis=-1)
        b = 3.0 * np.sqrt(np.maximum(np.einsum("kii->k", s["cov_m2"]), 0.0))
        inside = float(np.mean(e <= b)) if e.size else math.nan
        ax.semilogy(s["t_s"], np.maximum(e, 1e-3), lw=1.0, label="|error|")
        ax.semilogy(s["t_s"], np.maximum(b, 1e-3), lw=1.0, ls="--", label="3 sigma")
        ax.set_title(f"station {sid} ({s['state']})", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        out[sid] = {"final_err_m": float(e[-1]), "final_bound3_m": float(b[-1]), "inside_3sigma": inside,
                    "n_estimates": int(e.size), "n_updates": int(s["n_updates"][-1])}
    for ax in axes.flat[n:]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("fleet time, s")
    for ax in axes[:, 0]:
        ax.set_ylabel("m")
    fig.suptitle("Station position error and 3-sigma bound (network frame)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return out


def _surveying(d: dict) -> dict[int, dict]:
    return {k: v for k, v in d["stations"].items() if v["truth_m"] is not None and v["state"] != "frame" and k != 1}


def fig_convergence(d: dict, path: Path, n_grid: int = 200) -> dict[str, Any]:
    plt = _plt()
    st = _surveying(d)
    if not st:
        return {}
    t_end = max(v["t_s"][-1] for v in st.values())
    t_beg = min(v["t_s"][0] for v in st.values())
    grid = np.linspace(t_beg, t_end, n_grid)
    H = np.full((len(st), n_grid), np.nan)
    S = np.full((len(st), n_grid), np.nan)
    for i, s in enumerate(st.values()):
        eh = np.linalg.norm((s["pos_m"] - s["truth_m"])[:, :2], axis=-1)
        sh = np.sqrt(np.maximum(s["cov_m2"][:, 0, 0] + s["cov_m2"][:, 1, 1], 0.0))
        H[i] = _hold(s["t_s"], eh, grid)  # last estimate at or before the grid time
        S[i] = _hold(s["t_s"], sh, grid)
    with np.errstate(all="ignore"):
        mean_h = np.nanmean(H, axis=0)
        max_h = np.nanmax(H, axis=0)
        mean_s = np.nanmean(S, axis=0)
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(grid, mean_h, label="mean horizontal error")
    ax.plot(grid, max_h, label="max horizontal error")
    ax.plot(grid, mean_s, ls="--", label="mean 1-sigma horizontal (own covariance)")
    _save_log_plot(plt, fig, ax, "m", f"Survey convergence ({len(st)} surveying stations; seed 000 fig. 3 style)",
                   path)
    sigma_d = None
    for rec in d["init"].values():
        sigma_d = rec["cfg"].get("sigma_d_m")
        break
    conv = None
    if sigma_d:
        below = np.where(np.isfinite(mean_h) & (mean_h < sigma_d))[0]
        # first time after which the mean error stays below sigma_d
        if below.size and np.all(mean_h[below[0]:][np.isfinite(mean_h[below[0]:])] < sigma_d):
            conv = float(grid[below[0]])
    return {"final_mean_horizontal_m": float(mean_h[-1]), "final_max_horizontal_m": float(max_h[-1]),
            "sigma_d_m": sigma_d, "time_mean_below_sigma_d_s": conv}


def fig_histograms(d: dict, path: Path) -> dict[str, Any]:
    plt = _plt()
    st = _surveying(d)
    if not st:
        return {}
    from stations.estimators import free_mask

    eh, ev = [], []
    for sid, s in st.items():
        half = s["t_s"] >= s["t_s"][0] + 0.5 * (s["t_s"][-1] - s["t_s"][0])
        e = (s["pos_m"] - s["truth_m"])[half]
        eh.append(np.linalg.norm(e[:, :2], axis=-1))
        if free_mask(sid)[2]:  # the frame fixes z of stations 1-3: no vertical error to show
            ev.append(e[:, 2])
    eh = np.concatenate(eh)
    ev = np.concatenate(ev) if ev else np.zeros(0)
    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.6))
    a.hist(eh, bins=30, color="tab:blue", alpha=0.8)
    a.set_xlabel("horizontal error, m")
    a.set_title("Horizontal errors (seed 000 fig. 4 style)", fontsize=9)
    b.hist(ev, bins=30, color="tab:orange", alpha=0.8)
    b.set_xlabel("vertical error, m")
    b.set_title("Vertical errors, stations with free z (seed 000 fig. 5 style)", fontsize=9)
    for ax in (a, b):
        ax.set_ylabel("count")
        ax.grid(True, alpha=0.3)
    fig.suptitle("Station errors over the second half of the run")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return {"horizontal_rms_m": float(np.sqrt(np.mean(eh**2))),
            "vertical_rms_m": float(np.sqrt(np.mean(ev**2))) if ev.size else math.nan,
            "samples": int(eh.size)}


def aircraft_crlb(d: dict, name: str, sigma_m: float, n_points: int = 150) -> tuple[np.ndarray, np.ndarray] | None:
    """One-cycle CRLB of the position (pseudoranges, unknown clock offset; seed 003 eq. 7) along the
    true track, with the stations at their true positions and their TDMA slot offsets. The velocity
    is a parameter too when one cycle has >= 8 stations (else known: one cycle cannot observe it)."""
    from nav.pcrb import crlb_cycle, fisher_cycle

    tr = d["ac_truth"].get(name)
    if tr is None or not d["truth"] or tr["t_s"].size < 2:
        return None
    ids = sorted(d["truth"])
    S = np.array([d["truth"][i] for i in ids], float)
    slot_s, cycle_s = 0.01, 1.0
    for rec in d["init"].values():
        cycle_s, slot_s = rec["tdma"]
        break
    t_rel = np.array([((i - 1) * slot_s) % cycle_s for i in ids])
    k = np.unique(np.linspace(0, tr["t_s"].size - 1, n_points).astype(int))
    # position + clock offset (+ velocity when one cycle has enough stations to observe it)
    J = fisher_cycle(tr["pos_m"][k], tr["vel_m_s"][k], S, t_rel, sigma_m, clock=True, velocity=len(ids) >= 8)
    b = crlb_cycle(J)
    return tr["t_s"][k], b["total_m"]


def aircraft_pcrb(d: dict, name: str, tuning) -> tuple[np.ndarray, np.ndarray] | None:
    """Posterior CRLB (Tichavsky et al. 1998; covariance form as in ``nav.pcrb``) of the pseudorange
    filters' own model (CV + clock offset/drift, ``aircraft.estimators.Tuning``) for the sequential
    TDMA measurements the aircraft made: one scalar pseudorange per recorded nav broadcast, from the
    sender's true position at its true transmit time, along the recorded true track. Returns
    (times, sqrt of the position-bound trace)."""
    from aircraft import models as mdl

    tr = d["ac_truth"].get(name)
    navs = [n for n in d["navs"] if tr is not None and tr["t_s"][0] - 1.0 <= n[0] <= tr["t_s"][-1]]
    if tr is None or len(navs) < 8:
        return None
    layout = mdl.StateLayout("pr", drift=tuning.drift_state)
    n = layout.n
    P = tuning.p0(layout)
    t_prev = navs[0][0]
    eye = np.eye(n)
    ts, out = [], []
    for t, pos in navs:
        dt = max(t - t_prev, 0.0)
        t_prev = t
        if dt > 0:
            F = mdl.cv_transition(n, dt)
            P = F @ P @ F.T + mdl.cv_noise(n, dt, tuning.q_acc, tuning.q_clock, tuning.q_drift, tuning.q_acc_z)
        X = np.zeros(n)
        X[:3] = interp_truth(tr, np.array([t]))[0]
        H = mdl.jac_pr(X, np.asarray(pos, float)[None])  # (1, n)
        Jz = H.T @ H / tuning.sigma_m**2
        P = np.linalg.solve(eye + P @ Jz, P)
        P = 0.5 * (P + P.T)
        ts.append(t)
        out.append(np.sqrt(max(np.trace(P[:3, :3]), 0.0)))
    return np.array(ts), np.array(out)


def fig_aircraft(d: dict, path: Path, sigma_m: float | None, tuning=None) -> dict[str, Any]:
    plt = _plt()
    out: dict[str, Any] = {}
    if not d["aircraft"]:
        return out
    names = sorted(d["aircraft"])
    fig, axes = plt.subplots(len(names), 1, figsize=(8, 3.6 * len(names)), squeeze=False)
    for ax, name in zip(axes[:, 0], names):
        tr = d["ac_truth"].get(name)
        out[name] = {}
        for algo, a in sorted(d["aircraft"][name].items()):
            if tr is None:
                continue
            e = np.linalg.norm(a["pos_m"] - interp_truth(tr, a["t_s"]), axis=-1)
            ax.semilogy(a["t_s"], np.maximum(e, 1e-3), lw=0.9, label=f"{algo} |error|")
            tail = e[len(e) // 10:]
            out[name][algo] = {"n": int(e.size), "final_err_m": float(e[-1]),
                               "rms_err_m": float(np.sqrt(np.mean(tail**2))) if tail.size else math.nan}
        if tuning is not None:
            pc = aircraft_pcrb(d, name, tuning)
            if pc is not None:
                ax.semilogy(pc[0], pc[1], "k-", lw=1.4, label="PCRB, pseudorange filter model")
                out[name]["pcrb_final_m"] = float(pc[1][-1])
        if sigma_m:
            cr = aircraft_crlb(d, name, sigma_m)
            if cr is not None:
                ok = np.isfinite(cr[1])
                ax.semilogy(cr[0][ok], cr[1][ok], "k--", lw=1.2, label=f"one-cycle CRLB (sigma {sigma_m:g} m)")
                out[name]["crlb_median_m"] = float(np.median(cr[1][ok])) if ok.any() else math.inf
        ax.set_title(f"aircraft {name}")
        ax.set_xlabel("fleet time, s")
        ax.set_ylabel("position error, m")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return out


def fig_tdma(d: dict, path: Path, n_cycles: int = 4) -> dict[str, Any]:
    plt = _plt()
    reqs = sorted(d["reqs"])
    if not reqs:
        return {}
    ids = sorted({r[1] for r in reqs} | {r[2] for r in reqs})
    idx = {s: i for i, s in enumerate(ids)}
    cycles = sorted({r[4] for r in reqs})
    # the first cycles in which (nearly) everybody is ranging
    c0 = cycles[min(len(cycles) - 1, 1)]
    show = [r for r in reqs if c0 <= r[4] < c0 + n_cycles]
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.2), gridspec_kw={"width_ratios": [2.2, 1]})
    answered = 0
    for t, src, dst, seq, _c in show:
        ok = (src, dst, seq) in d["rsps"]
        answered += ok
        col = "tab:green" if ok else "tab:red"
        a.annotate("", xy=(t, dst), xytext=(t, src),
                   arrowprops=dict(arrowstyle="->", color=col, lw=1.0, alpha=0.8))
        a.plot([t], [src], "o", color=col, ms=3)
    a.set_yticks(ids)
    a.set_xlabel("initiator's time of the request, s")
    a.set_ylabel("station (arrow: initiator -> addressee)")
    a.set_title(f"TDMA timeline, cycles {c0}..{c0 + n_cycles - 1} (green: reply recorded)", fontsize=9)
    a.grid(True, alpha=0.3)
    Mx = np.zeros((len(ids), len(ids)), int)
    for _t, src, dst, seq, _c in reqs:
        if (src, dst, seq) in d["rsps"]:
            Mx[idx[src], idx[dst]] += 1
    im = b.imshow(Mx, cmap="viridis")
    b.set_xticks(range(len(ids)))
    b.set_xticklabels(ids, fontsize=7)
    b.set_yticks(range(len(ids)))
    b.set_yticklabels(ids, fontsize=7)
    b.set_xlabel("addressee")
    b.set_ylabel("initiator")
    b.set_title("answered exchanges (whole run)", fontsize=9)
    fig.colorbar(im, ax=b, shrink=0.8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    n_ans = sum(1 for r in reqs if (r[1], r[2], r[3]) in d["rsps"])
    return {"requests": len(reqs), "answered": n_ans, "answered_pct": 100.0 * n_ans / len(reqs)}


def fig_network(info: dict, d: dict, path: Path) -> None:
    plt = _plt()
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 3.8))
    kinds = list(info.get("loss", {}))
    a.bar(kinds, [info["loss"][k]["loss_pct"] for k in kinds], color="tab:red")
    a.set_ylabel("lost, % (sequence gaps)")
    a.set_title("Message loss by kind (as seen by the recorder)", fontsize=9)
    a.tick_params(axis="x", rotation=45, labelsize=8)
    a.grid(True, axis="y", alpha=0.3)
    lat = d["latency_ms"]
    for k in sorted(lat):
        v = np.sort(np.asarray(lat[k]))
        if v.size:
            b.plot(np.maximum(v, 1e-3), np.arange(1, v.size + 1) / v.size, label=k)
    b.set_xscale("log")
    b.set_xlabel("latency log_time - publish_time, wall ms")
    b.set_ylabel("fraction")
    b.set_title("Latency distribution by kind", fontsize=9)
    b.grid(True, which="both", alpha=0.3)
    if lat:
        b.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# --------------------------------------------------------------------------- the report

def _aircraft_config(logs, scenario: str | None):
    """The scenario's aircraft configuration (scenario from --scenario or the recording's metadata)."""
    name = scenario or (logs[0].larns_meta.get("scenario") if logs else None)
    if not name:
        return None
    try:
        from aircraft.config import from_scenario
        from net.scenario import load

        return from_scenario(load(name))
    except Exception:
        return None


def sync_series(logs) -> dict[int, np.ndarray]:
    """Per station: rows ``[t_s, error_ns, sigma_ns]`` of its clock estimate against the truth of the
    same stamp (the estimate's ``clock_offset_s`` minus the truth's ``clock_error_s``)."""
    from net import messages as M

    from .mcaputil import merge

    est: dict[int, dict[float, tuple[float, float, float]]] = defaultdict(dict)
    tru: dict[int, dict[float, float]] = defaultdict(dict)
    for m in merge(logs):
        if m.encoding != "msgpack" or not (m.topic.endswith("/estimate") or m.topic.endswith("/truth")):
            continue
        try:
            msg, _ = M.decode(m.data)
        except M.MessageError:
            continue
        if msg["kind"] == "estimate" and "clock_offset_s" in msg:
            est[msg["src"]][msg["stamp_s"]] = (msg["t_s"], msg["clock_offset_s"], msg.get("clock_offset_sd_s", 0.0))
        elif msg["kind"] == "truth" and "clock_error_s" in msg:
            tru[msg["src"]][msg["stamp_s"]] = msg["clock_error_s"]
    out = {}
    for sid, e in est.items():
        rows = sorted((e[k][0], (e[k][1] - tru[sid][k]) * 1e9, e[k][2] * 1e9) for k in e.keys() & tru[sid].keys())
        if rows:
            out[sid] = np.array(rows)
    return out


def fig_sync(series: dict[int, np.ndarray], path: Path, after_s: float = 60.0) -> dict[str, Any]:
    """Sync-error figure (survey-convergence style) and its numbers."""
    st = {k: v for k, v in series.items() if k != 1}
    if not st:
        return {}
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4))
    for sid, r in sorted(st.items()):
        ax.plot(r[:, 0], np.abs(r[:, 1]), lw=0.7, alpha=0.6)
    t_end = max(r[-1, 0] for r in st.values())
    t_beg = min(r[0, 0] for r in st.values())
    grid = np.linspace(t_beg, t_end, 200)
    E = np.full((len(st), grid.size), np.nan)
    S = np.full((len(st), grid.size), np.nan)
    for i, r in enumerate(st.values()):
        E[i], S[i] = _hold(r[:, 0], r[:, 1], grid), _hold(r[:, 0], r[:, 2], grid)
    with np.errstate(all="ignore"):
        rms = np.sqrt(np.nanmean(E**2, axis=0))
        sig = np.nanmean(S, axis=0)
    ax.plot(grid, rms, "k", lw=1.5, label="RMS over the stations")
    ax.plot(grid, sig, "k--", lw=1.0, label="mean 1-sigma (own covariance)")
    _save_log_plot(plt, fig, ax, "|clock error| vs network time, ns",
                   f"Network time: clock error of {len(st)} stations (station 1 = network time)", path)
    late = np.concatenate([r[r[:, 0] >= after_s, 1] for r in st.values()])
    return {"final_rms_ns": float(rms[-1]), "stations": len(st),
            "max_abs_ns_after_60s": float(np.max(np.abs(late))) if late.size else None,
            "rms_ns_after_60s": float(np.sqrt(np.mean(late**2))) if late.size else None}


def make_report(paths: Sequence[str | Path], outdir: str | Path, scenario: str | None = None,
                sigma_m: float | None = None) -> dict[str, Any]:
    from .info import summarize
    from .mcaputil import read_logs

    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    logs = read_logs(paths)
    info = summarize(paths, logs=logs)
    d = extract(logs)
    res: dict[str, Any] = {"files": [{"path": f["path"], "complete": f["complete"], "error": f["error"]}
                                     for f in info["files"]],
                           "messages": info["messages"], "duration_s": info.get("duration_s", 0.0),
                           "figures": []}
    figs = []
    if d["stations"]:
        res["stations"] = fig_station_errors(d, out / "station_errors.png")
        if res["stations"]:
            figs.append(("Station errors and 3-sigma bounds", "station_errors.png"))
        res["convergence"] = fig_convergence(d, out / "survey_convergence.png")
        if res["convergence"]:
            figs.append(("Survey convergence", "survey_convergence.png"))
        res["histograms"] = fig_histograms(d, out / "survey_histograms.png")
        if res["histograms"]:
            figs.append(("Error histograms", "survey_histograms.png"))
        res["sync"] = fig_sync(sync_series(logs), out / "sync_errors.png")
        if res["sync"]:
            figs.append(("Network time: clock errors", "sync_errors.png"))
    if d["aircraft"]:
        acfg = _aircraft_config(logs, scenario)
        sig = sigma_m if sigma_m is not None else (acfg.sigma_m if acfg is not None else None)
        if sig is None:
            for rec in d["init"].values():
                sig = rec["cfg"].get("sigma_d_m")
                break
        if acfg is not None:
            tuning = acfg.tuning
        else:
            from dataclasses import replace

            from aircraft.estimators import Tuning

            tuning = replace(Tuning(), sigma_m=float(sig or 0.5))
        res["aircraft"] = fig_aircraft(d, out / "aircraft_errors.png", sig, tuning)
        figs.append(("Aircraft errors with the CRLB", "aircraft_errors.png"))
    res["tdma"] = fig_tdma(d, out / "tdma_timeline.png")
    if res["tdma"]:
        figs.append(("TDMA timeline", "tdma_timeline.png"))
    fig_network(info, d, out / "network.png")
    figs.append(("Message loss and latency", "network.png"))
    res["loss"] = info.get("loss", {})
    res["loss_total"] = info.get("loss_total", {})
    res["latency_ms"] = info.get("latency_ms", {})
    res["figures"] = [f for _, f in figs]
    (out / "report.json").write_text(json.dumps(res, indent=1, default=float))
    (out / "report.md").write_text(markdown(res, info, figs))
    return res


def _fmt(x: Any, nd: int = 2) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        return "-" if math.isnan(x) else f"{x:.{nd}f}"
    return str(x)


def markdown(res: dict, info: dict, figs: list[tuple[str, str]]) -> str:
    L = ["# LARNS run report", ""]
    for f in res["files"]:
        L.append(f"- `{f['path']}`: {'complete' if f['complete'] else 'INCOMPLETE (' + str(f['error']) + ')'}")
    md = info["files"][0]["metadata"].get("larns", {}) if info["files"] else {}
    if md:
        L.append("- metadata: " + ", ".join(f"{k}={v}" for k, v in sorted(md.items())))
    L.append(f"- {res['messages']} messages, {res['duration_s']:.1f} s wall"
             + (f" ({info['fleet_duration_s']:.1f} s fleet time)" if "fleet_duration_s" in info else ""))
    L.append("")
    if res.get("stations"):
        L += ["## Stations", "", "| station | updates | final error m | final 3-sigma m | inside 3-sigma |",
              "|---:|---:|---:|---:|---:|"]
        for sid, s in res["stations"].items():
            L.append(f"| {sid} | {s['n_updates']} | {_fmt(s['final_err_m'])} | {_fmt(s['final_bound3_m'])} | "
                     f"{_fmt(100 * s['inside_3sigma'], 0)} % |")
        L.append("")
    c = res.get("convergence") or {}
    if c:
        L.append(f"Survey: final mean horizontal error {_fmt(c['final_mean_horizontal_m'])} m, max "
                 f"{_fmt(c['final_max_horizontal_m'])} m; mean error below sigma_d = {_fmt(c['sigma_d_m'])} m "
                 f"from t = {_fmt(c['time_mean_below_sigma_d_s'], 1)} s on.")
    sy = res.get("sync") or {}
    if sy:
        L.append(f"Network time: final RMS clock error {_fmt(sy['final_rms_ns'])} ns over {sy['stations']} stations; "
                 f"after 60 s RMS {_fmt(sy['rms_ns_after_60s'])} ns, largest {_fmt(sy['max_abs_ns_after_60s'])} ns.")
    h = res.get("histograms") or {}
    if h:
        L.append(f"Second half of the run: horizontal RMS {_fmt(h['horizontal_rms_m'])} m, vertical RMS "
                 f"{_fmt(h['vertical_rms_m'])} m ({h['samples']} samples).")
    L.append("")
    if res.get("aircraft"):
        L += ["## Aircraft", "", "| aircraft | algorithm | estimates | final error m | RMS error m (after 10 %) |",
              "|---|---|---:|---:|---:|"]
        for name, per in res["aircraft"].items():
            for algo, a in per.items():
                if isinstance(a, dict):
                    L.append(f"| {name} | {algo} | {a['n']} | {_fmt(a['final_err_m'])} | {_fmt(a['rms_err_m'])} |")
            if "pcrb_final_m" in per:
                L.append(f"| {name} | PCRB (pseudorange filter model) | | {_fmt(per['pcrb_final_m'])} | |")
            if "crlb_median_m" in per:
                L.append(f"| {name} | one-cycle CRLB (median) | | {_fmt(per['crlb_median_m'])} | |")
        L.append("")
    t = res.get("tdma") or {}
    if t:
        L.append(f"## TDMA\n\n{t['requests']} range requests recorded, {t['answered']} answered "
                 f"({_fmt(t['answered_pct'], 1)} %).\n")
    L += ["## Network", "", "| kind | received | missing | loss % | p50 latency ms | p99 latency ms |",
          "|---|---:|---:|---:|---:|---:|"]
    for k, v in res.get("loss", {}).items():
        la = res.get("latency_ms", {}).get(k, {})
        L.append(f"| {k} | {v['received']} | {v['missing']} | {_fmt(v['loss_pct'])} | {_fmt(la.get('p50'))} | "
                 f"{_fmt(la.get('p99'))} |")
    L.append("")
    L += ["## Figures", ""]
    for title, f in figs:
        L += [f"### {title}", "", f"![{title}]({f})", ""]
    return "\n".join(L)


def cmd_report(args: argparse.Namespace) -> int:
    try:
        res = make_report(args.files, args.output, scenario=args.scenario, sigma_m=args.sigma)
    except (OSError, ValueError) as e:
        print(f"larns report: {e}", file=sys.stderr)
        return 1
    print(f"[report] {len(res['figures'])} figures + report.md in {args.output}", file=sys.stderr)
    return 0


def register(sub) -> None:
    p = sub.add_parser("report", help="PNG figures and a Markdown summary of a recording",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("files", nargs="+", help="MCAP recording(s), merged by log time")
    p.add_argument("-o", "--output", default="report", help="output folder (default ./report)")
    p.add_argument("--scenario", default=None, help="scenario (for the aircraft's ranging sigma in the CRLB); "
                                                    "default: the recording's metadata")
    p.add_argument("--sigma", type=float, default=None, help="aircraft ranging sigma for the CRLB, m")
    p.set_defaults(func=cmd_report)
