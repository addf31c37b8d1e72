"""`larns bench slots`: distributed TDMA slot assignment with spatial reuse (issue 33 item 4).

Each trial draws a layout from its own seed - ``field``: stations uniform over 40 x 30 km (seed 003's
area); ``corridor``: along a 100 km road - takes the link graph of the ``[radio]`` model
(:func:`net.radio.link`, default radio unless overridden, antennas ``--antenna-height-m`` up), cold
starts every station at once in the MAC simulator (:mod:`stations.slotsim`, the cores of
:mod:`stations.slots`), then powers on ``--joiners`` late joiners one at a time. With
``--scenario`` the same figures come from the station simulator (``stations/sim.py``: the station cores
with the nav's summaries, their ranging and survey) on a scenario with ``[tdma] assignment =
"distributed"`` (docs/slots.md).
"""

from __future__ import annotations

import json
import math
import multiprocessing as mp
import time
from pathlib import Path

import numpy as np

JOIN_WINDOW_CYCLES = 12  # cycles between two late joiners (each is scored on the cycles until the next)
BAR_SLOTS, BAR_AFTER_S, BAR_JOIN_CYCLES = 40, 60.0, 3


def register(sub) -> None:
    from stations.tdma import TdmaPlan

    p = sub.add_parser(
        "slots",
        help="distributed slot assignment (spatial TDMA reuse) on a radio link graph: MAC simulator",
        description=(
            "Monte Carlo of the distributed slot assignment of stations/slots.py in the MAC simulator "
            "stations/slotsim.py (with --scenario: the station simulator). Per trial: the link graph's densest "
            "neighbourhoods (closed 1-hop: a lower bound on the slots; closed 2-hop: with that many slots a "
            "free slot always exists), cycles until no two stations within two hops share a slot, slots used "
            "(max index + 1), reuse factor (stations holding a slot) / slots used, collided transmissions per station-hour (the whole "
            "run, and from 60 s on), and the cycles a late joiner takes to hold a slot (its power-on cycle "
            "counts 1). A cycle is --cycle-slots x --slot-s. Bar of issue 33: 200 stations in <= 40 slots, "
            "0 collisions after 60 s, joiners hold a slot within 3 cycles. JSON: the per-trial figures and "
            "the summary."),
    )
    p.add_argument("--stations", type=int, default=200, help="stations per trial")
    p.add_argument("--trials", type=int, default=5, help="Monte Carlo trials (layouts)")
    p.add_argument("--seed", type=int, default=1, help="base seed; trial k uses seed + k")
    p.add_argument("--layout", choices=["field", "corridor"], default="field",
                   help="field: uniform over 40 x 30 km; corridor: along a 100 km road (+-200 m)")
    p.add_argument("--cycle-slots", type=int, default=BAR_SLOTS, metavar="C",
                   help="slots per cycle; 0: sized per trial for the densest closed two-hop neighbourhood "
                        "(late joiners included)")
    p.add_argument("--slot-s", type=float, default=TdmaPlan().slot_s, help="slot duration, s (stations/tdma.py)")
    p.add_argument("--duration", type=float, default=120.0, help="simulated seconds of the cold start")
    p.add_argument("--joiners", type=int, default=5, help="late joiners per trial, one at a time")
    p.add_argument("--tx-power-dbm", type=float, default=None,
                   help="[radio] tx_power_dbm (default: net.radio's, 30 dBm: links to the 26 km horizon)")
    p.add_argument("--antenna-height-m", type=float, default=10.0, help="[radio] antenna_height_m")
    p.add_argument("--jobs", type=int, default=1, help="worker processes")
    p.add_argument("--json", metavar="FILE", help="write the results as JSON")
    p.add_argument("--png-dir", metavar="DIR", default="bench-out/slots",
                   help="where to write the PNG figure ('' to skip)")
    p.add_argument("--scenario", metavar="FILE",
                   help="instead of the MAC simulator: the station simulator (stations/sim.py, the station cores "
                        "with the nav's summaries, ranging and survey) on this scenario with [tdma] assignment = "
                        "\"distributed\"; its [layout] joiners power on one at a time after --duration; the same "
                        "figures, the survey's horizontal error, and with --compare-fixed the fixed plan's")
    p.add_argument("--compare-fixed", action="store_true",
                   help="with --scenario: also run the fixed plan (one slot per station, the cycle sized for them)")
    p.set_defaults(func=main)


def _radio(args):
    from net.radio import RadioParams

    kw = {"antenna_height_m": args.antenna_height_m}
    if args.tx_power_dbm is not None:
        kw["tx_power_dbm"] = args.tx_power_dbm
    return RadioParams(**kw)


