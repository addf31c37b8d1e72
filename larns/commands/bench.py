"""`larns bench ...`: benchmarks that print a table and write JSON (and PNG where it helps).

Each benchmark module listed in ``BENCHES`` exposes ``register(subparsers)`` like the top-level
commands.
"""

from __future__ import annotations

import argparse
import importlib

BENCHES: list[str] = [
    "larns.bench.aircraft",
    "larns.bench.survey",
    "larns.bench.net",
    "larns.bench.replay",
    "larns.bench.sync",
    "larns.bench.speed",
    "larns.bench.ins",
    "larns.bench.integrity",
    "larns.bench.vehicle",
    "larns.bench.triad",
]


class _BenchParser(argparse.ArgumentParser):
    """A bench's parser. Its ``description`` is printed like its help strings: argparse %-formats help
    strings (``95%%`` prints ``95%``) but prints descriptions as written, and the benches write ``%%``
    in both for one spelling."""

    def __init__(self, *args, description: str | None = None, **kwargs):
        super().__init__(*args, description=description and description.replace("%%", "%"), **kwargs)


def register(sub) -> None:
    p = sub.add_parser(
        "bench",
        help="run a benchmark (table + JSON)",
        description="Benchmarks: accuracy and speed targets are measured here, not in unit tests.",
    )
    bsub = p.add_subparsers(dest="bench", metavar="BENCH", parser_class=_BenchParser)
    for mod in BENCHES:
        importlib.import_module(mod).register(bsub)
    p.set_defaults(func=lambda a: (p.print_help(), 2)[1])
