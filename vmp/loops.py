"""Loop closure by geometry, ranked by signatures.

At every new milestone the live scan is searched for in the submaps of stored milestones that could
be where the robot is: those inside the window that the drift since them allows (a few sigma
of the drift between the milestone and the robot, capped), far enough back along the path. The
milestones' signatures rank them (the paper's job for signatures: cheap identification), and
the best few are searched by branch and bound (:mod:`vmp.branch_bound`) over the window, then
refined by ICP against the submap's points. A find must score well, stand clear of the best
pose elsewhere in the window, fit closely and pin the pose; in a corridor, whose walls leave the
refinement free along the axis, a peak that nothing else in the window comes near, and that
falls off within half a metre along the axis, places the scan there to the search's cell (the
submap's doors, posts and ends do what the walls cannot). It then becomes a signature match
seeded by the search, judged like any other (:mod:`vmp.matcher`), and closes the loop in the
milestone graph, whose robust adjustment (:mod:`vmp.pose_graph`) keeps a wrong one from bending
the map.
"""

from __future__ import annotations

import math
from collections import Counter, OrderedDict
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from milestones.manager import MilestoneManager
from vmp.branch_bound import Match, SearchGrid, search, search_points
from vmp.config import MappingConfig
from vmp.registration import Reference, Registration, fits, register
from vmp.types import FloatArray, ScanFrame, relative, transform_points, widest_variance

__all__ = ["Find", "LoopSearch"]

SIGMAS = 3.0  # the window spans this many sigma of the drift either way ...
MIN_WINDOW_XY = 0.5  # ... at least this (m) ...
MAX_WINDOW_XY = 7.0  # ... and at most this (m)
MIN_WINDOW_THETA = math.radians(10.0)
MAX_WINDOW_THETA = math.radians(30.0)
REACH = 3.0  # a milestone this far beyond the window may still share the view (m)
# A candidate's submap takes in the segments of this many milestones either way. They are
# placed by the graph as it stands, bends and all: with three either way, the Intel part's
# finds on milestones 43-53 come out 4-5 degrees off, all alike, and confirm each other.
NEIGHBOURS = 2
# Submaps searched per search, best signatures first: at ACES's two long returns the right
# one is the third or fourth, and with two those loops stay open (docs/benchmarks.md).
CANDIDATES = 4
RESOLUTION = 0.1  # search grid cell (m)
SIGMA = 0.1  # likelihood fall-off (m)
DEPTH = 5  # levels of block maxima: the coarsest blocks are 3.2 m
GRID_RADIUS = 20.0  # submap points farther than this from the milestone are left out (m)
MIN_SCORE = 0.55  # mean likelihood of the live points at the find
MIN_SEARCH_POINTS = 20  # a scan, or its part within a submap's reach, with fewer is not searched
MAX_RATIO = 0.9  # the best pose elsewhere in the window scores at most this share of it
SEPARATION_XY = 0.5  # "elsewhere": this far from the find (m) ...
SEPARATION_THETA = math.radians(5.0)  # ... or turned this much
MAX_SHIFT = 0.3  # ICP may move this far from the find (m) ...
MAX_TURN = math.radians(5.0)  # ... and turn this much
FREE_VARIANCE = 1.0  # a direction the lines' covariance leaves this open (m^2) is free
RIVAL_CHI2 = 11.34  # a rival this far out under the fit's covariance makes a find ambiguous
CACHED_GRIDS = 64  # search grids kept (least recently used dropped)
LINKED = 2  # a candidate this near (in ids) to a milestone the recent path is joined to
#             needs no search: the prediction already knows where it is


class _Submap:
    """A candidate's submap as the search needs it: the segments it was made of, its search
    grid, and its registration reference, built when a search first finds something there
    (about a third of the searches on the Intel part find nothing, and the reference, a
    k-d tree and a normal per point, costs more to build than the grid)."""

    def __init__(self, segments: tuple[int, ...], points: FloatArray) -> None:
        self.segments = segments
        self.grid = SearchGrid(points, RESOLUTION, SIGMA, DEPTH, MAX_WINDOW_XY)
        self._points: FloatArray | None = points
        self._reference: Reference | None = None

    @property
    def reference(self) -> Reference:
        if self._reference is None:
            self._reference = Reference(self._points)
            self._points = None  # the reference holds them
        return self._reference


class Find:
    """A loop found: the milestone, the live scan's pose in its frame, the search's figures."""

    def __init__(self, milestone: int, registration: Registration, score: float,
                 ratio: float, signature: float) -> None:
        self.milestone, self.registration = milestone, registration
        self.score, self.ratio, self.signature = score, ratio, signature


