"""Short CPU slices for real-time processes (net/procsched.py): applied per thread, inherited by the
threads created afterwards, refused outside the kernel's range, a no-op where unsupported."""

from __future__ import annotations

import argparse
import os
import platform
import threading

import pytest

from net import procsched as P


def _in_thread(fn):
    out = []
    t = threading.Thread(target=lambda: out.append(fn()))
    t.start()
    t.join()
    return out[0]


def _kernel_has_custom_slices() -> bool:
    if platform.system() != "Linux" or os.uname().machine not in ("x86_64", "aarch64"):
        return False
    major, minor = (int(x) for x in platform.release().split(".")[:2])
    return (major, minor) >= (6, 12)


def test_slice_applies_to_the_thread_and_its_children():
    def work():
        before = P.current_slice_ns()
        got = P.set_slice_us(250)
        child = _in_thread(P.current_slice_ns)
        return before, got, P.current_slice_ns(), child

    before, got, after, child = _in_thread(work)
    if not _kernel_has_custom_slices():
        pytest.skip("kernel without EEVDF custom slices")
    assert got == 250_000 and after == 250_000 and child == 250_000
    assert before != 250_000
    assert P.current_slice_ns() != 250_000  # the test's own thread is untouched


def test_slice_keeps_the_nice_value():
    def work():
        os.setpriority(os.PRIO_PROCESS, 0, os.getpriority(os.PRIO_PROCESS, 0) + 3)  # this thread only
        nice = os.getpriority(os.PRIO_PROCESS, 0)
        got = P.set_slice_us(100)
        return nice, got, os.getpriority(os.PRIO_PROCESS, 0)

    nice, got, after = _in_thread(work)
    if got is None:  # the slice was not set: nothing could have changed the nice value
        pytest.skip("kernel without EEVDF custom slices: set_slice_us is a no-op, the test cannot fail here")
    assert got == 100_000
    assert after == nice


def test_slice_range_is_checked():
    with pytest.raises(ValueError):
        P.set_slice_us(50)
    p = argparse.ArgumentParser()
    P.add_sched_args(p)
    assert p.parse_args([]).slice_us == P.DEFAULT_SLICE_US
    assert p.parse_args(["--slice-us", "0"]).slice_us == 0
    with pytest.raises(SystemExit):
        p.parse_args(["--slice-us", "20"])
