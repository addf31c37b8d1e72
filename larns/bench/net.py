"""`larns bench net` and `larns bench scale`: the networked emulator's timing budget.

bench net
    Request/response round trip between two station-like processes over Zenoh on loopback (peer
    mode, explicit endpoints): the initiator publishes an encoded ``range_req`` (with its physical
    part), the responder decodes and validates it, builds and encodes a ``range_rsp`` and publishes
    it; the initiator decodes the answer. Round trip = wall time from publish to decoded answer.
    Goal: p99 well inside a 10 ms TDMA slot.

bench scale
    Runs N real station processes (``larns station``) in real time (speed 1) for a while and counts
    missed slots (a slot whose request went out after the slot had ended), late / lost replies,
    CPU and memory per process. Increases N until a run misses slots; reports the largest N with
    zero missed slots.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


# --------------------------------------------------------------------------- bench net workers

def _responder(listen: str, connect: list[str], duration_s: float) -> None:
    """Answers in the Zenoh callback, like the station node's receive path."""
    import threading

    from net import messages as M
    from net.bus import Bus

    bus = Bus(listen=[listen], connect=connect)
    lock = threading.Lock()
    seq = [0]

    def on_req(k: str, data: bytes) -> None:
        msg, phy = M.decode(data)
        with lock:
            seq[0] += 1
            rsp = {"kind": "range_rsp", "src": 2, "seq": seq[0], "stamp_s": msg["t_tx_s"] + 0.001,
                   "dst": msg["src"], "req_seq": msg["seq"], "turnaround_s": 0.001,
                   "t_tx_s": msg["t_tx_s"] + 0.001, "pos_m": [100.0, 0.0, 0.0],
                   "cov_m2": np.eye(3), "n_updates": seq[0], "state": "surveying"}
            out = M.encode(rsp, {"pos_m": [100.0, 0.0, 0.0], "t_true_s": phy["t_true_s"] + 0.001})
            bus.publish(M.key_for(rsp), out)

    bus.subscribe("larns/station/*/range/req/2", on_req)
    bus.declare_token("larns/alive/station/2")
    time.sleep(duration_s)
    bus.close()


def _initiator(listen: str, connect: list[str], n: int, period_s: float, warmup: int) -> dict:
    """Sends one request every ``period_s`` (like one exchange per slot) and stamps each answer
    on arrival (decoded, in the Zenoh callback). Lost = never answered within 1 s."""
    from net import messages as M
    from net.bus import Bus

    bus = Bus(listen=[listen], connect=connect)
    recv: dict[int, int] = {}

    def on_rsp(k: str, d: bytes) -> None:
        t = time.perf_counter_ns()
        msg, _ = M.decode(d)
        recv.setdefault(msg["req_seq"], t)

    bus.subscribe("larns/station/*/range/rsp/1", on_rsp)
    t0 = time.time()
    while not bus.alive("larns/alive/station/2", 0.5) and time.time() - t0 < 20:
        time.sleep(0.05)
    time.sleep(0.3)
    sent: dict[int, int] = {}
    next_t = time.perf_counter()
    for i in range(1, n + warmup + 1):
        next_t += period_s
        req = {"kind": "range_req", "src": 1, "seq": i, "stamp_s": float(i), "dst": 2,
               "cycle": i, "slot": 0, "t_tx_s": float(i)}
        data = M.encode(req, {"pos_m": [0.0, 0.0, 0.0], "t_true_s": float(i)})
        sent[i] = time.perf_counter_ns()
        bus.publish(M.key_for(req), data)
        delay = next_t - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
    time.sleep(1.0)
    bus.close()
    rtts = [(recv[i] - sent[i]) / 1e6 for i in range(warmup + 1, n + warmup + 1) if i in recv]
    return {"rtt_ms": rtts, "lost": n - len(rtts)}


