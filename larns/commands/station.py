"""`larns station --id N --scenario S [--join] [--speed K] [--epoch T] ...`: one station process."""

from __future__ import annotations


def register(sub) -> None:
    import argparse

    from stations import node

    p = sub.add_parser("station", help="run one ground station process over Zenoh",
                       description=node.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    node.add_args(p)
    p.set_defaults(func=node.main_args)
