"""`larns report run.mcap -o DIR`: PNG figures and a Markdown summary from a recording alone.

Everything is computed from the log: station estimates against the station truth topics, aircraft
estimates against the aircraft truth topic, the TDMA timeline from the recorded range requests and
replies, loss from sequence gaps and latency from ``log_time - publish_time``. A recording killed
with SIGKILL works too (stream-read up to the damage).

Figures (``DIR/*.png``; the stations' and the aircraft's against their own covariance are drawn by
:mod:`larns.viz.report_nav` from :mod:`larns.analysis.consistency`):

* ``station_map.png`` - the stations in plan, true and estimated, with 2-sigma horizontal error
  ellipses (magnification stated), and the final errors whitened by their own covariance;
* ``station_errors.png`` - per station: horizontal error against 2 sigma_h and vertical error against
  2 sigma_z, in separate panels;
* ``survey_convergence.png`` - mean, RMS and max horizontal error over the surveying stations vs time
  (seed 000, fig. 3) with the mean 1-sigma and the centralized CRLB of the RMS horizontal error for
  the ranges measured so far (``nav.crlb``, the bound of ``larns bench survey``);
* ``station_nees.png`` - the stations' NEES / dof on their free coordinates with its 95 % chi-square
  band (dof stated);
* ``survey_histograms.png`` - histograms of horizontal and vertical errors over the second half of
  the run (seed 000, figs. 4 and 5);
* ``aircraft_errors.png`` - aircraft error per algorithm vs time with the posterior CRLB of the
  pseudorange filters' model for the recorded sequence of broadcasts, and the one-cycle snapshot
  CRLB (seed 003 eq. 7, ``nav.pcrb``) along the true track (if aircraft topics are present);
* ``aircraft_sigma.png`` / ``aircraft_track.png`` - each algorithm's horizontal and vertical error
  against its own 2 sigma and its NEES; the tracks in plan and the horizontal error cloud;
* ``vehicle_errors.png`` - each ground vehicle's position error and 3-sigma vs time (if present);
* ``tdma_timeline.png`` - one TDMA cycle on network time with its slots drawn (arrows initiator ->
  addressee, green = answered, red = no reply recorded; nav broadcasts) and the exchange count
  matrix over the whole run;
* ``network.png`` - message loss per kind (sequence gaps) and latency distributions per kind
  (negative latencies drawn: the stamps are on the senders' emulated clocks);
* ``sync_errors.png`` - each station's clock error against network time (estimate minus truth of the
  same stamp, ns) vs time with the RMS over the stations and the mean 1-sigma bound (docs/sync.md).

``DIR/report.md`` summarizes the numbers and embeds the figures; ``DIR/report.json`` holds them
(strict JSON: ``null`` where a number is not finite).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..analysis import metrics as M


# --------------------------------------------------------------------------- data extraction

def extract(rec) -> dict[str, Any]:
    """The series the figures draw, from a decoded recording (:class:`larns.log.series.Recording`)."""
    stations = {}
    for sid, st in sorted(rec.stations.items()):
        if st.estimates:
            tr = st.track()
            stations[sid] = {**{k: tr[k] for k in ("t_s", "pos_m", "cov_m2", "n_updates", "state")},
                             "truth_m": np.asarray(st.truth_m, float) if st.truth_m is not None else None}
    aircraft = {name: {algo: a.track(algo) for algo in a.algos} for name, a in sorted(rec.aircraft.items())
                if a.estimates}
    ac_tr = {name: a.truth_track() for name, a in rec.aircraft.items() if a.truths}
    ac_int = {name: {algo: a.integrity(algo) for algo in a.algos} for name, a in sorted(rec.aircraft.items())
              if a.estimates}
    return {"stations": stations, "aircraft": aircraft, "ac_truth": ac_tr, "ac_integrity": ac_int,
            "reqs": rec.range_requests,
            "rsps": rec.range_replies, "init": rec.init_record, "latency_ms": rec.net.latency_ms,
            "truth": rec.truth_positions, "slots": {sid: st.slot for sid, st in rec.stations.items()},
            "navs": rec.nav_truth, "inits": {sid: st.init for sid, st in rec.stations.items() if st.init},
            "nav_msgs": {sid: [m for _, m in st.nav] for sid, st in rec.stations.items()},
            "finals": _finals(rec),
            "clock_err": {sid: _clock_errors(st) for sid, st in rec.stations.items()}}


def _finals(rec) -> np.ndarray | None:
    """Protocol v2's finals the members took (:func:`larns.analysis.consistency.final_events`, from
    the recorded journals); None for a recording without polls."""
    if not any(m.get("poll") for st in rec.stations.values() for _, m in st.nav):
        return None
    from ..analysis.consistency import final_events
    from ..log.series import collect_journals

    return final_events(collect_journals(rec.messages))


def _clock_errors(st) -> tuple[np.ndarray, np.ndarray]:
    """A station's true clock error against network time at its own stamps: ``(stamp_s, error_s)``
    sorted (from its truth topic; empty where not recorded)."""
    rows = sorted((t["stamp_s"], t["clock_error_s"]) for t in st.truths if "clock_error_s" in t and "stamp_s" in t)
    return np.array([r[0] for r in rows], float), np.array([r[1] for r in rows], float)


def _network_time(d: dict, sid: int, stamp_s: float) -> float:
    """A station's own stamp on network time: ``stamp - clock error`` (interpolated; the stamp itself
    when the station's clock error is not recorded)."""
    t, e = d.get("clock_err", {}).get(sid, (np.zeros(0), np.zeros(0)))
    return float(stamp_s - np.interp(stamp_s, t, e)) if len(t) else float(stamp_s)


