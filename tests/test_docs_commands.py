"""Every command in the docs is executed or deliberately skipped (issue 28, item 4).

Extraction rule (``doc_commands``): the files are ``README.md`` and ``docs/*.md``. A *command* is a
line that starts with ``larns ``, ``./dev ``, ``docker compose ``, ``docker-compose ``, ``scripts/``
or ``python -m `` (for ``larns `` the next word must be a ``larns`` command or an option, so a table
row that begins with the word "larns" is not one), found

* in a fenced code block whose info string is empty, ``bash``, ``sh``, ``shell`` or ``console``:
  every such line (a leading ``$ `` dropped, ``\\`` continuations joined);
* in inline code outside fences: a span that has at least one argument or option after the
  command's name (its leading plain lower-case words, e.g. ``larns bench aircraft``); a span of
  plain words only names a command in a sentence and is not an example.

A command is keyed by its text without its trailing ``# comment`` and with blanks collapsed; the
same command in several places is one key. Every key must be in ``TABLE`` below, and every
``TABLE`` entry must still be in the docs (new docs must be classified, stale rows removed).

``TABLE`` classifies each command:

* ``Run``: executed by ``test_doc_command_runs`` in a scratch directory holding the session's
  recording under every name the docs give it (``runs/demo.mcap``, ``run.mcap``, ...), a ``docs``
  link (``docs/routes/...``), the scenario files the docs ask the reader to write, and a copy of
  ``./dev`` beside the project's venv (``./dev`` lines run through the real script). The session's
  recording is made once by the docs' own ``./dev demo`` line, with ``--duration 30 --speed 3
  --aircraft --vehicle --no-table`` appended (``./dev demo`` passes fleet args through).
  ``edits`` / ``append`` state every rewrite (durations shortened, ``--duration`` given to a
  process that otherwise runs until Ctrl-C); the doc line itself is never changed. A run must end
  with the stated exit code within its timeout, and ``expect`` (a regex) must be in its output.
  Long ones (``slow=True`` in the table: fleets of 10-25 s wall each) are marked ``matrix``: ``./dev test``
  runs them after the default suite, with the defaults matrix (CI runs both stages).
* ``Skip``: not executed, with the reason (long bench, Docker, fixed ports or a second terminal
  beside a fleet, prose). Skipped ``larns`` lines are still checked statically.

``test_doc_command_is_well_formed`` checks every entry without running it: each ``--option`` exists
for its (sub)command; a line one could type as written (``concrete``) is accepted by the ``larns``
argument parser; ``--scenario NAME`` is a packaged scenario; paths into ``docs/``, ``tests/``,
``scripts/`` exist (or their folder does, for outputs).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import hashlib
import io
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable
PREFIXES = ("larns ", "./dev ", "docker compose ", "docker-compose ", "scripts/", "python -m ")
SHELL_FENCES = {"", "bash", "sh", "shell", "console"}
_FENCE = re.compile(r"^\s*(```+|~~~+)\s*([\w+-]*)")
_COMMENT = re.compile(r"\s+#.*$")
_WORD = re.compile(r"^[a-z][a-z0-9-]*$")


# ----------------------------------------------------------------------------- extraction

def doc_files() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


@functools.lru_cache(maxsize=1)
def _parser() -> argparse.ArgumentParser:
    from larns.cli import build_parser

    return build_parser()


def _subparsers(p: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for a in p._actions:
        if isinstance(a, argparse._SubParsersAction):
            return dict(a.choices)
    return {}


def _is_command(text: str, commands: set[str]) -> bool:
    if not text.startswith(PREFIXES):
        return False
    if text.startswith("larns "):  # not a table row that happens to start with the word "larns"
        nxt = text.split()[1]
        return nxt in commands or nxt.startswith("-")
    return True


def _command_name_len(tokens: list[str]) -> int:
    """How many leading tokens name the command: the program (``docker compose`` and ``python -m X``
    count as one) and the plain lower-case words after it (its subcommands)."""
    n = {"docker": 2, "python": 3}.get(tokens[0], 1)
    while n < len(tokens) and _WORD.match(tokens[n]):
        n += 1
    return n


def normalize(line: str) -> str:
    """A command as the table keys it: no leading ``$ ``, no trailing ``# comment``, single blanks."""
    line = line.strip()
    if line.startswith("$ "):
        line = line[2:]
    return " ".join(_COMMENT.sub("", line).split())


def extract(path: Path, commands: set[str]) -> list[tuple[int, str]]:
    """(line number, command) of every example command of one Markdown file (rule: module docstring)."""
    out: list[tuple[int, str]] = []
    fence: str | None = None
    lines = path.read_text().splitlines()
    i = 0
    while i < len(lines):
        line, no = lines[i], i + 1
        m = _FENCE.match(line)
        if m:
            fence = m.group(2) if fence is None else None
        elif fence is not None:
            while line.rstrip().endswith("\\") and i + 1 < len(lines):
                i += 1
                line = line.rstrip()[:-1] + " " + lines[i].strip()
            cmd = normalize(line)
            if fence in SHELL_FENCES and _is_command(cmd, commands):
                out.append((no, cmd))
        else:
            for span in re.findall(r"`([^`\n]+)`", line):
                cmd = normalize(span)
                if _is_command(cmd, commands) and _command_name_len(cmd.split()) < len(cmd.split()):
                    out.append((no, cmd))
        i += 1
    return out


def doc_commands() -> dict[str, list[str]]:
    """Every example command of README.md and docs/*.md -> where it appears (``docs/fleet.md:12``, ...)."""
    commands = set(_subparsers(_parser()))
    found: dict[str, list[str]] = {}
    for path in doc_files():
        for no, cmd in extract(path, commands):
            found.setdefault(cmd, []).append(f"{path.relative_to(ROOT)}:{no}")
    return found


# ----------------------------------------------------------------------------- the table

@dataclass(frozen=True)
class Run:
    """Execute the line (after ``edits`` and ``append``, each stated) in a scratch directory."""
    how: str = "as written"
    edits: tuple[tuple[str, str], ...] = ()   # (old, new) text replacements
    append: str = ""                          # arguments appended
    before: tuple[str, ...] = ()              # table lines run first in the same directory (their own rewrite)
    in_dir_of: str = ""                       # run where this (cached, once per session) table line ran
    expect: str | tuple[str, ...] = ""        # regex(es) that must be in stdout + stderr
    rc: int = 0
    timeout_s: float = 120.0
    slow: bool = False


@dataclass(frozen=True)
class Skip:
    reason: str
    concrete: bool = True       # typed as written it is a complete line: the larns parser must accept it
    options_exist: bool = True  # its --options exist (False only for a doc that says they do not yet)


MENTION = "prose: names an option or mode of the command inside a sentence, not a line to run"
SYNOPSIS = "synopsis with placeholders or [optional] parts, not a line to run as written"
COMPOSE = "needs a Docker engine: the compose timeline (up, hot-join station11 with its keys, logs, down -v -> a valid MCAP) is tests/larns/test_compose.py (marker compose)"
SITES = ("needs a Docker engine: tests/larns/test_compose_sites.py (marker compose) writes the file with "
         "scripts/compose-sites.py, runs it up, cuts and heals the backbone, and takes it down -v")
