"""The live vehicle's sans-I/O core (vehicle/core.py) and navigator (vehicle/navigator/live.py):
fed synthetic station broadcasts in-process, no Zenoh."""

from __future__ import annotations

import numpy as np
import pytest

from net import messages as M
from net.scenario import load
from vehicle.core import VehicleCore, vehicle_map
from vehicle.field import field_layout
from vehicle.navigator.live import ALGO, VehicleNavigator, replay


def _broadcasts(scn, t_end_s: float, cycle_s: float = 1.0, slot_s: float = 0.01, sigma_pos_m: float = 0.0):
    """Perfect-sync nav broadcasts (msg, phy) of every station, TDMA order, up to ``t_end_s``."""
    _, _, pos, _, _ = field_layout(scn)
    rng = np.random.default_rng(7)
    seq = {}
    c = 0
    while True:
        for i, sid in enumerate(scn.ids):
            t = c * cycle_s + i * slot_s
            if t > t_end_s:
                return
            seq[sid] = seq.get(sid, 0) + 1
            p = pos[i] + sigma_pos_m * rng.standard_normal(3)
            msg = {"kind": "nav", "src": sid, "seq": seq[sid], "stamp_s": t, "cycle": c, "slot": i, "t_tx_s": t,
                   "pos_m": p.tolist(), "cov_m2": (np.eye(3) * max(sigma_pos_m, 1e-3) ** 2).tolist(),
                   "n_updates": 5, "state": "frame", "ranges": [], "members": list(scn.ids)}
            yield msg, {"pos_m": pos[i].tolist(), "t_true_s": t}
        c += 1


def _drive(core: VehicleCore, scn, t_end_s: float, **kw) -> list[dict]:
    out = []
    for msg, phy in _broadcasts(scn, t_end_s, **kw):
        out += core.advance_to(phy["t_true_s"] - 0.25)
        out += core.on_nav(msg, phy)
    return out + core.close()


@pytest.fixture(scope="module")
def run40():
    scn = load("seed000")
    core = VehicleCore(scn, "veh1", t0_s=2.0, imu_rate_hz=10.0)
    return scn, core, _drive(core, scn, 26.0, sigma_pos_m=0.05)


