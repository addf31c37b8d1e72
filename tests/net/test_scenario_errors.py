"""Scenario validation: every invalid entry raises ``ScenarioError`` whose message starts with the
key it is about (GUIDE: "a scenario error names the key"), and the packaged scenarios are valid.
Through the real CLI (``larns scenario validate``, ``larns fleet``, ``larns crlb``), every broken
file gives one line ``FILE: [section] key: what is wrong (expected ...)`` and exit code 2."""

from __future__ import annotations

import importlib.resources
import subprocess
import sys
import tomllib
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from net.scenario import AIRCRAFT_ALGOS, SURVEY_ESTIMATORS, ScenarioError, ScenarioNotFound, from_dict, load

STATIONS = [{"id": i, "pos_m": [100.0 * i, 50.0 * (i % 2), 0.0]} for i in range(1, 6)]

CASES = [
    ({"seed": "x"}, "seed"),
    ({"seed": -1}, "seed"),
    ({"channel": {"sigma_d_mm": 1.0}}, "[channel] sigma_d_mm"),
    ({"channel": {"sigma_d_m": "half"}}, "[channel] sigma_d_m"),
    ({"channel": {"sigma_d_m": -0.5}}, "[channel] sigma_d_m"),
    ({"channel": {"nlos_prob": 1.5}}, "[channel] nlos_prob"),
    ({"channel": {"turnaround_s": float("nan")}}, "[channel] turnaround_s"),
    ({"channel": 3}, "[channel]"),
    ({"tdma": {"slot": 0.01}}, "[tdma] slot"),
    ({"tdma": {"slot_s": 0.0}}, "[tdma] slot_s"),
    ({"tdma": {"slot_s": 2.0, "cycle_s": 1.0}}, "[tdma] slot_s"),
    ({"tdma": {"assignment": "dynamic"}}, "[tdma] assignment"),
    ({"tdma": {"cycle_slots": 4}}, "[tdma] cycle_slots"),
    ({"tdma": {"assignment": "distributed", "cycle_slots": 101}}, "[tdma] cycle_slots"),
    ({"net": {"loss": 0.1}}, "[net] loss"),
    ({"net": {"dup_prob": 2.0}}, "[net] dup_prob"),
    ({"net": {"delay_s": -1.0}}, "[net] delay_s"),
    ({"init": {"sigma0_m": -1.0}}, "[init] sigma0_m"),
    ({"init": {"sigma_m": 1.0}}, "[init] sigma_m"),
    ({"layout": {"n": "ten"}}, "[layout] n"),
    ({"layout": {"n": 2}}, "[layout] n"),
    ({"layout": {"nn": 4}}, "[layout] nn"),
    ({"layout": {"area_m": [1.0, 2.0]}}, "[layout] area_m"),
    ({"layout": {"join_ids": [11, "x"]}}, "[layout] join_ids[1]"),
    ({"layout": {"joiners": -1}}, "[layout] joiners"),
    ({"frame": {"z_ref": 0}}, "[frame] z_ref"),
    ({"survey": {"ranges_per_update": 0}}, "[survey] ranges_per_update"),
    ({"survey": {"datum": "everyone"}}, "[survey] datum"),
    ({"survey": {"estimator": 3}}, "[survey] estimator"),
    ({"survey": {"estimater": "dmap"}}, "[survey] estimater"),
    ({"clock": {"model": "atomic"}}, "[clock] model"),
    ({"clock": {"model": "tcxo", "freq": 1.0}}, "[clock] freq"),
    ({"stations": []}, "stations"),
    ({"stations": [{"id": 1}]}, "stations[0].pos_m"),
    ({"stations": [{"pos_m": [0.0, 0.0, 0.0]}]}, "stations[0].id"),
    ({"stations": [*STATIONS[:2], {"id": "c", "pos_m": [0.0, 0.0, 0.0]}]}, "stations[2].id"),
    ({"stations": [*STATIONS[:3], {"id": 4, "pos_m": [0.0, "y", 0.0]}]}, "stations[3].pos_m[1]"),
    ({"stations": [*STATIONS[:3], {"id": 4, "pos_m": [0.0, 0.0]}]}, "stations[3].pos_m"),
    ({"stations": [*STATIONS[:3], {"id": 4, "pos_m": [0.0, 0.0, 1.0], "join": "yes"}]}, "stations[3].join"),
    ({"stations": STATIONS, "faults": [{"kind": "liar", "station": 9, "offset_m": [1.0, 0.0, 0.0]}]},
     "faults[0].station"),
    ({"stations": STATIONS, "faults": [{"kind": "liar", "station": 2, "offset_m": [1.0, 0.0]}]},
     "faults[0].offset_m"),
    ({"stations": STATIONS, "faults": [{"kind": "melt", "station": 2}]}, "faults[0].kind"),
    ({"stations": STATIONS, "faults": [{"kind": "range_bias", "station": 2}]}, "faults[0].bias_m"),
    ({"stations": STATIONS, "links": [{"station": 2, "nlos_prob": 3.0}]}, "links[0].nlos_prob"),
    ({"stations": STATIONS, "links": [{"stations": [2, 2]}]}, "links[0].stations"),
    ({"stations": STATIONS, "links": [{"station": 2, "colour": "red"}]}, "links[0].colour"),
    # top level, names, slots and geometry
    ({"sead": 3}, "sead"),
    ({"layot": {"n": 5}}, "[layot]"),
    ({"name": 3}, "name"),
    ({"survey": {"estimator": "kalman"}}, "[survey] estimator"),
    ({"survey": {"estimator": "seed-ukf"}, "init": {"sigma0_m": 0.0}}, "[survey] estimator"),
    ({"aircraft": {"algos": ["ekf-pr", "kalman"]}}, "[aircraft] algos"),
    ({"aircraft": {"algos": "ekf-pr"}}, "[aircraft] algos"),
    ({"vehicle": 3}, "[vehicle]"),
    ({"layout": {"n": 20}, "tdma": {"cycle_s": 0.1, "slot_s": 0.01}}, "[layout] n"),
    ({"layout": {"n": 9, "joiners": 2}, "tdma": {"cycle_s": 0.1, "slot_s": 0.01}}, "[layout] joiners"),
    ({"layout": {"n": 5, "join_ids": [7]}}, "[layout] join_ids[0]"),
    ({"layout": {"kind": "grid"}}, "[layout] kind"),
    ({"layout": {"n": 10, "area_m": [100.0, 100.0, 10.0], "min_separation_m": 100.0}}, "[layout] min_separation_m"),
    ({"stations": STATIONS, "tdma": {"cycle_s": 0.04, "slot_s": 0.01}}, "stations[4].id"),
    ({"stations": [*STATIONS[:3], {"id": 2, "pos_m": [0.0, 9.0, 0.0]}]}, "stations[3].id"),
    ({"stations": [STATIONS[0], STATIONS[1], {"id": 4, "pos_m": [0.0, 9.0, 0.0]}]}, "stations"),
    ({"stations": [*STATIONS[:3], {"id": 4, "pos_m": [100.0, 50.0, 0.0]}]}, "stations[3].pos_m"),
    ({"stations": [{"id": 1, "pos_m": [0.0, 0.0, 0.0]}, {"id": 2, "pos_m": [100.0, 0.0, 0.0]},
                   {"id": 3, "pos_m": [300.0, 0.01, 0.0]}]}, "stations[2].pos_m"),
    ({"stations": [*STATIONS[:3], {"id": 4, "pos_m": [0.0, 0.0, 1.0], "hieght": 3.0}]}, "stations[3].hieght"),
    ({"stations": STATIONS, "frame": {"z_ref": 9}}, "[frame] z_ref"),
]


