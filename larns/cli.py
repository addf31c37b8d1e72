"""`larns` command line: one entry point, subcommands registered by their own modules.

Each module of :mod:`larns.commands` listed in ``COMMANDS`` exposes ``register(subparsers)`` which adds its parser and
sets ``func`` (called with the parsed args, returns an exit code). Registration must stay cheap:
heavy imports (zenoh, matplotlib, scipy) happen inside the command functions, so ``--help``
is instant. Bad user input that reaches :func:`main` (a scenario file, a keystore: :func:`user_errors`)
is printed as its one line on stderr with exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from . import __version__

# (module, one-line purpose) in the order shown by --help
COMMANDS: list[str] = [
    "larns.commands.bench",
    "larns.commands.record",
    "larns.commands.view",
    "larns.commands.station",
    "larns.commands.fleet",
    "larns.commands.monitor",
    "larns.commands.router",
    "larns.commands.crlb",
    "larns.commands.scenario",
    "larns.commands.info",
    "larns.commands.replay",
    "larns.commands.reestimate",
    "larns.commands.recover",
    "larns.commands.export",
    "larns.commands.report",
    "larns.commands.aircraft",
    "larns.commands.vehicle",
    "larns.commands.keys",
    "larns.commands.attack",
]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="larns",
        description=(
            "LARNS - emulator of a Local Autonomous Radio Navigation System. Ground stations "
            "survey their own coordinate frame by two-way ranging over Eclipse Zenoh; an aircraft "
            "positions itself from their broadcasts; everything is recorded to MCAP."
        ),
        epilog="Run `larns COMMAND --help` for the options of a command. Docs: docs/architecture.md",
    )
    p.add_argument("--version", action="version", version=f"larns {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    for mod in COMMANDS:
        importlib.import_module(mod).register(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    func = getattr(args, "func", None)
    if func is None:
        parser.print_help()
        return 2
    try:
        return int(func(args) or 0)
    except KeyboardInterrupt:
        return 130
    except Exception as e:  # bad user input: its one line on stderr and exit 2, never a traceback
        if not isinstance(e, user_errors()):
            raise
        print(e, file=sys.stderr)
        return 2


def user_errors() -> tuple[type[Exception], ...]:
    """The errors that mean bad user input, whose message is the whole story: a scenario file
    (``ScenarioError``: ``FILE: [section] key: what is wrong (expected ...)``) or a keystore."""
    from net.scenario import ScenarioError
    from net.security import KeystoreError

    return (ScenarioError, KeystoreError)


def entry() -> None:
    """The ``larns`` console script and ``python -m larns``: :func:`main`, then
    :func:`net.cli.exit_process` (which skips the interpreter's finalization where a command asked
    for it: ``net.cli.EXIT_AT_ONCE``)."""
    from net.cli import exit_process

    exit_process(main())


if __name__ == "__main__":
    entry()
