"""Process scheduling for real-time LARNS processes (station, router): short CPU slices, GIL hand-over.

Many station processes share two cores. What makes a slot late is not the average CPU load (about
half of one core for 50 stations) but *waiting*: a thread woken for a range request or its own-slot
timer queues behind others that are working through a burst (every nav broadcast wakes every other
process at once). Linux >= 6.12 (EEVDF) lets an ordinary, unprivileged ``SCHED_OTHER`` thread ask
for a shorter time slice through ``sched_setattr(2)`` (field ``sched_runtime``, 0.1 to 100 ms): such
a thread gets an earlier virtual deadline and preempts a longer-slice thread when it wakes up,
without any more CPU share (its weight, i.e. its nice value, is unchanged). Threads created
afterwards (Zenoh's runtime, BLAS pools) inherit it. No root, no real-time class; on older kernels
or other architectures this is a no-op and the functions say so.

Measured with ``larns bench scale`` (docs/fleet.md): at N = 50 the median lateness of the own-slot
timer went from 1.0-1.5 ms to 0.2-0.3 ms.
"""

from __future__ import annotations

import ctypes
import os
import sys

DEFAULT_SLICE_US = 100.0  # the kernel's minimum custom slice
MIN_SLICE_US, MAX_SLICE_US = 100.0, 100_000.0
_SYS_SCHED_SETATTR = {"x86_64": 314, "aarch64": 274}
SCHED_OTHER = 0


class _SchedAttr(ctypes.Structure):
    # struct sched_attr, SCHED_ATTR_SIZE_VER1 (56 bytes)
    _fields_ = [("size", ctypes.c_uint32), ("sched_policy", ctypes.c_uint32),
                ("sched_flags", ctypes.c_uint64), ("sched_nice", ctypes.c_int32),
                ("sched_priority", ctypes.c_uint32), ("sched_runtime", ctypes.c_uint64),
                ("sched_deadline", ctypes.c_uint64), ("sched_period", ctypes.c_uint64),
                ("sched_util_min", ctypes.c_uint32), ("sched_util_max", ctypes.c_uint32)]


def current_slice_ns() -> int | None:
    """The calling thread's time slice (``se.slice`` of ``/proc/thread-self/sched``), or None when
    the kernel does not report one (no EEVDF)."""
    try:
        with open("/proc/thread-self/sched") as f:
            for line in f:
                if line.startswith("se.slice"):
                    return int(line.split(":")[1])
    except (OSError, ValueError, IndexError):
        pass
    return None


def set_slice_us(slice_us: float) -> int | None:
    """Ask for a ``slice_us`` time slice for the calling thread (and the threads it creates later);
    the policy stays ``SCHED_OTHER`` and the nice value is kept. Best effort.

    Returns the slice now in effect in ns, or None if the platform has no such knob (not Linux,
    unknown architecture, kernel without EEVDF custom slices, call refused)."""
    if not MIN_SLICE_US <= slice_us <= MAX_SLICE_US:
        raise ValueError(f"slice must be within [{MIN_SLICE_US:g}, {MAX_SLICE_US:g}] us, got {slice_us:g}")
    nr = _SYS_SCHED_SETATTR.get(os.uname().machine) if sys.platform == "linux" else None
    if nr is None or current_slice_ns() is None:
        return None
    attr = _SchedAttr(size=ctypes.sizeof(_SchedAttr), sched_policy=SCHED_OTHER,
                      sched_nice=os.getpriority(os.PRIO_PROCESS, 0),
                      sched_runtime=int(round(slice_us * 1000)))
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.syscall(nr, 0, ctypes.byref(attr), 0) != 0:
        return None
    now = current_slice_ns()
    return now if now == attr.sched_runtime else None


def _slice_arg(text: str) -> float:
    import argparse

    us = float(text)
    if us != 0 and not MIN_SLICE_US <= us <= MAX_SLICE_US:
        raise argparse.ArgumentTypeError(f"0 or within [{MIN_SLICE_US:g}, {MAX_SLICE_US:g}]")
    return us


def add_sched_args(p) -> None:
    """``--slice-us`` for the real-time commands."""
    p.add_argument("--slice-us", type=_slice_arg, default=DEFAULT_SLICE_US, metavar="US",
                   help=f"CPU time slice asked of the kernel for this process's threads, microseconds "
                        f"(default {DEFAULT_SLICE_US:g}; Linux >= 6.12, unprivileged: a woken thread "
                        f"preempts longer-slice work sooner; 0 = kernel default)")


def apply_sched_args(args, who: str, log) -> int | None:
    """Apply ``--slice-us`` (from :func:`add_sched_args`); logs when the platform ignores it."""
    us = float(getattr(args, "slice_us", 0.0) or 0.0)
    if us <= 0:
        return None
    got = set_slice_us(us)
    if got is None:
        log.info("%s: short CPU slice not available on this kernel; running with the default", who)
    return got
