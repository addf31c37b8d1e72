"""The distributed slot assignment in a fleet of real station processes (issue 33 item 4, docs/slots.md):
seed000's world with ``[tdma] assignment = "distributed"`` and 10 slots for its 10 stations in the
1 s cycle (slots of 100 ms), 40 s at speed 1, recorded. Every station hears every other, so two
stations that pick the same slot collide at all the others: the station process's radio
(``stations.slots.reception_in_slot`` on the slots announced on the air) drops both transmissions and
hands the nav's slot to its core as garbage. Checked from the MCAP alone: no station consumed a nav of
a slot two stations sent in within one cycle, those clashes were heard as garbage, the assignment
settles on distinct slots, the survey reaches the simulator's accuracy on the same world, and every
estimate re-computes bit for bit from the journals (``g`` entries included)."""

from __future__ import annotations

import subprocess
import sys
from collections import defaultdict

import numpy as np
import pytest

# second stage (the default suite is at its budget), with the other fleets of a scenario variant
pytestmark = [pytest.mark.e2e, pytest.mark.matrix, pytest.mark.timeout(600)]

PY = sys.executable
DURATION_S = 40.0
SETTLED_BY_S = 25.0   # fleet s: no clash from here on (the simulator's world settles in 9-10 cycles)


@pytest.fixture(scope="module")
def slots_run(tmp_path_factory):
    from net.scenario import resolve

    tmp = tmp_path_factory.mktemp("slots")
    text = resolve("seed000").read_text().replace('name = "seed000"', 'name = "seed000-slots"')
    assert text.count("slot_s = 0.01\n") == 1
    text = text.replace("slot_s = 0.01\n", 'slot_s = 0.01\nassignment = "distributed"\ncycle_slots = 10\n')
    scn_path = tmp / "slots.toml"
    scn_path.write_text(text)
    out = tmp / "run.mcap"
    r = subprocess.run([PY, "-m", "larns", "fleet", "--scenario", str(scn_path), "--duration", str(DURATION_S),
                        "--record", str(out), "--no-table"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, (r.stdout + r.stderr)[-3000:]
    return scn_path, out


def _read(path) -> tuple[dict, dict, list]:
    """Navs on the wire by ``(cycle, slot)`` -> senders; per station its consumed navs' ``(cycle, slot,
    src)`` and its garbage entries' local times, from the core journals."""
    from mcap.reader import make_reader

    from net import messages as M

    sent: dict[tuple[int, int], set[int]] = defaultdict(set)
    consumed: dict[int, list[tuple[int, int, int]]] = defaultdict(list)
    garbage: dict[int, list[float]] = defaultdict(list)
    navs = []
    with open(path, "rb") as f:
        for _s, ch, m in make_reader(f).iter_messages():
            if M.is_nav_key(ch.topic):
                d = M.decode(m.data)[0]
                sent[(d["cycle"], d["slot"])].add(d["src"])
                navs.append((d["stamp_s"], d["src"], d["slot"]))
            elif ch.topic.endswith("/input"):  # the core journal (larns/station/<id>/input)
                d = M.decode(m.data)[0]
                if d["kind"] != "core_input":
                    continue
                for e in d["entries"]:
                    if e[0] == "g":
                        garbage[d["src"]].append(e[1])
                    elif e[0] == "m" and e[2]["kind"] == "nav":
                        consumed[d["src"]].append((e[2]["cycle"], e[2]["slot"], e[2]["src"]))
    return sent, {"consumed": consumed, "garbage": garbage}, sorted(navs)


def test_clashing_navs_are_lost_and_heard_as_garbage(slots_run):
    _scn, out = slots_run
    sent, journal, _ = _read(out)
    clashes = {k for k, s in sent.items() if len(s) > 1}
    # 10 stations picking among 10 slots: the chance that no two pick alike is about 1 % (two groups of
    # starts: 4 picks among 10, then 6 among the 6 left free)
    assert clashes, "no two stations ever picked the same slot: nothing was tested"
    n_consumed = sum(len(v) for v in journal["consumed"].values())
    assert n_consumed > 1000, n_consumed
    lost = [(sid, c) for sid, cs in journal["consumed"].items() for c in cs if c[:2] in clashes and sid not in sent[c[:2]]]
    assert lost == [], lost[:5]  # every station hears both senders: neither nav decodes
    n_garbage = sum(len(v) for v in journal["garbage"].values())
    assert n_garbage >= len(clashes), (n_garbage, sorted(clashes)[:5])


def test_the_assignment_settles_on_distinct_slots(slots_run):
    _scn, out = slots_run
    sent, _journal, navs = _read(out)
    late = {k: s for k, s in sent.items() if k[0] >= SETTLED_BY_S}  # (cycle of 1 s)
    assert late and all(len(s) == 1 for s in late.values()), sorted((k, s) for k, s in late.items() if len(s) > 1)[:5]
    final = {src: slot for _t, src, slot in navs}
    assert sorted(final) == list(range(1, 11)) and len(set(final.values())) == 10, final


def test_the_survey_matches_the_simulator_and_re_runs_bit_for_bit(slots_run):
    from larns.analysis.summary import mcap_station_summary
    from net.scenario import load
    from stations.sim import Simulator

    scn_path, out = slots_run
    summ = mcap_station_summary(out)
    t_cmp = DURATION_S - 2.0
    err, sig = [], []
    for sid, v in summ.items():
        if sid == 1:
            continue
        k = int(np.searchsorted(np.asarray(v["t_s"]), t_cmp)) - 1
        assert k >= 0, (sid, "no estimate before", t_cmp)
        e = (np.asarray(v["pos_m"])[k] - np.asarray(v["truth_m"]))[:2]
        err.append(float(np.linalg.norm(e)))
        sig.append(float(np.sqrt(np.trace(np.asarray(v["cov_m2"])[k][:2, :2]))))
    fleet_rms = float(np.sqrt(np.mean(np.square(err))))
    r = Simulator(load(scn_path)).run(t_cmp, [t_cmp])
    e_sim = np.linalg.norm((r.pos_m[0] - r.truth_m)[1:, :2], axis=1)
    sim_rms = float(np.sqrt(np.mean(e_sim**2)))
    print(f"[slots fleet] horizontal at {t_cmp:.0f} s: fleet RMS {fleet_rms:.3f} m (errors {np.round(err, 2)}, "
          f"sigma_h {np.round(sig, 2)}), simulator RMS {sim_rms:.3f} m")
    # each its own covariance's claim; the field as accurate as the simulator's run of the world within
    # what two slot histories differ by (which stations clash, for how many cycles: in the fleet the
    # picks also depend on when each process heard what; 0.18-0.34 m in fleets beside 0.185 m)
    assert all(e <= 3.0 * s for e, s in zip(err, sig)), (err, sig)
    assert fleet_rms <= 2.0 * sim_rms + 0.1, (fleet_rms, sim_rms)
    rr = subprocess.run([PY, "-m", "larns", "reestimate", str(out), "--check"], capture_output=True, text=True,
                        timeout=300)
    assert rr.returncode == 0, (rr.stdout + rr.stderr)[-3000:]
