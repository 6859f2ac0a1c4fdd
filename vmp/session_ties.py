"""Loops between two sessions, searched once more when a run that mapped on in a saved map
ends.

While a run maps on in a saved map, its loops to the old session close as any loop does: at
each new milestone the scan is searched where the drift since the last fix allows
(:mod:`vmp.loops`), and a find joins the graph once another confirms it. A pass over the old
session's ground that no search tied stays where the new session's own drift put it, held only
by the ties before and after it. Merging ACES's halves without the search below can leave one
such stretch 1.3 m off the first half's map (its relation error 0.0462 m against 0.0355 m
mapped in one go), depending on which pose of an ICP cycle the localizer's first fix ends on.

So at the end, each new milestone's stored scan is searched again in the submaps of the old
milestones around where the graph puts it (within :data:`WINDOW_XY` and
:data:`WINDOW_THETA`), best signatures first, as the loop search does; old milestones that the
new one or its neighbours on the path are joined to already are left out. A find joins the
graph as a loop edge when a find of another new milestone, at most
:data:`vmp.backend.CONFIRM_WITHIN` milestones away, moves the map the same way (as a loop
search's find must be confirmed), before the graph's last adjustment.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from milestones.manager import MilestoneManager
from vmp.backend import CONFIRM_WITHIN, BackEnd, corrections_agree
from vmp.branch_bound import search_points
from vmp.loops import CANDIDATES, LINKED, MIN_SEARCH_POINTS, REACH, LoopSearch
from vmp.registration import Registration
from vmp.types import BeamGeometry, FloatArray, ScanFrame, compose, inverse, relative

__all__ = ["tie_sessions"]

# How far the graph may have left a new milestone from where the old session's map has it
# (m, rad): an untied stretch's drift (ACES: 1.3 m).
WINDOW_XY = 2.0
WINDOW_THETA = math.radians(10.0)


@dataclass(frozen=True)
class _Tie:
    new: int  # the new session's milestone ...
    old: int  # ... found in this old one's submap ...
    registration: Registration  # ... here (its stored scan's pose in the old one's frame)
    correction: FloatArray  # what the find does to the new milestone (map frame)


def tie_sessions(first_new: int, geometry: BeamGeometry, milestones: MilestoneManager,
                 loops: LoopSearch, back: BackEnd, stats: Counter[str]) -> int:
    """Search every milestone from ``first_new`` on in the old session's submaps around it,
    and join the confirmed finds to the graph as loop edges; how many were joined."""
    started = time.perf_counter()
    ids, poses = milestones.ids, milestones.poses
    old, new = ids < first_new, ids >= first_new
    if not old.any() or not new.any():
        return 0
    # The old milestones within reach of each new one, all at once (a building's map may
    # hold a hundred thousand).
    near = cKDTree(poses[old, :2]).query_ball_point(poses[new, :2], WINDOW_XY + REACH)
    found: dict[int, _Tie] = {}
    for mid, rows in zip(ids[new], near, strict=True):
        within = ids[old][np.sort(np.asarray(rows, dtype=np.int64))]
        tie = _search(int(mid), within, first_new, geometry, milestones, loops, back, stats)
        if tie is not None:
            found[tie.new] = tie
    confirmed = [tie for tie in found.values()
                 if any(corrections_agree(tie.correction, found[other].correction,
                                          milestones.pose(tie.new))
                        for other in range(tie.new - CONFIRM_WITHIN, tie.new + CONFIRM_WITHIN + 1)
                        if other != tie.new and other in found)]
    for tie in confirmed:
        back.tie(tie.new, tie.old, tie.registration)
    stats["loop edges between the sessions found at the end"] += len(confirmed)
    stats["finds between the sessions not confirmed at the end"] += len(found) - len(confirmed)
    stats["loop search between the sessions at the end: seconds"] += time.perf_counter() - started
    return len(confirmed)


def _search(mid: int, near: NDArray[np.int64], first_new: int, geometry: BeamGeometry,
            milestones: MilestoneManager, loops: LoopSearch, back: BackEnd,
            stats: Counter[str]) -> _Tie | None:
    """The first find of milestone ``mid``'s stored scan among the old milestones ``near``
    it (ids below ``first_new``), the best signatures searched first; None when none is
    found."""
    joined = {j for k in (mid - 1, mid, mid + 1) for j in back.joined(k) if j < first_new}
    candidates = [int(c) for c in near if not any(abs(c - j) <= LINKED for j in joined)]
    if not candidates:
        return None
    pose = milestones.pose(mid)
    ranges = milestones.scan(mid).astype(np.float64)
    points = ScanFrame(0.0, ranges, geometry.angle_min, geometry.angle_increment,
                       geometry.max_range).points()
    thinned = search_points(points)
    if len(thinned) < MIN_SEARCH_POINTS:
        return None
    ranked = milestones.rank(ranges, geometry.angle_min, geometry.angle_increment,
                             geometry.max_range, candidates)
    for old_mid, _, _ in ranked[:CANDIDATES]:
        stats["loop searches between the sessions at the end"] += 1
        center = relative(milestones.pose(old_mid), pose)
        find = loops.search_submap(old_mid, thinned, points, center, WINDOW_XY, WINDOW_THETA)
        if find is not None:
            placed = compose(milestones.pose(old_mid), find.registration.pose)
            return _Tie(mid, old_mid, find.registration, compose(placed, inverse(pose)))
    return None