# --------------------------------------------------------------------------- figures

def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


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


def _surveying(d: dict) -> dict[int, dict]:
    return {k: v for k, v in d["stations"].items() if v["truth_m"] is not None and v["state"] != "frame" and k != 1}


def fig_convergence(d: dict, path: Path, n_grid: int = 200) -> dict[str, Any]:
    """Mean, RMS and max horizontal error over the surveying stations with their mean own 1-sigma and
    the centralized CRLB of the RMS horizontal error for the ranges measured so far
    (:func:`larns.viz.report_nav.survey_bound`, the bound of ``larns bench survey``); the NEES figure
    on the same grid (``station_nees.png`` beside ``path``)."""
    from . import report_nav as RN
    from ..analysis.consistency import rms_horizontal

    plt = _plt()
    st = _surveying(d)
    if not st:
        return {}
    truths = {k: v["truth_m"] for k, v in st.items()}
    grid, mean_h, max_h, mean_s = M.survey_convergence(st, truths, n_grid)
    rms_h = rms_horizontal(st, truths, grid)
    bound = RN.survey_bound(d, st, grid)
    fig, ax = plt.subplots(figsize=(8, 4.4))
    ax.plot(grid, mean_h, label="mean horizontal error")
    ax.plot(grid, rms_h, label="RMS horizontal error")
    ax.plot(grid, max_h, label="max horizontal error")
    ax.plot(grid, mean_s, ls="--", label="mean 1-sigma horizontal (own covariance)")
    if bound is not None:
        ax.plot(grid, bound, "k-.", lw=1.4, label="CRLB of the RMS horizontal error (centralized, ranges so far)")
    _save_log_plot(plt, fig, ax, "horizontal error, m",
                   f"Survey convergence ({len(st)} surveying stations; seed 000 fig. 3 style)", path)
    sigma_d = d["init"]["cfg"].get("sigma_d_m") if d["init"] else None
    # first time after which the mean error stays below sigma_d
    conv = M.first_time_staying_below(grid, mean_h, sigma_d) if sigma_d else None
    out = {"final_mean_horizontal_m": float(mean_h[-1]), "final_max_horizontal_m": float(max_h[-1]),
           "final_rms_horizontal_m": float(rms_h[-1]), "sigma_d_m": sigma_d, "time_mean_below_sigma_d_s": conv,
           "final_crlb_horizontal_rms_m": None if bound is None else float(bound[-1]),
           "final_rms_over_crlb": None if bound is None else float(rms_h[-1] / bound[-1])}
    out["nees"] = RN.fig_nees(d, st, grid, path.with_name("station_nees.png"))
    return out


def fig_histograms(d: dict, path: Path) -> dict[str, Any]:
    plt = _plt()
    st = _surveying(d)
    if not st:
        return {}
    from stations.estimators import free_mask

    # the frame fixes z of stations 1-3: no vertical error to show
    eh, ev = M.second_half_errors(st, {k: v["truth_m"] for k, v in st.items()}, lambda sid: free_mask(sid)[2])
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
    return M.histogram_numbers(eh, ev)


