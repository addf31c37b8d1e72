"""Scenario validation: every invalid entry raises ``ScenarioError`` whose message starts with the
key it is about (GUIDE: "a scenario error names the key"), and the packaged scenarios are valid."""

from __future__ import annotations

import importlib.resources
import tomllib

import pytest

from net.scenario import ScenarioError, from_dict, load

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
    for name in files:
        with (importlib.resources.files("net") / "scenarios" / name).open("rb") as f:
            from_dict(tomllib.load(f))
        assert load(name[:-5]).ids[:3] == [1, 2, 3]
