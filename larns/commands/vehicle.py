"""`larns vehicle --scenario S [--route FILE]`: the ground vehicle process over Zenoh (docs/vehicle.md,
:mod:`vehicle.node`)."""

from __future__ import annotations

DESCRIPTION = """\
Run the ground vehicle: it drives a map route with an IMU and an odometer and positions itself
from the stations' broadcasts (docs/vehicle.md); it publishes its estimates and its truth.

Started beside a running `larns fleet`, it attaches with --fleet FILE (by default runs/fleet.json
when that describes a running fleet). --duration is the run length (--until: an absolute fleet
time); attached without either, it stops with the fleet."""


def register(sub) -> None:
    from vehicle import node

    from .helptext import add_parser, attached

    p = add_parser(sub, "vehicle",
                   help="run a ground vehicle process: map route, IMU, odometer and the stations' broadcasts",
                   description=DESCRIPTION,
                   example=["larns vehicle --fleet runs/fleet.json --duration 120",
                            "larns vehicle --route docs/routes/field-straight.toml --outage 30,60 "
                            "--epoch 1767225600 --connect tcp/127.0.0.1:7447"])
    node.add_args(p)
    p.set_defaults(func=attached(p, "vehicle", node.main_args))
