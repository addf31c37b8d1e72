"""The example lines of `larns bench`, `view`, `crlb` and `scenario` --help (and of every bench and
scenario action) are command lines the real parser accepts (issue 34 item 7), and the benches' help
shows each option's default."""

from __future__ import annotations

import argparse
import shlex

import pytest


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            return dict(a.choices)
    return {}


def _helps() -> list[tuple[str, str]]:
    """(name, --help text) of the four commands and of their subcommands."""
    from larns.cli import build_parser

    top = _subparsers(build_parser())
    out = []
    for cmd in ("bench", "view", "crlb", "scenario"):
        out.append((cmd, top[cmd].format_help()))
        out += [(f"{cmd} {name}", p.format_help()) for name, p in _subparsers(top[cmd]).items()]
    return out


def _example_lines(text: str) -> list[str]:
    block = text.split("\nexamples:\n", 1)[1]
    lines = []
    for ln in block.splitlines():
        if not ln.startswith("  "):
            break
        lines.append(ln.strip())
    return lines


HELPS = _helps()


@pytest.mark.parametrize("name,text", HELPS, ids=[n for n, _ in HELPS])
def test_examples_parse(name, text):
    from larns.cli import build_parser

    assert "\nexamples:\n" in text, f"larns {name} --help has no examples"
    lines = _example_lines(text)
    assert any(ln.startswith(f"larns {name}") for ln in lines), f"larns {name}: no example of itself: {lines}"
    for ln in lines:
        argv = shlex.split(ln, comments=True)
        assert argv[0] == "larns", ln
        if "--help" in argv:
            continue
        try:
            build_parser().parse_args(argv[1:])
        except SystemExit as e:  # argparse refused the line
            pytest.fail(f"larns {name} --help: example {ln!r} does not parse (exit {e.code})")


def test_bench_help_shows_defaults_also_of_options_without_help():
    from larns.cli import build_parser

    bench = _subparsers(build_parser())["bench"]
    text = " ".join(_subparsers(bench)["ins"].format_help().split())
    assert "--seed SEED (default: 1)" in text  # no help string of its own
    assert "flight heights, m (default: 250.0 500.0 1000.0)" in text  # a list, as typed
    text = " ".join(_subparsers(bench)["integrity"].format_help().split())
    assert "(default: dmap)" in text
