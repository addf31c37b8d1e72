"""The product on its own defaults (issue 28): every packaged scenario with every process kind it
configures, run whole as a user launches it (`larns fleet`, real processes over Zenoh), scored from the
MCAP alone (larns/analysis/whole.py).

``MATRIX`` below is the one table: for each file of ``net/scenarios/`` the processes it runs and what its
run must show. Every estimate is checked against its own covariance and against a stated absolute
bound:

* stations: every honest surveying station's horizontal error ``<= 3 sigma_h + 5 cm`` and ``<= survey_m``;
  with station clocks, each station's last sync error ``<= sync_ns`` against network time and the field's
  agreement on network time (``time_spread_ns``, the spread of the stations' realizations of it) ``<=
  spread_ns``; joiners surveying;
* radio aircraft, every algorithm the scenario lists: only valid estimates (finite, PSD; the process
  publishes an ``ac_status`` otherwise), horizontal error ``<= ac_window_m`` from 30 s on and ``<= ac_final_m``
  at the end, the last within ``3 sigma_h + 1 m``, NEES over 30 s .. end within its 95 % band or below
  (filters);
* the inertial aircraft (``ins-ekf``) and the vehicle: final error within ``3 sigma + 1 m`` and ``<= ins_m`` /
  ``veh_m``.

The default scenario (seed000 with the radio aircraft and the vehicle) runs in the default suite; the
rest, and seed000 with ``--secure``, under the marker ``matrix``, which ``./dev test`` runs after the
default suite (CI runs both). Speed 2 (a 90 s run in 45 s of wall time): the fleets of this table keep
97-100 % of their exchanges at that speed on 2 cores; seed001 (10 ms slots in a 40 ms cycle) runs at
speed 1 (46 % of its exchanges at speed 2, 90 % at speed 1).
"""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "net" / "scenarios"
PY = sys.executable
SPEED = 2.0
DURATION_S = 90.0


@dataclass(frozen=True)
class Case:
    """What one scenario runs and must show (module docstring)."""

    aircraft: bool = True            # the scenario's [aircraft] (default: ukf-pr hovering) via --aircraft
    vehicle: bool = False            # --vehicle (the default route)
    faulty: tuple[int, ...] = ()     # stations whose own estimate is not held to the bounds (their fault)
    joiners: tuple[int, ...] = ()    # hot-joining stations that must reach 'surveying'
    survey_m: float = 0.5
    sync_ns: float | None = None     # None: perfect station clocks in this scenario
    spread_ns: float | None = None
    ac_window_m: float = 5.0
    ac_final_m: float = 3.0
    lsq_window_m: float | None = None  # snapshot LSQ: its own bound (no filter memory); None = filters' bounds
    ins_m: float = 10.0
    veh_m: float = 5.0
    speed: float = SPEED             # seed001's 10 ms slots in a 40 ms cycle keep their exchanges at speed 1 only
    nees: bool = True                # the filters' NEES from 30 s on within its 95 % band or below
    intermittent: tuple[str, ...] = ()  # algorithms that hold them in some runs only (test_intermittent_defects)
    extra: tuple[str, ...] = field(default=())


TCXO = dict(sync_ns=2.0, spread_ns=5.0)
MATRIX: dict[str, Case] = {
    "seed000": Case(vehicle=True, **TCXO),
    "seed000-geo": Case(**TCXO),  # seed000's stations given on WGS84 ([site]): the same field on the map
    "seed000-join": Case(joiners=(11,), **TCXO),
    "seed000-liar": Case(faulty=(6,)),
    "seed000-nlos5": Case(),
    "seed000-poll": Case(**TCXO),  # protocol v2: one poll per slot, every member replies (issue 31)
    "seed000-range-bias": Case(faulty=(6,)),
    # a 50 m array seen from 1 km with no prior: one batch's fix is off by kilometres and the curvature
    # that carries the range takes minutes; the filters must stay honest, their accuracy is the start's
    "seed001": Case(**TCXO, survey_m=3.0, speed=1.0, ac_window_m=5000.0, ac_final_m=5000.0, lsq_window_m=5000.0,
                    nees=False, intermittent=("ekf-tdoa", "ukf-tdoa")),
    # 8 stations over 40 x 30 km, the aircraft on a 50 m/s ellipse
    "seed003": Case(**TCXO, survey_m=5.0, ac_window_m=10.0, ac_final_m=5.0, lsq_window_m=100.0, nees=False),
    # the same field heard through a radio ([radio]): links beyond the 26 km horizon do not exist
    "seed003-radio": Case(**TCXO, survey_m=5.0, ac_window_m=10.0, ac_final_m=5.0, lsq_window_m=100.0, nees=False),
    # a ring of 8 stations 5 km around a 300 m hill ([radio] terrain): 12 of 28 pairs masked, the aircraft on
    # a 3 km circle at 1000 m sees all 8 (simulator, 90 s: every station within 0.9 m, sigma_h <= 1.7 m; on a
    # 7 km circle, outside the ring, ekf-pr was 15.5 m off at 30-90 s in one fleet run: beyond ac_window_m)
    "hill": Case(**TCXO, survey_m=5.0, ac_window_m=10.0, ac_final_m=5.0, lsq_window_m=100.0, nees=False),
    "seed003-text": Case(survey_m=5.0),
    "seed003-text-10": Case(survey_m=5.0),
}
DEFAULT = "seed000"


