"""Progress of long work on standard error: done / total, rate and time left.

On a terminal the line is redrawn in place (up to 10 times a second); elsewhere (a log file, a
pipe) a plain line is written at each further tenth of the work and at least every half minute,
but not within 5 s of the last one or of the start (work of a few seconds writes none). The
rate leaves out the time spent compiling kernels (:mod:`milestones.jit`), so that a first run's
compiling does not read as a slow run.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from typing import IO, TypeVar

from milestones.jit import compile_seconds, compiling, on_first_compile

__all__ = ["Progress", "duration"]

T = TypeVar("T")

LINE_EVERY = 30.0  # seconds: the longest wait between two plain lines
LINE_MIN = 5.0  # seconds: the shortest
LINE_FRACTION = 0.1  # a plain line at each further tenth of the total


def duration(seconds: float) -> str:
    """``seconds`` for a person: '42 s', '3 min 05 s', '1 h 02 min'."""
    s = max(0, round(seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"


class Progress:
    """Count the items of a long job and show how far it is.

    Shown in place on a terminal and as plain lines elsewhere; ``enabled`` False shows
    nothing. ``tick``: also redraw every that many seconds from a thread of its own
    (for work whose items take long: a batch of runs). :attr:`status` is appended to the line;
    :attr:`activity`, when set, is called at each draw for what is under way. While it is
    shown, the first kernel compiled in the process is told on a line above it.
    """

    def __init__(self, total: int | None, label: str, unit: str = "scans",
                 stream: IO[str] | None = None, enabled: bool = True,
                 tick: float | None = None) -> None:
        self.total, self.label, self.unit = total, label, unit
        self.stream = stream if stream is not None else sys.stderr
        self.live = _is_terminal(self.stream)
        self.enabled = enabled
        self.done = 0
        self.status = ""  # appended to the line (errors so far, for instance)
        self.activity: Callable[[], str] | None = None
        self.start = time.perf_counter()
        self._compiled_before = compile_seconds()
        self._drawn = 0.0  # when the line was last drawn
        self._lined = (self.start, 0)  # when, and at how many done, the last plain line
        self._lines = 0  # plain lines written
        self._lock = threading.Lock()
        self._closed = False
        if self.enabled and self.live:
            self._draw(time.perf_counter())
        if self.enabled:
            on_first_compile(self.note)  # a first run after an install compiles for a while
        if self.enabled and tick:
            threading.Thread(target=self._tick, args=(tick,), daemon=True,
                             name="progress").start()

    @property
    def elapsed(self) -> float:
        return time.perf_counter() - self.start

    @property
    def working(self) -> float:
        """Seconds since the start, less those spent compiling kernels."""
        return self.elapsed - (compile_seconds() - self._compiled_before)

    @property
    def rate(self) -> float:
        """Items a second, compiling left out."""
        w = self.working
        return self.done / w if w > 0 else 0.0

    def left(self) -> float | None:
        """Seconds to the end at the rate so far, when there is a total and a rate."""
        rate = self.rate
        if not self.total or self.done <= 0 or rate <= 0:
            return None
        return max(self.total - self.done, 0) / rate

    def update(self, n: int = 1) -> None:
        self.done += n
        if not self.enabled:
            return
        now = time.perf_counter()
        if self.live:
            if now - self._drawn >= 0.1 or self.done == self.total:
                self._draw(now)
            return
        at, done_then = self._lined
        tenth = self.total and self.done - done_then >= LINE_FRACTION * self.total
        if now - at >= LINE_MIN and (tenth or now - at >= LINE_EVERY):
            self._line(now)

    def note(self, text: str) -> None:
        """Say ``text`` on a line of its own, the progress line kept below it."""
        with self._lock:
            self.stream.write(("\r\033[K" if self.live else "") + text + "\n")
            self.stream.flush()
        if self.enabled and self.live and not self._closed:
            self._draw(time.perf_counter())

    def text(self) -> str:
        """The progress as one line of text."""
        if self.total:
            share = min(self.done / self.total, 1.0)
            counted = f"{self.done}/{self.total} {self.unit}"
            counted = (f"[{'#' * int(30 * share)}{'.' * (30 - int(30 * share))}] {counted}"
                       if self.live else f"{counted} ({100 * share:.0f} %)")
        else:
            counted = f"{self.done} {self.unit}"
        parts = [f"{self.label} {counted}"]
        if self.done and self.working > 0.5:
            parts.append(f"{self.rate:,.1f}/s" if self.rate < 10 else f"{self.rate:,.0f}/s")
        left = self.left()
        if left is not None and self.done < (self.total or 0):
            parts.append(f"{duration(left)} left")
        elif not self.done or self.working <= 0.5:
            parts.append(duration(self.elapsed))
        activity = self.activity() if self.activity is not None else ""
        parts.extend(p for p in (self.status, activity) if p)
        if compiling():
            parts.append("compiling kernels")
        return "  ".join(parts)

    def _draw(self, now: float) -> None:
        with self._lock:
            self._drawn = now
            self.stream.write(f"\r{self.text()}\033[K")
            self.stream.flush()

    def _line(self, now: float) -> None:
        with self._lock:
            self._lined = (now, self.done)
            self._lines += 1
            self.stream.write(self.text() + "\n")
            self.stream.flush()

    def _tick(self, every: float) -> None:
        while True:
            time.sleep(every)
            if self._closed:
                return
            now = time.perf_counter()
            if self.live:
                self._draw(now)
            elif now - self._lined[0] >= LINE_EVERY:
                self._line(now)

    def close(self) -> None:
        """End the line (once): the last figures are drawn."""
        if self._closed:
            return
        self._closed = True
        if not self.enabled:
            return
        on_first_compile(None)
        if self.live:
            self._draw(time.perf_counter())
            with self._lock:
                self.stream.write("\n")
                self.stream.flush()
        elif self._lines and self._lined[1] != self.done:  # the end of what was told
            self._line(time.perf_counter())

    def wrap(self, items: Iterable[T]) -> Iterator[T]:
        """Yield the items, counting each; closes the line at the end."""
        try:
            for item in items:
                yield item
                self.update()
        finally:
            self.close()


def _is_terminal(stream: IO[str]) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):  # a closed or foreign stream
        return False
