"""A small stderr progress bar (no dependency): ``for x in progress(items, "label"): ...``."""

from __future__ import annotations

import sys
import time
from typing import Iterable, Iterator, TypeVar

T = TypeVar("T")


class Progress:
    """Manual progress bar: ``p = Progress(total, "label"); p.update(1); p.close()``."""

    def __init__(self, total: int, label: str = "", stream=None, width: int = 28):
        self.total = max(int(total), 1)
        self.label = label
        self.stream = stream or sys.stderr
        self.width = width
        self.n = 0
        self.t0 = time.monotonic()
        self._last = 0.0
        self.enabled = hasattr(self.stream, "isatty") and self.stream.isatty()
        self._draw(force=True)

    def update(self, k: int = 1) -> None:
        self.n += k
        self._draw()

    def _draw(self, force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self._last < 0.1 and self.n < self.total:
            return
        self._last = now
        frac = min(self.n / self.total, 1.0)
        el = now - self.t0
        eta = el / frac - el if frac > 0 else float("nan")
        bar = "#" * int(frac * self.width) + "-" * (self.width - int(frac * self.width))
        line = f"{self.label} [{bar}] {self.n}/{self.total} {el:5.1f}s eta {eta:5.1f}s"
        if self.enabled:
            self.stream.write("\r" + line)
            self.stream.flush()
        elif self.n >= self.total and not getattr(self, "_done", False):
            self._done = True
            self.stream.write(line + "\n")

    def close(self) -> None:
        self._draw(force=True)
        if self.enabled:
            self.stream.write("\n")
            self.stream.flush()


def progress(items: Iterable[T], label: str = "", total: int | None = None) -> Iterator[T]:
    items = list(items) if total is None else items
    p = Progress(total if total is not None else len(items), label)
    try:
        for x in items:
            yield x
            p.update(1)
    finally:
        p.close()
