"""The aircraft navigator's journal (aircraft/journal.py): each core (radio, INS, triad) driven like the
node drives it, with an irregular loop; its published ``ac_init`` / ``ac_input`` messages, through
the wire schema, re-fly every published estimate bit for bit (``larns.analysis.offline``); a removed
journal message stops the re-flight exactly there; the journal holds what the navigator saw, never
the truth."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from aircraft.events import to_msgs
from net import messages as M

SECONDS = 14.0  # past the inertial cores' 10 s start window


@functools.lru_cache(maxsize=None)
def _fly(kind: str, loop_step_s: float = 0.37):
    """(core, published messages as the wire carries them, the navs' phy positions)."""
    from aircraft.config import from_scenario
    from net.scenario import load

    sc = load("seed003-text")
    ac = from_scenario(sc)
    if kind == "ins":
        from aircraft.ins_core import InsAircraftCore

        core = InsAircraftCore(sc, ac, "ac1", np.random.default_rng(9), seed=5)
    elif kind == "triad":
        from aircraft.triad_core import TriadAircraftCore

        core = TriadAircraftCore(sc, ac, "ac1", n_sv=4, seed=5)
    else:
        from aircraft.radio_core import RadioAircraftCore

        core = RadioAircraftCore(ac, ("ukf-pr", "lsq-pr", "ekf-tdoa"), "ac1", np.random.default_rng(3),
                                 horizon_s=60.0)
    rng = np.random.default_rng(2)
    out, seq, t_loop = [], {}, 0.0
    for k in range(int(SECONDS / sc.tdma.slot_s)):
        t = k * sc.tdma.slot_s
        j = k % 8
        if kind != "radio":  # the node's loop integrates the IMU behind fleet time, at its own pace
            while t_loop + loop_step_s < t - core.lag_s:
                t_loop += loop_step_s * (0.5 + rng.random())
                core.advance_to(t_loop)
        seq[j] = seq.get(j, 0) + 1
        msg = {"kind": "nav", "src": j + 1, "seq": seq[j], "stamp_s": t, "cycle": seq[j], "slot": j, "t_tx_s": t,
               "pos_m": (sc.pos_m[j] + rng.normal(0, 0.05, 3)).tolist(), "cov_m2": (0.05**2 * np.eye(3)).tolist(),
               "n_updates": 1, "state": "frame", "ranges": [], "members": []}
        out += to_msgs(core.on_nav(msg, {"pos_m": sc.pos_m[j].tolist(), "t_true_s": t}) + core.journal.take())
    out += to_msgs(core.journal.close())
    return core, [M.decode(M.encode(o))[0] for o in out]


def _recording(msgs: list[dict], drop_input: int | None = None):
    from larns.log import Msg

    rec = []
    for i, m in enumerate(msgs):
        if m["kind"] == "ac_input" and m["seq"] == drop_input:
            continue
        ns = int(m["stamp_s"] * 1e9) + i
        rec.append(Msg(M.key_for(m), ns, ns, m["seq"], M.encode(m)))
    return rec


@pytest.fixture(scope="module", params=["radio", "ins", "triad"])
def flown(request):
    return (request.param, *_fly(request.param))


def test_the_journal_re_flies_every_estimate_bit_for_bit(flown):
    from larns.analysis.offline import reestimate_aircraft

    kind, core, msgs = flown
    est = [m for m in msgs if m["kind"] == "ac_estimate"]
    algos = sorted({m["algo"] for m in est})
    assert len(est) > 30 and algos == sorted(core.estimators if kind == "radio" else [core.algo if kind == "triad"
                                                                                          else "ins-ekf"])
    res = reestimate_aircraft(_recording(msgs))["ac1"]
    assert sorted(res) == algos
    for algo, d in res.items():
        n = sum(m["algo"] == algo for m in est)
        assert d["error"] is None and d["missing_from"] is None and d["stopped"] is None, d
        assert d["n"] == d["recorded"] == d["compared"] == d["equal"] == n > 0, d
        assert d["rerun"]["samples"] > 0, d


def test_a_removed_journal_message_stops_the_re_flight_exactly_there(flown):
    from larns.analysis.offline import reestimate_aircraft

    kind, _core, msgs = flown
    n_in = max(m["seq"] for m in msgs if m["kind"] == "ac_input")
    hole = n_in - 2  # past the inertial start window
    res = reestimate_aircraft(_recording(msgs, drop_input=hole))["ac1"]
    t_hole = next(m["stamp_s"] for m in msgs if m["kind"] == "ac_input" and m["seq"] == hole)
    for algo, d in res.items():
        assert d["missing_from"] == hole and d["inputs"] == hole - 1 and d["stopped_at_s"] <= t_hole, d
        assert 0 < d["compared"] < d["recorded"] and d["equal"] == d["compared"], d


def test_the_journal_holds_what_the_navigator_saw_never_the_truth(flown):
    kind, core, msgs = flown
    entries = [e for m in msgs if m["kind"] == "ac_input" for e in m["entries"]]
    inits = [m for m in msgs if m["kind"] == "ac_init"]
    assert inits[0]["seq"] == 1 and inits[0]["record"]["kind"] == kind
    assert len(inits) == 1 + max(m["seq"] for m in msgs if m["kind"] == "ac_input") // 10  # re-sent every 10
    from net.scenario import load

    ms = [e for e in entries if e[0] == "m"]
    assert len(ms) == sum(m["kind"] == "ac_truth" for m in msgs)  # one measurement per measured broadcast
    # the broadcast (estimated) station positions, never the senders' true ones (phy)
    true_pos = {tuple(p) for p in np.asarray(load("seed003-text").pos_m, float).tolist()}
    assert not any(tuple(e[3]) in true_pos for e in ms)
    imu = sum(len(e[2]) for e in entries if e[0] == "imu")
    if kind == "radio":
        assert imu == 0
    else:  # every IMU step once, in order
        ks = [e[1] + i for e in entries if e[0] == "imu" for i in range(len(e[2]))]
        assert ks == list(range(core.imu_steps))
    # compact: per second of flight (msgpack doubles; the INS at 100 Hz is the largest)
    rate = sum(len(M.encode(m)) for m in msgs if m["kind"] in ("ac_input", "ac_init")) / SECONDS
    assert rate < {"radio": 2500, "ins": 8000, "triad": 3000}[kind], rate


def test_other_algorithms_on_the_same_journal():
    """Radio filters re-run on an inertial aircraft's measurements; an algorithm whose inputs the
    journal does not hold says so."""
    from larns.analysis.offline import reestimate_aircraft

    _core, msgs = _fly("ins")
    res = reestimate_aircraft(_recording(msgs), algos=["ekf-pr", "triad"])["ac1"]
    assert res["ins-ekf"]["equal"] == res["ins-ekf"]["compared"] > 30
    assert res["ekf-pr"]["error"] is None and res["ekf-pr"]["n"] > 30 and res["ekf-pr"]["compared"] == 0
    assert res["triad"]["error"] == "the journal of a ins aircraft holds no inputs for triad"


@pytest.mark.parametrize("entries", [
    3,
    [["x", 1.0]],
    [["m", 1.0, 2, [0.0, 0.0, 0.0], np.eye(3).tolist(), 0.0, float("nan")]],   # pseudorange not finite
    [["m", 1.0, 0, [0.0, 0.0, 0.0], np.eye(3).tolist(), 0.0, 1.0]],            # station id 0
    [["m", 1.0, 2, [0.0, 0.0, 0.0], np.eye(3).tolist(), -1.0, 1.0]],           # negative clock variance
    [["imu", 0, [[0.0, 0.0, 0.0]], []]],                                        # unequal gyro / accel
    [["imu", -1, [[0.0, 0.0, 0.0]], [[0.0, 0.0, 0.0]]]],                        # negative step
    [["sv", 3, ["far"], None]],
    [["t", 1.0]] * 2,
])
def test_the_wire_schema_rejects_malformed_journals(entries):
    good = {"kind": "ac_input", "src": "ac1", "seq": 1, "stamp_s": 1.0,
            "entries": [["m", 1.0, 2, [0.0, 0.0, 0.0], np.eye(3).tolist(), 0.0, 1.0],
                        ["imu", 0, [[0.0, 0.0, 0.0]], [[0.0, 0.0, 0.0]]], ["sv", 3, [1.0, None], None]]}
    assert M.decode(M.encode(good))[0]["entries"] == good["entries"]
    with pytest.raises(M.MessageError):
        M.encode(dict(good, entries=entries))
    with pytest.raises(M.MessageError):  # an init record of no known navigator kind
        M.encode({"kind": "ac_init", "src": "ac1", "seq": 1, "stamp_s": 0.0, "record": {"kind": "sonar"}})