def _positions(layout: str, n: int, rng: np.random.Generator) -> np.ndarray:
    from stations.slotsim import corridor_positions, field_positions

    return field_positions(n, rng) if layout == "field" else corridor_positions(n, rng)


def trial(job: tuple) -> dict:
    """One layout: ``(layout, n, joiners, seed, cycle_slots, slot_s, duration_s, radio)``."""
    from dataclasses import asdict

    from stations.slots import SlotConfig
    from stations.slotsim import graph_stats, link_graph, simulate_graph

    layout, n, joiners, seed, cycle_slots, slot_s, duration_s, radio = job
    rng = np.random.default_rng(seed)
    pos = _positions(layout, n + joiners, rng)
    adj_all = link_graph(pos, radio)
    stats = graph_stats(adj_all[:n, :n])
    # 0: sized for the densest closed two-hop neighbourhood of the deployment, late joiners included
    C = int(cycle_slots) if cycle_slots > 0 else graph_stats(adj_all).max_closed_2hop
    cycle_s = C * slot_s
    main_cycles = max(int(math.ceil(duration_s / cycle_s)), 2)
    start = np.concatenate([np.zeros(n, int), main_cycles + JOIN_WINDOW_CYCLES * np.arange(joiners)])
    res = simulate_graph(adj_all, SlotConfig(C), main_cycles + JOIN_WINDOW_CYCLES * joiners, rng, start)
    return _score(res, adj_all, n, start, main_cycles, cycle_s) | {
        "seed": seed, "graph": asdict(stats), "cycle_slots": C, "cycle_s": cycle_s, "pos_m": pos[:, :2].tolist()}


def _score(res, adj_all, n: int, start: np.ndarray, main_cycles: int, cycle_s: float) -> dict:
    """The figures of one run sampled once per cycle of ``cycle_s`` (a scenario's cycle may be longer
    than its assigned slots: ``[tdma] cycle_slots`` of ``slot_s`` at its start)."""
    from stations.slotsim import converged_cycle, hold_cycle, two_hop

    last = res.slot[main_cycles - 1, :n]
    held = last[last >= 0]
    used = int(held.max()) + 1 if held.size else 0
    main = _cut(res, main_cycles)
    conv = converged_cycle(main)
    after = int(math.ceil(BAR_AFTER_S / cycle_s))
    hours_main = n * main_cycles * cycle_s / 3600.0
    hours_after = n * max(main_cycles - after, 0) * cycle_s / 3600.0
    coll_after = int(main.collided_tx[after:].sum())
    # joiner j is scored while the first n + j + 1 stations are on (two hops of that graph)
    join = [hold_cycle(_cut(res, int(s) + JOIN_WINDOW_CYCLES), n + j, int(s),
                       two_hop(_first(adj_all, n + j + 1)))
            for j, s in enumerate(start[n:])]
    return {"main_cycles": main_cycles, "converged_cycle": conv,
            "converged_s": None if conv is None else conv * cycle_s,
            "slots_used": used, "holding": int(held.size), "reuse": held.size / used if used else 0.0,
            "unassigned_end": int(main.unassigned[-1]), "conflict_pairs_end": int(main.conflict_pairs[-1]),
            "collided_tx": int(main.collided_tx.sum()),
            "collisions_per_station_hour": float(main.collided_tx.sum()) / hours_main,
            "collided_tx_after_60s": coll_after,
            "collisions_per_station_hour_after_60s": coll_after / hours_after if hours_after > 0 else None,
            "joiner_hold_cycles": join,
            "joiner_collided_tx": int(res.collided_tx[main_cycles:].sum()),
            "slot_end": last.tolist(), "collided_per_cycle": res.collided_tx.tolist()}


def _first(adj: np.ndarray, k: int) -> np.ndarray:
    """``adj`` (N, N) with only its first ``k`` stations linked."""
    out = np.zeros_like(adj)
    out[:k, :k] = adj[:k, :k]
    return out


def _cut(res, cycles: int):
    """The first ``cycles`` cycles of a :class:`stations.slotsim.SimResult`."""
    from stations.slotsim import SimResult

    return SimResult(res.conflict_pairs[:cycles], res.unassigned[:cycles], res.collided_tx[:cycles],
                     res.tx[:cycles], res.slot[:cycles], res.cores)