def run_bench_net(n: int = 2000, period_s: float = 0.005, warmup: int = 50) -> dict:
    from net.bus import free_tcp_ports

    load0 = os.getloadavg()[0]

    p1, p2 = free_tcp_ports(2)
    e1, e2 = f"tcp/127.0.0.1:{p1}", f"tcp/127.0.0.1:{p2}"
    dur = 30 + (n + warmup) * (period_s + 0.002)
    resp = subprocess.Popen([sys.executable, "-m", "larns.bench.net", "_responder", e2, e1, str(dur)])
    try:
        out = subprocess.run([sys.executable, "-m", "larns.bench.net", "_initiator", e1, e2, str(n),
                              str(period_s), str(warmup)], capture_output=True, text=True,
                             timeout=dur + 30)
        if out.returncode != 0:
            raise RuntimeError(out.stderr[-2000:])
        res = json.loads(out.stdout.strip().splitlines()[-1])
    finally:
        resp.terminate()
        try:
            resp.wait(10)
        except subprocess.TimeoutExpired:
            resp.kill()
    r = np.asarray(res["rtt_ms"], float)
    stats = {"n": int(r.size), "lost": int(res["lost"]), "period_ms": period_s * 1e3,
             "loadavg_1min": [load0, os.getloadavg()[0]], "cpus": os.cpu_count()}
    if r.size:
        stats.update({"p50_ms": float(np.percentile(r, 50)), "p90_ms": float(np.percentile(r, 90)),
                      "p99_ms": float(np.percentile(r, 99)), "max_ms": float(r.max()),
                      "mean_ms": float(r.mean())})
    return stats


def cmd_bench_net(args: argparse.Namespace) -> int:
    s = run_bench_net(args.n, args.period_ms / 1e3)
    print("larns bench net: range_req -> range_rsp round trip, 2 processes, Zenoh peer on loopback")
    print(f"{'samples':>8} {'lost':>5} {'p50 ms':>8} {'p90 ms':>8} {'p99 ms':>8} {'max ms':>8}")
    print(f"{s['n']:>8} {s['lost']:>5} {s.get('p50_ms', float('nan')):>8.3f} "
          f"{s.get('p90_ms', float('nan')):>8.3f} {s.get('p99_ms', float('nan')):>8.3f} "
          f"{s.get('max_ms', float('nan')):>8.3f}")
    print(f"machine load (1-min average) before/after: {s['loadavg_1min'][0]:.1f} / "
          f"{s['loadavg_1min'][1]:.1f} on {s['cpus']} CPUs (other jobs inflate the tail)")
    goal = s.get("p99_ms", 1e9) < 10.0
    print(f"goal p99 < 10 ms slot: {'PASS' if goal else 'FAIL'}")
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(s, indent=2))
    print(f"wrote {args.json}")
    return 0


# --------------------------------------------------------------------------- bench scale

def _proc_stats(pid: int) -> tuple[float, int]:
    """(cpu seconds user+sys, rss bytes) of a live process from /proc."""
    with open(f"/proc/{pid}/stat") as f:
        parts = f.read().rsplit(")", 1)[1].split()
    tick = os.sysconf("SC_CLK_TCK")
    cpu = (int(parts[11]) + int(parts[12])) / tick
    rss = int(parts[21]) * os.sysconf("SC_PAGE_SIZE")
    return cpu, rss


def _scale_router(router_ep: str, run_s: float, router_nice: int, slice_us: float | None,
                  secure: str | None) -> subprocess.Popen:
    """Start the ``larns router`` of the client/router topology."""
    router = subprocess.Popen([sys.executable, "-m", "larns.commands.router", "--listen", router_ep, "--quiet",
                               "--duration", str(run_s), "--nice", str(router_nice)]
                              + ([] if slice_us is None else ["--slice-us", str(slice_us)])
                              + (["--secure", secure, "--scenario", "seed000"] if secure else []))
    time.sleep(1.0)
    return router