def test_messages_valid_and_estimate_error_bounded(run40):
    scn, core, out = run40
    kinds = [m["kind"] for m in out]
    assert kinds[0] == "veh_init" and {"veh_input", "veh_estimate", "veh_truth"} <= set(kinds)
    for m in out:  # every message passes the wire schema
        assert M.decode(M.encode(m))[0]["kind"] == m["kind"]
        assert M.key_for(m).startswith(f"larns/vehicle/{core.name}/")
    est = [m for m in out if m["kind"] == "veh_estimate"]
    tru = {m["t_s"]: m for m in out if m["kind"] == "veh_truth"}
    assert all(e["algo"] == ALGO for e in est)
    err = np.array([np.linalg.norm(np.subtract(e["pos_m"], tru[e["t_s"]]["pos_m"])) for e in est])
    sig = np.array([np.sqrt(np.trace(e["cov_m2"])) for e in est])
    late = err[len(err) // 2:]
    assert core.stats["measurements"] > 200
    assert np.max(late) < 2.5, np.max(late)  # 0.5 m pseudoranges, 10 stations; along-track shares the clock
    assert np.mean(late**2) < 9 * np.mean(sig[len(err) // 2:] ** 2)  # covariance not wildly optimistic
    # the truth moves along the route at its speed (5 m/s), in the network frame
    t = sorted(tru)
    v = np.linalg.norm(np.subtract(tru[t[-1]]["pos_m"], tru[t[0]]["pos_m"])) / (t[-1] - t[0])
    assert v == pytest.approx(5.0, rel=0.02)


def test_journal_replay_is_bit_exact(run40):
    _, core, out = run40
    rec = next(m for m in out if m["kind"] == "veh_init")["record"]
    entries = [e for m in out if m["kind"] == "veh_input" for e in M.decode(M.encode(m))[0]["entries"]]
    live = [m for m in out if m["kind"] == "veh_estimate"]
    again = replay(M.decode(M.encode(next(m for m in out if m["kind"] == "veh_init")))[0]["record"], entries)
    assert len(again) >= len(live)
    for a, b in zip(live, again):
        assert {k: a[k] for k in b} == b  # floats compared exactly
    assert rec["t0_s"] == 2.0


def test_init_record_repeats_for_a_late_recorder(run40):
    """A recorder whose link came up after the vehicle's first publish misses the first veh_init: the
    same record follows every INIT_EVERY_INPUTS journal inputs, and the series loader rebuilds the
    navigator from a repeat (offline re-run bit for bit)."""
    from larns.analysis.offline import reestimate_vehicles
    from vehicle.core import INIT_EVERY_INPUTS

    _, core, out = run40
    inits = [i for i, m in enumerate(out) if m["kind"] == "veh_init"]
    n_in = sum(m["kind"] == "veh_input" for m in out)
    assert len(inits) == 1 + n_in // INIT_EVERY_INPUTS and n_in >= INIT_EVERY_INPUTS
    assert all(out[i]["record"] == out[0]["record"] for i in inits)
    from larns.log.reader import Msg

    # the recorder's view when the first init never reached it
    late = [Msg(M.key_for(m), i, i, i, M.encode(m)) for i, m in enumerate(out[1:])]
    r = reestimate_vehicles(late)[core.name]
    assert r["error"] is None and r["compared"] > 50 and r["equal"] == r["compared"], r


def test_outage_and_late_broadcasts_are_counted():
    scn = load("seed000")
    core = VehicleCore(scn, "veh2", t0_s=0.0, outage_s=(3.0, 6.0), imu_rate_hz=10.0)
    out = _drive(core, scn, 8.0)
    assert core.stats["nav_outage"] == pytest.approx(3 * len(scn.ids), abs=len(scn.ids))
    upd = [m["t_s"] for m in out if m["kind"] == "veh_estimate" and m["extra"]["updated"]]
    assert upd and not any(3.0 <= t <= 6.0 for t in upd)
    # a broadcast older than the filter time is late: counted, not journaled
    n = core.stats["measurements"]
    msg, phy = next(_broadcasts(scn, 0.0))
    core.on_nav(msg, phy)
    assert core.stats["nav_late"] == 1 and core.stats["measurements"] == n
    # one from the far future (a bad stamp) is refused, not integrated towards
    core.on_nav(msg, dict(phy, t_true_s=1e9))
    assert core.stats["nav_future"] == 1 and core.blocks < 20


def test_route_file_estimates_are_valid_messages():
    """On a leg along a network-frame axis two position variances are zero in exact arithmetic: the
    published covariances stay valid (no -1e-17 m^2 variance refused by the schema)."""
    scn = load("seed000")
    core = VehicleCore(scn, "veh3", t0_s=0.0, route_file="docs/routes/field-straight.toml", imu_rate_hz=10.0)
    out = _drive(core, scn, 8.0)
    est = [m for m in out if m["kind"] == "veh_estimate"]
    assert len(est) > 40
    for m in est:
        M.encode(m)
        assert min(np.diag(m["cov_m2"])) >= 0.0 and np.allclose(m["cov_m2"], np.transpose(m["cov_m2"]))


def test_navigator_refuses_bad_records_and_route_files(tmp_path):
    with pytest.raises(ValueError, match="missing"):
        VehicleNavigator({"dt_s": 0.05})
    scn = load("seed000")
    gc = tmp_path / "gc.toml"
    gc.write_text('[route]\nkind = "great_circle"\npoints_deg = [[47.2, 39.7], [47.3, 39.8]]\n')
    with pytest.raises(ValueError, match="straight"):
        vehicle_map(scn, gc)
    m = vehicle_map(scn, "docs/routes/field-straight.toml")
    assert m["route_enu_m"][0] == [-1500.0, 1000.0, 20.0] and m["speeds_m_s"] == [5.0]


def test_hostile_vehicle_messages_are_refused_with_the_key_named(run40):
    _, _, out = run40
    inp = next(m for m in out if m["kind"] == "veh_input")
    init = next(m for m in out if m["kind"] == "veh_init")
    bad = [dict(inp, entries=[["imu", 0, [[0.0, 0.0, 0.0]], [], [1.0]]]),            # unequal lengths
           dict(inp, entries=[["m", 1.0, 0, [0.0] * 3, [[0.0] * 3] * 3, 0.0, 1.0, 0.0]]),  # station id 0
           dict(inp, entries=[["m", float("nan"), 1, [0.0] * 3, [[0.0] * 3] * 3, 0.0, 1.0, 0.0]]),
           dict(inp, entries=[["x"]]),
           dict(init, record={k: v for k, v in init["record"].items() if k != "dt_s"}),
           dict(init, record=dict(init["record"], speeds_m_s=[]))]
    for m in bad:
        with pytest.raises(M.MessageError):
            M.validate_msg(M.to_plain(m))


def test_cli_flags_and_fleet_child():
    import argparse

    from larns.fleet.plan import _vehicle_child, wants_vehicle
    from vehicle.node import build_parser

    a = build_parser().parse_args(["--route", "docs/routes/field-straight.toml", "--outage", "100,400",
                                   "--imu-rate", "10", "--speed", "2", "--net-loss", "0.1"])
    assert a.outage == (100.0, 400.0) and a.imu_rate == 10.0 and a.scenario == "seed000"
    with pytest.raises(SystemExit):
        build_parser().parse_args(["--outage", "400,100"])
    ns = argparse.Namespace(vehicle=False, vehicle_route="r.toml", vehicle_outage="1,2", duration=30.0,
                            zenoh_config=None)
    assert wants_vehicle(ns)

    class P:
        seeds, mode, secure, logdir = ["tcp/127.0.0.1:7447"], "peer", None, None

    c = _vehicle_child(ns, P(), ["--scenario", "seed000", "--speed", "2.0", "--epoch", "5.0"])
    assert c.cmd[1:3] == ["-m", "vehicle"] and c.cmd[c.cmd.index("--route") + 1] == "r.toml"
    assert c.cmd[c.cmd.index("--outage") + 1] == "1,2" and c.cmd[c.cmd.index("--until") + 1] == "30.0"


def test_offline_reestimation_of_a_written_recording(run40, tmp_path):
    """The core's messages written as the recorder writes them (one estimate lost on the way):
    ``larns reestimate``'s run re-runs the navigator from the journal, every recorded estimate equal."""
    from larns.analysis.offline import format_result, run_offline
    from larns.log import LogWriter

    _, _, out = run40
    path = tmp_path / "veh.mcap"
    epoch = 1.7e9
    lost = next(m["seq"] for m in out if m["kind"] == "veh_estimate" and m["seq"] > 20)
    with LogWriter(path, {"larns": {"epoch_unix_s": repr(epoch), "speed": "1.0"}}) as w:
        for m in out:
            if m["kind"] == "veh_estimate" and m["seq"] == lost:
                continue
            t = int((epoch + m["stamp_s"]) * 1e9)
            w.write(M.key_for(m), M.encode(m), t, t)
    res = run_offline([path])
    d = res.vehicles["veh1"]
    n_live = sum(m["kind"] == "veh_estimate" for m in out)
    assert d["error"] is None and d["recorded"] == n_live - 1 and d["compared"] == n_live - 1 and d["bit_exact"]
    assert "vehicle veh1 cdekf-map" in format_result(res) and res.as_dict()["vehicles"]["veh1"]["bit_exact"]
    # a hole in the journal stops the re-run there, reported
    with LogWriter(tmp_path / "hole.mcap", {"larns": {"epoch_unix_s": repr(epoch)}}) as w:
        for m in out:
            if not (m["kind"] == "veh_input" and m["seq"] == 5):
                t = int((epoch + m["stamp_s"]) * 1e9)
                w.write(M.key_for(m), M.encode(m), t, t)
    d = run_offline([tmp_path / "hole.mcap"]).vehicles["veh1"]
    assert d["missing_from"] == 5 and d["bit_exact"] and d["n"] < n_live
