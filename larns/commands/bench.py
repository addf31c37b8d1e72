"""`larns bench ...`: benchmarks that print a table and write JSON (and PNG where it helps).

Each benchmark module listed in ``BENCHES`` exposes ``register(subparsers)`` like the top-level
commands.
"""

from __future__ import annotations

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


def register(sub) -> None:
    p = sub.add_parser(
        "bench",
        help="run a benchmark (table + JSON)",
        description="Benchmarks: accuracy and speed targets are measured here, not in unit tests.",
    )
    bsub = p.add_subparsers(dest="bench", metavar="BENCH")
    for mod in BENCHES:
        importlib.import_module(mod).register(bsub)
    p.set_defaults(func=lambda a: (p.print_help(), 2)[1])