def aircraft_crlb(d: dict, name: str, sigma_m: float, n_points: int = 150) -> tuple[np.ndarray, np.ndarray] | None:
    """One-cycle CRLB along the true track (:func:`larns.analysis.metrics.aircraft_crlb`) with each
    station's recorded slot (the TDMA plan's default slot where none was recorded)."""
    from stations.tdma import TdmaPlan

    cycle_s, slot_s = tuple(d["init"]["tdma"]) if d["init"] else (1.0, 0.01)
    plan = TdmaPlan(cycle_s=cycle_s, slot_s=slot_s)
    slots = {i: (d["slots"].get(i) if d["slots"].get(i) is not None else plan.default_slot(i)) for i in d["truth"]}
    return M.aircraft_crlb(d["ac_truth"].get(name), d["truth"], slots, (cycle_s, slot_s), sigma_m, n_points)


def aircraft_pcrb(d: dict, name: str, tuning) -> tuple[np.ndarray, np.ndarray] | None:
    """Posterior CRLB of the pseudorange filters' model (:func:`larns.analysis.metrics.aircraft_pcrb`)."""
    return M.aircraft_pcrb(d["ac_truth"].get(name), d["navs"], tuning)


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
            e, out[name][algo] = M.aircraft_numbers(a, tr)
            ax.semilogy(a["t_s"], np.maximum(e, 1e-3), lw=0.9, label=f"{algo} |error|")
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


def fig_vehicles(rec, path: Path) -> dict[str, dict]:
    """Each ground vehicle's 3-D position error against its truth of the same time, with its 3-sigma
    (root of the covariance trace), vs fleet time; returns :func:`larns.analysis.summary.vehicle_row`."""
    from ..analysis.summary import vehicle_row

    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 4.5))
    out = {}
    for name, v in sorted(rec.vehicles.items()):
        e = v.errors()
        out[name] = vehicle_row(v)
        if not e["t_s"].size:
            continue
        ax.plot(e["t_s"], np.maximum(e["err_m"], 1e-3), lw=0.8, label=f"{name} error")
        ax.plot(e["t_s"], 3 * e["sigma_m"], lw=0.8, ls="--", label=f"{name} 3 sigma")
    _save_log_plot(plt, fig, ax, "position error, m", "ground vehicle: error and 3-sigma", path)
    return out