class LoopSearch:
    """Searches the live scan in the submaps of milestones it may have come back to."""

    def __init__(self, config: MappingConfig, milestones: MilestoneManager,
                 submap_segments: Callable[[int], tuple[int, ...]],
                 submap_points: Callable[[int], tuple[tuple[int, ...], FloatArray] | None],
                 stats: Counter[str]) -> None:
        self.config = config
        self.milestones = milestones
        # A milestone's submap: its segments alone (cheap: a cached grid whose segments are
        # unchanged is reused without its points gathered again), and with its points.
        self.submap_segments = submap_segments
        self.submap_points = submap_points
        self.stats = stats
        self._grids: OrderedDict[int, _Submap] = OrderedDict()
        self._searched: int | None = None  # the anchor of the last search

    def due(self, anchor: int) -> bool:
        """Whether to search now: once per anchor, at its first scan (a new milestone, so
        every metre or so along the path)."""
        return anchor != self._searched

    def candidates(self, pose: FloatArray, anchor: int, linked: set[int],
                   drift: Callable[[int], FloatArray]) -> list[tuple[int, float, float]]:
        """Milestones the robot at ``pose`` may be near: (id, window xy, window theta).

        Left out: milestones near the anchor or the newest one along the path (the anchor
        match covers them) and those within :data:`LINKED` of a milestone the graph already
        joins to the recent path (``linked``): there the prediction is right, and signature
        matches registered from it close the loops more cheaply.
        """
        ids = self.milestones.ids
        sep = self.config.loops.separation
        far_back = (np.abs(ids - anchor) > sep) & (ids < ids[-1] - sep)
        if linked:
            near_linked = np.abs(ids[:, None] - np.fromiter(linked, np.int64)[None, :])
            far_back &= near_linked.min(axis=1) > LINKED
        if not far_back.any():
            return []
        d = np.hypot(*(self.milestones.poses[far_back, :2] - pose[:2]).T)
        reach = d <= MAX_WINDOW_XY + REACH
        out = []
        for mid, dist in zip(ids[far_back][reach], d[reach], strict=True):  # a handful
            cov = drift(int(mid))
            wxy = min(max(SIGMAS * math.sqrt(widest_variance(cov)), MIN_WINDOW_XY),
                      MAX_WINDOW_XY)
            if dist <= wxy + REACH:
                wth = min(max(SIGMAS * math.sqrt(cov[2, 2]), MIN_WINDOW_THETA),
                          MAX_WINDOW_THETA)
                out.append((int(mid), wxy, wth))
        return out

    def search(self, frame: ScanFrame, pose: FloatArray, anchor: int, linked: set[int],
               scan: int, drift: Callable[[int], FloatArray]) -> list[Find]:
        """Loops the live scan closes (at most :data:`CANDIDATES` searched)."""
        self._searched = anchor
        near = self.candidates(pose, anchor, linked, drift)
        if not near:
            return []
        windows = {mid: (wxy, wth) for mid, wxy, wth in near}
        ranked = self.milestones.rank(frame.ranges, frame.angle_min, frame.angle_increment,
                                      frame.max_range, list(windows))
        points = search_points(frame.points())
        if len(points) < MIN_SEARCH_POINTS:
            return []
        out = []
        for mid, signature, _ in ranked[:CANDIDATES]:
            self.stats["loop searches"] += 1
            center = relative(self.milestones.pose(mid), pose)
            found = self.search_submap(mid, points, frame.points(), center, *windows[mid])
            if found is not None:
                found.signature = signature
                out.append(found)
        return out

    def _submap(self, mid: int) -> _Submap | None:
        cached = self._grids.get(mid)
        if cached is not None and cached.segments == self.submap_segments(mid):
            self._grids.move_to_end(mid)
            return cached
        held = self.submap_points(mid)
        if held is None:
            return None
        segments, pts = held
        pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= GRID_RADIUS]
        if len(pts) < 20:  # too few to search in
            return None
        built = self._grids[mid] = _Submap(segments, pts)
        if len(self._grids) > CACHED_GRIDS:
            self._grids.popitem(last=False)
        return built

    def search_submap(self, mid: int, points: FloatArray, all_points: FloatArray,
                      center: FloatArray, wxy: float, wth: float) -> Find | None:
        """The live scan in milestone ``mid``'s submap, searched within the window around
        ``center`` (a pose in its frame), verified; or None. ``points``: the scan's points
        thinned for the search (:func:`vmp.branch_bound.search_points`); ``all_points``: all
        of them, for the refinement."""
        submap = self._submap(mid)
        if submap is None:
            return None
        grid = submap.grid
        best = search(grid, points, center, wxy, wth, MIN_SCORE)
        if best is None:
            self.stats["loop searches below the score"] += 1
            return None
        ref = submap.reference
        # Refined with the live points that fall inside the submap's reach: beyond it (ACES's
        # beams reach 50 m down a corridor) nothing can match, and counted against the fit
        # they failed finds that two searches agreed on to 0.1 m (scans 6703-6741).
        placed = transform_points(best.pose, all_points)
        inside = all_points[np.hypot(placed[:, 0], placed[:, 1]) <= GRID_RADIUS]
        if len(inside) < MIN_SEARCH_POINTS:
            self.stats["loop searches with a poor refinement"] += 1
            return None
        reg = register(ref, inside, best.pose)
        shift = relative(best.pose, reg.pose)
        if (not fits(reg, self.config.registration) or math.hypot(shift[0], shift[1]) > MAX_SHIFT
                or abs(shift[2]) > MAX_TURN):
            self.stats["loop searches with a poor refinement"] += 1
            return None
        if reg.by_corners:
            # The edge takes only what the lines pin down: along a corridor's axis a corner's
            # sampling bias would otherwise pull the loop.
            lines = register(ref, inside, reg.pose, corners=False)
            if np.isfinite(lines.rms):
                reg = replace(reg, covariance=lines.covariance, by_corners=False)
        rival = search(grid, points, center, wxy, wth, MAX_RATIO * best.score,
                       exclude=(best.pose, SEPARATION_XY, SEPARATION_THETA))
        ratio = 0.0 if rival is None else rival.score / best.score
        close_rival = rival is not None and _rivals(grid, inside, best, rival)
        if close_rival and _distinct(rival.pose, reg):
            # Another pose fits about as well, with the near points searched with and with
            # all of them, and the refined fit can tell the two apart: which one is right is
            # a guess. (A rival along a corridor's axis, where the fit's covariance is wide,
            # is the same answer: the edge leaves that direction free.)
            self.stats["loop searches ambiguous"] += 1
            return None
        placed = None if close_rival else _placed_by_search(reg.covariance, grid, inside,
                                                            reg.pose)
        if placed is not None:
            # No pose elsewhere in the window comes near the peak, along the corridor's axis
            # either: the submap's doors and ends place the scan there, to the search's cell.
            reg = replace(reg, covariance=placed)
            self.stats["loop searches placed along a corridor"] += 1
        self.stats["loop searches found"] += 1
        return Find(mid, reg, best.score, ratio, math.nan)