BENCH = "long bench (minutes of Monte Carlo or real-time fleets on 2 cores); options checked by the parser here"
SUITE = "a pytest run of this suite's own files: the suite runs them (path checked here)"
MANUAL = "a piece of a fleet started by hand on fixed ports (7447/7450/7500), typed beside a running fleet in other terminals; the launcher does the same with free ports: larns fleet lines RUN here, tests/net/test_bus_router.py (router + clients), tests/larns/test_record.py (record)"
HOTJOIN = "covered by tests/larns/test_attach.py::test_readme_hot_join_attaches_to_a_running_fleet (this very line against ./dev demo, with larns monitor)"
VIEW = "serves Foxglove on the fixed port 8765 (shared machine: others may hold it) and runs until Ctrl-C; the live view beside a fleet is tests/larns/test_view_live.py, replay --view tests/larns/test_view_replay.py"
SURVEYED = r"(?m)^\s+10 surveying"  # the fleet's final table: station 10 surveyed itself
ROUTER = r"processes alive: 11"  # 10 stations + the router (no recorder without --record)
DEMO = "the session recording (30 fleet s at speed 3 with aircraft and vehicle) in place of this file"


def _short(old: str, new: str) -> tuple[tuple[str, str], ...]:
    return ((old, new),)


TABLE: dict[str, Run | Skip] = {
    # --- README.md: quick start
    "./dev demo": Run("the session recording: ./dev demo --duration 30 --speed 3 --aircraft --vehicle --no-table"),
    "./dev test": Skip("the default suite itself (this test is part of it)"),
    "./dev larns --help": Run(expect=r"usage: larns"),
    "./dev larns scenario list": Run(expect=r"seed000"),
    "./dev larns fleet --scenario seed000 --duration 60 --speed 5 --record runs/run.mcap":
        Run("--duration 60 -> 45 (~10 s wall)", edits=_short("--duration 60", "--duration 45"),
            expect=(r"fleet file runs/fleet.json", SURVEYED), slow=True),
    "./dev larns station --id 11 --scenario seed000 --join": Skip(HOTJOIN),
    "./dev larns monitor": Skip("needs a running fleet (a 3rd terminal); covered by tests/larns/test_attach.py (larns monitor --once against ./dev demo)"),
    "./dev bench survey --trials 100 --json survey.json": Skip(BENCH),
    "./dev bench sync --trials 100 --json sync.json": Skip(BENCH),
    "./dev bench speed --speeds 1,2,5,10": Skip(BENCH),
    "./dev bench wire --compare --json wire.json": Skip(BENCH),
    "larns bench wire --compare --speed 0.5 --duration 30 --json bench-out/wire.json --png-dir bench-out/wire": Skip(BENCH),
    "larns bench speed --scenario docs/scenarios/field40.toml --worlds 1 --speeds 0.5 --duration 120 --json bench-out/field40-speed.json --png-dir bench-out/field40": Skip(BENCH),
    "larns bench survey --scenario seed003-radio --stations 8 --sigma-d 0.9 --estimator dmap --trials 20": Skip(BENCH),
    "larns bench survey --scenario field.toml --estimator dmap --sigma-d 0.9 --trials 2 --duration 300": Skip(BENCH),
    "larns bench survey --scenario f500.toml --trials 1 --duration 60 --times 30 60 --no-map --jobs 1 --estimator dmap --sigma-d 0.5": Skip(BENCH),
    "larns bench survey --scenario docs/scenarios/field40.toml --trials 4 --duration 120 --estimator dmap --sigma-d 0.5 --no-map": Skip(BENCH),
    "larns bench survey --trials 20 --estimator dmap": Skip(BENCH),
    "larns bench sync --scenario seed003-radio --stations 8 --sigma-d 0.9 --trials 20": Skip(BENCH),
    "./dev bench aircraft --json aircraft.json": Skip(BENCH),
    "./dev bench aircraft --envelope --png-dir png/": Skip(BENCH),
    "./dev bench aircraft --clocks --no-sweep --no-speed": Skip(BENCH),
    "./dev bench cold-start runs/demo.mcap --without survey --without floor": Skip(
        "needs ./dev demo's recording; the bench runs on the shared fleet's in tests/larns/test_bench_coldstart.py"),
    "larns bench cold-start e2ev1.mcap e2ev2.mcap e2ev3.mcap e2ev4.mcap --span 3 --without survey --without survey,floor --without floor --png cold.png": Skip(
        "needs four CPU-starved fleet recordings (the lines above it); the bench runs on the shared fleet's in tests/larns/test_bench_coldstart.py"),
    "larns bench cold-start REC --starts 20 --span 10": Skip(
        "needs a fleet recording REC of the e2e scenario (the line beside it); the bench runs on the shared fleet's in tests/larns/test_bench_coldstart.py"),
    "./dev bench net": Skip("real-time Zenoh latency bench (~1 min); options checked by the parser here"),
    "./dev bench ins --json ins.json --png ins.png": Skip(BENCH),
    "./dev bench integrity --aircraft --json integrity.json": Skip(BENCH),
    "./dev bench vehicle --json vehicle.json": Skip(BENCH),
    "./dev bench triad --json triad.json --png triad.png": Skip(BENCH),
    "./dev larns aircraft --scenario seed003-text --imu adis16480":
        Run("runs until Ctrl-C beside a fleet: --duration 5 appended", append="--duration 5",
            expect=r"\[aircraft ac1\] stopped", slow=True),
    "./dev larns vehicle --scenario seed000 --route docs/routes/field-straight.toml":
        Run("runs until Ctrl-C beside a fleet: --duration 5 appended", append="--duration 5",
            expect=r"\[vehicle veh1\] stopped", slow=True),
    "./dev larns info runs/demo.mcap": Run(expect=r"Stations:\s+10"),
    "./dev larns replay runs/demo.mcap --rate 2": Run(expect=r"\[replay\] published \d+ messages"),
    "./dev larns fleet --scenario seed000 --aircraft --view": Skip(VIEW),
    "./dev larns view --connect tcp/127.0.0.1:7447": Skip(VIEW),
    "./dev larns report runs/demo.mcap -o runs/report": Run(expect=r"figures \+ report.md in runs/report"),
    "./dev larns export runs/demo.mcap -o runs/fox.mcap": Run(expect=r"Foxglove JSON messages -> runs/fox.mcap"),
    "./dev larns keys init runs/keys --stations 1-10 --aircraft ac1": Run(expect=r"keystore runs/keys: CA \+ 14 enclaves"),
    "./dev larns fleet --secure runs/keys --duration 60":
        Run("--duration 60 -> 20, after the README's keys init line", edits=_short("--duration 60", "--duration 20"),
            before=("./dev larns keys init runs/keys --stations 1-10 --aircraft ac1",), expect=SURVEYED, slow=True),
    "scripts/docker-build.sh": Skip(COMPOSE),
    "docker compose up": Skip(COMPOSE),
    "docker compose run --rm keys add /keys --station 11": Skip(COMPOSE),
    "docker compose --profile hotjoin up -d station11": Skip(COMPOSE),
    "docker compose down -v": Skip(COMPOSE),
    # --- docs/deploy.md, two sites
    "scripts/compose-sites.py --out runs/sites.yml": Skip(SITES),
    "docker compose -f runs/sites.yml --project-directory . -p sites up -d": Skip(SITES),
    "docker compose -f runs/sites.yml --project-directory . -p sites down -v": Skip(SITES),
    # --- docs/slots.md
    "larns bench slots --trials 5": Skip(BENCH),
    "larns bench slots --trials 5 --cycle-slots 0": Skip(BENCH),
    "larns bench slots --trials 5 --tx-power-dbm 0": Skip(BENCH),
    "larns bench slots --trials 5 --tx-power-dbm 3": Skip(BENCH),
    "larns bench slots --trials 5 --tx-power-dbm 5": Skip(BENCH),
    "larns bench slots --layout corridor --trials 5": Skip(BENCH),
    "larns bench slots --layout corridor --trials 5 --cycle-slots 0": Skip(BENCH),
    "larns bench slots --layout corridor --trials 5 --tx-power-dbm 0": Skip(BENCH),
    "larns bench slots --stations 40 --trials 1 --duration 20 --joiners 2 --tx-power-dbm -5 --cycle-slots 20":
        Run(expect=r"bar joiners_hold_within_3_cycles: PASS", timeout_s=60.0),
    "larns bench slots --scenario docs/scenarios/slots-field.toml --duration 80 --compare-fixed":
        Skip(BENCH + "; its small twin (--scenario, --compare-fixed) runs in tests/larns/test_bench_slots.py"),
    "larns bench slots --scenario FILE --duration 60": Skip(SYNOPSIS, concrete=False),
    # --- docs/aircraft.md
    "larns crlb --scenario seed003 --png crlb.png [--height 1000] [--params posvel|pos] [--clock] [--json F]":
        Run("the [optional] parts dropped", edits=_short(" [--height 1000] [--params posvel|pos] [--clock] [--json F]", ""),
            expect=r"wrote crlb.png"),
    "larns bench aircraft [--trials 32] [--duration 40] [--warmup 10] [--height H] [--seed 1]": Skip(SYNOPSIS, concrete=False),
    "larns bench aircraft --seed 2 --no-sweep": Skip(BENCH),
    "larns bench aircraft --quick --no-speed": Skip("a minute of Monte Carlo; its smaller twin runs in tests/larns/test_bench_aircraft.py::test_bench_aircraft_quick_smoke"),
    "larns bench aircraft --clocks": Skip(BENCH),
    "larns bench aircraft --clocks --clock-bias white": Skip(BENCH),
    "larns bench aircraft --envelope": Skip(BENCH),
    "larns bench aircraft --envelope [--trials 12] [--duration 16] [--warmup 6] [--seed 1]": Skip(SYNOPSIS, concrete=False),
    "larns bench aircraft --clocks --no-sweep --no-speed --trials 32": Skip(BENCH),
    "larns aircraft --scenario seed003 --algo ukf-pr --algo ekf-tdoa [--name ac1] [--speed K] [--epoch T]": Skip(SYNOPSIS, concrete=False),
    "python -m aircraft ...": Skip(SYNOPSIS + " (= larns aircraft ...)", concrete=False),
    "larns fleet --scenario seed000 --aircraft":
        Run("default 60 fleet s: --duration 20 appended", append="--duration 20",
            expect=(SURVEYED, r"aircraft\s+ac1\s+ukf-pr: t="), slow=True),
    "larns bench integrity --aircraft seed001 seed003": Skip(BENCH),
    "larns bench integrity --aircraft": Skip(BENCH),
    "./dev larns bench integrity --cases liar range_bias --trials 40 --duration 90 --recovery --png-dir docs/img": Skip(BENCH),
    "larns keys add DIR --vehicle veh1": Skip(SYNOPSIS, concrete=False),
    "./dev larns fleet --scenario FILE --duration 45 --speed 3 --aircraft --record f.mcap": Skip(SYNOPSIS + " (FILE: a world written from tests/scenario_text.py)", concrete=False),
    "./dev larns report f.mcap -o rep": Run("f.mcap: " + DEMO, expect=r"figures \+ report.md in rep", slow=True),
    "./dev larns bench aircraft --quick --no-speed --json ...": Skip(SYNOPSIS, concrete=False),
    # --- docs/architecture.md, docs/replay.md, docs/view.md, docs/sync.md, docs/security.md: prose
    "larns fleet --vehicle": Skip(MENTION, concrete=False),
    "larns replay --secure": Skip(MENTION, concrete=False),
    "larns replay --offline": Skip(MENTION, concrete=False),
    "larns fleet --record": Skip(MENTION, concrete=False),
    "larns record --no-foxglove": Skip(MENTION, concrete=False),
    "larns fleet --view": Skip(MENTION, concrete=False),
    "larns replay --view": Skip(MENTION, concrete=False),
    "larns fleet --view [PORT]": Skip(MENTION, concrete=False),
    "larns replay --view [PORT]": Skip(MENTION, concrete=False),
    "larns view --host 0.0.0.0": Skip(MENTION, concrete=False),
    "larns fleet --duration": Skip(MENTION, concrete=False),
    "larns fleet --topology router": Skip(MENTION, concrete=False),
    "larns station --report-json": Skip(MENTION, concrete=False),
    "larns replay --offline --algo triad": Skip(MENTION, concrete=False),
    "larns reestimate FILES [options]": Skip(SYNOPSIS, concrete=False),
    "larns replay --offline FILES [options]": Skip(SYNOPSIS, concrete=False),
    "larns report run.mcap -o DIR": Skip(SYNOPSIS, concrete=False),
    "larns keys add DIR --station 11": Skip(SYNOPSIS, concrete=False),
    "larns record -o run.mcap [--connect E] [--epoch T --speed K] [--scenario NAME]": Skip(SYNOPSIS, concrete=False),
    # --- docs/deploy.md
    "docker compose logs -f station5": Skip(COMPOSE),
    "docker compose run -d --no-deps ...": Skip(COMPOSE),
    "larns info runs/fleet.mcap": Run("runs/fleet.mcap (the compose recorder's file): " + DEMO, expect=r"complete"),
    # --- docs/fleet.md
    "larns fleet --scenario seed000 --duration 60 --speed 1 --record run.mcap":
        Run("--duration 60 -> 15", edits=_short("--duration 60", "--duration 15"),
            expect=(r"recording: run.mcap", SURVEYED), slow=True),
    "larns fleet --scenario seed000 --duration 60 --join 11@20":
        Run("--duration 60 -> 40 (the join is at 20 s)", edits=_short("--duration 60", "--duration 40"),
            expect=r"(?m)^\s+11 +(joining|surveying)", slow=True),
    "larns fleet --scenario seed000 --duration 60 --topology router":
        Run("--duration 60 -> 15", edits=_short("--duration 60", "--duration 15"), expect=(ROUTER, SURVEYED), slow=True),
    "larns fleet --scenario seed000 --duration 180 --speed 2 --vehicle --record run.mcap":
        Run("--duration 180 -> 30", edits=_short("--duration 180", "--duration 30"),
            expect=(SURVEYED, r"vehicle\s+veh1\s+cdekf-map: t="), slow=True),
    "larns record -o runs/extra.mcap --fleet runs/fleet.json": Skip("attaches to the running ./dev demo (terminal 4); the attach logic (fleet file, its end) is tests/larns/test_attach.py"),
    "larns aircraft --fleet runs/fleet.json --duration 120": Skip("attaches to the running ./dev demo (terminal 5); the attach logic (fleet file, its end) is tests/larns/test_attach.py"),
    "larns station --id 5 --scenario seed000 --epoch 1795300000 --listen tcp/127.0.0.1:7450 --connect tcp/127.0.0.1:7447": Skip(MANUAL),
    "larns record -o run.mcap --connect tcp/127.0.0.1:7447": Skip(MANUAL),
    "larns monitor --connect tcp/127.0.0.1:7447 --epoch 1795300000": Skip(MANUAL),
    "larns router --listen tcp/127.0.0.1:7447": Skip(MANUAL),
    "larns station --id 5 --scenario seed000 --zenoh-mode client --connect tcp/127.0.0.1:7447": Skip(MANUAL),
    "larns record -o run.mcap --zenoh-mode client --connect tcp/127.0.0.1:7447": Skip(MANUAL),
    "larns fleet --scenario seed000 --topology router":
        Run("default 60 fleet s: --duration 15 appended", append="--duration 15", expect=(ROUTER, SURVEYED), slow=True),
    "larns bench scale --topology router --n 50": Skip(BENCH),
    "larns bench net": Skip("real-time Zenoh latency bench (~1 min); options checked by the parser here"),
    "larns bench scale": Skip(BENCH),
    "larns bench scale --n 50 --duration 60": Skip(BENCH),
    "larns bench scale --topology router --n 50 --duration 60": Skip(BENCH),
    "larns bench scale --topology router|peer --n N --duration 60": Skip(SYNOPSIS, concrete=False),
    "larns bench scale --topology peer|router --n N --duration 60": Skip(SYNOPSIS, concrete=False),
    # --- docs/ins.md
    "larns aircraft --scenario seed003-text --imu adis16480":
        Run("runs until Ctrl-C beside a fleet: --duration 5 appended", append="--duration 5",
            expect=r"\[aircraft ac1\] stopped", slow=True),
    "larns fleet --scenario seed003-text --duration 120 --aircraft --record runs/ins.mcap":
        Run("--duration 120 -> 50 (the INS starts from the broadcasts at ~35 s)", edits=_short("--duration 120", "--duration 50"),
            expect=r"aircraft\s+ac1\s+ins-ekf: t=", slow=True),
    "larns replay --offline runs/ins.mcap --algo ins-ekf":
        Run("on the recording of ins.md's fleet line (shortened)",
            in_dir_of="larns fleet --scenario seed003-text --duration 120 --aircraft --record runs/ins.mcap",
            expect=r"aircraft ac1 ins-ekf: [1-9]\d* estimates.*vs the (\d+) recorded: \1/\1 identical", slow=True),
    "larns replay --offline runs/ins600/ins.mcap --algo ins-ekf --scenario seed003-text-10": Skip("needs the 600 s ten-station INS recording of the text (runs/ins600); the same re-flight RUNs on ins.md's fleet line"),
    "./dev larns bench ins --json ins.json --png ins.png": Skip(BENCH),
    "./dev larns bench ins --runs 64 --no-speed --no-tilt-cost --json ins64.json": Skip(BENCH),
    "./dev larns bench ins --runs 16 --no-tilt-cost --no-speed --json ...": Skip(SYNOPSIS, concrete=False),
    "./dev larns bench ins --runs 64 --no-speed --no-tilt-cost --json ins64.json --png ins64.png": Skip(BENCH),
    # --- docs/replay.md (run.mcap, old.mcap, out.mcap: the session recording; killed.mcap: it cut at 60 %)
    "larns info run.mcap": Run(expect=r"Vehicle veh1: .*position error RMS"),
    "larns replay run.mcap": Run("real-time playback of the session recording (~12 s wall)",
                                 expect=r"\[replay\] published \d+ messages", slow=True),
    "larns replay run.mcap --offline --check": Run(expect=r"identical"),
    "larns reestimate run.mcap --check": Run(expect=r"vehicle veh1 cdekf-map: \d+ estimates re-run from its journal"),
    "larns replay run.mcap --offline --estimator seed-ukf -o ukf.mcap": Run(expect=r"seed-ukf"),
    "larns replay run.mcap --offline --algo ekf-pr --algo ukf-tdoa -o ac.mcap": Run(expect=r"aircraft ac1 ukf-tdoa: \d+ estimates"),
    "larns report run.mcap -o report/": Run(expect=r"figures \+ report.md in report", slow=True),
    "larns export old.mcap -o view.mcap": Run(expect=r"-> view.mcap"),
    "larns recover killed.mcap -o fixed.mcap": Run(expect=r"kept \d+ messages"),
    "larns bench replay": Skip(BENCH + " (a 10-station, 10-minute log first)"),
    "larns bench replay --repeat 3": Skip(BENCH),
    "larns bench replay --duration 60": Skip(BENCH),
    "larns bench replay --duration 60 --ranging poll": Skip(BENCH),
    "larns bench survey --trials 3 --ranging poll --duration 60 --jobs 1 --json survey.json": Skip(BENCH),
    "larns bench sync --trials 3 --ranging poll --duration 60 --jobs 1 --json sync.json": Skip(BENCH),
    "larns bench survey --trials 100 --sigma-d 0.5 --estimator dmap": Skip(BENCH),
    "larns bench survey --trials 100 --sigma-d 0.5 --estimator dmap --ranging poll": Skip(BENCH),
    "larns bench survey --trials 100 --sigma-d 0.5 --estimator dmap --ranging poll --duration 10 --times 1 2 3 5 10 --no-map": Skip(BENCH),
    "larns bench survey --trials 20 --sigma-d 0.5 --estimator dmap --ranging poll --duration 40 --times 10 20 30 40 --jobs 1 --no-map": Skip(BENCH),
    "larns bench survey --trials 20 --seed 21 --sigma-d 0.5 --estimator dmap --ranging poll --duration 40 --times 10 20 30 40 --jobs 1 --no-map": Skip(BENCH),
    "larns bench sync --trials 100 --duration 60": Skip(BENCH),
    "larns bench sync --trials 100 --duration 60 --ranging poll": Skip(BENCH),
    "larns bench sync --trials 100 --ranging poll --jobs 2": Skip(BENCH),
    "larns bench sync --founders-leave --ranging poll --trials 20 --jobs 1": Skip(BENCH),
    "larns bench sync --founders-leave --ranging poll --trials 100 --jobs 2": Skip(BENCH),
    "larns bench survey --founders-leave --ranging poll --trials 20 --sigma-d 0.5 --seed 1 --jobs 1": Skip(BENCH),
    "larns bench survey --founders-leave --trials 20 --sigma-d 0.5 --seed 1 --jobs 1": Skip(BENCH),
    "larns bench survey --datum field --estimator dmap --duration 300 --trials 20 --sigma-d 0.5 --seed 1 --no-map --jobs 1": Skip(BENCH),
    "larns bench survey --datum field --ranging poll --estimator dmap --duration 300 --trials 20 --sigma-d 0.5 --seed 1 --no-map --jobs 1": Skip(BENCH),
    "larns bench sync --trials 20 --ranging poll --duration 60 --jobs 1": Skip(BENCH),
    "larns bench survey --trials 20 --ranging poll --sigma-d 0.5 --no-map --jobs 1": Skip(BENCH),
    "larns bench sync --trials 40": Skip(BENCH),
    "larns bench survey --trials 20": Skip(BENCH),
    "larns reestimate --algo": Skip(MENTION, concrete=False),
    "larns reestimate --check": Skip(MENTION, concrete=False),
    "larns info --json": Skip(MENTION, concrete=False),
    "larns info REC --json": Skip(MENTION, concrete=False),
    "larns fleet --scenario seed000-poll --duration 60 --speed 1 --record poll.mcap --json poll.json":
        Skip(BENCH + " (a 60 s fleet at speed 1 measured on a quiet machine; seed000-poll runs whole in the matrix)"),
    "larns info poll.mcap": Skip(BENCH + " (reads the recording of the fleet line above)"),
    "larns fleet --scenario s1.toml --duration 0": Skip(MENTION + "; s1.toml is the measurement's scratch copy of seed001", concrete=False),
    "larns reestimate --stations 99 -o": Skip(MENTION, concrete=False),
    "larns reestimate REC --stations 99 -o OUT": Skip(MENTION + "; REC / OUT: a measurement's recordings", concrete=False),
    "larns fleet --scenario seed000 --duration 90 --aircraft":
        Skip(BENCH + " (90 s fleets recorded for a re-flight measurement in docs/aircraft.md)"),
    "larns aircraft --scenario S --algo ekf-tdoa --epoch $(date +%s) --duration 3600 --listen tcp/127.0.0.1:7500 &": Skip(MANUAL + "; S is a placeholder", concrete=False),
    "larns replay run.mcap --topics 'larns/station/*/nav/**' --connect tcp/127.0.0.1:7500 --wait-for 'larns/alive/aircraft/*'": Skip(MANUAL + " (waits for the aircraft of the line above)"),
    "larns report out.mcap": Run("out.mcap (a reestimate -o output): " + DEMO, expect=r"figures \+ report.md", slow=True),
    "./dev larns replay runs/demo.mcap --view": Skip(VIEW),
    "larns replay run.mcap --view": Skip(VIEW),
    # --- docs/scenarios.md
    "larns scenario list": Run(expect=r"seed003"),
    "larns scenario show seed003": Run(expect=r"seed003"),
    "larns scenario validate my.toml other.toml": Run("my.toml, other.toml: copies of seed000 and seed003", expect=r"my.toml: ok"),
    # --- docs/security.md
    "larns keys init keys/ --stations 1-10 --aircraft ac1": Run(expect=r"CA \+ 14 enclaves"),
    "larns fleet --secure keys/ --duration 120 --record run.mcap":
        Run("--duration 120 -> 20, after the keys init line", edits=_short("--duration 120", "--duration 20"),
            before=("larns keys init keys/ --stations 1-10 --aircraft ac1",), expect=(r"recording: run.mcap", SURVEYED),
            slow=True),
    "larns keys add keys/ --station 11": Run("after the keys init line", before=("larns keys init keys/ --stations 1-10 --aircraft ac1",),
                                             expect=r"issued station-11"),
    "larns station --id 11 --join --secure keys/ --connect tls/127.0.0.1:PORT": Skip(MANUAL + "; PORT is a placeholder", concrete=False),
    "larns keys revoke keys/ --station 5 --publish --connect tls/127.0.0.1:PORT":
        Skip("publishes to a running --secure fleet (PORT: a placeholder); revocation on a live fleet is tests/net/test_revocation_live.py",
             concrete=False),
    "larns keys renew keys/ --all": Run("after the keys init line", before=("larns keys init keys/ --stations 1-10 --aircraft ac1",), expect=r"station-9: renewed until"),
    "larns keys export keys/ host5/ --enclave station-5": Run("after the keys init line", before=("larns keys init keys/ --stations 1-10 --aircraft ac1",),
                                                               expect=r"host5/: station-5 \+ \d+ public files"),
    "larns info run.mcap --keystore keys/":
        Run("on the recording of the secure fleet line (shortened) in its directory",
            in_dir_of="larns fleet --secure keys/ --duration 120 --record run.mcap", expect=r"Stations:\s+10", slow=True),
    "larns keys revoke --publish": Skip(MENTION, concrete=False),
    "larns keys revoke DIR --station 5": Skip(SYNOPSIS, concrete=False),
    "larns keys add DIR --station 5": Skip(SYNOPSIS, concrete=False),
    "larns keys add DIR": Skip(SYNOPSIS, concrete=False),
    "larns keys init --days N": Skip(MENTION, concrete=False),
    "larns keys renew DIR --all [--days N]": Skip(SYNOPSIS, concrete=False),
    "larns keys export DIR OUT --enclave station-5": Skip(SYNOPSIS, concrete=False),
    "larns info --keystore DIR": Skip(MENTION, concrete=False),
    # docs/aircraft.md "Cold start": issue 28's bar run and how it is read
    "larns fleet --scenario seed000 --duration 90 --aircraft --record run.mcap":
        Skip("the issue-28 bar run (90 s at speed 1, measured in docs/aircraft.md); the same fleet whole, scored "
             "from its MCAP, is tests/test_defaults_matrix.py::test_the_default_scenario_whole (speed 2)"),
    "larns info RUN.mcap": Run("RUN.mcap: " + DEMO, expect=r"ac1 ukf-pr: \d+ estimates, first at"),
    "larns keys add / renew / revoke": Skip(MENTION, concrete=False),
    "docker compose run --rm keys revoke /keys --station 5": Skip(COMPOSE),
    "larns router --secure keys/ --listen tls/127.0.0.1:7447": Skip(MANUAL),
    "larns fleet --secure keys/ --topology router --connect tls/127.0.0.1:7447": Skip(MANUAL + " (connects to the router of the line above)"),
    "larns bench scale --topology router --n 20 --duration 30": Skip(BENCH),
    "larns bench scale --secure --topology router --n 50": Skip(BENCH),
    "./dev larns bench scale [--secure] --topology router --n 50 --duration 60 --json F": Skip(SYNOPSIS, concrete=False),
    "larns attack flood --as 9 --rate 20000": Skip("attacks a running --secure fleet (a second terminal); tests/net/test_security.py::test_flood_from_station_9_leaves_other_slots_intact"),
    "larns attack --as station-N": Skip(MENTION, concrete=False),
    "larns station --secure": Skip(MENTION, concrete=False),
    "larns attack --as station-2 --mode all": Skip("the insider of the fleet bar, started by tests/larns/test_insider_fleet.py beside its fleet"),
    "larns attack --as station-2 --mode all --secure keys/ --connect tls/127.0.0.1:7447 --duration 60": Skip("an insider against a running --secure fleet (a second terminal); tests/larns/test_insider.py::test_insider_modes_against_secure_stations, tests/larns/test_insider_fleet.py"),
    "larns attack --as station-2 --mode slots --secure keys/ --zenoh-mode client --connect tls/127.0.0.1:7447": Skip("an insider against a running --secure fleet through its router (a second terminal); tests/larns/test_insider_fleet.py"),
    "scripts/secure-bar.sh 120 runs/secure-barK": Skip("the secure bar: secure fleets and all attacks for 120 s (minutes); path checked"),
    "scripts/secure-bar.sh 120": Skip("the secure bar: secure fleets and all attacks for 120 s (minutes); path checked"),
    "scripts/secure-bar.sh 45": Skip("the secure bar: secure fleets and all attacks for 45 s (minutes); path checked"),
    "larns keys init /keys --stations 1-10 --aircraft ac1": Skip("the compose keys service's command (/keys: its volume); " + COMPOSE),
    # --- docs/survey.md
    "./dev bench survey --trials 100 --json bench-out/survey.json --png-dir bench-out/survey": Skip(BENCH),
    "./dev bench survey --trials 100 --sigma-d 0.5 --estimator dmap --no-map": Skip(BENCH),
    "./dev larns bench survey --trials 100 --sigma-d 0.5 --estimator dmap --no-map": Skip(BENCH),
    "./dev larns bench integrity --trials 20 --aircraft seed001 seed003 --json bench-out/integrity.json --png-dir docs/img": Skip(BENCH),
    "./dev larns bench integrity --cases --aircraft seed001 seed003": Skip(BENCH),
    # --- docs/sync.md
    "larns bench sync --founders-leave": Skip(BENCH),
    "larns bench sync --trials 20": Skip(BENCH),
    "larns bench sync --trials 100 --jobs 2 --bound-draws 4000": Skip(BENCH),
    "larns bench sync --scenario mh60.toml --sigma-d 0.9 --trials 4 --jobs 2 --duration 240 --hops-from 120 "
    "--png-dir bench-out/mh": Skip(BENCH),
    "larns bench sync --scenario mh60.toml --sigma-d 0.9 --trials 2 --jobs 2 --duration 240 --hops-from 120": Skip(BENCH),
    "larns bench sync --scenario mh60.toml --sigma-d 0.9 --trials 2 --seed 3 --jobs 2 --duration 240 "
    "--hops-from 120": Skip(BENCH),
    "larns bench sync --trials 20 --duration 60 --jobs 1": Skip(BENCH),
    "larns bench sync --trials 20 --duration 60 --ranging poll --jobs 1": Skip(BENCH),
    "larns bench sync --trials 20 --jobs 2": Skip(BENCH),
    "larns bench sync --late-founder 5 --trials 20 --duration 60 --jobs 2": Skip(BENCH),
    "larns bench integrity --trials 20": Skip(BENCH),
    "larns bench integrity --cases clock_jump": Skip(BENCH),
    "larns bench sync --late-founder 5 --trials 100 --duration 60 --jobs 2": Skip(BENCH),
    "larns bench sync --trials 100 --founders-leave --json bench-out/sync/founders-leave.json": Skip(BENCH),
    "./dev larns bench survey --founders-leave --trials 18 --sigma-d 0.5 --seed 1": Skip(BENCH),
    "./dev larns bench survey --founders-leave --trials 6 --sigma-d 0.5 --seed 1 --jobs 1": Skip(BENCH),
    "scripts/datum_nees.py seed000 --trials 8 --duration 300 --sigma-d 0.5 --founders-leave": Skip(BENCH + "; path checked"),
    "scripts/datum_nees.py seed001 --trials 10 --duration 90": Skip(BENCH + "; path checked"),
    "scripts/datum_nees.py --world7": Skip("a few seconds, but a measurement script, not a product line; its 59 s check is "
                                           "tests/stations/test_datum.py::test_seven_station_world_survivors_within_4_sigma"),
    "scripts/datum_nees.py --world7 --fleet-timing": Skip("a few seconds, but a measurement script, not a product line; "
                                                          "path checked"),
    "./dev larns bench integrity --trials 20 --jobs 2": Skip(BENCH),
    "larns fleet --scenario seed000-poll": Skip("a fleet run whole by the defaults matrix (tests/test_defaults_matrix.py, "
                                                 "seed000-poll, with the aircraft)"),
    "larns fleet --scenario seed001 --aircraft": Skip(BENCH + " (the live aircraft's CPU, read from /proc over 30 s)"),
    "larns bench sync --trials 100 --json bench-out/sync/sync.json": Skip(BENCH),
    "larns fleet --scenario seed000 --duration 600 --speed 1 --record ten.mcap": Skip("a 10-minute measurement run; the same line with --duration 15 RUNs as docs/fleet.md's 'larns fleet --scenario seed000 --duration 60 --speed 1 --record run.mcap'"),
    "larns info ten.mcap": Run("ten.mcap: " + DEMO, expect=r"Stations:\s+10"),
    "larns fleet --scenario seed000 --duration 60 --speed S --record s.mcap": Skip(SYNOPSIS + " (S: the speed under test)", concrete=False),
    "larns fleet --duration 60 --speed S --record": Skip(SYNOPSIS + " (S: the speed under test)", concrete=False),
    "./dev bench speed --worlds 1,2,3,4 --speeds 1,2,5,10,20 --json bench-out/speed10.json": Skip(BENCH),
    "./dev bench speed --stations 30 --worlds 1,2 --speeds 1,2,5 --json bench-out/speed30.json": Skip(BENCH),
    "./dev bench speed --worlds 1,2,3,4 --speeds 1,2,5,10,20 --json speed10.json": Skip(BENCH),
    "./dev bench speed --stations 30 --worlds 1,2 --speeds 1,2,5 --json speed30.json": Skip(BENCH),
    # --- docs/triad.md
    "./dev larns bench triad --json runs/bench_triad.json --png docs/img/bench_triad.png": Skip(BENCH),
    "./dev larns bench triad --quick": Skip("~1.5 min even quick; tests/aircraft/test_triad.py runs the triad Monte Carlo"),
    "./dev test tests/aircraft/test_triad.py -q": Skip(SUITE),
    "./dev test tests/aircraft/test_triad_live.py -q": Skip(SUITE),
    "./dev larns aircraft --scenario seed003-text --satellites 4 --epoch E --connect EP": Skip(MANUAL + "; E, EP are placeholders", concrete=False),
    "./dev larns fleet --scenario triad_live.toml --duration 60 --aircraft --record runs/triad.mcap":
        Run("--duration 60 -> 45 (the triad starts from the broadcasts); triad_live.toml written as the doc says "
            "(seed003-text with algos = [\"triad\"])",
            edits=_short("--duration 60", "--duration 45"), expect=r"aircraft\s+ac1\s+triad: t=", slow=True),
    "./dev larns replay --offline runs/triad.mcap --algo triad --scenario triad_live.toml":
        Run("on the recording of triad.md's fleet line (shortened)",
            in_dir_of="./dev larns fleet --scenario triad_live.toml --duration 60 --aircraft --record runs/triad.mcap",
            expect=r"aircraft ac1 triad: [1-9]\d* estimates.*vs the (\d+) recorded: \1/\1 identical", slow=True),
    # --- docs/vehicle.md
    "larns bench vehicle --json vehicle.json --png-dir img/": Skip(BENCH),
    "larns vehicle --scenario seed000 --route docs/routes/field-straight.toml":
        Run("runs until Ctrl-C beside a fleet: --duration 5 appended", append="--duration 5",
            expect=r"\[vehicle veh1\] stopped", slow=True),
    "larns fleet --scenario seed000 --duration 180 --speed 2 --vehicle --vehicle-outage 80,110 --record run.mcap":
        Run("--duration 180 -> 30 (the outage then lies after the run)", edits=_short("--duration 180", "--duration 30"),
            expect=(SURVEYED, r"vehicle\s+veh1\s+cdekf-map: t="), slow=True),
    "larns reestimate run.mcap": Run(expect=r"vehicle veh1 cdekf-map: .*identical"),
    "larns fleet --scenario seed000 --duration 180 --speed 2 --record run.mcap --vehicle --vehicle-outage 80,110 --no-table":
        Skip("the same run as the line above it in docs/vehicle.md (RUN) with --no-table"),
    "./dev bench vehicle --runs 20 --runs-other 8 --json vehicle.json --png-dir img/": Skip(BENCH),
    "./dev bench vehicle --cases paper --runs 50": Skip(BENCH),
    # --- docs/view.md
    "./dev larns fleet --scenario seed000 --duration 120 --speed 2 --aircraft --view": Skip(VIEW),
    "./dev larns fleet --scenario seed000 --duration 300 --aircraft --view": Skip(VIEW),
    "./dev larns fleet --scenario seed000-geo --duration 120 --speed 2 --aircraft --view": Skip(VIEW),
    "./dev larns view --scenario seed000-geo --connect tcp/127.0.0.1:7447": Skip(VIEW),
    "./dev larns export runs/demo.mcap --scenario seed000-geo --geojson runs/demo.geojson --kml runs/demo.kml "
    "--csv runs/demo.csv --nmea runs/demo.nmea":
        Run(expect=(r"GeoJSON features -> runs/demo.geojson", r"\(CSV, with lat/lon/h\) -> runs/demo.csv",
                    r"NMEA sentences \(ac1 ")),
    "./dev larns export runs/demo.mcap --csv runs/stations.csv": Run(expect=r"10 stations \(CSV\) -> runs/stations.csv"),
    "larns export -o": Skip(MENTION, concrete=False),
    "larns view --scenario NAME|FILE": Skip(SYNOPSIS, concrete=False),
    # --- docs/scenarios.md, Sites on the Earth
    "larns export --geojson / --kml / --csv / --nmea": Skip(MENTION, concrete=False),
    "larns bench survey --trials 1 --seed 1 --sigma-d 0.5 --estimator dmap seed-ukf --no-map": Skip(BENCH),
}


