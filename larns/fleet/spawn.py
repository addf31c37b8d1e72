"""Starting the fleet's child processes."""

from __future__ import annotations

import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Any


@dataclass
class Child:
    name: str
    cmd: list[str]
    log_path: Path | None
    proc: subprocess.Popen | None = None
    start_wall: float = 0.0  # when to spawn (wall clock)
    log_file: Any = None
    expected_exit: bool = False  # killed or stopped on purpose (--kill, [[faults]] leave / kill)


def spawn(c: Child) -> None:
    if c.log_path is not None:
        c.log_file = open(c.log_path, "w")
        c.proc = subprocess.Popen(c.cmd, stdout=c.log_file, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                  start_new_session=True)
    else:
        c.proc = subprocess.Popen(c.cmd, stdin=subprocess.DEVNULL, start_new_session=True)