def _vehicle_markdown(vehicles: dict[str, dict]) -> list[str]:
    if not vehicles:
        return []
    L = ["## Ground vehicles", "", "| vehicle | estimates | RMS error m | second half m | p95 m | max m | final m "
         "| final sigma m |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for name, v in vehicles.items():
        L.append(f"| {name} | {v['estimates']} | {_fmt(v.get('rms_err_m'))} | {_fmt(v.get('rms_err_second_half_m'))} | "
                 f"{_fmt(v.get('p95_err_m'))} | {_fmt(v.get('max_err_m'))} | {_fmt(v.get('final_err_m'))} | "
                 f"{_fmt(v.get('final_sigma_m'))} |")
    return L + [""]


def _tdma_plan(d: dict) -> tuple[float, float]:
    """(cycle_s, slot_s) from the recorded init record (the TDMA plan's defaults without one)."""
    if d["init"]:
        return tuple(map(float, d["init"]["tdma"]))
    from stations.tdma import TdmaPlan

    plan = TdmaPlan()
    return float(plan.cycle_s), float(plan.slot_s)


def _busiest_cycle(reqs: list) -> int:
    """The middle one of the cycles with the most range requests recorded."""
    count: dict[int, int] = {}
    for r in reqs:
        count[r[4]] = count.get(r[4], 0) + 1
    top = max(count.values())
    best = sorted(c for c, n in count.items() if n == top)
    return best[len(best) // 2]


def _exchange_matrix(fig, b, reqs: list, rsps: set, ids: list[int]) -> None:
    """Answered exchanges of the whole run per (initiator, addressee)."""
    idx = {s: i for i, s in enumerate(ids)}
    Mx = np.zeros((len(ids), len(ids)), int)
    for _t, src, dst, seq, _c in reqs:
        if (src, dst, seq) in rsps:
            Mx[idx[src], idx[dst]] += 1
    im = b.imshow(Mx, cmap="viridis")
    b.set_xticks(range(len(ids)))
    b.set_xticklabels(ids, fontsize=7)
    b.set_yticks(range(len(ids)))
    b.set_yticklabels(ids, fontsize=7)
    b.set_xlabel("addressee")
    b.set_ylabel("initiator")
    b.set_title("answered exchanges (whole run)", fontsize=9)
    fig.colorbar(im, ax=b, shrink=0.8, label="exchanges")


def fig_tdma(d: dict, path: Path) -> dict[str, Any]:
    """One TDMA cycle at the scale of its slots: slot boundaries drawn and labelled with their owner,
    each range request (protocol v2: each member a poll names) as an arrow initiator -> addressee at
    its time in the cycle (green: the reply was recorded; a poll's: its final lists the reply), each nav broadcast as a diamond; the free slots after the last used one are left
    out (stated). Beside it the answered exchanges of the whole run per pair."""
    plt = _plt()
    reqs = sorted(d["reqs"])
    if not reqs:
        return {}
    cycle_s, slot_s = _tdma_plan(d)
    ids = sorted({r[1] for r in reqs} | {r[2] for r in reqs})
    c0 = _busiest_cycle(reqs)
    t0 = c0 * cycle_s
    show = [r for r in reqs if r[4] == c0]
    owners = {sl: sid for sid, sl in d["slots"].items() if sl is not None}
    used = set(owners) | {int((_network_time(d, r[1], r[0]) - t0 + 1e-6) // slot_s) for r in show}  # (a slot's start)
    n_show = max(used) + 1
    n_slots = int(round(cycle_s / slot_s))
    fig, (a, b) = plt.subplots(1, 2, figsize=(14, 4.8), gridspec_kw={"width_ratios": [2.4, 1]})
    for k in range(n_show + 1):
        a.axvline(k * slot_s * 1e3, color="0.6", lw=0.7)
    for k in range(n_show):
        if k % 2:
            a.axvspan(k * slot_s * 1e3, (k + 1) * slot_s * 1e3, color="0.93", zorder=0)
        a.text((k + 0.5) * slot_s * 1e3, 1.01, f"slot {k}" + (f"\nst. {owners[k]}" if k in owners else ""),
               transform=a.get_xaxis_transform(), ha="center", va="bottom", fontsize=7)
    answered = 0
    for t, src, dst, seq, _c in show:
        ok = (src, dst, seq) in d["rsps"]
        answered += ok
        col = "tab:green" if ok else "tab:red"
        x = (_network_time(d, src, t) - t0) * 1e3
        a.annotate("", xy=(x, dst), xytext=(x, src), arrowprops=dict(arrowstyle="->", color=col, lw=1.0))
        a.plot([x], [src], "o", color=col, ms=3)
    nav_x = [((_network_time(d, sid, m["t_tx_s"]) - t0) * 1e3, sid) for sid, msgs in d.get("nav_msgs", {}).items() for m in msgs
             if m.get("cycle") == c0 and "t_tx_s" in m]
    if nav_x:
        a.plot([x for x, _ in nav_x], [s for _, s in nav_x], "D", color="tab:purple", ms=4, label="nav broadcast")
    a.plot([], [], color="tab:green", label="range request -> addressee (poll -> member), answered")
    a.plot([], [], color="tab:red", label="range request (poll member), no answer recorded")
    a.set_xlim(-0.2 * slot_s * 1e3, (n_show + 0.2) * slot_s * 1e3)
    a.set_ylim(min(ids) - 0.7, max(ids) + 0.7)
    a.set_yticks(ids)
    a.set_xlabel(f"time in cycle {c0}, ms (slot {slot_s * 1e3:g} ms; network time: each stamp less its station's true clock error)")
    a.set_ylabel("station")
    free = f"; slots {n_show}..{n_slots - 1} free, not drawn" if n_show < n_slots else ""
    a.set_title(f"One TDMA cycle ({cycle_s:g} s{free})", fontsize=9, pad=24)
    a.legend(fontsize=7, loc="lower right")
    a.grid(True, axis="y", alpha=0.3)
    _exchange_matrix(fig, b, reqs, d["rsps"], ids)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return {**M.tdma_numbers(reqs, d["rsps"]), "cycle_shown": c0, "cycle_s": cycle_s, "slot_s": slot_s,
            "slots_drawn": n_show}


def fig_network(info: dict, d: dict, path: Path) -> dict[str, Any]:
    """Loss per kind and the latency distributions on a symmetric-log axis (linear within +-1 ms):
    negative latencies are drawn, not clamped. ``publish_time`` is the sender's stamp on its own
    emulated clock, so ``log_time - publish_time`` is the transport delay plus the sender's clock
    error against the host's; a station whose oscillator runs ahead by more than the delay shows a
    negative latency. Returns the count of negative samples per kind."""
    plt = _plt()
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.2))
    kinds = list(info.get("loss", {}))
    a.bar(kinds, [info["loss"][k]["loss_pct"] for k in kinds], color="tab:red")
    a.set_ylabel("lost, % (sequence gaps)")
    a.set_title("Message loss by kind (as seen by the recorder)", fontsize=9)
    a.tick_params(axis="x", rotation=45, labelsize=8)
    a.grid(True, axis="y", alpha=0.3)
    lat = d["latency_ms"]
    neg: dict[str, int] = {}
    for k in sorted(lat):
        v = np.sort(np.asarray(lat[k], float))
        if v.size:
            neg[k] = int(np.sum(v < 0))
            b.plot(v, np.arange(1, v.size + 1) / v.size, label=k + (f" ({neg[k]} < 0)" if neg[k] else ""))
    b.set_xscale("symlog", linthresh=1.0)
    b.axvline(0.0, color="k", lw=0.8)
    b.set_xlabel("latency log_time - publish_time, wall ms (linear within +-1 ms, log beyond)")
    b.set_ylabel("fraction of messages <= latency")
    n_neg = sum(neg.values())
    b.set_title("Latency distribution by kind" + (f"; {n_neg} negative: the stamp is on the sender's emulated "
                                                  "clock" if n_neg else ""), fontsize=9)
    b.grid(True, which="both", alpha=0.3)
    if lat:
        b.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return {"negative_latency": neg}


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


def sync_series(rec) -> dict[int, np.ndarray]:
    """Per station: rows ``[t_s, error_ns, sigma_ns]`` of its clock estimate against the truth of the
    same stamp (:meth:`larns.log.series.StationSeries.clock`)."""
    out = {}
    for sid, st in rec.stations.items():
        rows = st.clock()
        if len(rows):
            out[sid] = rows
    return out


def fig_sync(series: dict[int, np.ndarray], path: Path, after_s: float = 60.0) -> dict[str, Any]:
    """Sync-error figure (survey-convergence style) and its numbers (none with perfect clocks: every
    error exactly 0, nothing to draw on a log axis)."""
    st = {k: v for k, v in series.items() if k != 1}
    if not st or not any(np.any(r[:, 1] != 0) for r in st.values()):
        return {}
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4))
    for sid, r in sorted(st.items()):
        ax.plot(r[:, 0], np.abs(r[:, 1]), lw=0.7, alpha=0.6)
    grid, rms, sig = M.sync_curves(st)
    ax.plot(grid, rms, "k", lw=1.5, label="RMS over the stations")
    ax.plot(grid, sig, "k--", lw=1.0, label="mean 1-sigma (own covariance)")
    _save_log_plot(plt, fig, ax, "|clock error| vs network time, ns",
                   f"Network time: clock error of {len(st)} stations (station 1 = network time)", path)
    return M.sync_numbers(st, rms, after_s)