@pytest.mark.parametrize("raw, key", CASES, ids=[k for _r, k in CASES])
def test_an_invalid_entry_names_its_key(raw, key):
    with pytest.raises(ScenarioError) as ei:
        from_dict(raw)
    msg = str(ei.value)
    assert msg.startswith(key), msg
    assert isinstance(ei.value, ValueError)  # callers catching ValueError keep working


def test_the_same_entries_valid_load():
    """The cases above fail for the entry they name, not for their surroundings."""
    scn = from_dict({"seed": 3, "channel": {"sigma_d_m": 0.5, "nlos_prob": 0.1}, "tdma": {"slot_s": 0.02},
                     "net": {"loss_prob": 0.1}, "init": {"sigma0_m": 0.0}, "layout": {"n": 4, "joiners": 1},
                     "frame": {"z_ref": 4}, "survey": {"estimator": "dmap", "ranges_per_update": 2},
                     "clock": {"model": "tcxo"}})
    assert scn.ids == [1, 2, 3, 4, 5] and scn.join_ids == [5] and scn.tdma.slot_s == 0.02
    scn = from_dict({"stations": STATIONS, "faults": [{"kind": "liar", "station": 2, "offset_m": [1.0, 0.0, 0.0]}],
                     "links": [{"stations": [2, 3], "nlos_prob": 0.5}]})
    assert scn.ids == [1, 2, 3, 4, 5] and len(scn.faults) == 1 and len(scn.links) == 1