def test_the_matrix_covers_every_packaged_scenario():
    assert sorted(MATRIX) == sorted(p.stem for p in SCENARIOS.glob("*.toml"))


_RUNS: dict[tuple[str, bool], tuple[Path, dict]] = {}


def recorded(name: str, tmp_path_factory, secure: bool = False) -> tuple[Path, dict]:
    """One recorded whole run per scenario (and security) per session."""
    if (name, secure) not in _RUNS:
        rec, report, _ = run_whole(name, MATRIX[name], tmp_path_factory.mktemp(name), secure)
        _RUNS[name, secure] = (rec, report)
    return _RUNS[name, secure]


def run_whole(name: str, case: Case, d: Path, secure: bool = False) -> tuple[Path, dict, str]:
    """``larns fleet`` as a user starts it; returns (recording, the fleet's JSON report, its log)."""
    rec, js = d / f"{name}.mcap", d / f"{name}.json"
    cmd = [PY, "-m", "larns", "fleet", "--scenario", name, "--duration", str(DURATION_S), "--speed", str(case.speed),
           "--record", str(rec), "--no-table", "--json", str(js)]
    cmd += ["--aircraft"] * case.aircraft + ["--vehicle"] * case.vehicle + (["--secure"] if secure else [])
    cmd += list(case.extra)
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=DURATION_S / case.speed + 180, cwd=d)
    log = p.stdout + p.stderr
    assert p.returncode == 0, log[-3000:]
    return rec, json.loads(js.read_text()), log


def check_whole(name: str, case: Case, rec: Path, report: dict) -> dict:
    """The module docstring's checks on one recorded run; returns the scores (for the message)."""
    from larns.analysis.whole import score
    from net.scenario import load

    scn = load(name)
    assert all(v == 0 for v in report["exit_codes"].values()), report["exit_codes"]
    s = score(rec, scn, after_s=30.0)
    st = s["stations"]
    for sid in scn.ids:
        assert sid in st, f"{name}: station {sid} recorded nothing"
    for sid in case.joiners:
        assert st.get(sid, {}).get("state") == "surveying", (name, sid, st.get(sid))
    for sid, row in st.items():
        if sid in case.faulty or row.get("state") != "surveying":
            continue
        assert row["err_h_m"] <= min(3.0 * row["sigma_h_m"] + 0.05, case.survey_m), (name, sid, row)
        if case.sync_ns is not None:
            assert abs(row["sync_ns"]) <= case.sync_ns, (name, sid, row["sync_ns"])
    if case.spread_ns is not None:
        assert s["time_spread_ns"] is not None and s["time_spread_ns"] <= case.spread_ns, (name, s["time_spread_ns"])
    if case.aircraft:
        algos = scn.raw.get("aircraft", {}).get("algos", ["ukf-pr"])
        (ac,) = s["aircraft"].values()
        assert sorted(ac) == sorted(algos), (name, sorted(ac))
        for algo, row in ac.items():
            if algo not in case.intermittent:
                _check_aircraft(name, case, algo, row)
    if case.vehicle:
        (v,) = s["vehicles"].values()
        assert v["matched"] > 100 and v["final_err_m"] <= min(3.0 * v["final_sigma_m"] + 1.0, case.veh_m), (name, v)
    return s


