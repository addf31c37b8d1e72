"""`larns vehicle --scenario S [--route FILE]`: the ground vehicle process over Zenoh (docs/vehicle.md)."""

from __future__ import annotations


def register(sub) -> None:
    import argparse

    from vehicle import node

    p = sub.add_parser("vehicle", help="run a ground vehicle process: map route, IMU, odometer and the stations' broadcasts",
                       description=node.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    node.add_args(p)
    p.set_defaults(func=node.main_args)
