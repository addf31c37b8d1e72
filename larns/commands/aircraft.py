"""`larns aircraft --scenario S --algo ukf-pr [--algo ...]`: one aircraft process over Zenoh
(:mod:`aircraft.node`)."""

from __future__ import annotations

DESCRIPTION = """\
Run an aircraft: it flies the scenario's trajectory and positions itself from the stations'
navigation broadcasts with one or more estimators (docs/aircraft.md); it publishes its estimates
and its truth for the recorder.

Started beside a running `larns fleet`, it attaches with --fleet FILE (by default runs/fleet.json
when that describes a running fleet): same epoch, speed, scenario, endpoints. --duration is the
run length (--until: an absolute fleet time); attached without either, it stops with the fleet."""


def register(sub) -> None:
    from aircraft import node

    from .helptext import add_parser, attached

    p = add_parser(sub, "aircraft", help="run an aircraft process: positions itself from the stations' broadcasts",
                   description=DESCRIPTION,
                   example=["larns aircraft --fleet runs/fleet.json --algo ukf-pr --duration 120",
                            "larns aircraft --scenario seed003 --algo ekf-tdoa --epoch 1767225600 "
                            "--connect tcp/127.0.0.1:7447 --duration 600"])
    node.add_args(p)
    p.set_defaults(func=attached(p, "aircraft", node.main_args))