def _scale_station_argv(sid: int, n: int, epoch: float, duration_s: float, nice: int, journal: bool,
                        slice_us: float | None, secure: str | None, topology: str, router_ep: str,
                        listen: str, seeds: list[str]) -> list[str]:
    """``python -m stations`` arguments of station ``sid`` in the scale benchmark."""
    cmd = [sys.executable, "-m", "stations", "--id", str(sid), "--scenario", "seed000",
           "--n-stations", str(n), "--epoch", repr(epoch), "--duration", str(duration_s),
           "--quiet", "--report-json", "--nice", str(nice)]
    if not journal:
        cmd += ["--no-journal"]
    if slice_us is not None:
        cmd += ["--slice-us", str(slice_us)]
    if secure:  # TLS/mTLS, access control, signed messages, receive guards (docs/security.md)
        cmd += ["--secure", secure]
    if topology == "router":
        return cmd + ["--zenoh-mode", "client", "--connect", router_ep]
    cmd += ["--listen", listen]
    for s in seeds:
        if s != listen:
            cmd += ["--connect", s]
    return cmd


def _stats_of(proc: subprocess.Popen | None):
    return _proc_stats(proc.pid) if proc is not None and proc.poll() is None else None


def _scale_measure(procs: list[subprocess.Popen], router: subprocess.Popen | None, epoch: float,
                   duration_s: float) -> dict:
    """CPU and RSS of the stations (and router) over the steady part of the run: from 5 s after the
    epoch to 1 s before the end."""
    time.sleep(max(0.0, epoch + 5.0 - time.time()))
    c0 = {p.pid: _proc_stats(p.pid)[0] for p in procs if p.poll() is None}
    r0 = _stats_of(router)
    t_c0 = time.time()
    time.sleep(max(0.0, epoch + duration_s - 1.0 - time.time()))
    cpu_rss = {p.pid: _proc_stats(p.pid) for p in procs if p.poll() is None}
    r1 = _stats_of(router)
    dt = time.time() - t_c0
    return {"cpu": [(cpu_rss[pid][0] - c0[pid]) / dt for pid in cpu_rss if pid in c0],
            "rss": [cpu_rss[pid][1] for pid in cpu_rss],
            "router_cpu_pct": float((r1[0] - r0[0]) / dt * 100) if r0 and r1 else None,
            "router_rss_mb": float(r1[1] / 2**20) if r1 else None}


def _scale_collect(procs: list[subprocess.Popen], router: subprocess.Popen | None, duration_s: float) -> list:
    """Each station's final JSON report (None if it printed none); the router is stopped."""
    reports = []
    for p in procs:
        out, _ = p.communicate(timeout=duration_s + 60)
        lines = [ln for ln in (out or "").splitlines() if ln.startswith("{")]
        reports.append(json.loads(lines[-1]) if lines else None)
    if router is not None:
        router.terminate()
        try:
            router.wait(10)
        except subprocess.TimeoutExpired:
            router.kill()
    return reports


def _median_of(ok: list[dict], q: str) -> float:
    return float(np.median([r["range_delay_ms"][q] for r in ok if r.get("range_delay_ms")] or [float("nan")]))


def _scale_result(n: int, duration_s: float, reports: list, m: dict) -> dict:
    ok = [r for r in reports if r]
    cpu, rss = m["cpu"], m["rss"]
    return {
        "n": n, "duration_s": duration_s, "reported": len(ok),
        "missed_slots": int(sum(r["missed_slots"] for r in ok)),
        "slots": int(sum(r["slots"] for r in ok)),
        "late_replies": int(sum(r["late"] for r in ok)),
        "requests": int(sum(r["counters"].get("requests", 0) for r in ok)),
        "responses": int(sum(r["counters"].get("responses", 0) for r in ok)),
        "max_lateness_ms": float(max((r["max_lateness_ms"] for r in ok), default=float("nan"))),
        "range_delay_p50_ms": _median_of(ok, "p50"),
        "range_delay_p99_ms": _median_of(ok, "p99"),
        "cpu_per_proc_pct": float(np.mean(cpu) * 100) if cpu else float("nan"),
        "cpu_total_pct": float(np.sum(cpu) * 100) if cpu else float("nan"),
        "rss_per_proc_mb": float(np.mean(rss) / 2**20) if rss else float("nan"),
    }


