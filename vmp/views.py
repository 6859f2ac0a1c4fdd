"""A saved map's scans as views: how many of a live scan's ranges a place explains.

The localizer scores a place by where the live scan's end points fall in the map
(:meth:`vmp.places.Places.score`). Between two rows of identical rack bays that score cannot
tell the bays apart: every end point lands on some rack. What tells them apart is where the
beams pass: a beam that stops short at one bay passes a rack's end at the next, one that
returns here has no return there. The saved map keeps every scan it was made of, ranges and
pose, so the view from a place the mapper passed is known beam by beam: the stored scans taken
near it, seen from the place (each beam's end point, or the far end of its reach where it had
no return, put into the bearing it falls in from there, the nearest end point winning). A live
beam agrees with such a view when both read within :data:`AGREE` of each other, or neither has a
return.

In the simulated warehouse, along aisles whose bays all score 1.000 by their end points, the
right place's stored views contradicted 0-1.2 % of the live beams (mean over a run's first 80
scans) and the closest look-alike's 2.3-28 % in seven of nine runs whose start or kidnap the
world tells apart, 0.4 and 0.9 % in the other two (docs/benchmarks.md, twenty-second session).
A place the mapper never passed, or passed facing another way, has no view: nothing is known
of it, and nothing is concluded from it.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from vmp.types import FloatArray, relative
from vmp.vector_map import VectorMap

__all__ = ["AGREE", "SavedViews"]

AGREE = 0.1  # a live beam agrees with a view when the two ranges are this close (m) ...
# ... or when it reads what a beam this many either side of it would in the view: a wall seen
# at a grazing angle from a few centimetres aside moves its ranges by decimetres (the simulated
# corridor, seed 110's kidnap, scan 112: the right place's nearest stored scan, 6 cm aside,
# contradicted 30 beams by 0.1-0.3 m; with one beam either side the best stored scan nearby, 1).
# In the warehouse's runs the right places' shares fell by half or more so, the look-alikes' by
# a fifth to two thirds (docs/benchmarks.md, twenty-second session).
SPREAD = 1
# Stored scans taken this near a place (m) and facing this close to it make its view ...
NEAR_XY = 0.5
NEAR_THETA = math.radians(30.0)
CANDIDATES = 8  # ... the nearest this many of them, the one the live scan agrees with best
# A view must know at least this share of the live beams to be one (a stored scan turned away
# sees little of what the live one sees).
MIN_KNOWN = 0.5


class SavedViews:
    """The stored scans of a saved map, rendered at places near its path."""

    def __init__(self, vmap: VectorMap, trajectory: FloatArray) -> None:
        """``trajectory``: the map's assembled scan poses (as saved with it)."""
        g = vmap.geometry
        self.geometry = g
        self._poses = np.asarray(trajectory, dtype=np.float64)
        hits = vmap.scan_hits(range(len(vmap)))
        angles = g.angles
        reach = np.column_stack([np.cos(angles), np.sin(angles)]) * g.max_range
        # Where a beam had no return, the far end of its reach stands for it: the bearing
        # it falls in from the place is free as far as that.
        self._points = np.where(hits[..., None], vmap.end_points, reach[None]).astype(np.float64)
        self._hits = hits
        self._tree = cKDTree(self._poses[:, :2]) if len(self._poses) else None

    def disagreement(self, ranges: FloatArray, pose: FloatArray) -> tuple[int, int]:
        """The live beams (``ranges``, ``inf`` without a return) that the view from ``pose``
        (map frame) contradicts, and those it knows, for the stored scan nearby that agrees
        best; (0, 0) where the map holds no view of ``pose``."""
        rows = self._near(pose)
        if len(rows) == 0:
            return 0, 0
        expected, known = self._render(rows, pose)
        agree = np.zeros(expected.shape, dtype=bool)
        for shift in range(-SPREAD, SPREAD + 1):  # three shifts of a (K, B) array
            near = np.roll(expected, shift, axis=1)
            with np.errstate(invalid="ignore"):  # inf - inf: no return in either, below
                agree |= np.abs(near - ranges) <= AGREE
            agree |= np.isinf(near) & np.isinf(ranges) & np.roll(known, shift, axis=1)
        agree &= known
        n_known = known.sum(axis=1)
        n_agree = agree.sum(axis=1)
        share = np.where(n_known >= MIN_KNOWN * len(ranges), n_agree / np.maximum(n_known, 1),
                         -1.0)
        best = int(np.argmax(share))
        if share[best] < 0.0:
            return 0, 0
        return int(n_known[best] - n_agree[best]), int(n_known[best])

    def _near(self, pose: FloatArray) -> np.ndarray:
        """The stored scans taken near ``pose`` and facing about as it faces, nearest first
        (:data:`CANDIDATES` at most)."""
        if self._tree is None:
            return np.zeros(0, dtype=np.int64)
        rows = np.asarray(self._tree.query_ball_point(pose[:2], NEAR_XY), dtype=np.int64)
        if len(rows) == 0:
            return rows
        poses = self._poses[rows]
        turn = np.abs((poses[:, 2] - pose[2] + math.pi) % (2 * math.pi) - math.pi)
        rows, poses = rows[turn <= NEAR_THETA], poses[turn <= NEAR_THETA]
        apart = np.hypot(poses[:, 0] - pose[0], poses[:, 1] - pose[1])
        return rows[np.argsort(apart, kind="stable")[:CANDIDATES]]

    def _render(self, rows: np.ndarray, pose: FloatArray) -> tuple[FloatArray, np.ndarray]:
        """Each stored scan of ``rows`` seen from ``pose``: the expected range of every beam
        (``inf``: free to the scanner's reach) and whether the scan knows it, ``(K, B)``."""
        g = self.geometry
        beams = g.num_beams
        at = relative(pose, self._poses[rows])  # the stored scanners, seen from the place
        c, s = np.cos(at[:, 2])[:, None], np.sin(at[:, 2])[:, None]
        px, py = self._points[rows, :, 0], self._points[rows, :, 1]
        x = at[:, 0, None] + c * px - s * py
        y = at[:, 1, None] + s * px + c * py
        turn = math.copysign(1.0, g.angle_increment)  # a scanner may sweep clockwise
        offset = (turn * (np.arctan2(y, x) - g.angle_min)) % (2.0 * math.pi)
        beam = np.rint(offset / abs(g.angle_increment)).astype(np.int64)
        if g.full_circle:
            beam %= beams
        inside = beam < beams
        k = np.broadcast_to(np.arange(len(rows))[:, None], beam.shape)
        hit = inside & self._hits[rows]
        expected = np.full((len(rows), beams), np.inf)
        np.minimum.at(expected, (k[hit], beam[hit]), np.hypot(x[hit], y[hit]))
        known = np.isfinite(expected)
        free = inside & ~self._hits[rows]
        known[k[free], beam[free]] = True
        return expected, known
