"""`larns fleet`'s start barrier (larns/fleet/spawn.py ``start_barrier``, net/cli.py ``await_epoch``):
the epoch is fixed once every process started at launch is up, with real child processes."""

from __future__ import annotations

import argparse
import subprocess
import sys
import threading
import time

import pytest

from larns.fleet.spawn import Child, start_barrier
from net.cli import await_epoch

# real child processes timed against each other: run with the other process tests (alone), not in parallel
pytestmark = pytest.mark.e2e

PY = sys.executable


def _child(name: str, epoch_file, script: str) -> Child:
    """A real process that takes ``--epoch-from`` (the barrier finds its children by that flag)."""
    c = Child(name, [PY, "-c", script, "--epoch-from", str(epoch_file)], None)
    c.proc = subprocess.Popen(c.cmd)
    return c


def _ready_after(delay_s: float, epoch_file) -> str:
    """A child script: up after ``delay_s`` (the ready mark of net/cli.await_epoch), then it waits for
    the epoch file and exits 0."""
    return (f"import os, time, pathlib; time.sleep({delay_s}); "
            f"pathlib.Path('{epoch_file}.ready.' + str(os.getpid())).touch(); "
            f"[time.sleep(0.01) for _ in range(1000) if not pathlib.Path('{epoch_file}').exists()]")


def test_epoch_is_fixed_after_the_slowest_process_is_up(tmp_path):
    f = tmp_path / "epoch"
    kids = [_child("fast", f, _ready_after(0.1, f)), _child("slow", f, _ready_after(1.5, f))]
    t0 = time.time()
    epoch, late = start_barrier(kids, f, threading.Event(), timeout_s=30.0, lead_s=0.5)
    waited = time.time() - t0
    assert late == []
    assert 1.4 < waited < 10.0  # it waited for the slow one (1.5 s after its start), not for the timeout
    assert abs(epoch - (t0 + waited + 0.5)) < 0.2
    assert float(f.read_text()) == epoch
    assert [c.proc.wait(10) for c in kids] == [0, 0]  # both read the epoch and ended


def _dies_once_another_is_up(epoch_file) -> str:
    """A child script that exits 3 without saying it is up, once another child has said so (on a
    loaded host a fixed delay let it die first, and the barrier rightly stopped with both late)."""
    return (f"import glob, sys, time; [time.sleep(0.01) for _ in range(1000) "
            f"if not glob.glob('{epoch_file}.ready.*')]; sys.exit(3)")


def test_a_process_that_dies_before_it_is_up_does_not_hold_the_field(tmp_path):
    f = tmp_path / "epoch"
    kids = [_child("ok", f, _ready_after(0.1, f)), _child("dies", f, _dies_once_another_is_up(f))]
    t0 = time.time()
    epoch, late = start_barrier(kids, f, threading.Event(), timeout_s=60.0, lead_s=0.2)
    assert time.time() - t0 < 10.0 and late == ["dies"]
    assert f.exists() and kids[0].proc.wait(10) == 0 and kids[1].proc.wait(10) == 3


def test_timeout_and_children_without_the_flag(tmp_path):
    f = tmp_path / "epoch"
    never = _child("never", f, "import time; time.sleep(30)")
    other = Child("router", [PY, "-c", "import time; time.sleep(30)"], None)  # takes no epoch: not waited for
    other.proc = subprocess.Popen(other.cmd)
    try:
        t0 = time.time()
        _, late = start_barrier([never, other], f, threading.Event(), timeout_s=0.5, lead_s=0.0)
        assert 0.4 < time.time() - t0 < 5.0 and late == ["never"]
    finally:
        for c in (never, other):
            c.proc.kill()
            c.proc.wait(10)


def test_await_epoch_reads_what_the_launcher_writes(tmp_path):
    f = tmp_path / "epoch"
    args = argparse.Namespace(epoch_from=str(f), epoch=123.0)

    def launcher():
        import os

        ready = tmp_path / f"epoch.ready.{os.getpid()}"
        for _ in range(500):
            if ready.exists():
                f.write_text("")  # a partial write is read as "not yet" ...
                time.sleep(0.05)
                f.write_text("1700000000.25")  # ... and the whole one taken
                return
            time.sleep(0.01)

    th = threading.Thread(target=launcher)
    th.start()
    await_epoch(args, "test")
    th.join()
    assert args.epoch == 1700000000.25
    # without --epoch-from: nothing happens
    plain = argparse.Namespace(epoch_from=None, epoch=5.0)
    await_epoch(plain, "test")
    assert plain.epoch == 5.0


def test_await_epoch_stops_on_a_signal_event(tmp_path):
    args = argparse.Namespace(epoch_from=str(tmp_path / "epoch"), epoch=7.0)
    ev = threading.Event()
    ev.set()
    await_epoch(args, "test", ev)  # returns at once, the epoch unchanged (the node then stops cleanly)
    assert args.epoch == 7.0


def test_the_flag_is_hidden_from_users():
    r = subprocess.run([PY, "-m", "stations", "--help"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "--epoch" in r.stdout and "--epoch-from" not in r.stdout