def integrity_numbers(d: dict, info: dict) -> dict[str, Any]:
    """Exclusions (issue 14): stations excluded by their neighbours (``info`` from the summary) and, per
    aircraft algorithm, the excluded stations with the first time, HPL/VPL medians and how often the
    horizontal error (truth interpolated to the estimate times) exceeded the published HPL."""
    out: dict[str, Any] = {"stations": {sid: v["excluded_by"] for sid, v in (info.get("stations") or {}).items()
                                        if v.get("excluded_by")}, "aircraft": {}}
    for name, per in d.get("ac_integrity", {}).items():
        tr = d["ac_truth"].get(name)
        for algo, ig in per.items():
            has = np.isfinite(ig["hpl_m"])
            if not has.any() and not ig["exclusions"]:
                continue
            row = {"exclusions": {str(k): v for k, v in sorted(ig["exclusions"].items())},
                   "hpl_median_m": float(np.median(ig["hpl_m"][has])) if has.any() else None,
                   "vpl_median_m": float(np.nanmedian(ig["vpl_m"])) if np.isfinite(ig["vpl_m"]).any() else None,
                   "hpl_exceed": None}
            if tr is not None and has.any() and len(tr["t_s"]) > 1:
                p = d["aircraft"][name][algo]["pos_m"][has]
                t = ig["t_s"][has]
                e = [p[:, k] - np.interp(t, tr["t_s"], tr["pos_m"][:, k]) for k in (0, 1)]
                row["hpl_exceed"] = int(np.sum(np.hypot(*e) > ig["hpl_m"][has]))
                row["hpl_samples"] = int(has.sum())
            out["aircraft"].setdefault(name, {})[algo] = row
    return out


