"""`larns bench ...`: benchmarks that print a table and write JSON (and PNG where it helps).

Each benchmark module listed in ``BENCHES`` exposes ``register(subparsers)`` like the top-level
commands.
"""

from __future__ import annotations

import argparse
import copy
import importlib

BENCHES: list[str] = [
    "larns.bench.aircraft",
    "larns.bench.coldstart",
    "larns.bench.survey",
    "larns.bench.net",
    "larns.bench.replay",
    "larns.bench.sync",
    "larns.bench.speed",
    "larns.bench.ins",
    "larns.bench.integrity",
    "larns.bench.vehicle",
    "larns.bench.triad",
    "larns.bench.slots",
    "larns.bench.wire",
]


DESCRIPTION = """\
Benchmarks: the accuracy and speed targets are measured here, not in unit tests. Each bench prints
a table, writes JSON with --json and, where it helps, PNG figures (README.md lists them; the doc of
each part gives its results). Most are Monte Carlo runs that take minutes (`larns bench BENCH
--help`: its options and examples); the real-time ones (net, scale, speed) start real Zenoh
processes: run them alone on the machine, since the host's timing is part of what they measure."""

# One to three real command lines per bench, shown under its --help ("examples:").
EXAMPLES: dict[str, list[str]] = {
    "aircraft": ["larns bench aircraft --quick --no-speed                 # smoke test, a minute",
                 "larns bench aircraft --json out.json --png-dir png/",
                 "larns bench aircraft --envelope --json env.json --png-dir png/"],
    "cold-start": ["larns bench cold-start runs/demo.mcap                  # the demo's recording (./dev demo)",
                   "larns bench cold-start runs/a.mcap runs/b.mcap --without survey --without floor --json cold.json"],
    "survey": ["larns bench survey --trials 10 --duration 30 --estimator dmap --no-map   # a quick look",
               "larns bench survey --trials 100 --sigma-d 0.5 --estimator dmap --no-map --json survey.json"],
    "net": ["larns bench net                               # 2000 round trips between 2 processes: p50/p99",
            "larns bench net --n 500 --json net.json"],
    "scale": ["larns bench scale --n 10,20 --duration 30",
              "larns bench scale --topology router --n 50 --duration 60 --json scale.json"],
    "replay": ["larns bench replay --duration 120 --repeat 1      # a 2-minute log",
               "larns bench replay --from runs/demo.mcap --json replay.json   # the recording of ./dev demo"],
    "sync": ["larns bench sync --trials 10 --duration 60            # a quick look",
             "larns bench sync --trials 100 --json bench-out/sync/sync.json",
             "larns bench sync --trials 100 --founders-leave --json bench-out/sync/founders-leave.json"],
    "speed": ["larns bench speed --worlds 1 --speeds 1,5 --duration 30",
              "larns bench speed --json speed.json --keep runs/speed"],
    "ins": ["larns bench ins --quick                              # smoke test, ~1.5 min",
            "larns bench ins --runs 64 --no-speed --no-tilt-cost --json ins64.json --png ins64.png"],
    "integrity": ["larns bench integrity --trials 4 --cases clean liar",
                  "larns bench integrity --trials 20 --aircraft seed001 seed003 --json integrity.json"],
    "vehicle": ["larns bench vehicle --quick                          # smoke test",
                "larns bench vehicle --json vehicle.json --png-dir img/"],
    "slots": ["larns bench slots --trials 5 --tx-power-dbm 0 --json slots.json   # 200 stations, 40 x 30 km, 4.7 km links",
              "larns bench slots --layout corridor --tx-power-dbm 0 --trials 5",
              "larns bench slots --cycle-slots 0 --trials 2                # default radio: cycle sized for the densest 2-hop neighbourhood"],
    "wire": ["larns bench wire --compare --json bench-out/wire.json   # 20 and 40 stations, tiles on and off",
             "larns bench wire --sizes 20,40,60 --speed 0.25 --duration 20"],
    "triad": ["larns bench triad --quick                            # 10 runs, durations / 5: ~1.5 min",
              "larns bench triad --cases 4gs 2sv2gs --json triad.json"],
}


class _Defaults:
    """Formatter mixin: an option's default appended when its help does not already state one (and the
    default says something: not None, not False), the rule of :class:`larns.commands.helptext.Formatter`;
    a list default is written as on the command line (``250.0 500.0``)."""

    @staticmethod
    def _default_text(action: argparse.Action) -> str | None:
        """``(default: ...)`` for ``action`` (``%`` escaped for argparse), or None when it says nothing."""
        default = action.default
        if (not action.option_strings or default is None or default is False or default is argparse.SUPPRESS
                or default == []):
            return None
        shown = " ".join(map(str, default)) if isinstance(default, (list, tuple)) else str(default)
        return f"(default: {shown.replace('%', '%%')})"

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        shown = self._default_text(action)
        return text if shown is None or "default" in text.lower() else f"{text} {shown}"

    def _format_action(self, action: argparse.Action) -> str:
        """argparse skips the help of an option without one; such an option still shows its default."""
        shown = self._default_text(action)
        if action.help is None and shown is not None:
            action = copy.copy(action)
            action.help = shown
        return super()._format_action(action)  # type: ignore[misc]


class _WrappedFormatter(_Defaults, argparse.HelpFormatter):
    """Descriptions wrapped by argparse, defaults shown."""


class _RawFormatter(_Defaults, argparse.RawDescriptionHelpFormatter):
    """Descriptions as written, defaults shown."""


class _BenchParser(argparse.ArgumentParser):
    """A bench's parser. Its ``description`` is printed like its help strings: argparse %-formats help
    strings (``95%%`` prints ``95%``) but prints descriptions as written, and the benches write ``%%``
    in both for one spelling. Its help shows each option's default (:class:`_Defaults`) and the
    bench's :data:`EXAMPLES`."""

    def __init__(self, *args, description: str | None = None, **kwargs):
        from .helptext import examples

        fc = kwargs.get("formatter_class", argparse.HelpFormatter)
        kwargs["formatter_class"] = {argparse.HelpFormatter: _WrappedFormatter,
                                     argparse.RawDescriptionHelpFormatter: _RawFormatter}.get(fc, fc)
        name = (kwargs.get("prog") or "").rsplit(" ", 1)[-1]
        self.examples = examples(*EXAMPLES[name]) if name in EXAMPLES else ""
        super().__init__(*args, description=description and description.replace("%%", "%"), **kwargs)

    def format_help(self) -> str:
        """argparse's help, then the examples as written (a wrapping formatter would join their lines)."""
        text = super().format_help()
        return f"{text}\n{self.examples}\n" if self.examples else text


def register(sub) -> None:
    from .helptext import add_parser

    p = add_parser(sub, "bench", help="run a benchmark (table + JSON)", description=DESCRIPTION,
                   example=["larns bench survey --trials 10 --duration 30 --estimator dmap --no-map   # a quick look",
                            "larns bench aircraft --quick --no-speed",
                            "larns bench net",
                            "larns bench survey --help                    # one bench's options and examples"])
    bsub = p.add_subparsers(dest="bench", metavar="BENCH", parser_class=_BenchParser)
    for mod in BENCHES:
        importlib.import_module(mod).register(bsub)
    p.set_defaults(func=lambda a: (p.print_help(), 2)[1])
