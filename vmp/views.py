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

    def disagreements(self, ranges: FloatArray, poses: FloatArray) -> np.ndarray:
        """For each live scan (``ranges`` ``(N, B)``, ``inf`` without a return) and place
        (``poses`` ``(N, 3)``, map frame): the beams the view from the place contradicts, and
        those it knows, for the stored scan nearby that agrees best; (0, 0) where the map holds
        no view of the place. ``(N, 2)`` integers. (Many places a call, the places followed or
        one place's past scans: a view at a time, the small arrays' overhead cost the search
        half its speed in the simulated warehouse; docs/benchmarks.md, twenty-third
        session.)"""
        ranges = np.asarray(ranges, dtype=np.float64).reshape(-1, self.geometry.num_beams)
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        if len(ranges) != len(poses):
            raise ValueError(f"{len(ranges)} scans of {self.geometry.num_beams} beams for "
                             f"{len(poses)} places")
        out = np.zeros((len(poses), 2), dtype=np.int64)
        query, rows = self._near(poses)
        if len(rows) == 0:
            return out
        expected, known = self._render(rows, poses[query])
        live = ranges[query]
        agree = np.zeros(expected.shape, dtype=bool)
        for near, near_known in self._spread(expected, known):  # three (M, B) arrays
            with np.errstate(invalid="ignore"):  # inf - inf: no return in either, below
                agree |= np.abs(near - live) <= AGREE
            agree |= np.isinf(near) & np.isinf(live) & near_known
        agree &= known
        n_known = known.sum(axis=1)
        n_agree = agree.sum(axis=1)
        share = np.where(n_known >= MIN_KNOWN * ranges.shape[1],
                         n_agree / np.maximum(n_known, 1), -1.0)
        # Per place, the stored scan that agrees best (the nearest among equals): the pairs
        # come grouped by place, nearest first.
        order = np.lexsort((-share, query))
        first = order[np.r_[True, query[order][1:] != query[order][:-1]]]
        first = first[share[first] >= 0.0]
        out[query[first], 0] = n_known[first] - n_agree[first]
        out[query[first], 1] = n_known[first]
        return out

    def _spread(self, expected: FloatArray, known: np.ndarray
                ) -> list[tuple[FloatArray, np.ndarray]]:
        """The views shifted by each beam offset within :data:`SPREAD`: what beam ``j``
        would read from beam ``j + shift`` of the view. Around the circle for a scanner that
        sees all of it; past the ends of a narrower one's sweep, nothing known."""
        wrap = self.geometry.full_circle
        width = ((0, 0), (SPREAD, SPREAD))
        padded = (np.pad(expected, width, mode="wrap") if wrap
                  else np.pad(expected, width, constant_values=np.nan))
        padded_known = np.pad(known, width, mode="wrap") if wrap else np.pad(known, width)
        beams = expected.shape[1]
        return [(padded[:, SPREAD + d:SPREAD + d + beams],
                 padded_known[:, SPREAD + d:SPREAD + d + beams])
                for d in range(-SPREAD, SPREAD + 1)]

    def _near(self, poses: FloatArray) -> tuple[np.ndarray, np.ndarray]:
        """Pairs of a place (index into ``poses``) and a stored scan taken near it and facing
        about as it faces: :data:`CANDIDATES` at most per place, grouped by place, nearest
        first."""
        none = np.zeros(0, dtype=np.int64)
        if self._tree is None:
            return none, none
        found = self._tree.query_ball_point(poses[:, :2], NEAR_XY)
        counts = np.fromiter((len(f) for f in found), dtype=np.int64, count=len(found))
        if counts.sum() == 0:
            return none, none
        query = np.repeat(np.arange(len(poses)), counts)
        rows = np.fromiter((r for f in found for r in f), dtype=np.int64, count=counts.sum())
        stored = self._poses[rows]
        turn = np.abs((stored[:, 2] - poses[query, 2] + math.pi) % (2 * math.pi) - math.pi)
        facing = turn <= NEAR_THETA
        query, rows, stored = query[facing], rows[facing], stored[facing]
        apart = np.hypot(stored[:, 0] - poses[query, 0], stored[:, 1] - poses[query, 1])
        order = np.lexsort((apart, query))
        query, rows = query[order], rows[order]
        # The rank of each pair within its place's group.
        starts = np.r_[0, np.flatnonzero(query[1:] != query[:-1]) + 1]
        rank = np.arange(len(query)) - np.repeat(starts, np.diff(np.r_[starts, len(query)]))
        keep = rank < CANDIDATES
        return query[keep], rows[keep]

    def _render(self, rows: np.ndarray, poses: FloatArray) -> tuple[FloatArray, np.ndarray]:
        """Each stored scan of ``rows`` seen from the place beside it in ``poses``: the
        expected range of every beam (``inf``: free to the scanner's reach) and whether the
        scan knows it, ``(M, B)``."""
        g = self.geometry
        beams = g.num_beams
        at = relative(poses, self._poses[rows])  # the stored scanners, seen from the places
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
        cell = beam + (np.arange(len(rows)) * beams)[:, None]  # (scan, beam), flattened
        hit = inside & self._hits[rows]
        expected = np.full(len(rows) * beams, np.inf)
        # (On one flat index ufunc.at takes numpy's fast path: a third of the time.)
        np.minimum.at(expected, cell[hit], np.hypot(x[hit], y[hit]))
        expected = expected.reshape(len(rows), beams)
        known = np.isfinite(expected)
        free = inside & ~self._hits[rows]
        known.ravel()[cell[free]] = True
        return expected, known
