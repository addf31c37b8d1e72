"""CPU of the live radio aircraft's core at its scenario's broadcast rate (``larns bench aircraft``'s
speed section): the sans-I/O :class:`aircraft.radio_core.RadioAircraftCore` (world side: light-time
channel, plausibility; navigator side: every algorithm with its integrity and divergence monitors;
the journal) fed the stations' nav broadcasts in their TDMA slots as the node hands them over (one
per ``slot_s``: seed001's four stations at 100 Hz), every returned message encoded for the wire.
The broadcasts carry an estimated position (truth + 5 cm noise, covariance 5 cm) and a clock
correction known to 0.7 ns, so the filters carry the stations' clock-bias states as in a fleet.

What it leaves out is the process shell (Zenoh receive and publish, decoding): a fleet's aircraft
process adds that, measured from ``/proc`` in docs/aircraft.md ("CPU of the live process").
"""

from __future__ import annotations

import time

import numpy as np

CLOCK_SIGMA_S = 0.7e-9  # the broadcast clock correction's sigma (a converged TCXO field, docs/sync.md)


def nav_broadcasts(sc, seconds: float, rng: np.random.Generator) -> list[tuple[dict, dict]]:
    """``(nav message, phy)`` pairs of the scenario's stations in their TDMA slots for ``seconds``."""
    n = len(sc.pos_m)
    slot, out = sc.tdma.slot_s, []
    for k in range(int(seconds / slot)):
        t, j = k * slot, k % n
        msg = {"kind": "nav", "src": j + 1, "seq": k // n + 1, "stamp_s": t, "cycle": k // n + 1, "slot": j,
               "t_tx_s": t, "pos_m": (sc.pos_m[j] + rng.normal(0.0, 0.05, 3)).tolist(),
               "cov_m2": (0.05**2 * np.eye(3)).tolist(), "n_updates": k // n + 1, "state": "frame",
               "ranges": [], "members": [], "clock": [t, 0.0, 0.0, CLOCK_SIGMA_S**2, 0.0, 1e-24]}
        out.append((msg, {"pos_m": sc.pos_m[j].tolist(), "t_true_s": t}))
    return out


def core_cpu_s(sc, ac, algos: tuple[str, ...], navs: list[tuple[dict, dict]]) -> tuple[float, int]:
    """CPU seconds (this process) of one core running ``algos`` over ``navs``, and messages returned."""
    from aircraft.radio_core import RadioAircraftCore
    from net import messages as M

    span = navs[-1][1]["t_true_s"] + 5.0
    core = RadioAircraftCore(ac, algos, "ac1", np.random.default_rng(3), horizon_s=span)
    n_out = 0
    c0 = time.process_time()
    for msg, phy in navs:
        for ev in core.on_nav(msg, phy) + core.journal.take():
            M.encode(ev.to_msg())
            n_out += 1
    return time.process_time() - c0, n_out


def live_core_cpu(sc, ac, seconds: float = 20.0) -> dict:
    """Percent of one core per second of flight: every algorithm of the scenario together, and each
    alone; the broadcast rate and the number of messages published."""
    navs = nav_broadcasts(sc, seconds, np.random.default_rng(11))
    algos = tuple(a for a in ac.nav.algos if a not in ("ins-ekf", "triad"))
    cpu, n_out = core_cpu_s(sc, ac, algos, navs)
    each = {a: 100.0 * core_cpu_s(sc, ac, (a,), navs)[0] / seconds for a in algos}
    return {"seconds": seconds, "broadcasts_per_s": len(navs) / seconds, "algos": list(algos),
            "all_pct_of_core": 100.0 * cpu / seconds, "each_pct_of_core": each,
            "messages_per_s": n_out / seconds}
