"""`larns station --id N [--join] [--fleet FILE] ...`: one ground station process over Zenoh
(:mod:`stations.node`)."""

from __future__ import annotations

DESCRIPTION = """\
Run one ground station: it ranges with its peers in its TDMA slot, estimates its own coordinates
in the network frame and broadcasts them (docs/fleet.md, docs/protocol.md).

To hot-join a running `larns fleet` (or `./dev demo`), start it with --join: it reads the fleet's
epoch, speed, scenario and endpoints from the fleet file (--fleet FILE; by default runs/fleet.json
when that describes a running fleet), listens for a cycle, claims a free slot and surveys itself.
A station id the scenario does not list may join; its true position (world side only) is drawn
from the scenario, where its peers look it up too. --duration is the run length from power-on
(--until: an absolute fleet time); attached without either, the station stops when the fleet ends."""


def register(sub) -> None:
    from stations import node

    from .helptext import add_parser, attached

    p = add_parser(sub, "station", help="run one ground station process over Zenoh", description=DESCRIPTION,
                   example=["larns station --id 11 --scenario seed000 --join       # hot-join the fleet of runs/fleet.json",
                            "larns station --id 12 --join --fleet runs/fleet.json --start-at 30",
                            "larns station --id 3 --epoch 1767225600 --connect tcp/127.0.0.1:7447 --duration 60"])
    node.add_args(p)
    p.set_defaults(func=attached(p, "station", node.main_args))