def _integrity_md(ig: dict | None) -> list[str]:
    if not ig or not (ig["stations"] or ig["aircraft"]):
        return []
    L = ["## Integrity", ""]
    for sid, by in ig["stations"].items():
        L.append(f"- station {sid} EXCLUDED by {','.join(map(str, by))}")
    if ig["aircraft"]:
        L += ([""] if ig["stations"] else []) + ["| aircraft | algorithm | excluded (first t s) | HPL median m | VPL median m | error > HPL |",
              "|---|---|---|---:|---:|---:|"]
        for name, per in ig["aircraft"].items():
            for algo, r in per.items():
                ex = ", ".join(f"{k} ({v:.1f})" for k, v in r["exclusions"].items()) or "-"
                hx = "-" if r["hpl_exceed"] is None else f"{r['hpl_exceed']}/{r['hpl_samples']}"
                L.append(f"| {name} | {algo} | {ex} | {_fmt(r['hpl_median_m'])} | {_fmt(r['vpl_median_m'])} | {hx} |")
    return L + [""]


def _station_figures(d: dict, rec, out: Path, res: dict, figs: list) -> None:
    from . import report_nav as RN

    res["station_map"] = RN.fig_station_map(d, out / "station_map.png")
    if res["station_map"]:
        figs.append(("Stations in plan with 2-sigma horizontal ellipses", "station_map.png"))
    res["stations"] = RN.fig_station_errors(d, out / "station_errors.png")
    if res["stations"]:
        figs.append(("Station errors: horizontal and vertical against their own sigma", "station_errors.png"))
    res["convergence"] = fig_convergence(d, out / "survey_convergence.png")
    if res["convergence"]:
        figs.append(("Survey convergence with the CRLB", "survey_convergence.png"))
        if res["convergence"].get("nees"):
            figs.append(("Station NEES with its chi-square band", "station_nees.png"))
    res["histograms"] = fig_histograms(d, out / "survey_histograms.png")
    if res["histograms"]:
        figs.append(("Error histograms", "survey_histograms.png"))
    res["sync"] = fig_sync(sync_series(rec), out / "sync_errors.png")
    if res["sync"]:
        figs.append(("Network time: clock errors", "sync_errors.png"))


def _aircraft_figures(d: dict, logs, out: Path, res: dict, figs: list, scenario: str | None,
                      sigma_m: float | None) -> None:
    from . import report_nav as RN

    acfg = _aircraft_config(logs, scenario)
    sig = sigma_m if sigma_m is not None else (acfg.world.sigma_m if acfg is not None else None)
    if sig is None and d["init"]:
        sig = d["init"]["cfg"].get("sigma_d_m")
    if acfg is not None:
        tuning = acfg.nav.tuning
    else:
        from dataclasses import replace

        from aircraft.navigator.radio.tuning import Tuning

        tuning = replace(Tuning(), sigma_m=float(sig or 0.5))
    res["aircraft"] = fig_aircraft(d, out / "aircraft_errors.png", sig, tuning)
    figs.append(("Aircraft errors with the CRLB", "aircraft_errors.png"))
    res["aircraft_sigma"] = RN.fig_aircraft_sigma(d, out / "aircraft_sigma.png")
    if res["aircraft_sigma"]:
        figs.append(("Aircraft errors against their own sigma, NEES", "aircraft_sigma.png"))
    res["aircraft_track"] = RN.fig_aircraft_track(d, out / "aircraft_track.png")
    if res["aircraft_track"]:
        figs.append(("Aircraft tracks in plan and horizontal errors", "aircraft_track.png"))


