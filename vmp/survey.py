"""What a source holds, read through once in constant memory: scans, beams, time, odometry."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vmp.errors import InputError
from vmp.source import Source
from vmp.types import BeamGeometry, FloatArray

__all__ = ["Survey", "survey"]


@dataclass(frozen=True)
class Survey:
    """A source's contents at a glance."""

    scans: int
    geometry: BeamGeometry  # of the first scan
    beam_counts: tuple[int, ...]  # every beam count seen
    returned: float  # mean share of beams with a return
    first_stamp: float
    last_stamp: float
    with_odom: int  # scans that carry odometry
    odom_moves: bool  # whether the odometry ever changes
    last_odom: FloatArray | None

    @property
    def duration(self) -> float:
        return self.last_stamp - self.first_stamp


def survey(source: Source) -> Survey:
    """Read ``source`` through (one pass, constant memory); InputError if it holds no scan."""
    n = with_odom = 0
    first = None
    beams: set[int] = set()
    t0, t1 = math.inf, -math.inf
    returned = 0.0
    first_odom = last_odom = None
    moves = False
    for frame in source:
        if frame.odom is not None:
            with_odom += 1
            if first_odom is None:
                first_odom = frame.odom
            elif not moves and not np.array_equal(frame.odom, first_odom):
                moves = True
            last_odom = frame.odom
        if first is None:
            first = frame
        n += 1
        beams.add(frame.num_beams)
        t0, t1 = min(t0, frame.stamp), max(t1, frame.stamp)
        returned += float(frame.returned.mean())
    if first is None:
        raise InputError(f"{source.name}: no laser scans")
    return Survey(n, first.geometry, tuple(sorted(beams)), returned / n, t0, t1, with_odom,
                  moves, last_odom)