def _scale_line(res: dict, topology: str, load0: float) -> str:
    return (f"  {topology} N={res['n']:3d} missed={res['missed_slots']:5d}/{res['slots']:6d} "
            f"replies {res['responses']}/{res['requests']} late={res['late_replies']} "
            f"max_lateness={res['max_lateness_ms']:.2f} ms cpu/proc={res['cpu_per_proc_pct']:.1f}% "
            f"rss/proc={res['rss_per_proc_mb']:.0f} MB "
            + (f"router cpu={res['router_cpu_pct']:.1f}% " if res["router_cpu_pct"] is not None else "")
            + f"load before={load0:.1f} "
            f"-> {'OK' if res['ok'] else 'MISSED'}")


def run_scale_once(n: int, duration_s: float, warmup_s: float = 4.0, quiet: bool = False,
                   nice: int = 0, topology: str = "peer", journal: bool = True, router_nice: int = 0,
                   slice_us: float | None = None, secure: str | None = None) -> dict:
    """N station processes at speed 1 for ``duration_s`` (fleet time after warm-up).

    ``topology`` "peer": full mesh by gossip from two seed stations; "router": one ``larns router``
    process and every station a Zenoh client of it (its CPU is reported separately)."""
    from net.bus import free_tcp_ports

    if topology not in ("peer", "router"):
        raise ValueError("topology must be peer or router")
    ports = free_tcp_ports(n + 1)
    seeds = [f"tcp/127.0.0.1:{p}" for p in ports[:2]]
    router_ep = f"tcp/127.0.0.1:{ports[n]}"
    load0 = os.getloadavg()[0]
    router = None
    if topology == "router":
        router = _scale_router(router_ep, duration_s + warmup_s + 0.5 * n + 30, router_nice, slice_us, secure)
    start = time.time()
    epoch = start + warmup_s + 0.5 * n
    procs = [subprocess.Popen(_scale_station_argv(k + 1, n, epoch, duration_s, nice, journal, slice_us, secure,
                                                  topology, router_ep, f"tcp/127.0.0.1:{ports[k]}", seeds),
                              stdout=subprocess.PIPE, text=True) for k in range(n)]
    m = _scale_measure(procs, router, epoch, duration_s)  # CPU measured over the steady part only
    res = _scale_result(n, duration_s, _scale_collect(procs, router, duration_s), m)
    res["loadavg_1min_before"] = load0
    res["loadavg_1min_after"] = os.getloadavg()[0]
    res["nice"] = nice
    res["topology"] = topology
    res["router_nice"] = router_nice if topology == "router" else None
    res["journal"] = journal
    res["slice_us"] = slice_us
    res["router_cpu_pct"] = m["router_cpu_pct"]
    res["router_rss_mb"] = m["router_rss_mb"]
    res["ok"] = bool(res["reported"] == n and res["missed_slots"] == 0)
    if not quiet:
        print(_scale_line(res, topology, load0), flush=True)
    return res


