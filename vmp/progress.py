"""A progress line on standard error for long work; silent when the stream is not a terminal."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable, Iterator
from typing import IO, TypeVar

T = TypeVar("T")


class Progress:
    """Count the items of a long job; redraw ``label [###...] done/total rate`` up to 10 Hz."""

    def __init__(self, total: int | None, label: str, unit: str = "scans",
                 stream: IO[str] | None = None, enabled: bool | None = None) -> None:
        self.total, self.label, self.unit = total, label, unit
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = self.stream.isatty() if enabled is None else enabled
        self.done = 0
        self.status = ""  # appended to the line (errors so far, for instance)
        self.start = time.perf_counter()
        self._drawn = 0.0

    @property
    def elapsed(self) -> float:
        return time.perf_counter() - self.start

    @property
    def rate(self) -> float:
        e = self.elapsed
        return self.done / e if e > 0 else 0.0

    def update(self, n: int = 1) -> None:
        self.done += n
        now = time.perf_counter()
        if self.enabled and (now - self._drawn >= 0.1 or self.done == self.total):
            self._drawn = now
            self._draw()

    def _draw(self) -> None:
        if self.total:
            width = 30
            filled = int(width * min(self.done / self.total, 1.0))
            bar = f"[{'#' * filled}{'.' * (width - filled)}] {self.done}/{self.total}"
        else:
            bar = f"{self.done}"
        extra = f"  {self.status}" if self.status else ""
        self.stream.write(f"\r{self.label} {bar} {self.unit} {self.rate:,.0f}/s{extra}\033[K")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            self._draw()
            self.stream.write("\n")
            self.stream.flush()

    def wrap(self, items: Iterable[T]) -> Iterator[T]:
        """Yield the items, counting each; closes the line at the end."""
        try:
            for item in items:
                yield item
                self.update()
        finally:
            self.close()
