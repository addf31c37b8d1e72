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
    join_t_s: float | None = None  # a joiner's fleet time of joining (its start_wall follows from the epoch)
    log_file: Any = None
    expected_exit: bool = False  # killed or stopped on purpose (--kill, [[faults]] leave / kill)


def spawn(c: Child) -> None:
    if c.log_path is not None:
        c.log_file = open(c.log_path, "w")
        c.proc = subprocess.Popen(c.cmd, stdout=c.log_file, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                  start_new_session=True)
    else:
        c.proc = subprocess.Popen(c.cmd, stdin=subprocess.DEVNULL, start_new_session=True)


#: the longest the launcher waits for its processes to be up before it starts the field anyway
BARRIER_TIMEOUT_S = 120.0
#: wall seconds from "every process is up" to the epoch: each builds its node (world, filters) and
#: takes its first timer after that (a few hundred ms on a loaded 2-core machine)
EPOCH_AFTER_READY_S = 1.0


def start_barrier(children: list[Child], epoch_file: Path, stop, timeout_s: float = BARRIER_TIMEOUT_S,
                  lead_s: float = EPOCH_AFTER_READY_S) -> tuple[float, list[str]]:
    """Wait until every started child that takes ``--epoch-from epoch_file`` is up (it has created
    ``<epoch_file>.ready.<pid>``, net/cli.py ``await_epoch``), one of them has exited, ``stop`` is set
    or ``timeout_s`` has passed; then fix the epoch ``lead_s`` ahead and write it (atomically) for
    them. Returns (epoch Unix s, names of the children that were not up)."""
    import os
    import time

    flag = str(epoch_file)
    waiting = [c for c in children if c.proc is not None and flag in c.cmd]
    t_end = time.monotonic() + timeout_s
    while True:
        late = [c for c in waiting if not Path(f"{flag}.ready.{c.proc.pid}").exists()]
        if not late or stop.is_set() or time.monotonic() > t_end or any(c.proc.poll() is not None for c in waiting):
            break
        time.sleep(0.02)
    epoch = time.time() + lead_s
    tmp = epoch_file.with_suffix(".tmp")
    tmp.write_text(repr(epoch))
    os.replace(tmp, epoch_file)
    return epoch, [c.name for c in late]


def remove_barrier(epoch_file: Path | None) -> None:
    """The barrier's folder (the epoch file and the ready marks), at the fleet's end."""
    import shutil

    if epoch_file is not None:
        shutil.rmtree(epoch_file.parent, ignore_errors=True)