def summarize(trials: list[dict], meta: dict) -> dict:
    g = [t["graph"] for t in trials]
    join = [c for t in trials for c in t["joiner_hold_cycles"]]
    conv = [t["converged_cycle"] for t in trials]
    summary = {
        "max_closed_1hop": max(x["max_closed_1hop"] for x in g),
        "max_closed_2hop": max(x["max_closed_2hop"] for x in g),
        "no_link_fraction_mean": float(np.mean([x["no_link_fraction"] for x in g])),
        "hop_diameter_max": max(x["hop_diameter"] for x in g),
        "cycle_slots_max": max(t["cycle_slots"] for t in trials),
        "slots_used_max": max(t["slots_used"] for t in trials),
        "reuse_min": min(t["reuse"] for t in trials),
        "converged_all": all(c is not None for c in conv),
        "converged_cycle_max": None if None in conv else max(conv),
        "converged_s_max": None if None in conv else max(t["converged_s"] for t in trials),
        "collisions_per_station_hour_mean": float(np.mean([t["collisions_per_station_hour"] for t in trials])),
        "collided_tx_after_60s": sum(t["collided_tx_after_60s"] for t in trials),
        "joiner_hold_cycles_max": None if (not join or None in join) else max(join),
        "joiners_never_held": sum(c is None for c in join),
        "joiners_total": len(join),
    }
    return meta | {"summary": summary, "bar": _bar(summary), "trials": trials}


def _bar(s: dict) -> dict:
    """Issue 33's bar: <= 40 slots (and converged), no collision after 60 s, joiners within 3 cycles."""
    join = s["joiner_hold_cycles_max"]
    return {"slots_le_40": s["cycle_slots_max"] <= BAR_SLOTS and s["converged_all"],
            "converged_and_no_collisions_after_60s": s["collided_tx_after_60s"] == 0 and s["converged_all"],
            # (no joiner: not measured)
            "joiners_hold_within_3_cycles": (join is not None and join <= BAR_JOIN_CYCLES) if s["joiners_total"] else None}


def print_table(res: dict) -> None:
    print(f"\nlayout={res['layout']}  stations={res['stations']}  trials={res['trial_count']}  "
          f"tx_power={res['tx_power_dbm']:g} dBm  antenna={res['antenna_height_m']:g} m  "
          f"slot={res['slot_s'] * 1e3:g} ms  wall={res['wall_s']:.1f} s")
    hdr = ("seed", "deg1+1", "2hop+1", "nolink%", "hops", "C", "used", "reuse", "conv_cyc", "conv_s",
           "coll/st-h", "coll>60s", "unassig", "join_cyc")
    print("  ".join(f"{h:>9}" for h in hdr))
    for t in res["trials"]:
        g = t["graph"]
        row = [t["seed"], g["max_closed_1hop"], g["max_closed_2hop"], f"{100 * g['no_link_fraction']:.1f}",
               g["hop_diameter"], t["cycle_slots"], t["slots_used"], f"{t['reuse']:.2f}",
               _s(t["converged_cycle"]), _s(t["converged_s"], ".1f"),
               f"{t['collisions_per_station_hour']:.1f}", t["collided_tx_after_60s"], t["unassigned_end"],
               ",".join(_s(c) for c in t["joiner_hold_cycles"]) or "-"]
        print("  ".join(f"{str(x):>9}" for x in row))
    s = res["summary"]
    print("deg1+1: densest closed 1-hop neighbourhood (no cycle can be shorter); 2hop+1: densest closed 2-hop "
          "neighbourhood (the greedy bound); nolink%: pairs with no link; hops: hop diameter; C: slots per "
          "cycle; used: max slot index + 1 at the end of the cold start; reuse: stations holding a slot / used; conv_cyc: cycles until no two "
          "stations within two hops share a slot and every station holds one (-: not by the end); "
          "coll/st-h: collided transmissions per station-hour over the cold start; join_cyc: each late "
          "joiner's cycles to hold a slot (power-on cycle = 1; -: never)")
    for C in sorted({min(t["cycle_slots"] for t in res["trials"]), BAR_SLOTS}):
        if s["max_closed_1hop"] > C:
            print(f"a cycle of {C} slots cannot hold this layout: a station hears {s['max_closed_1hop'] - 1} "
                  f"others, and it and they are pairwise within two hops, so at least {s['max_closed_1hop']} "
                  f"slots are needed (densest closed 2-hop neighbourhood: {s['max_closed_2hop']})")
    for name, ok in res["bar"].items():
        print(f"  bar {name}: {'n/a' if ok is None else 'PASS' if ok else 'FAIL'}")


def _s(x, fmt: str = "") -> str:
    return "-" if x is None else format(x, fmt)


