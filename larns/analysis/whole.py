"""A fleet run scored whole from its recording alone (issue 28's defaults matrix, ``larns info``).

Everything here reads the MCAP: station estimates against their truth topics (in a field that holds
its own datum, ``[survey] datum = "field"``, that truth moved into the field's datum:
``larns.analysis.datum``), each station's clock
against network time (its ``truth.clock_error_s``), the field's agreement on network time, every
aircraft algorithm and every vehicle against its own truth, and the statuses the navigators published.

**Agreement on network time.** Each station realizes network time through its own clock filter; a
station's truth scores it against its own definition, which says nothing about whether the stations
define the *same* time. The recording holds each station's broadcast clock correction; the world's
true oscillator of each station is drawn from the scenario's seed exactly as its process draws it
(``net.nettime``), so the realization ``E_i(t) = x_i(t) - theta_i(T)`` of every station can be compared
at the same instant: ``time_spread_ns`` is the largest ``max_i E_i - min_i E_i`` over the synchronized
stations (broadcast clock sigma below 1 us) sampled at each nav after ``after_s``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .metrics import aircraft_accuracy
from .summary import station_table, vehicle_row


def _time_spread_ns(rec, scn, after_s: float) -> float | None:
    """Largest spread of the stations' realizations of network time after ``after_s`` (ns)."""
    from nav.geometry import SPEED_OF_LIGHT_M_S  # noqa: F401  (units in the docstring)
    from net import messages as M
    from net.nettime import network_time

    nt = network_time(scn, scn.seed)
    if nt is None:
        return None
    last: dict[int, tuple] = {}
    worst = 0.0
    seen = False
    for m, msg in rec.records:
        if msg is None or msg.get("kind") != "nav" or msg.get("clock") is None:
            continue
        try:
            _, phy = M.decode(m.data)
        except M.MessageError:
            continue
        t = float(phy["t_true_s"]) if phy else float(msg["stamp_s"])
        last[int(msg["src"])] = tuple(msg["clock"])
        if t < after_s:
            continue
        real = []
        for sid, (t_ref, off, freq, p00, p01, p11) in last.items():
            x = nt.clock(sid).error_s(t)
            dT = t + x - t_ref
            if p00 + 2 * dT * p01 + dT * dT * p11 > 1e-12:
                continue
            real.append(x - (off + freq * dT))
        if len(real) >= 2:
            seen = True
            worst = max(worst, (max(real) - min(real)) * 1e9)
    return worst if seen else None


def score(path, scn=None, after_s: float = 30.0, t_to_s: float | None = None) -> dict[str, Any]:
    """The run's numbers: ``stations`` (the ``larns info`` rows, each with ``err_h_m`` and its
    horizontal ``sigma_h_m``; in a field that holds its own datum, against the truth in that datum:
    :func:`larns.analysis.summary.station_table`), ``time_spread_ns`` (module docstring; None without station clocks),
    ``aircraft`` {name: {algo: :func:`aircraft_accuracy` + ``statuses`` {state: count}}}, ``vehicles``
    (the ``larns info`` rows)."""
    from ..log.series import load

    rec = load([path])
    out: dict[str, Any] = {"stations": station_table(rec, scn)}
    for sid, row in out["stations"].items():
        s = rec.stations[sid].last
        if s is not None and "truth_m" in row:
            d = np.asarray(s["pos_m"], float) - np.asarray(row["truth_m"], float)
            P = np.asarray(s["cov_m2"], float)
            row["err_h_m"] = float(math.hypot(d[0], d[1]))
            row["sigma_h_m"] = float(math.sqrt(max(P[0, 0] + P[1, 1], 0.0)))
    out["time_spread_ns"] = _time_spread_ns(rec, scn, after_s) if scn is not None else None
    out["aircraft"] = {}
    for name, a in sorted(rec.aircraft.items()):
        tt = a.truth_track()
        algos = {}
        for algo in sorted(set(a.estimates) | set(a.statuses)):
            row = (aircraft_accuracy(a.track(algo), tt, after_s, t_to_s)
                   if algo in a.estimates and tt is not None else {"n": 0})
            counts: dict[str, int] = {}
            for st in a.statuses.get(algo, ()):
                counts[st["state"]] = counts.get(st["state"], 0) + 1
            row["statuses"] = counts
            algos[algo] = row
        out["aircraft"][name] = algos
    out["vehicles"] = {name: vehicle_row(v) for name, v in sorted(rec.vehicles.items())}
    return out
