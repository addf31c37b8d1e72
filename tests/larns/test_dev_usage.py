"""Packaging and usage texts (issue 34 item 7): `./dev` prints its real usage lines, the benches'
help prints 95% (not 95%%), and the project metadata uses the SPDX licence string."""

from __future__ import annotations

import hashlib
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
USAGE = ["usage: ./dev COMMAND [ARGS]",
         "  ./dev demo [fleet args]   run the local fleet demo (10 stations + aircraft + recorder), live table, MCAP in runs/",
         "  ./dev test [pytest args]  run the default test suite, then (no args) the long defaults matrix (-m matrix)",
         "  ./dev bench ...           run `larns bench ...`",
         "  ./dev larns ...           run any larns command inside the venv"]


@pytest.fixture()
def dev(tmp_path: Path) -> Path:
    """A copy of ./dev beside a stand-in venv that is already installed (so it never runs pip)."""
    shutil.copy(ROOT / "dev", tmp_path / "dev")
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    (tmp_path / ".venv" / "bin").mkdir(parents=True)
    py = tmp_path / ".venv" / "bin" / "python"
    py.write_text("#!/bin/sh\nexit 0\n")
    py.chmod(0o755)
    stamp = hashlib.sha1((tmp_path / "pyproject.toml").read_bytes()).hexdigest()[:12]
    (tmp_path / ".venv" / f".installed-{stamp}").touch()
    return tmp_path / "dev"


def test_dev_alone_prints_the_usage_lines(dev):
    run = subprocess.run(["bash", str(dev)], capture_output=True, text=True, timeout=30)
    assert run.returncode == 2 and run.stdout == ""
    assert run.stderr.splitlines() == USAGE


def test_dev_help_and_an_unknown_command(dev):
    run = subprocess.run(["bash", str(dev), "help"], capture_output=True, text=True, timeout=30)
    assert run.returncode == 0 and run.stdout.splitlines() == USAGE and run.stderr == ""
    run = subprocess.run(["bash", str(dev), "tset"], capture_output=True, text=True, timeout=30)
    assert run.returncode == 2 and run.stderr.splitlines() == ["./dev: unknown command 'tset'", *USAGE]


@pytest.mark.parametrize("bench", ["survey", "sync"])
def test_bench_help_prints_a_single_percent_sign(bench):
    run = subprocess.run([sys.executable, "-m", "larns", "bench", bench, "--help"], capture_output=True,
                         text=True, timeout=60, cwd=ROOT)
    assert run.returncode == 0, run.stderr
    text = " ".join(run.stdout.split())  # argparse wraps lines
    assert "95% " in text and "%%" not in text


def test_the_licence_is_an_spdx_string_with_a_setuptools_that_reads_it():
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert meta["project"]["license"] == "Apache-2.0"
    assert "setuptools>=77" in meta["build-system"]["requires"]  # SPDX strings: setuptools 77 and later