def test_every_packaged_scenario_is_valid():
    files = sorted(p.name for p in (importlib.resources.files("net") / "scenarios").iterdir()
                   if p.name.endswith(".toml"))
    assert "seed000.toml" in files and len(files) >= 8
    folder = importlib.resources.files("net") / "scenarios"
    for name in files:
        with (folder / name).open("rb") as f:
            from_dict(tomllib.load(f), base_dir=str(folder))  # files they name ([radio] terrain) lie beside them
        assert load(name[:-5]).ids[:3] == [1, 2, 3]


def test_the_error_carries_section_and_key():
    e = ScenarioError("[channel] sigma_d_m: got -0.5 (expected a number >= 0)", file="a.toml")
    assert (e.file, e.section, e.key) == ("a.toml", "channel", "sigma_d_m")
    assert str(e) == "a.toml: [channel] sigma_d_m: got -0.5 (expected a number >= 0)"
    e = ScenarioError("stations[2].pos_m[1]: got 'y' (expected a finite number)")
    assert (e.section, e.key, str(e)) == ("stations[2]", "pos_m[1]", e.message)
    assert (ScenarioError("sead: unknown top-level key").section, ScenarioError("sead: x").key) == ("", "sead")
    assert (ScenarioError("[layot]: unknown section").section, ScenarioError("[layot]: x").key) == ("layot", "")


def test_a_missing_scenario_lists_the_packaged_ones():
    with pytest.raises(ScenarioNotFound) as ei:
        load("seed00")
    assert isinstance(ei.value, FileNotFoundError) and isinstance(ei.value, ScenarioError)
    assert str(ei.value).startswith("seed00: ") and "seed000, seed000-geo, seed000-join" in str(ei.value)


def test_the_name_lists_match_the_estimators_and_algorithms():
    """net may not import stations or aircraft: its copies of their names must stay equal."""
    from aircraft.navigator.radio.models import ALGOS
    from stations.estimators import ESTIMATORS

    assert set(SURVEY_ESTIMATORS) == set(ESTIMATORS)
    assert set(AIRCRAFT_ALGOS) == set(ALGOS) | {"ins-ekf", "triad"}


# ---------------------------------------------------------------- broken files through the real CLI
_FIVE = "".join(f"[[stations]]\nid = {i}\npos_m = [{100.0 * i}, {50.0 * (i % 2)}, 0.0]\n" for i in range(1, 6))
_CRLB = '[aircraft]\nalgos = ["ekf-pr"]\n[aircraft.crlb]\nheight_m = 1000.0\n'

