"""Playing recorded messages back with their recorded timing (``larns replay``): selection by key
expression, pause / step / loop / rate controls, the terminal keyboard. Publishing is a callback, so
the player runs without Zenoh in the tests."""

from __future__ import annotations

import math
import os
import select
import sys
import threading
import time
from dataclasses import dataclass
from typing import Sequence

from .keyexpr import remap
from .reader import Msg


def select_messages(msgs: Sequence[Msg], topics: Sequence[str] | None = None, exclude: Sequence[str] | None = None,
                    start_offset_s: float = 0.0, until_s: float | None = None) -> list[Msg]:
    """Wire messages (msgpack) matching the globs, inside ``[start + offset, start + until]``;
    offsets in seconds of log time from the first message of the recording."""
    from ..log import topic_selected

    if not msgs:
        return []
    t0 = msgs[0].log_time
    lo = t0 + int(start_offset_s * 1e9)
    hi = t0 + int(until_s * 1e9) if until_s is not None else None
    return [m for m in msgs if m.encoding == "msgpack" and m.log_time >= lo and (hi is None or m.log_time <= hi)
            and topic_selected(m.topic, topics, exclude)]


# --------------------------------------------------------------------------- keyboard

class Controls:
    """Pause / step / quit state; fed by the keyboard thread (or by tests)."""

    def __init__(self, paused: bool = False):
        self.paused = paused
        self.steps = 0
        self.quit = False
        self.cv = threading.Condition()

    def key(self, ch: str) -> None:
        with self.cv:
            if ch == " ":
                self.paused = not self.paused
            elif ch in ("s", "S") and self.paused:
                self.steps += 1
            elif ch in ("q", "Q", "\x03"):
                self.quit = True
            self.cv.notify_all()


class Keyboard:
    """Reads single keys from a TTY stdin in cbreak mode (restored on exit). No-op otherwise."""

    def __init__(self, controls: Controls, stream=None):
        self.c = controls
        self.stream = stream or sys.stdin
        self.enabled = hasattr(self.stream, "isatty") and self.stream.isatty() and self._foreground()
        self._old = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _foreground(self) -> bool:
        """Only a foreground job may change the terminal (a background one would get SIGTTOU)."""
        try:
            return os.tcgetpgrp(self.stream.fileno()) == os.getpgrp()
        except OSError:  # not our controlling terminal: no job control applies
            return True

    def __enter__(self) -> "Keyboard":
        if self.enabled:
            import termios
            import tty

            fd = self.stream.fileno()
            self._old = termios.tcgetattr(fd)
            tty.setcbreak(fd)
            self._thread = threading.Thread(target=self._loop, daemon=True)
            self._thread.start()
        return self

    def _loop(self) -> None:
        fd = self.stream.fileno()
        while not self._stop.is_set():
            r, _, _ = select.select([fd], [], [], 0.1)
            if r:
                ch = os.read(fd, 1).decode(errors="ignore")
                if ch:
                    self.c.key(ch)

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._thread:
            self._thread.join(1.0)
        if self._old is not None:
            import termios

            termios.tcsetattr(self.stream.fileno(), termios.TCSADRAIN, self._old)


# --------------------------------------------------------------------------- player

@dataclass
class PlayStats:
    published: int = 0
    loops: int = 0
    wall_s: float = 0.0
    max_lag_ms: float = 0.0


def _wait_due(offset_ns: int, rate: float, c: Controls, clock, sleep, base_ref: list, st: PlayStats) -> bool:
    """Block until the message at ``offset_ns`` is due (or stepped while paused). Pauses shift the
    schedule (``base_ref[0]``). Returns False on quit."""
    while True:
        with c.cv:
            if c.quit:
                return False
            if c.paused:
                if c.steps > 0:
                    c.steps -= 1
                    return True
                t_p = clock()
                c.cv.wait(0.05)
                base_ref[0] += clock() - t_p
                continue
        due = base_ref[0] + offset_ns * 1e-9 / rate
        dt = due - clock()
        if dt <= 0:
            st.max_lag_ms = max(st.max_lag_ms, -dt * 1e3)
            return True
        sleep(min(dt, 0.05))


def play(msgs: Sequence[Msg], publish, rate: float = 1.0, loop: bool = False, remaps=(),
         controls: Controls | None = None, progress: bool = True, clock=time.monotonic,
         sleep=time.sleep) -> PlayStats:
    """Publish ``msgs`` with their recorded timing: ``publish(key, data)`` at
    ``wall_start + (log_time - first) / rate``. Pauses shift the schedule."""
    if rate <= 0:
        raise ValueError("--rate must be > 0")
    c = controls or Controls()
    st = PlayStats()
    t_start = clock()
    while True:
        if not msgs:
            break
        first = msgs[0].log_time
        bar = None
        if progress:
            from ..bench.progress import Progress

            bar = Progress(len(msgs), f"replay{' loop %d' % (st.loops + 1) if loop else ''}")
        base = clock()
        for m in msgs:
            if not _wait_due(m.log_time - first, rate, c, clock, sleep, base_ref := [base], st):
                break
            base = base_ref[0]
            publish(remap(m.topic, remaps) if remaps else m.topic, m.data)
            st.published += 1
            if bar:
                bar.update(1)
        if bar:
            bar.close()
        st.loops += 1
        if c.quit or not loop:
            break
    st.wall_s = clock() - t_start
    return st


# --------------------------------------------------------------------------- commands


# --------------------------------------------------------------------------- remote controls (Foxglove)

class SeekablePlayer:
    """Playback driven by a remote client - Foxglove's playback controls (``larns replay --view``):
    play, pause, speed and seek on one time axis ``times_ns`` (sorted, one per message).

    No clock of its own: every call passes the wall time ``now_s``; thread-safe (the control
    requests arrive on the server's thread)."""

    def __init__(self, times_ns: Sequence[int], speed: float = 1.0, playing: bool = True, now_s: float = 0.0):
        self.times_ns = list(times_ns)
        self.start_ns = self.times_ns[0] if self.times_ns else 0
        self.end_ns = self.times_ns[-1] if self.times_ns else 0
        self.cur_ns = self.start_ns
        self.i = 0                 # next message to deliver
        self.speed = float(speed)
        self.playing = playing
        self.seeks = 0             # seeks so far (the caller resets its view on a change)
        self._wall_s = now_s
        self._lock = threading.Lock()

    @property
    def ended(self) -> bool:
        return self.i >= len(self.times_ns)

    def _advance(self, now_s: float) -> None:
        if self.playing:
            self.cur_ns = min(self.end_ns, self.cur_ns + int((now_s - self._wall_s) * 1e9 * self.speed))
        self._wall_s = now_s

    def control(self, play: bool, speed: float | None, seek_ns: int | None, now_s: float) -> None:
        """A client's request: play or pause, a new speed (ignored unless > 0), an optional seek."""
        import bisect

        with self._lock:
            self._advance(now_s)
            if seek_ns is not None:
                self.cur_ns = min(max(int(seek_ns), self.start_ns), self.end_ns)
                self.i = bisect.bisect_left(self.times_ns, self.cur_ns)
                self.seeks += 1
            if speed is not None and speed > 0 and math.isfinite(speed):
                self.speed = float(speed)
            self.playing = bool(play)

    def step(self, now_s: float) -> tuple[range, int]:
        """Indices of the messages due by ``now_s`` (in order) and the current time, ns."""
        with self._lock:
            self._advance(now_s)
            j = self.i
            while j < len(self.times_ns) and self.times_ns[j] <= self.cur_ns:
                j += 1
            due, self.i = range(self.i, j), j
            return due, self.cur_ns