def _check_aircraft(name: str, case: Case, algo: str, row: dict) -> None:
    assert row["n"] > 50 and row["finite"], (name, algo, row)
    if algo == "ins-ekf":
        assert row["final_eh_m"] <= min(3.0 * row["final_sigma_h_m"] + 1.0, case.ins_m), (name, algo, row)
        return
    window = case.lsq_window_m if algo.startswith("lsq") and case.lsq_window_m else case.ac_window_m
    final = case.lsq_window_m if algo.startswith("lsq") and case.lsq_window_m else case.ac_final_m
    assert row.get("max_eh_window_m") is not None, (name, algo, "no estimate from 30 s on", row)
    assert row["max_eh_window_m"] <= window, (name, algo, row)
    assert row["final_eh_m"] <= min(final, 3.0 * row["final_sigma_h_m"] + 1.0), (name, algo, row)
    if case.nees and not algo.startswith("lsq"):
        assert row["nees_mean"] <= row["nees_band"][1], (name, algo, row)


@pytest.mark.e2e
def test_the_default_scenario_whole(tmp_path_factory):
    """seed000, as the README's `larns fleet` starts it, with the radio aircraft and the vehicle."""
    check_whole(DEFAULT, MATRIX[DEFAULT], *recorded(DEFAULT, tmp_path_factory))


@pytest.mark.e2e
@pytest.mark.matrix
@pytest.mark.parametrize("name", sorted(set(MATRIX) - {DEFAULT}))
def test_every_packaged_scenario_whole(name, tmp_path_factory):
    check_whole(name, MATRIX[name], *recorded(name, tmp_path_factory))


@pytest.mark.e2e
@pytest.mark.matrix
def test_the_default_scenario_whole_secure(tmp_path_factory):
    """seed000 with --secure (temporary keys: mTLS, access control, signed messages), the stations, the
    aircraft and the vehicle (its own enclave ``vehicle-veh1``): held to the plain run's bounds, and every
    recorded air message signed by the enclave its key names."""
    import re

    from larns.analysis.verify import verify_recording
    from net.security import Keystore

    case = MATRIX[DEFAULT]
    rec, report, log = run_whole(DEFAULT, case, tmp_path_factory.mktemp("secure"), secure=True)
    _RUNS.setdefault((DEFAULT, True), (rec, report))
    check_whole(DEFAULT, case, rec, report)
    keys = re.search(r"--secure: temporary keystore (\S+)", log)
    assert keys, log[-2000:]
    res = verify_recording(Keystore(keys.group(1)), [rec])
    assert not res["by_reason"] and res["by_signer"].get("vehicle-veh1", 0) > 100, res
    assert res["by_signer"].get("aircraft-ac1", 0) > 100 and res["by_signer"].get("station-1", 0) > 100, res


def _held_to_the_bounds(name: str, algo: str, tmp_path_factory) -> None:
    from larns.analysis.whole import score
    from net.scenario import load

    rec, _ = recorded(name, tmp_path_factory)
    row = score(rec, load(name), after_s=30.0)["aircraft"]
    (ac,) = row.values()
    _check_aircraft(name, MATRIX[name], algo, ac[algo])
    assert ac[algo]["nees_mean"] <= ac[algo]["nees_band"][1], ac[algo]


@pytest.mark.e2e
@pytest.mark.matrix
@pytest.mark.xfail(strict=False, reason="defect, owner issue 29: seed001's TDOA filters in the far field start from a "
                   "2 km wide prior and settle on the range within their first second, sometimes on a wrong one: "
                   "in 3 later fleets of 2026-11-29 ukf-tdoa held NEES 2.6 once and 19.4 / 19.7 twice (380-760 m along "
                   "the range against sigma 80-165 m from 4 s on), ekf-tdoa 2.9-4.7 (held; it failed one of 3 earlier "
                   "that day at NEES 6.4); docs/aircraft.md, 'seed001's far field'")
@pytest.mark.parametrize("name,algo", [(n, a) for n, c in sorted(MATRIX.items()) for a in c.intermittent])
def test_intermittent_defects(name, algo, tmp_path_factory):
    """The algorithms ``Case.intermittent`` excludes, held to the same bounds (they fail in some runs)."""
    _held_to_the_bounds(name, algo, tmp_path_factory)
