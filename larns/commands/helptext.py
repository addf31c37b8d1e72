"""What every ``larns`` command's ``--help`` shows: a short description, examples, and each option's
default (:class:`Formatter`); and :func:`attached`, the ``--fleet`` / ``--duration`` plumbing of the
processes that join a running fleet (``station``, ``aircraft``, ``vehicle``)."""

from __future__ import annotations

import argparse
from typing import Callable


class Formatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions and epilogs as written; an option's default appended when its help does not
    already state one (and the default says something: not None, not False)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if (not action.option_strings or "default" in text.lower() or default is None or default is False
                or default is argparse.SUPPRESS or default == []):
            return text
        return f"{text} (default: {default})"


def examples(*lines: str) -> str:
    """An epilog listing example command lines (the ``--help`` of every command has one)."""
    return "examples:\n" + "\n".join(f"  {ln}" for ln in lines)


def add_parser(sub, name: str, *, help: str, description: str, example: list[str],
               **kw) -> argparse.ArgumentParser:
    """``sub.add_parser`` with :class:`Formatter` and an examples epilog."""
    return sub.add_parser(name, help=help, description=description, epilog=examples(*example),
                          formatter_class=Formatter, **kw)


def attached(parser: argparse.ArgumentParser, who: str,
             main: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """``main`` behind ``--fleet`` (or the default fleet file: ``net.attach``) and ``--duration`` as a
    run length: a bad fleet file or a contradicting option is one line and exit 2."""

    def run(args: argparse.Namespace) -> int:
        import sys
        import time

        from net.attach import FleetFileError, resolve

        try:
            resolve(args, time.time(), who, parser)
        except FleetFileError as e:
            print(f"larns {who}: {e}", file=sys.stderr)
            return 2
        return main(args)

    return run
