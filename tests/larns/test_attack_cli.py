"""`larns attack`: the argparse adapter offers exactly the attacks larns.adversary implements, and
refuses non-loopback endpoints and missing credentials before any Zenoh session opens."""

import argparse

from larns.adversary.attacks import ATTACKS
from larns.commands import attack as cmd


def _parse(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    cmd.register(p.add_subparsers())
    return p.parse_args(["attack", *argv])


def test_choices_are_the_implemented_attacks():
    assert set(cmd.ATTACK_NAMES) == set(ATTACKS)
    assert cmd.forged_nav is ATTACKS["forge"].__globals__["forged_nav"]  # the old home still resolves


def test_refuses_before_connecting(capsys):
    assert cmd.cmd_attack(_parse("flood", "--connect", "tcp/10.0.0.1:7447")) == 2
    assert "loopback" in capsys.readouterr().err
    assert cmd.cmd_attack(_parse("flood", "--connect", "tcp/127.0.0.1:7447")) == 2
    assert "--secure" in capsys.readouterr().err
