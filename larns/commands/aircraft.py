"""`larns aircraft --scenario S --algo ukf-pr [--algo ...]`: one aircraft process over Zenoh."""

from __future__ import annotations


def register(sub) -> None:
    import argparse

    from aircraft import node

    p = sub.add_parser("aircraft", help="run an aircraft process: positions itself from the stations' broadcasts",
                       description=node.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    node.add_args(p)
    p.set_defaults(func=node.main_args)
