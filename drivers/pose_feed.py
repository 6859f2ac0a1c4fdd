"""Odometry for live mapping from a JSON-lines pose feed on a serial port, pipe or file.

One pose per line: ``{"x": 1.0, "y": 2.0, "theta": 0.1}`` in metres and radians in the
odometry frame (``"t"``, the sender's clock, is accepted and kept but not used: poses are
stamped on arrival, like the scans, so both share one clock). A line that is not such an
object, or holds a value that is not a finite number, is skipped and counted with its line
number. Scans take the pose interpolated at their arrival time.
"""

from __future__ import annotations

import json
import math
import os
import stat
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path

import numpy as np
import serial

from vmp.types import FloatArray, interpolate_pose

__all__ = ["PoseFeed", "parse_pose_line"]


def parse_pose_line(line: str) -> FloatArray:
    """``(x, y, theta)`` of one feed line; ValueError says what is wrong with it."""
    try:
        obj = json.loads(line)
    except json.JSONDecodeError as exc:
        raise ValueError(f"not JSON ({exc.msg})") from None
    if not isinstance(obj, dict):
        raise ValueError("not a JSON object")
    pose = []
    for key in ("x", "y", "theta"):
        if key not in obj:
            raise ValueError(f"no {key!r}")
        v = obj[key]
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise ValueError(f"{key!r} is not a finite number: {v!r}")
        pose.append(float(v))
    return np.array(pose)


class PoseFeed:
    """Read a pose feed in a thread; :meth:`pose_at` gives the odometry at a time.

    ``source`` is a serial device or pyserial URL (read as a port), or a named pipe or
    regular file (read as text). ``keep`` poses are kept (seconds of history at the feed's rate).
    """

    def __init__(self, source: str, *, baudrate: int = 115200, keep: int = 2000,
                 clock: Callable[[], float] = time.time) -> None:
        self.source = source
        self.baudrate = baudrate
        self.clock = clock
        self._stamps: deque[float] = deque(maxlen=keep)
        self._poses: deque[FloatArray] = deque(maxlen=keep)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.lines = 0
        self.bad = 0
        self.problems: list[tuple[int, str]] = []
        self.error = ""
        self._thread = threading.Thread(target=self._run, name="pose-feed", daemon=True)

    def start(self) -> PoseFeed:
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)

    @property
    def count(self) -> int:
        return len(self._stamps)

    def _lines(self):
        path = Path(self.source)
        is_text = path.exists() and (stat.S_ISFIFO(os.stat(path).st_mode) or path.is_file())
        if is_text:
            with open(path, encoding="utf-8", errors="replace") as f:
                while not self._stop.is_set():
                    line = f.readline()
                    if not line:
                        if path.is_file():
                            time.sleep(0.01)  # a file being appended to: follow it
                            continue
                        return
                    yield line
        else:
            with serial.serial_for_url(self.source, baudrate=self.baudrate, timeout=0.05) as ser:
                buf = b""
                while not self._stop.is_set():
                    buf += ser.read(max(1, ser.in_waiting))
                    *lines, buf = buf.split(b"\n")
                    for raw in lines:
                        yield raw.decode("utf-8", errors="replace")

    def _run(self) -> None:
        try:
            for line in self._lines():
                now = self.clock()
                self.lines += 1
                if not line.strip():
                    continue
                try:
                    pose = parse_pose_line(line)
                except ValueError as exc:
                    self.bad += 1
                    if len(self.problems) < 100:
                        self.problems.append((self.lines, str(exc)))
                    continue
                with self._lock:
                    self._stamps.append(now)
                    self._poses.append(pose)
        except (OSError, serial.SerialException) as exc:
            self.error = f"{self.source}: {exc}"

    def pose_at(self, stamp: float) -> FloatArray | None:
        """The pose at ``stamp``: interpolated between the poses around it, else the nearest.

        None before the first pose arrived.
        """
        with self._lock:
            stamps = np.fromiter(self._stamps, dtype=np.float64, count=len(self._stamps))
            poses = np.array(self._poses).reshape(-1, 3)
        return interpolate_pose(stamps, poses, stamp)

    def summary(self) -> str:
        first = "; ".join(f"line {n}: {w}" for n, w in self.problems[:3])
        bad = f", {self.bad} bad lines skipped ({first})" if self.bad else ""
        err = f", stopped: {self.error}" if self.error else ""
        return f"pose feed {self.source}: {self.lines} lines{bad}{err}"
