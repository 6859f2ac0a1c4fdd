"""BreezySLAM / CoreSLAM "Mines" logs: one scan per line with wheel encoder ticks.

Tokens: 0 time (microseconds), 2 and 3 left / right wheel ticks (cumulative), 24 onwards the
ranges in millimetres (0 = no return) of a Hokuyo URG-04LX, 682 beams over 240 degrees; the
last token is not a range (BreezySLAM drops it too). Over half the readings are 0, and a 0
of the URG-04LX is an error code (nothing seen, a weak or dazzling echo, a step it could not
measure) as often as open space: it proves no free space, so those beams do not mark any
(``no_return_free=0``); walls behind a dark surface are not cleared.

The wheels (radius 77 mm, half axle 165 mm, 2000 ticks a turn) give the odometry; the laser
sits 145 mm ahead of the axle.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np

from drivers.textlog import LineLog
from vmp.types import ScanFrame, compose

__all__ = ["BreezySlamLog"]

BEAMS = 682
FOV = math.radians(240.0)
MAX_RANGE = 5.6  # URG-04LX
WHEEL_RADIUS = 0.077
HALF_AXLE = 0.165
TICKS_PER_TURN = 2000.0
LASER_OFFSET = np.array([0.145, 0.0, 0.0])


class BreezySlamLog(LineLog):
    format_name = "BreezySLAM log"
    scan_words = tuple(str(d).encode() for d in range(10))  # a line is a scan: numbers

    def _frames(self, lines: Iterator[tuple[int, str]]) -> Iterator[ScanFrame]:
        pose = np.zeros(3)  # robot (axle) pose in the odometry frame
        ticks: np.ndarray | None = None
        for no, line in lines:
            parts = line.split()
            if not parts:
                continue
            try:
                if len(parts) != 24 + BEAMS + 1:
                    raise ValueError(f"expected {24 + BEAMS + 1} values, got {len(parts)}")
                values = np.array([float(v) for v in parts])
                if not np.isfinite(values).all():
                    raise ValueError("values must be finite")
                mm = values[24:24 + BEAMS]
                if (mm < 0).any():
                    raise ValueError("a range is negative")
            except ValueError as exc:
                self._bad(no, f"bad scan line: {exc}")
                continue
            now = values[2:4]
            if ticks is not None:
                with np.errstate(over="ignore", invalid="ignore"):
                    turn = 2.0 * math.pi * (now - ticks) / TICKS_PER_TURN
                    d_left, d_right = WHEEL_RADIUS * turn
                    ds = 0.5 * (d_left + d_right)
                    dth = (d_right - d_left) / (2.0 * HALF_AXLE)
                step = (np.array([ds * math.cos(dth / 2), ds * math.sin(dth / 2), dth])
                        if math.isfinite(ds) and math.isfinite(dth) else np.full(3, np.nan))
                if not np.isfinite(step).all():  # the next line counts from the last good one
                    self._bad(no, "bad scan line: the wheel ticks jump beyond any motion")
                    continue
                pose = compose(pose, step)
            ticks = now
            r = mm / 1000.0
            ranges = np.where((r <= 0) | (r >= MAX_RANGE), np.inf, r)
            self._line = no
            yield ScanFrame(stamp=values[0] * 1e-6, ranges=ranges, angle_min=-FOV / 2,
                            angle_increment=FOV / (BEAMS - 1), max_range=MAX_RANGE,
                            odom=compose(pose, LASER_OFFSET), index=self.scans,
                            no_return_free=0.0)
