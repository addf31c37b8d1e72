"""The fleet's live view: estimate and truth samples from the bus -> per-station table."""

from __future__ import annotations

import math
import threading
from collections import deque
from dataclasses import dataclass, field

from ..log.series import sigma_m


@dataclass
class StationView:
    id: int
    slot: int | None = None
    state: str = "-"
    n_updates: int = 0
    pos_m: list[float] | None = None
    sigma_m: float = math.nan
    truth_m: list[float] | None = None
    t_s: float = math.nan
    dropped: int = 0
    n_estimates: int = 0
    clock_est: dict = field(default_factory=dict)   # estimate stamp -> estimated clock offset, s
    sync_ns: float = math.nan                       # estimated minus true offset vs network time, ns
    excludes: list = field(default_factory=list)    # peers its latest integrity message excludes

    @property
    def err_m(self) -> float:
        if self.pos_m is None or self.truth_m is None:
            return math.nan
        return math.dist(self.pos_m, self.truth_m)


@dataclass
class Monitor:
    """Collects estimate and truth messages from the bus (thread-safe snapshot)."""

    views: dict[int, StationView] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)
    alive: set = field(default_factory=set)
    aircraft: dict[tuple[str, str], dict] = field(default_factory=dict)  # (name, algo) -> last estimate
    ac_truth: dict[str, deque] = field(default_factory=dict)              # name -> recent truths
    vehicle: dict[str, dict] = field(default_factory=dict)                # name -> last veh_estimate
    veh_truth: dict[str, dict] = field(default_factory=dict)              # name -> {t_s: veh_truth}, recent

    def on_sample(self, key: str, data: bytes) -> None:
        from net import messages as M

        try:
            msg, _ = M.decode(data)
        except M.MessageError:
            return
        if msg["kind"] in ("ac_estimate", "ac_truth"):
            with self.lock:
                if msg["kind"] == "ac_truth":
                    self.ac_truth.setdefault(msg["src"], deque(maxlen=256)).append(msg)
                else:
                    self.aircraft[(msg["src"], msg["algo"])] = msg
            return
        if msg["kind"] in ("veh_estimate", "veh_truth"):
            self._on_vehicle(msg)
            return
        if msg["kind"] == "integrity":
            with self.lock:
                v = self.views.setdefault(msg["src"], StationView(msg["src"]))
                v.excludes = sorted(msg.get("excluded", []))
            return
        if msg["kind"] not in ("estimate", "truth"):
            return
        with self.lock:
            v = self.views.setdefault(msg["src"], StationView(msg["src"]))
            if msg["kind"] == "truth":
                v.truth_m = msg["pos_m"]
                est = v.clock_est.pop(msg["stamp_s"], None)
                if est is not None and "clock_error_s" in msg:
                    v.sync_ns = (est - msg["clock_error_s"]) * 1e9
            else:
                if "clock_offset_s" in msg:  # matched with the truth of the same stamp
                    v.clock_est[msg["stamp_s"]] = msg["clock_offset_s"]
                    while len(v.clock_est) > 8:
                        v.clock_est.pop(next(iter(v.clock_est)))
                v.pos_m = msg["pos_m"]
                v.n_updates = msg["n_updates"]
                v.state = msg["state"]
                v.slot = msg.get("slot", v.slot)
                v.dropped = msg.get("dropped", v.dropped)
                v.t_s = msg["t_s"]
                v.n_estimates += 1
                v.sigma_m = float(sigma_m(msg["cov_m2"]))

    def _on_vehicle(self, msg: dict) -> None:
        """The vehicle publishes its truth at each estimate's time: matched by ``t_s``."""
        with self.lock:
            if msg["kind"] == "veh_truth":
                hist = self.veh_truth.setdefault(msg["src"], {})
                hist[msg["t_s"]] = msg
                while len(hist) > 64:
                    hist.pop(next(iter(hist)))
            else:
                self.vehicle[msg["src"]] = msg

    def vehicle_lines(self) -> list[str]:
        """One line per vehicle: its last estimate's error against its truth at the same time."""
        out = []
        with self.lock:
            for name, m in sorted(self.vehicle.items()):
                tr = self.veh_truth.get(name, {}).get(m["t_s"])
                err = math.dist(m["pos_m"], tr["pos_m"]) if tr else math.nan
                out.append(f"vehicle  {name:>6} {m['algo']:>10}: t={m['t_s']:7.1f} s  sigma "
                           f"{float(sigma_m(m['cov_m2'])):7.2f} m  error {err:7.2f} m  updates {m['n_updates']}")
        return out

    def on_alive(self, key: str, alive: bool) -> None:
        with self.lock:
            (self.alive.add if alive else self.alive.discard)(key)

    def snapshot(self) -> list[StationView]:
        with self.lock:
            return [StationView(**{**vars(v), "clock_est": {}}) for _, v in sorted(self.views.items())]

    def aircraft_lines(self) -> list[str]:
        """One line per (aircraft, algorithm): estimate error against the truth sample nearest in time."""
        out = []
        with self.lock:
            for (name, algo), m in sorted(self.aircraft.items()):
                hist = self.ac_truth.get(name)
                # truth sample nearest in time to the estimate (the aircraft moves fast)
                tr = min(hist, key=lambda h: abs(h["t_s"] - m["t_s"])) if hist else None
                err = math.dist(m["pos_m"], tr["pos_m"]) if tr else math.nan
                sig = float(sigma_m(m["cov_m2"]))
                line = f"aircraft {name:>6} {algo:>10}: t={m['t_s']:7.1f} s  sigma {sig:7.2f} m  error {err:7.2f} m"
                if "hpl_m" in m:
                    line += f"  HPL {m['hpl_m']:7.2f} m  VPL {m.get('vpl_m', math.nan):7.2f} m"
                if m.get("excluded"):
                    line += f"  EXCLUDED {','.join(map(str, m['excluded']))}"
                out.append(line)
        return out


def format_table(views: list[StationView], t_s: float, n_alive: int | None = None) -> str:
    head = f"fleet time {t_s:7.1f} s" + (f"   processes alive: {n_alive}" if n_alive is not None else "")
    lines = [head, f"{'station':>7} {'state':>9} {'slot':>4} {'updates':>7} {'x m':>9} {'y m':>9} "
                   f"{'z m':>8} {'sigma m':>8} {'error m':>8} {'drops':>5} {'sync ns':>8}"]
    for v in views:
        p = v.pos_m or [math.nan] * 3
        lines.append(f"{v.id:>7} {v.state:>9} {'-' if v.slot is None else v.slot:>4} {v.n_updates:>7} "
                     f"{p[0]:>9.2f} {p[1]:>9.2f} {p[2]:>8.2f} {v.sigma_m:>8.2f} {v.err_m:>8.2f} {v.dropped:>5} "
                     f"{v.sync_ns:>8.2f}")
    for v in views:  # integrity (issue 14): who is excluded by whom
        by = [o.id for o in views if v.id in o.excludes]
        if by:
            lines.append(f"{'':>7} station {v.id} EXCLUDED by {','.join(map(str, by))}")
    errs = [v.err_m for v in views if v.state != "frame" and not math.isnan(v.err_m)]
    if errs:
        rms = math.sqrt(sum(e * e for e in errs) / len(errs))
        lines.append(f"{'':>7} RMS error of surveying stations: {rms:.2f} m")
    return "\n".join(lines)