def _placed_by_search(cov: FloatArray, grid: SearchGrid, points: FloatArray,
                      pose: FloatArray) -> FloatArray | None:
    """The covariance of a find whose peak is unique in its window, from the lines'
    covariance ``cov``: along the directions the lines leave free, the search's cell (the
    truth within half a cell of the peak's centre). None when the lines leave no direction
    free, or when along one the peak is a ridge: ``points`` at ``pose`` moved that way keep
    :data:`MAX_RATIO` of its score as far as :data:`SEPARATION_XY` to one side (the rival
    search, which looks only farther away, cannot tell such a ridge from a peak)."""
    vals, vecs = np.linalg.eigh(cov)
    free = vals >= FREE_VARIANCE
    if not free.any():
        return None
    peak = grid.score(points, pose)
    steps = np.arange(1, math.ceil(SEPARATION_XY / RESOLUTION - 1e-9) + 1) * RESOLUTION
    for k in np.flatnonzero(free):
        v = vecs[:, k] / max(float(np.hypot(vecs[0, k], vecs[1, k])), 1e-9)
        for side in (1.0, -1.0):  # ten poses at most, and only for a find
            if all(grid.score(points, pose + side * t * v) >= MAX_RATIO * peak for t in steps):
                return None
    return (vecs * np.where(free, (0.5 * RESOLUTION) ** 2, vals)) @ vecs.T


def _distinct(pose: FloatArray, reg: Registration) -> bool:
    """Whether ``pose`` lies outside the refined fit's uncertainty (chi-square, 3 dof, 99 %)."""
    d = relative(reg.pose, pose)
    try:
        return float(d @ np.linalg.solve(reg.covariance, d)) > RIVAL_CHI2
    except np.linalg.LinAlgError:  # singular: free along some direction, the rival too
        return False


def _rivals(grid: SearchGrid, far: FloatArray, best: Match, rival: Match) -> bool:
    """Whether ``rival`` still scores :data:`MAX_RATIO` of ``best`` with ``far``, every live
    point in the grid's reach: the near points searched with may show only a corridor both
    poses fit, while the far ones (ACES's beams reach 50 m) see where along it the robot is."""
    return grid.score(far, rival.pose) >= MAX_RATIO * grid.score(far, best.pose)
