"""The reading a scanner writes for "no echo", found in the data.

Some loggers write a beam that saw nothing as the scanner's largest reading instead of
marking it: ACES's SICK writes exactly 50.00 m (0.83 % of its readings; 2,251 readings of 50.00
against 4 between 48 and 49 m in a fifth of the log), acapulco's 51.15 m (5.9 %). Drawn as
hits they put a ring of walls 50 m out and fans of free space up to it. Such a reading shows
in the data as a spike at the very top of the ranges: many readings within
:data:`TOLERANCE` of the largest, few in the metre below it, and in many directions of the
scanner. Real long returns thin out towards the largest instead, and a robot standing still
repeats its largest reading in one or two directions only.
"""

from __future__ import annotations

import numpy as np

from vmp.types import FloatArray

__all__ = ["no_echo_level"]

TOLERANCE = 0.01  # readings this near the largest count as the spike (m)
BELOW = 1.0  # the band below the spike it must stand out of (m)
MIN_SHARE = 0.001  # the spike holds at least this share of all readings (at most half) ...
MIN_RATIO = 20.0  # ... and this many times the readings in the band below it ...
MIN_COUNT = 50  # ... and at least this many readings ...
MIN_BEAMS = 0.05  # ... by at least this share of the beams (and 5 of them)


def no_echo_level(ranges: FloatArray) -> float | None:
    """The range at and beyond which the hits among ``ranges`` ``(S, N)`` (scans by beams, m;
    not finite where a beam has no return) are "no echo", or None when they show no such
    spike."""
    r = np.asarray(ranges, dtype=np.float64)
    hit = np.isfinite(r)
    if r.ndim != 2 or not hit.any():
        return None
    values = r[hit]
    top = float(values.max())
    level = top - TOLERANCE
    at = int(np.count_nonzero(values >= level))
    below = int(np.count_nonzero((values >= top - BELOW) & (values < level)))
    beams = int(np.count_nonzero((hit & (r >= level)).any(axis=0)))
    if (max(MIN_COUNT, MIN_SHARE * len(values)) <= at <= 0.5 * len(values)
            and at >= MIN_RATIO * below
            and beams >= max(5, MIN_BEAMS * r.shape[1])):
        return level
    return None