def make_report(paths: Sequence[str | Path], outdir: str | Path, scenario: str | None = None,
                sigma_m: float | None = None) -> dict[str, Any]:
    """Read the recording(s), write the figures, ``report.md`` and ``report.json`` (strict JSON:
    ``null`` where a number is not finite) into ``outdir``; returns what ``report.json`` holds."""
    from ..analysis.summary import dumps_strict, summarize
    from ..log.series import load

    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    rec = load(paths)  # every message decoded once, for the summary and the figures
    info = summarize(paths, rec=rec)
    d = extract(rec)
    res: dict[str, Any] = {"files": [{"path": f["path"], "complete": f["complete"], "error": f["error"]}
                                     for f in info["files"]],
                           "messages": info["messages"], "duration_s": info.get("duration_s", 0.0),
                           "figures": []}
    figs: list[tuple[str, str]] = []
    if d["stations"]:
        _station_figures(d, rec, out, res, figs)
    if d["aircraft"]:
        _aircraft_figures(d, rec.logs, out, res, figs, scenario, sigma_m)
    if rec.vehicles:
        res["vehicles"] = fig_vehicles(rec, out / "vehicle_errors.png")
        figs.append(("Ground vehicle error and 3-sigma", "vehicle_errors.png"))
    res["integrity"] = integrity_numbers(d, info)
    res["tdma"] = fig_tdma(d, out / "tdma_timeline.png")
    if res["tdma"]:
        figs.append(("One TDMA cycle", "tdma_timeline.png"))
    res["network"] = fig_network(info, d, out / "network.png")
    figs.append(("Message loss and latency", "network.png"))
    res["loss"] = info.get("loss", {})
    res["loss_total"] = info.get("loss_total", {})
    res["latency_ms"] = info.get("latency_ms", {})
    res["figures"] = [f for _, f in figs]
    (out / "report.json").write_text(dumps_strict(res, indent=1))
    (out / "report.md").write_text(markdown(res, info, figs))
    return res


def _fmt(x: Any, nd: int = 2) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        return "-" if math.isnan(x) else f"{x:.{nd}f}"
    return str(x)


def _aircraft_sigma_md(sig: dict, track: dict) -> list[str]:
    """Per aircraft algorithm: shares inside its own 2 sigma, the horizontal error from 30 s, the NEES."""
    if not sig:
        return []
    L = ["| aircraft | algorithm | inside 2 sigma_h | inside 2 sigma_z | horizontal RMS m (window) | inside 2-sigma "
         "ellipse | NEES mean (3 dof) | 95 % band (n_eff) |", "|---|---|---:|---:|---:|---:|---:|---:|"]
    for name, per in sig.items():
        for algo, r in per.items():
            tk = track.get(name, {}).get(algo, {})
            band = r.get("nees_band")
            L.append(f"| {name} | {algo} | {_fmt(100 * r['inside_2sigma_h'], 0)} % | {_fmt(100 * r['inside_2sigma_v'], 0)} % | "
                     f"{_fmt(tk.get('rms_eh_m'))} (from {_fmt(tk.get('from_s'), 0)} s) | "
                     f"{'-' if tk.get('inside_2sigma_ellipse') is None else _fmt(100 * tk['inside_2sigma_ellipse'], 0) + ' %'} | "
                     f"{_fmt(r.get('nees_mean'))} | "
                     + ("-" if not band else f"[{_fmt(band[0])}, {_fmt(band[1])}] ({_fmt(r.get('nees_n_eff'), 1)})") + " |")
    return L + [""]


