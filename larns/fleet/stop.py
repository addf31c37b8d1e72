"""Stopping the fleet: SIGINT to every child, SIGKILL after a grace period; stations first, then
the recorder (it must hear the last samples), the router last (it carries everyone's traffic)."""

from __future__ import annotations

import signal
import subprocess
import time

from .spawn import Child


def stop_children(children: list[Child], grace_s: float = 8.0) -> None:
    live = [c for c in children if c.proc is not None and c.proc.poll() is None]
    for c in live:
        try:
            c.proc.send_signal(signal.SIGINT)
        except ProcessLookupError:
            pass
    deadline = time.time() + grace_s
    for c in live:
        try:
            c.proc.wait(max(0.1, deadline - time.time()))
        except subprocess.TimeoutExpired:
            c.proc.kill()
            c.proc.wait()


def shutdown(children: list[Child], wait_for_stations: bool) -> None:
    """Stop everything in order; ``wait_for_stations``: give the stations 5 s to exit at their
    ``--duration`` on their own first."""
    stations = [c for c in children if c.name not in ("recorder", "router")]
    if wait_for_stations:
        for c in stations:
            if c.proc is not None:
                try:
                    c.proc.wait(5.0)
                except subprocess.TimeoutExpired:
                    pass
    stop_children(stations)
    time.sleep(0.3)  # let the recorder receive the last samples
    stop_children([c for c in children if c.name == "recorder"], grace_s=20.0)
    stop_children([c for c in children if c.name == "router"])  # last: it carries everyone's traffic
    for c in children:
        if c.log_file:
            c.log_file.close()