# ----------------------------------------------------------------------------- table vs docs

def test_every_doc_command_is_classified_and_every_row_is_in_the_docs():
    found = doc_commands()
    missing = {c: where for c, where in found.items() if c not in TABLE}
    stale = [c for c in TABLE if c not in found]
    assert not missing, "commands in the docs without a row in TABLE (classify them as Run or Skip):\n" + "\n".join(
        f"  {c!r}  ({', '.join(w)})" for c, w in missing.items())
    assert not stale, "TABLE rows no longer in the docs (remove them):\n" + "\n".join(f"  {c!r}" for c in stale)


def test_extraction_rule():
    """The rule of the module docstring on a small document: fenced shell lines, inline examples with
    arguments, not prose names of commands, not other fences, not table rows that begin with "larns"."""
    text = "\n".join([
        "Run `larns info` or `larns bench aircraft` (names), `larns info run.mcap` (an example).",
        "```bash", "$ larns scenario list   # comment", "./dev larns fleet \\", "   --duration 5", "echo hi", "```",
        "```toml", "larns fleet --x", "```",
        "```", "larns          13   0.001 / 0.001", "```",
    ])
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "x.md"
        p.write_text(text)
        got = [c for _n, c in extract(p, set(_subparsers(_parser())))]
    assert got == ["larns info run.mcap", "larns scenario list", "./dev larns fleet --duration 5"], got


