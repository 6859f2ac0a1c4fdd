"""The front end: where the robot is between corrections.

The filter moves by the wheel odometry increment since the last scan, refined by registering
the scan against a recent keyframe (:mod:`vmp.scan_odometry`). The increment is the odometry's
between the times the two scans were taken: their stamps less the delay learned from the
registered turns (:mod:`vmp.latency`). Odometry alone is tracked beside it, for comparison; a
source whose odometry pauses (scans without it) resumes where it stopped.
"""

from __future__ import annotations

import math

import numpy as np

from vmp.config import MappingConfig
from vmp.fusion import PoseFilter
from vmp.latency import Latency
from vmp.scan_odometry import ScanOdometry
from vmp.types import FloatArray, ScanFrame, compose, inverse, relative, rotate_covariance

__all__ = ["FrontEnd", "new_view"]

# How well the first pose is known (m, m, rad): it defines the map frame.
INITIAL_SIGMA = (0.01, 0.01, math.radians(0.5))
# A scan is registered against the map (the mapper's milestones, a saved map's submaps) once
# the robot has moved this far (m) or turned this much since the last registered scan: standing
# still, it sees what it saw, and a registration of the same view again would count the same
# evidence twice in the filter. (Matching only every 0.1 m or 5 degrees, as a view that is
# new, would map the Intel part in 29 s rather than 40 but raise the simulated office's median
# ATE from 1.31 to 1.73 cm: a moving robot's scans are new evidence; docs/benchmarks.md.)
NEW_VIEW_XY = 0.02
NEW_VIEW_THETA = math.radians(1.0)


def new_view(last: FloatArray | None, pose: FloatArray, xy: float = NEW_VIEW_XY,
             theta: float = NEW_VIEW_THETA) -> bool:
    """Whether the robot at ``pose`` has moved ``xy`` or turned ``theta`` since it was at
    ``last`` (the pose of the last registered scan; None: none yet)."""
    if last is None:
        return True
    turn = abs(math.remainder(float(pose[2] - last[2]), math.tau))
    return bool(math.hypot(pose[0] - last[0], pose[1] - last[1]) >= xy or turn >= theta)


class FrontEnd:
    """The filter's prediction from odometry and scan registration."""

    def __init__(self, config: MappingConfig, filtered: bool = True,
                 stops_early: bool = False, by_all_points: bool = True) -> None:
        self.config = config
        # Without a filter of its own it only works out the increments (a localizer moves its
        # hypotheses' filters by them).
        self.filtered = filtered
        self.scan_odometry = ScanOdometry(config.scan_odometry, config.registration,
                                          config.motion, stops_early, by_all_points)
        self.filter: PoseFilter | None = None
        self._first = True  # no scan yet
        self.odom_pose = np.zeros(3)  # where odometry alone puts the robot
        self._odom_offset = np.zeros(3)  # odometry frame -> that pose, after any gaps
        self._last_odom: FloatArray | None = None  # the odometry of the scan before ...
        self._last_taken: FloatArray | None = None  # ... and when it was taken (the delay off)
        self._last_stamp = 0.0
        self.latency = Latency()
        # Motion noise since the last anchor correction: how far a correction may move.
        self.motion_since_fix = np.zeros((3, 3))
        # The last increment (scanner frame) and its covariance; zero before the second scan.
        self.increment: tuple[FloatArray, FloatArray] = (np.zeros(3), np.zeros((3, 3)))

    def predict(self, frame: ScanFrame, points: FloatArray | None = None) -> None:
        """Move the filter to this scan (the first scan starts it at its odometry);
        ``points`` are the scan's end points when the caller has them already."""
        odom = frame.odom
        taken = None
        if odom is not None:
            self.latency.odometry(frame.stamp, odom)
            taken = self.latency.at(frame.stamp)
            if taken is None:  # the history does not reach back: the stamp's own
                taken = odom
        if self._first:
            self._first = False
            start = odom if odom is not None else np.zeros(3)
            if self.filtered:
                self.filter = PoseFilter(start, np.diag(np.square(INITIAL_SIGMA)),
                                         self.config.motion)
            self.odom_pose = start.copy()
        else:
            # The wheel increment is known when this scan and the one before carry odometry.
            wheel = (relative(self._last_taken, taken)
                     if taken is not None and self._last_taken is not None else None)
            if odom is not None:
                if self._last_odom is None:  # odometry resumes: continue from where it stopped
                    self._odom_offset = compose(self.odom_pose, inverse(odom))
                self.odom_pose = compose(self._odom_offset, odom)
            u, q = self.scan_odometry.increment(
                frame.points() if points is None else points, wheel)
            self.increment = (u, q)
            if self.filter is not None:
                self.filter.predict(u, q)
                self.motion_since_fix = self.motion_since_fix + rotate_covariance(
                    q, self.filter.pose[2])
            if wheel is not None and self.scan_odometry.registered is not None:
                self.latency.registered(self._last_stamp, frame.stamp,
                                        float(self.scan_odometry.registered[2]))
        self._last_odom = odom
        self._last_taken = taken
        self._last_stamp = frame.stamp

    def hold(self, frame: ScanFrame) -> None:
        """Leave this scan out (the caller found the robot standing where it was at the last
        scan predicted): its odometry is kept for the delay's interpolation, and the next
        scan's increment spans it."""
        if frame.odom is not None:
            self.latency.odometry(frame.stamp, frame.odom)

    @property
    def pose(self) -> FloatArray:
        return self.filter.pose

    @property
    def covariance(self) -> FloatArray:
        return self.filter.covariance