# file name -> (TOML text, the section and the key the line must name)
BROKEN = {
    "syntax_value": ("seed = 1\n[channel]\nsigma_d_m = = 0.5\n", "[channel]", "sigma_d_m"),
    "syntax_string": ('[survey]\nestimator = "dmap\n', "[survey]", "estimator"),
    "syntax_array": (_FIVE + "[[stations]]\nid = 6\npos_m = [0.0, 0.0\n", "[[stations]]", "pos_m"),
    "top_level_typo": ("sead = 3\n", "sead", "top-level"),
    "unknown_section": ("[layot]\nn = 5\n", "[layot]", "section"),
    "unknown_key": ("[layout]\nnn = 4\n", "[layout]", "nn"),
    "wrong_type": ('[channel]\nsigma_d_m = "half"\n', "[channel]", "sigma_d_m"),
    "out_of_range": ("[channel]\nnlos_prob = 1.5\n", "[channel]", "nlos_prob"),
    "slot_longer_than_cycle": ("[tdma]\ncycle_s = 1.0\nslot_s = 2.0\n", "[tdma]", "slot_s"),
    "unknown_estimator": ('[survey]\nestimator = "kalman"\n', "[survey]", "estimator"),
    "seed_ukf_without_fix": ('[init]\nsigma0_m = 0.0\n[survey]\nestimator = "seed-ukf"\n', "[survey]", "estimator"),
    "unknown_algorithm": (_FIVE + '[aircraft]\nalgos = ["ekf-pr", "kalman"]\n', "[aircraft]", "algos"),
    "unknown_aircraft_key": (_FIVE + '[aircraft]\nalgos = ["ekf-pr"]\ncolour = "red"\n', "[aircraft]", "colour"),
    "stations_beyond_slots": ("[layout]\nn = 20\n[tdma]\ncycle_s = 0.1\nslot_s = 0.01\n", "[layout]", "n"),
    "explicit_beyond_slots": (_FIVE + "[tdma]\ncycle_s = 0.04\nslot_s = 0.01\n", "stations[4]", "id"),
    "collinear": ("[[stations]]\nid = 1\npos_m = [0.0, 0.0, 0.0]\n[[stations]]\nid = 2\npos_m = [100.0, 0.0, 0.0]\n"
                  "[[stations]]\nid = 3\npos_m = [300.0, 0.0, 0.0]\n", "stations[2]", "pos_m"),
    "coincident": (_FIVE + "[[stations]]\nid = 6\npos_m = [300.0, 50.0, 0.0]\n", "stations[5]", "pos_m"),
    "duplicate_id": (_FIVE + "[[stations]]\nid = 3\npos_m = [0.0, 700.0, 0.0]\n", "stations[5]", "id"),
    "station_key_typo": ("[[stations]]\nid = 1\nposm = [0.0, 0.0, 0.0]\n", "stations[0]", "posm"),
    "fault_unknown_station": (_FIVE + '[[faults]]\nkind = "liar"\nstation = 9\noffset_m = [1.0, 0.0, 0.0]\n',
                              "faults[0]", "station"),
    "link_key_typo": (_FIVE + '[[links]]\nstation = 2\ncolour = "red"\n', "links[0]", "colour"),
    "clock_model": ('[clock]\nmodel = "atomic"\n', "[clock]", "model"),
    "z_ref_missing": (_FIVE + "[frame]\nz_ref = 9\n", "[frame]", "z_ref"),
    "crlb_params": (_FIVE + _CRLB + 'params = "both"\n', "[aircraft.crlb]", "params"),
    "slot_assignment": ('[tdma]\nassignment = "distribute"\n', "[tdma]", "assignment"),
    "cycle_slots_beyond_cycle": ('[tdma]\ncycle_s = 0.4\nassignment = "distributed"\ncycle_slots = 41\n', "[tdma]",
                                 "cycle_slots"),
}


def _larns(*argv: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "larns", *argv], capture_output=True, text=True, cwd=cwd,
                          timeout=120)


@pytest.fixture(scope="module")
def validated(tmp_path_factory) -> dict[str, tuple[Path, subprocess.CompletedProcess]]:
    """Every broken file written and checked by its own `larns scenario validate FILE` (a few at once)."""
    folder = tmp_path_factory.mktemp("broken")
    paths = {}
    for name, (text, _s, _k) in BROKEN.items():
        paths[name] = folder / f"{name}.toml"
        paths[name].write_text(text)
    with ThreadPoolExecutor(4) as pool:
        runs = dict(zip(paths, pool.map(lambda p: _larns("scenario", "validate", str(p), cwd=folder),
                                        paths.values())))
    return {name: (paths[name], runs[name]) for name in paths}


