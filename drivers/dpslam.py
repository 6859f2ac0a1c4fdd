"""DP-SLAM logs (Duke): alternating ``Odometry x y theta`` and ``Laser 181 r_0 .. r_180`` lines.

The beams span -90 to +90 degrees at 1 degree; 8.191 m is the SICK's no-return reading. The
format has no timestamps: scans are stamped by their index at an assumed 10 Hz.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np

from drivers.textlog import LineLog
from vmp.types import ScanFrame

__all__ = ["DpSlamLog"]

MAX_RANGE = 8.191
RATE_HZ = 10.0


class DpSlamLog(LineLog):
    format_name = "DP-SLAM log"
    scan_words = (b"Laser",)

    def _frames(self, lines: Iterator[tuple[int, str]]) -> Iterator[ScanFrame]:
        odom: np.ndarray | None = None
        for no, line in lines:
            parts = line.split()
            if not parts:
                continue
            if parts[0] == "Odometry":
                try:
                    odom = np.array([float(v) for v in parts[1:]])
                    if odom.shape != (3,) or not np.isfinite(odom).all():
                        raise ValueError("expected 3 finite numbers x y theta")
                except ValueError as exc:
                    self._bad(no, f"bad Odometry line: {exc}")
                    odom = None
                continue
            if parts[0] != "Laser":
                self._bad(no, f"unknown message {parts[0]!r} (expected Odometry or Laser)")
                continue
            try:
                n = int(parts[1])
                if len(parts) != n + 2:
                    raise ValueError(f"declares {n} ranges but holds {len(parts) - 2}")
                r = np.array([float(v) for v in parts[2:]])
                if np.isnan(r).any() or (r < 0).any():
                    raise ValueError("ranges must be numbers >= 0")
            except (ValueError, IndexError) as exc:
                self._bad(no, f"bad Laser line: {exc}")
                continue
            if odom is None:
                self._bad(no, "a Laser line without a valid Odometry line before it")
                continue
            ranges = np.where((r >= MAX_RANGE - 1e-6) | (r <= 0), np.inf, r)
            try:
                if n < 2:  # the beams span 180 degrees, first to last
                    raise ValueError(f"declares {n} ranges, a scan spanning 180 degrees needs 2 "
                                     "or more")
                frame = ScanFrame(stamp=self.scans / RATE_HZ, ranges=ranges,
                                  angle_min=-math.pi / 2, angle_increment=math.pi / (n - 1),
                                  max_range=MAX_RANGE, odom=odom, index=self.scans)
            except ValueError as exc:
                self._bad(no, f"bad Laser line: {exc}")
                continue
            self._line = no
            yield frame
            odom = None