def plot(res: dict, png_dir: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    png_dir.mkdir(parents=True, exist_ok=True)
    t0 = res["trials"][0]
    n = res["stations"]
    pos = np.asarray(t0["pos_m"])[:n] / 1e3
    slot = np.asarray(t0["slot_end"])
    fig, axs = plt.subplots(1, 2, figsize=(12, 4.5))
    # the field in plan; the corridor (a line) as position along the road against slot
    y = pos[:, 1] if res["layout"] == "field" else np.where(slot >= 0, slot, -1)
    sc = axs[0].scatter(pos[:, 0], y, c=np.where(slot >= 0, slot, np.nan), cmap="tab20", s=14)
    axs[0].scatter(pos[slot < 0, 0], y[slot < 0], marker="x", color="k", s=20, label="no slot")
    if res["layout"] == "field":
        axs[0].set_aspect("equal")
    axs[0].set_xlabel("x, km")
    axs[0].set_ylabel("y, km" if res["layout"] == "field" else "slot (-1: none)")
    axs[0].set_title(f"{res['layout']}, seed {t0['seed']}: slot of each station ({t0['cycle_slots']} slots)")
    fig.colorbar(sc, ax=axs[0], label="slot")
    for t in res["trials"]:
        c = np.asarray(t["collided_per_cycle"], float)
        axs[1].plot(np.arange(len(c)) * t["cycle_s"], np.maximum(c, 0.5), lw=0.8, label=f"seed {t['seed']}")
    axs[1].set_yscale("log")
    axs[1].axvline(BAR_AFTER_S, color="grey", lw=0.8)
    axs[1].set_xlabel("time, s (cold start, then late joiners)")
    axs[1].set_ylabel("collided transmissions per cycle (0 drawn at 0.5)")
    axs[1].grid(True, which="both", alpha=0.3)
    axs[1].legend(fontsize=7)
    f = png_dir / f"slots_{res['layout']}.png"
    fig.tight_layout()
    fig.savefig(f, dpi=110)
    plt.close(fig)
    return f


# --------------------------------------------------------------------------- the station simulator
def _held(core) -> int:
    """The slot a station core holds (-1: none or not on): the distributed assignment's (held while it
    listens in it, as in :mod:`stations.slotsim`), or the fixed plan's."""
    if core is None:
        return -1
    s = core.slots.slot if core.slots is not None else core.slot
    return -1 if s is None else int(s)


def station_trial(path: str, duration_s: float, fixed: bool = False) -> dict:
    """The scenario at ``path`` in :class:`stations.sim.Simulator`: the slot each station holds sampled
    in the middle of every cycle into a :class:`stations.slotsim.SimResult` (collided transmissions:
    navs lost at one or more receivers to another sender in their slot), scored by :func:`_score`, and
    the survey's horizontal error at the end of the cold start. ``fixed``: the same field on the fixed
    plan (a slot per station, the cycle sized for them; the joiners start as in the distributed run)."""
    from dataclasses import asdict

    from net.radio import may_link
    from net.scenario import load
    from stations.sim import Simulator
    from stations.slotsim import SimResult, conflicts, graph_stats, two_hop

    scn = load(path)
    if not scn.tdma.distributed:
        raise SystemExit(f"{path}: [tdma] assignment is not \"distributed\"")
    n, C, slot_s = len(scn.initial_ids), scn.tdma.assigned_slots, scn.tdma.slot_s
    cycle_s = scn.tdma.cycle_s
    if fixed:
        n_all = len(scn.ids)
        scn = load(path, tdma={"assignment": "fixed", "cycle_slots": 0, "cycle_s": n_all * slot_s})
    main_cycles = max(int(math.ceil(duration_s / cycle_s)), 2)
    joiners = [sid for sid in scn.ids if sid in scn.join_ids]
    start = np.concatenate([np.zeros(n, int), main_cycles + JOIN_WINDOW_CYCLES * np.arange(len(joiners))])
    adj = may_link(scn.pos_m, scn.channel.radio)
    np.fill_diagonal(adj, False)
    adj &= adj.T
    sim = Simulator(scn, start_s={sid: float(start[n + j]) * cycle_s for j, sid in enumerate(joiners)})
    T = main_cycles + JOIN_WINDOW_CYCLES * len(joiners)
    slot = np.full((T, len(scn.ids)), -1)
    r = None
    for c in range(T):
        rc = sim.run((c + 0.5) * cycle_s, [(c + 0.5) * cycle_s])
        slot[c] = [_held(k) for k in sim.cores]
        r = rc if c == main_cycles - 1 else r
    on = start[None, :] <= np.arange(T)[:, None]
    coll = np.zeros(T, int)
    for c, k in {(int(t // cycle_s), k) for t, k, _ in sim.collision_log}:
        coll[c] += c < T
    res = SimResult(conflict_pairs=np.array([conflicts(two_hop(adj & on[c][None, :] & on[c][:, None]), slot[c])
                                             for c in range(T)]),
                    unassigned=(on & (slot < 0)).sum(1), collided_tx=coll, tx=(slot >= 0).sum(1), slot=slot, cores=[])
    # (the fixed plan is sampled on the distributed cycle's clock too: only its survey is compared)
    out = {} if fixed else _score(res, adj, n, start, main_cycles, cycle_s)
    err = np.linalg.norm((r.pos_m[0] - r.truth_m)[:n, :2], axis=1)
    return out | {"seed": scn.seed, "graph": asdict(graph_stats(adj[:n, :n])), "cycle_slots": C if not fixed else len(scn.ids),
                  "cycle_s": scn.tdma.cycle_s, "pos_m": scn.pos_m[:, :2].tolist(), "plan": "fixed" if fixed else "distributed",
                  "survey_horizontal_err_m": {"median": float(np.nanmedian(err)), "rms": float(np.sqrt(np.nanmean(err**2))),
                                              "p95": float(np.nanpercentile(err, 95)), "at_s": float(main_cycles - 0.5) * cycle_s},
                  "ranges": len(sim.range_log), "collided_navs_at_receivers": sim.collisions,
                  "tx_power_dbm": scn.channel.radio.tx_power_dbm if scn.channel.radio else float("nan"),
                  "antenna_height_m": scn.channel.radio.antenna_height_m if scn.channel.radio else float("nan")}


def main_scenario(args) -> int:
    from net.scenario import load

    t0 = time.perf_counter()
    trials = [station_trial(args.scenario, args.duration)]
    if args.compare_fixed:
        trials.append(station_trial(args.scenario, args.duration, fixed=True))
    res = summarize(trials[:1], {"layout": f"scenario {args.scenario} (station simulator)", "stations": len(trials[0]["slot_end"]),
                                 "trial_count": 1, "tx_power_dbm": trials[0]["tx_power_dbm"],
                                 "antenna_height_m": trials[0]["antenna_height_m"],
                                 "slot_s": load(args.scenario).tdma.slot_s, "duration_s": args.duration,
                                 "joiners": len(trials[0]["joiner_hold_cycles"])})
    res["wall_s"] = time.perf_counter() - t0
    res["fixed"] = trials[1] if args.compare_fixed else None
    print_table(res)
    for t in trials:
        e = t["survey_horizontal_err_m"]
        print(f"{t['plan']:>11} plan: {t['cycle_slots']} slots of {1e3 * t['cycle_s'] / t['cycle_slots']:g} ms, "
              f"ranges {t['ranges']}, survey horizontal error at {e['at_s']:.1f} s: median {e['median']:.2f} m, "
              f"RMS {e['rms']:.2f} m, 95 % {e['p95']:.2f} m; collided navs at receivers {t['collided_navs_at_receivers']}")
    if args.json:
        out = Path(args.json)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(res, indent=1))
        print(f"wrote {out}")
    return 0


def main(args) -> int:
    from .progress import progress

    if args.scenario:
        return main_scenario(args)
    radio = _radio(args)
    jobs = [(args.layout, args.stations, args.joiners, args.seed + k, args.cycle_slots, args.slot_s,
             args.duration, radio) for k in range(args.trials)]
    t0 = time.perf_counter()
    if args.jobs > 1:
        with mp.get_context("fork").Pool(args.jobs) as pool:
            trials = list(progress(pool.imap(trial, jobs), "slots", total=len(jobs)))
    else:
        trials = list(progress(map(trial, jobs), "slots", total=len(jobs)))
    res = summarize(trials, {"layout": args.layout, "stations": args.stations, "trial_count": args.trials,
                             "tx_power_dbm": radio.tx_power_dbm, "antenna_height_m": radio.antenna_height_m,
                             "slot_s": args.slot_s, "duration_s": args.duration, "joiners": args.joiners})
    res["wall_s"] = time.perf_counter() - t0
    print_table(res)
    written = [plot(res, Path(args.png_dir))] if args.png_dir else []
    if args.json:
        out = Path(args.json)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(res, indent=1))
        written.append(out)
    for f in written:
        print(f"wrote {f}")
    return 0