# ----------------------------------------------------------------------------- static checks

def larns_argv(cmd: str) -> list[str] | None:
    """The ``larns`` arguments a line stands for (``./dev larns``, ``./dev bench``, ``./dev demo``), or None."""
    try:
        tok = shlex.split(cmd)
    except ValueError:
        tok = cmd.split()
    if tok[0] == "larns":
        return tok[1:]
    if tok[:2] == ["./dev", "larns"]:
        return tok[2:]
    if tok[:2] == ["./dev", "bench"]:
        return ["bench", *tok[2:]]
    if tok[:2] == ["./dev", "demo"]:
        return ["fleet", "--scenario", "seed000", "--duration", "60", "--aircraft", "--record", "runs/demo.mcap",
                *tok[2:]]  # ./dev's demo line
    return None


def _command_parser(argv: list[str]) -> argparse.ArgumentParser:
    p = _parser()
    for t in argv:
        sub = _subparsers(p)
        if t not in sub:
            break
        p = sub[t]
    return p


def _check_options(cmd: str, entry: Run | Skip, argv: list[str]) -> None:
    """Each ``--option`` of the line exists for its (sub)command."""
    p = _command_parser(argv)
    known = {o for a in p._actions for o in a.option_strings}
    unknown = [o for o in re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", cmd) if o not in known]
    if isinstance(entry, Skip) and not entry.options_exist:
        return
    assert not unknown, f"{cmd!r}: larns {p.prog.split(' ', 1)[-1]} has no option {unknown}"


def _check_parses(cmd: str, argv: list[str]) -> None:
    """The larns argument parser accepts the line (``--help`` exits 0)."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            _parser().parse_args(argv)
        except SystemExit as e:
            assert e.code == 0, f"{cmd!r}: the larns parser refuses it: {err.getvalue().strip()}"


def _check_scenarios(cmd: str) -> None:
    """``--scenario NAME`` names a packaged scenario (files and placeholders aside)."""
    from net.scenario import resolve

    for name in re.findall(r"--scenario (\S+)", cmd):
        if not name.endswith(".toml") and not name.isupper() and name != "S":
            assert resolve(name).exists(), f"{cmd!r}: no packaged scenario {name}"


def _check_paths(cmd: str) -> None:
    """Paths into docs/, tests/, scripts/ exist (an output's folder does; inputs themselves do)."""
    for tok in cmd.split():
        if tok.startswith(("docs/", "tests/", "scripts/")):
            path = ROOT / tok.rstrip("/")
            assert path.exists() or path.parent.is_dir(), f"{cmd!r}: {tok} is not in the repository"
            if tok.startswith(("tests/", "scripts/")) or tok.endswith(".toml"):
                assert path.exists(), f"{cmd!r}: {tok} is not in the repository"


@pytest.mark.parametrize("cmd", [pytest.param(c, id=c[:90]) for c in TABLE])
def test_doc_command_is_well_formed(cmd):
    entry = TABLE[cmd]
    argv = larns_argv(cmd)
    if argv is not None:
        _check_options(cmd, entry, argv)
        if isinstance(entry, Run):
            _check_parses(cmd, larns_argv(rewritten(cmd)))
        elif entry.concrete:
            _check_parses(cmd, argv)
        _check_scenarios(cmd)
    _check_paths(cmd)


# ----------------------------------------------------------------------------- running

DEMO_ARGS = ["--duration", "30", "--speed", "3", "--aircraft", "--vehicle", "--no-table"]
RECORDING_NAMES = ["run.mcap", "old.mcap", "out.mcap", "ten.mcap", "f.mcap", "runs/fleet.mcap", "RUN.mcap"]


def _dev_beside_venv(d: Path) -> None:
    """``./dev`` and ``pyproject.toml`` copied into d, with a ``.venv`` whose ``bin`` is the project's
    and whose install stamp matches (so ``./dev`` never runs pip)."""
    shutil.copy(ROOT / "dev", d / "dev")
    shutil.copy(ROOT / "pyproject.toml", d / "pyproject.toml")
    venv = d / ".venv"
    venv.mkdir(exist_ok=True)
    if not (venv / "bin").exists():
        (venv / "bin").symlink_to(Path(PY).parent)
    stamp = hashlib.sha1((d / "pyproject.toml").read_bytes()).hexdigest()[:12]
    (venv / f".installed-{stamp}").touch()


def run_line(line: str, cwd: Path, timeout_s: float) -> tuple[int, str]:
    """Run one command line in cwd (``larns`` as this interpreter's module, ``./dev`` the copy in cwd);
    its whole process group is stopped on timeout. (exit code, stdout + stderr)."""
    tok = shlex.split(line)
    if tok[0] == "larns":
        argv = [PY, "-m", "larns", *tok[1:]]
    elif tok[0] == "./dev":
        argv = ["bash", "./dev", *tok[1:]]
    else:
        raise AssertionError(f"no way to run {line!r}")
    p = subprocess.Popen(argv, cwd=cwd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                         stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        out, _ = p.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGINT)
        try:
            out, _ = p.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            out, _ = p.communicate()
        raise AssertionError(f"{line!r} did not finish within {timeout_s:.0f} s:\n{out[-3000:]}") from None
    return p.returncode, out


@dataclass
class Session:
    dir: Path
    rc: int
    log: str

    @property
    def recording(self) -> Path:
        return self.dir / "runs" / "demo.mcap"


@pytest.fixture(scope="session")
def docs_session(tmp_path_factory) -> Session:
    """The docs' ``./dev demo`` line run once (args appended: ``DEMO_ARGS``): the recording of the session."""
    d = tmp_path_factory.mktemp("docs_demo")
    _dev_beside_venv(d)
    rc, log = run_line("./dev demo " + " ".join(DEMO_ARGS), d, 240)
    if (d / "runs" / "demo.mcap").exists():  # a killed recording: the file cut at 60 %
        data = (d / "runs" / "demo.mcap").read_bytes()
        (d / "killed.mcap").write_bytes(data[: int(0.6 * len(data))])
    return Session(d, rc, log)


def scratch(d: Path, s: Session) -> Path:
    """A directory where every doc line finds what it reads (module docstring)."""
    assert s.rc == 0 and s.recording.exists(), f"./dev demo failed (rc {s.rc}):\n{s.log[-3000:]}"
    (d / "runs").mkdir(exist_ok=True)
    _dev_beside_venv(d)
    (d / "docs").symlink_to(ROOT / "docs")
    for name in ["runs/demo.mcap", *RECORDING_NAMES]:
        (d / name).symlink_to(s.recording)
    (d / "killed.mcap").symlink_to(s.dir / "killed.mcap")
    from net.scenario import resolve

    (d / "my.toml").write_text(resolve("seed000").read_text())
    (d / "other.toml").write_text(resolve("seed003").read_text())
    text = resolve("seed003-text").read_text()
    assert 'algos = ["ins-ekf"]' in text
    (d / "triad_live.toml").write_text(text.replace('algos = ["ins-ekf"]', 'algos = ["triad"]', 1))
    return d


def own_outputs(d: Path, line: str) -> None:
    """A line that writes a recording under a name :func:`scratch` linked to the session recording
    (``--record run.mcap``, ``-o out.mcap``) gets its own file: the link is removed first, so that the
    line does not write through it over the recording the other lines read."""
    words = line.split()
    for flag, name in zip(words, words[1:]):
        if flag in ("--record", "-o", "--output") and (d / name).is_symlink():
            (d / name).unlink()


def rewritten(cmd: str) -> str:
    entry = TABLE[cmd]
    assert isinstance(entry, Run)
    line = cmd
    for old, new in entry.edits:
        assert old in line, f"{cmd!r}: rewrite {old!r} does not apply"
        line = line.replace(old, new)
    return f"{line} {entry.append}".strip()


def run_before(cmd: str, d: Path) -> None:
    """The ``before`` lines of a table line, in d."""
    for pre in TABLE[cmd].before:
        own_outputs(d, rewritten(pre))
        rc, out = run_line(rewritten(pre), d, TABLE[pre].timeout_s)
        assert rc == 0, f"{pre!r} (run first) exited {rc}:\n{out[-3000:]}"


_ONCE: dict[str, tuple[Path, int, str]] = {}


def run_once(cmd: str, tmp_path_factory, s: Session) -> tuple[Path, int, str]:
    """A table line run once per session in its own directory (a recording other lines read)."""
    if cmd not in _ONCE:
        d = scratch(tmp_path_factory.mktemp("docs_once"), s)
        own_outputs(d, rewritten(cmd))
        run_before(cmd, d)
        rc, out = run_line(rewritten(cmd), d, TABLE[cmd].timeout_s)
        _ONCE[cmd] = (d, rc, out)
    return _ONCE[cmd]


def _runs() -> list:
    return [pytest.param(c, marks=[pytest.mark.matrix] if e.slow else [], id=c[:90])
            for c, e in TABLE.items() if isinstance(e, Run)]


def _check_demo(s: Session) -> None:
    """``./dev demo`` (the session recording): the fleet ran, surveyed, flew and drove, and recorded."""
    assert s.rc == 0, s.log[-3000:]
    assert "recording: runs/demo.mcap" in s.log and re.search(r"(?m)^\s+10 surveying", s.log), s.log[-3000:]
    assert re.search(r"aircraft\s+ac1", s.log) and re.search(r"vehicle\s+veh1", s.log), s.log[-3000:]


def _directory(cmd: str, s: Session, tmp_path: Path, factory) -> Path:
    """Where the line runs: beside the cached run of ``in_dir_of``, else a fresh scratch directory
    in which the ``before`` lines ran first."""
    entry = TABLE[cmd]
    if entry.in_dir_of:
        d, rc, out = run_once(entry.in_dir_of, factory, s)
        assert rc == 0, f"{entry.in_dir_of!r} (run first) exited {rc}:\n{out[-3000:]}"
        return d
    d = scratch(tmp_path, s)
    own_outputs(d, rewritten(cmd))
    run_before(cmd, d)
    return d


@pytest.mark.e2e
@pytest.mark.parametrize("cmd", _runs())
def test_doc_command_runs(cmd, docs_session, tmp_path, tmp_path_factory):
    entry = TABLE[cmd]
    if cmd == "./dev demo":
        return _check_demo(docs_session)
    if any(isinstance(e, Run) and e.in_dir_of == cmd for e in TABLE.values()):  # others read its output
        _d, rc, out = run_once(cmd, tmp_path_factory, docs_session)
    else:
        rc, out = run_line(rewritten(cmd), _directory(cmd, docs_session, tmp_path, tmp_path_factory), entry.timeout_s)
    assert rc == entry.rc, f"{rewritten(cmd)!r} exited {rc} (expected {entry.rc}):\n{out[-3000:]}"
    assert "Traceback" not in out, out[-3000:]
    for rx in (entry.expect,) if isinstance(entry.expect, str) else entry.expect:
        assert re.search(rx, out), f"{rewritten(cmd)!r}: no {rx!r} in its output:\n{out[-3000:]}"