def _stations_md(res: dict) -> list[str]:
    """The station table: 3-D error with its 3-sigma, horizontal and vertical errors with their own sigma."""
    if not res.get("stations"):
        return []
    L = ["## Stations", "", "| station | updates | final error m | final 3-sigma m | inside 3-sigma | horizontal m "
         "| sigma_h m | inside 2 sigma_h | vertical m | sigma_z m | inside 2 sigma_z |",
         "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for sid, s in res["stations"].items():
        pct = (lambda k: "-" if s.get(k) is None or math.isnan(s[k]) else f"{_fmt(100 * s[k], 0)} %")
        L.append(f"| {sid} | {s['n_updates']} | {_fmt(s['final_err_m'])} | {_fmt(s['final_bound3_m'])} | "
                 f"{pct('inside_3sigma')} | {_fmt(s.get('final_eh_m'))} | {_fmt(s.get('final_sigma_h_m'))} | "
                 f"{pct('inside_2sigma_h')} | {_fmt(s.get('final_ev_m'))} | {_fmt(s.get('final_sigma_v_m'))} | "
                 f"{pct('inside_2sigma_v')} |")
    m = res.get("station_map") or {}
    if m:
        out = [str(k) for k, v in m["stations"].items() if v["inside"] is False]
        L += ["", f"Final horizontal errors inside their own {m['sigma']:g}-sigma ellipse ({100 * m['probability']:.1f} % "
                  f"expected): {sum(v['inside'] is True for v in m['stations'].values())} of "
                  f"{sum(v['inside'] is not None for v in m['stations'].values())}"
                  + (f" (outside: {', '.join(out)})" if out else "") + "."]
    return L + [""]


def _survey_md(res: dict) -> list[str]:
    """The survey's numbers: convergence with its CRLB, NEES, network time, the second half."""
    L = []
    c = res.get("convergence") or {}
    if c:
        L.append(f"Survey: final mean horizontal error {_fmt(c['final_mean_horizontal_m'])} m, RMS "
                 f"{_fmt(c['final_rms_horizontal_m'])} m, max {_fmt(c['final_max_horizontal_m'])} m; mean error "
                 f"below sigma_d = {_fmt(c['sigma_d_m'])} m from t = {_fmt(c['time_mean_below_sigma_d_s'], 1)} s on.")
        if c.get("final_crlb_horizontal_rms_m") is not None:
            L.append(f"CRLB of the RMS horizontal error for the ranges measured (centralized, `nav.crlb`): "
                     f"{_fmt(c['final_crlb_horizontal_rms_m'], 3)} m at the end; RMS / CRLB "
                     f"{_fmt(c['final_rms_over_crlb'])} (one run: below 1 is chance, not a better estimator).")
        ne = c.get("nees") or {}
        if ne:
            L.append(f"NEES / dof of the surveying stations: {_fmt(ne['final'])} at the end, mean "
                     f"{_fmt(ne['mean_second_half'])} over the second half; {100 * ne['probability']:g} % band for "
                     f"dof {ne['dof']}: [{_fmt(ne['band'][0])}, {_fmt(ne['band'][1])}]; inside it "
                     f"{_fmt(ne['inside_band_pct'], 0)} % of the time.")
    sy = res.get("sync") or {}
    if sy:
        late = ("run shorter than 60 s" if sy["rms_ns_after_60s"] is None else
                f"after 60 s RMS {_fmt(sy['rms_ns_after_60s'])} ns, largest {_fmt(sy['max_abs_ns_after_60s'])} ns")
        L.append(f"Network time: final RMS clock error {_fmt(sy['final_rms_ns'])} ns over {sy['stations']} stations; "
                 f"{late}.")
    h = res.get("histograms") or {}
    if h:
        L.append(f"Second half of the run: horizontal RMS {_fmt(h['horizontal_rms_m'])} m, vertical RMS "
                 f"{_fmt(h['vertical_rms_m'])} m ({h['samples']} samples).")
    return L + [""]


def _aircraft_md(res: dict) -> list[str]:
    if not res.get("aircraft"):
        return []
    L = ["## Aircraft", "", "| aircraft | algorithm | estimates | final error m | RMS error m (after 10 %) |",
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
    return L + _aircraft_sigma_md(res.get("aircraft_sigma") or {}, res.get("aircraft_track") or {})


def _network_md(res: dict) -> list[str]:
    L = []
    t = res.get("tdma") or {}
    if t:
        L.append(f"## TDMA\n\n{t['requests']} range requests recorded, {t['answered']} answered "
                 f"({_fmt(t['answered_pct'], 1)} %).\n")
    neg = (res.get("network") or {}).get("negative_latency", {})
    L += ["## Network", "", "| kind | received | missing | loss % | p50 latency ms | p99 latency ms | latency < 0 |",
          "|---|---:|---:|---:|---:|---:|---:|"]
    for k, v in res.get("loss", {}).items():
        la = res.get("latency_ms", {}).get(k, {})
        L.append(f"| {k} | {v['received']} | {v['missing']} | {_fmt(v['loss_pct'])} | {_fmt(la.get('p50'))} | "
                 f"{_fmt(la.get('p99'))} | {neg.get(k, '-')} |")
    L.append("")
    if any(neg.values()):
        L += ["Latency is `log_time - publish_time`, and `publish_time` is the sender's stamp on its own emulated "
              "clock: a station whose oscillator runs ahead of the host's clock by more than the transport delay "
              "shows a negative latency (drawn, not clamped, in network.png).", ""]
    return L


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
    L += _stations_md(res)
    L += _survey_md(res)
    L += _aircraft_md(res)
    L += _vehicle_markdown(res.get("vehicles", {}))
    L += _integrity_md(res.get("integrity"))
    L += _network_md(res)
    L += ["## Figures", ""]
    for title, f in figs:
        L += [f"### {title}", "", f"![{title}]({f})", ""]
    return "\n".join(L)
