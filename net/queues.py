"""Bounded receive queues (issue 32): a flood must cost old samples, never memory.

Every process that hands Zenoh samples from the session's threads to its own loop (station wire
delays, aircraft, vehicle, recorder, live view) uses :class:`DropOldestQueue`: a thread-safe FIFO with the
interface of :class:`queue.SimpleQueue` (``put``, ``get``, ``get_nowait``, ``qsize``, ``empty``) and
a fixed capacity; a ``put`` on a full queue drops the *oldest* item (the newest data is worth
more to a navigator) and counts it in :attr:`DropOldestQueue.dropped`.
"""

from __future__ import annotations

import queue
import threading
import time
from collections import deque
from typing import Any

DEFAULT_MAXSIZE = 4096  # samples; a process reading 100 samples per cycle keeps 40 cycles


class DropOldestQueue:
    """A bounded FIFO that never blocks a producer: when full, ``put`` drops the oldest item."""

    def __init__(self, maxsize: int = DEFAULT_MAXSIZE):
        if maxsize < 1:
            raise ValueError("maxsize must be >= 1")
        self.maxsize = int(maxsize)
        self._q: deque = deque()
        self._cv = threading.Condition(threading.Lock())
        self.dropped = 0

    def put(self, item: Any, block: bool = True, timeout: float | None = None) -> bool:  # noqa: ARG002
        """Append ``item``; returns False if the oldest item had to be dropped to make room.
        (``block``/``timeout`` are accepted for :class:`queue.Queue` compatibility: it never blocks.)"""
        with self._cv:
            full = len(self._q) >= self.maxsize
            if full:
                self._q.popleft()
                self.dropped += 1
            self._q.append(item)
            self._cv.notify()
        return not full

    put_nowait = put

    def get(self, block: bool = True, timeout: float | None = None) -> Any:
        """The oldest item; waits up to ``timeout`` (None: forever) when ``block``, else raises
        :class:`queue.Empty` like the standard queues."""
        with self._cv:
            if not block:
                if not self._q:
                    raise queue.Empty
                return self._q.popleft()
            end = None if timeout is None else time.monotonic() + timeout
            while not self._q:
                left = None if end is None else end - time.monotonic()
                if left is not None and left <= 0:
                    raise queue.Empty
                self._cv.wait(left)
            return self._q.popleft()

    def get_nowait(self) -> Any:
        return self.get(block=False)

    def qsize(self) -> int:
        return len(self._q)

    def empty(self) -> bool:
        return not self._q

    def __len__(self) -> int:
        return len(self._q)