def _one_line(run: subprocess.CompletedProcess) -> str:
    assert run.returncode == 2, (run.returncode, run.stdout, run.stderr)
    assert "Traceback" not in run.stderr and run.stdout == "", (run.stdout, run.stderr)
    lines = run.stderr.splitlines()
    assert len(lines) == 1, run.stderr
    return lines[0]


def test_at_least_twenty_broken_files():
    assert len(BROKEN) >= 20


@pytest.mark.parametrize("name", sorted(BROKEN))
def test_a_broken_file_is_one_line_naming_file_section_and_key(validated, name):
    path, run = validated[name]
    _text, section, key = BROKEN[name]
    line = _one_line(run)
    assert line.startswith(f"{path}: "), line
    assert section in line and key in line and "expected" in line, line


def test_the_loader_gives_the_same_line_as_validate(validated):
    """`larns scenario validate` prints what the loader every command uses raises."""
    for name, (path, run) in validated.items():
        if name not in ("unknown_aircraft_key", "crlb_params"):  # checked by the aircraft / larns crlb
            with pytest.raises(ScenarioError) as ei:
                load(path)
            assert run.stderr.strip() == str(ei.value)


def test_fleet_and_crlb_refuse_a_broken_file_in_one_line(validated, tmp_path):
    path = validated["unknown_estimator"][0]
    run = _larns("fleet", "--scenario", str(path), "--duration", "5", cwd=tmp_path)
    assert _one_line(run).startswith(f"{path}: [survey] estimator: unknown estimator 'kalman'")
    assert list(tmp_path.iterdir()) == []  # nothing launched, nothing written
    path = validated["crlb_params"][0]
    run = _larns("crlb", "--scenario", str(path), "--step", "20000", cwd=tmp_path)
    assert _one_line(run).startswith(f"{path}: [aircraft.crlb] params: got 'both'")
    assert not (tmp_path / "crlb.png").exists()


def test_a_missing_file_lists_the_packaged_scenarios(tmp_path):
    line = _one_line(_larns("scenario", "validate", "no-such.toml", cwd=tmp_path))
    assert line.startswith("no-such.toml: no such file") and "seed000, seed000-geo, seed000-join" in line and "seed003" in line
    line = _one_line(_larns("scenario", "show", "seed00", cwd=tmp_path))
    assert line.startswith("seed00: no such file") and "seed003-text-10" in line


def test_every_packaged_scenario_validates_and_shows(tmp_path):
    names = sorted(p.name[:-5] for p in (importlib.resources.files("net") / "scenarios").iterdir()
                   if p.name.endswith(".toml"))
    run = _larns("scenario", "validate", *names, cwd=tmp_path)
    assert run.returncode == 0 and run.stderr == "", run.stderr
    assert [line.split(":")[0] for line in run.stdout.splitlines()] == names
    listing = _larns("scenario", "list", cwd=tmp_path)
    assert listing.returncode == 0 and [line.split()[0] for line in listing.stdout.splitlines()[:-1]] == names
    show = _larns("scenario", "show", "seed003", cwd=tmp_path)
    assert show.returncode == 0, show.stderr
    assert "[tdma]       cycle_s 0.8, slot_s 0.1 (8 slots per cycle)" in show.stdout
    assert "    2     30000.00         0.00       0.00" in show.stdout  # station 2 on +X of the network frame


def test_validate_reports_every_file_and_fails_if_one_is_bad(validated, tmp_path):
    bad = validated["unknown_section"][0]
    run = _larns("scenario", "validate", "seed000", str(bad), "seed001", cwd=tmp_path)
    assert run.returncode == 2
    assert [line.split(":")[0] for line in run.stdout.splitlines()] == ["seed000", "seed001"]
    assert run.stderr.splitlines() == [f"{bad}: [layot]: unknown section (expected one of [frame], [site], [layout], "
                                       "[stations], [tdma], [channel], [radio], [clock], [net], [init], [survey], "
                                       "[aircraft], [vehicle], [links], [faults]; did you mean [layout]?)"]