def cmd_bench_scale(args: argparse.Namespace) -> int:
    ns = [int(x) for x in args.n.split(",")] if args.n else [10, 20, 30, 40, 50, 60, 70, 80]
    print(f"larns bench scale: N station processes, real time, {args.duration:.0f} s each, "
          f"topology {args.topology}")
    runs, best = [], 0
    secure = None
    if args.secure:  # one keystore for the largest N (a temporary one unless given)
        import tempfile

        from net.keystore import init_keystore

        secure = str(Path(tempfile.mkdtemp(prefix="larns-bench-keys-")) / "keys")
        init_keystore(secure, list(range(1, max(ns) + 1)), [], recorder=False)
        print(f"--secure: keystore {secure} (TLS/mTLS, access control, signed messages)")
    for n in ns:
        r = run_scale_once(n, args.duration, nice=args.nice, topology=args.topology,
                           journal=not args.no_journal, router_nice=args.router_nice, slice_us=args.slice_us,
                           secure=secure)
        runs.append(r)
        if r["ok"]:
            best = max(best, n)
        elif not args.keep_going:
            break
    print(f"{'N':>4} {'missed':>7} {'slots':>7} {'late':>6} {'delay p50/p99 ms':>17} {'cpu/proc %':>10} "
          f"{'cpu total %':>11} {'rss/proc MB':>11} {'router %':>8} {'load':>9}")
    for r in runs:
        d = f"{r['range_delay_p50_ms']:.1f}/{r['range_delay_p99_ms']:.1f}"
        print(f"{r['n']:>4} {r['missed_slots']:>7} {r['slots']:>7} {r['late_replies']:>6} {d:>17} "
              f"{r['cpu_per_proc_pct']:>10.1f} {r['cpu_total_pct']:>11.1f} {r['rss_per_proc_mb']:>11.1f} "
              f"{(r['router_cpu_pct'] if r['router_cpu_pct'] is not None else float('nan')):>8.1f} "
              f"{r['loadavg_1min_before']:>4.1f}/{r['loadavg_1min_after']:<4.1f}")
    print("(missed: own-slot request sent more than half a slot late; late: range message delivered after "
          "its slot; delay: median over stations of the per-station percentile, air tx -> delivery; "
          "load: 1-min load average before/after)")
    print(f"largest N with zero missed slots: {best} (goal >= 50), topology {args.topology}")
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps({"best_n": best, "topology": args.topology, "secure": bool(secure),
                                           "runs": runs}, indent=2))
    print(f"wrote {args.json}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("net", help="Zenoh request/response round trip between two processes (p50/p99)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--n", type=int, default=2000, help="round trips to measure (default 2000)")
    p.add_argument("--period-ms", type=float, default=5.0, help="one exchange every N ms (default 5)")
    p.add_argument("--json", default="runs/bench_net.json", help="JSON output")
    p.set_defaults(func=cmd_bench_net)
    s = sub.add_parser("scale", help="largest N of real-time station processes with zero missed slots",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    s.add_argument("--n", default=None, help="comma-separated N values (default 10,20,...,80)")
    s.add_argument("--duration", type=float, default=60.0, help="seconds per N (default 60)")
    s.add_argument("--keep-going", action="store_true", help="try every N even after a failure")
    s.add_argument("--nice", type=int, default=0, metavar="N",
                   help="niceness change of the station processes (e.g. -10: ahead of other jobs; needs root)")
    s.add_argument("--topology", choices=("peer", "router"), default="peer",
                   help="peer: full mesh by gossip (default); router: one `larns router`, stations are "
                        "Zenoh clients of it (N links instead of N(N-1)/2)")
    s.add_argument("--router-nice", type=int, default=0, metavar="N",
                   help="niceness change of the router process (e.g. -10: ahead of everything; needs root)")
    s.add_argument("--no-journal", action="store_true",
                   help="stations do not publish their core journal (less traffic; not the default setup)")
    s.add_argument("--slice-us", type=float, default=None, metavar="US",
                   help="--slice-us for every station and the router (default: theirs, 100; 0 = kernel default)")
    s.add_argument("--secure", action="store_true",
                   help="run secure (a temporary keystore: TLS/mTLS, access control, signed messages)")
    s.add_argument("--json", default="runs/bench_scale.json", help="JSON output")
    s.set_defaults(func=cmd_bench_scale)


if __name__ == "__main__":
    role = sys.argv[1]
    if role == "_responder":
        _responder(sys.argv[2], [sys.argv[3]], float(sys.argv[4]))
    elif role == "_initiator":
        res = _initiator(sys.argv[2], [sys.argv[3]], int(sys.argv[4]), float(sys.argv[5]), int(sys.argv[6]))
        print(json.dumps(res))
