"""Stretches of a robot's frames joined as if it had been carried between them (a kidnap).

To test localization from an unknown start and after a kidnap, a run is cut into stretches
that start at chosen scans and joined: the true pose jumps where two stretches meet, the
odometry does not (the wheels did not turn while the robot was carried), and stamps run on.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from vmp.types import ScanFrame, compose, inverse

__all__ = ["carried"]


def carried(stretches: Sequence[Sequence[ScanFrame]]) -> list[ScanFrame]:
    """The frames of ``stretches`` in order, each stretch's odometry and stamps continuing
    from the end of the one before (the first stretch's kept); indices renumbered."""
    out: list[ScanFrame] = []
    for stretch in stretches:
        if not stretch:
            continue
        if not out:
            shift, step = np.zeros(3), 0.0
        else:
            last = out[-1]
            # Odometry: the stretch's first pose is put where the last frame's was.
            shift = (compose(last.odom, inverse(stretch[0].odom))
                     if last.odom is not None and stretch[0].odom is not None else None)
            step = last.stamp + _period(out) - stretch[0].stamp
        for f in stretch:
            odom = f.odom if shift is None or f.odom is None else compose(shift, f.odom)
            out.append(replace(f, stamp=f.stamp + step, odom=odom, index=len(out)))
    return out


def _period(frames: Sequence[ScanFrame]) -> float:
    """The median time between the last few frames (a scan period)."""
    stamps = np.array([f.stamp for f in frames[-10:]])
    return float(np.median(np.diff(stamps))) if len(stamps) > 1 else 0.1
