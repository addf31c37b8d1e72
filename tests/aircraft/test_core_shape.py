"""One live core shape (issue 29 item 4, aircraft/core.py): the factory picks the radio, inertial or
triad core by configuration, each has what the Zenoh shell drives, and the node holds exactly one."""

from __future__ import annotations

import time

import pytest

from aircraft.core import AircraftCore, make_core, split_ins
from aircraft.node import AircraftNode, AircraftOptions
from net.scenario import load

# the members of the protocol the node uses
MEMBERS = ("name", "seq", "stats", "journal", "algos", "lag_s", "step_s", "on_nav", "tick", "status_line", "summary")


class _Bus:
    def __init__(self):
        self.sent = []

    def publish(self, key, data, block=False):
        self.sent.append((key, data, block))


@pytest.mark.parametrize("opts, kind, algos", [
    (dict(algos=("ukf-pr", "lsq-pr")), "RadioAircraftCore", ("ukf-pr", "lsq-pr")),
    (dict(algos=("ins-ekf",)), "InsAircraftCore", ("ins-ekf",)),
    (dict(algos=(), imu="tactical"), "InsAircraftCore", ("ins-ekf",)),
    (dict(algos=("triad",)), "TriadAircraftCore", ("triad",)),
    (dict(algos=("triad",), satellites=6), "TriadAircraftCore", ("triad",)),
])
def test_the_factory_picks_the_core_by_configuration(opts, kind, algos):
    from aircraft.config import from_scenario

    scn = load("seed003")
    o = AircraftOptions(name="ac1", duration_s=30.0, **opts)
    core = make_core(scn, from_scenario(scn), o, 5, t0_s=0.0)
    assert type(core).__name__ == kind and core.algos == algos
    assert all(hasattr(core, m) for m in MEMBERS), [m for m in MEMBERS if not hasattr(core, m)]
    assert all(hasattr(AircraftCore, m) or m in AircraftCore.__annotations__ for m in MEMBERS)
    assert core.journal is not None and core.journal.take()[0].kind == "ac_init"
    assert (core.lag_s, core.step_s) == ((0.0, 0.1) if kind == "RadioAircraftCore" else (0.25, core.tn.dt_s))
    assert core.tick(1.0) == [] or kind != "RadioAircraftCore"
    assert o == AircraftOptions(name="ac1", duration_s=30.0, **opts)  # the options are not rewritten
    if kind == "TriadAircraftCore":
        assert core.n_sv == opts.get("satellites", 4)
    if kind == "InsAircraftCore":
        assert core.preset.name == opts.get("imu", "adis16480")


@pytest.mark.parametrize("opts, error", [
    (dict(algos=("ins-ekf", "ukf-pr")), "ins-ekf runs alone"),
    (dict(algos=("ukf-pr",), imu="adis16480"), "ins-ekf runs alone"),
    (dict(algos=("triad", "ekf-pr")), "triad runs alone"),
    (dict(algos=("ukf-pr",), satellites=4), "triad runs alone"),
])
def test_one_world_per_aircraft(opts, error):
    scn = load("seed003")
    with pytest.raises(ValueError, match=error):
        AircraftNode(scn, AircraftOptions(name="ac1", quiet=True, **opts), _Bus())


def test_split_ins():
    assert split_ins(("ins-ekf",), None) == (("ins-ekf",), (), "adis16480")
    assert split_ins((), "navigation") == (("ins-ekf",), (), "navigation")
    assert split_ins(("ukf-pr", "ekf-pr"), None) == ((), ("ukf-pr", "ekf-pr"), None)


@pytest.mark.parametrize("opts", [dict(algos=("ukf-pr",)), dict(algos=("ins-ekf",)), dict(algos=("triad",))])
def test_the_node_holds_exactly_one_core(opts):
    scn = load("seed003")
    node = AircraftNode(scn, AircraftOptions(name="ac1", quiet=True, epoch_unix_s=time.time(), **opts), _Bus())
    assert not hasattr(node, "ins")
    assert node.core.algos == opts["algos"]
    rep = node.report()
    assert rep == {"name": "ac1", "measurements": 0, "drops": node.drops.as_dict(), "estimates": {}}
    # the radio core's journal goes out with its first broadcast, an inertial core's from the first tick
    assert node.core.tick(0.0) == [] if opts["algos"] == ("ukf-pr",) else \
        [ev.kind for ev in node.core.tick(0.0)] == ["ac_init"]
