"""The vector map: every scan kept as a polygon, grouped into segments anchored at milestones.

A scan is stored as its beams' end points in its own frame (float32; a beam without a return
ends at the maximum range and is marked "not a hit"), and its pose in the frame of its
segment's anchor milestone. The polygon of a scan is the scanner origin followed by the end
points in angular order: its inside is free space, its hit end points are obstacle boundary.
Moving a milestone moves every scan of its segments; :meth:`VectorMap.spread` re-places the
scans since the last correction by spreading a correction along them.

181 beams cost 181 * 8 bytes of end points, 23 bytes of hit bits, 24 bytes of pose, 4 of
segment and 8 of stamp: 1,507 bytes a scan.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from vmp.saturation import no_echo_level
from vmp.types import (
    BeamGeometry,
    FloatArray,
    compose,
    inverse,
    relative,
    transform_points,
    wrap_angle,
)

__all__ = ["VectorMap"]

BLOCK = 4096  # scans drawn at a time (bounds the temporaries of the views)


class _Grow:
    """A contiguous array that grows by doubling along its first axis."""

    def __init__(self, shape: tuple[int, ...], dtype: type) -> None:
        self.a = np.zeros((64, *shape), dtype=dtype)
        self.n = 0

    def append(self, row) -> int:
        if self.n == len(self.a):
            grown = np.zeros((2 * len(self.a), *self.a.shape[1:]), dtype=self.a.dtype)
            grown[: self.n] = self.a
            self.a = grown
        self.a[self.n] = row
        self.n += 1
        return self.n - 1

    @property
    def view(self) -> NDArray:
        return self.a[: self.n]


class VectorMap:
    """Scan polygons in segments; each segment lives in the frame of its anchor milestone."""

    def __init__(self, geometry: BeamGeometry, free_range: float | None = None) -> None:
        """``free_range`` caps how far a beam without a return marks free space (default: the
        maximum range); real scanners report no return for glass and dark surfaces too, and
        80 m of invented free space is worse than none."""
        self.geometry = geometry
        self.free_range = min(geometry.max_range, free_range or geometry.max_range)
        n = geometry.num_beams
        self._points = _Grow((n, 2), np.float32)
        self._hits = _Grow(((n + 7) // 8,), np.uint8)
        self._rel = _Grow((3,), np.float64)
        self._segment = _Grow((), np.int32)
        self._stamp = _Grow((), np.float64)
        self.segment_anchor: list[int] = []  # milestone id of each segment
        self.segment_start: list[int] = []  # index of each segment's first scan
        self._by_anchor: dict[int, list[int]] = {}  # milestone id -> its segments
        # Where each closed segment handed over: (next anchor id, its pose in this anchor's
        # frame when the robot switched), or None while open.
        self.segment_end: list[tuple[int, FloatArray] | None] = []
        self._cos = np.cos(geometry.angles)
        self._sin = np.sin(geometry.angles)

    def __len__(self) -> int:
        return self._rel.n

    # ---- building ----------------------------------------------------------------------------

    def new_segment(self, anchor_id: int, handover: FloatArray | None = None) -> int:
        """Open a segment anchored at milestone ``anchor_id``; returns the segment index.

        ``handover`` is the new anchor's pose in the previous anchor's frame at the switch; it
        closes the previous segment so that assembly can bend it onto both its ends.
        """
        if self.segment_anchor and handover is not None:
            self.segment_end[-1] = (int(anchor_id), np.asarray(handover, dtype=np.float64))
        self.segment_anchor.append(int(anchor_id))
        self.segment_start.append(len(self))
        self.segment_end.append(None)
        self._by_anchor.setdefault(int(anchor_id), []).append(len(self.segment_anchor) - 1)
        return len(self.segment_anchor) - 1

    def segments_of(self, anchor_id: int) -> list[int]:
        """The segments anchored at a milestone, oldest first."""
        return self._by_anchor.get(int(anchor_id), [])

    def segment_scans(self, segment: int) -> range:
        """The indices of a segment's scans (a segment's scans are consecutive)."""
        starts = self.segment_start
        end = starts[segment + 1] if segment + 1 < len(starts) else len(self)
        return range(starts[segment], end)

    def scan_hits(self, scans: NDArray[np.int64] | range) -> NDArray[np.bool_]:
        """``(K, N)``: True where a beam of the given scans hit something."""
        packed = self._hits.view[np.asarray(scans, dtype=np.int64)]
        return np.unpackbits(packed, axis=1, count=self.geometry.num_beams).astype(bool)

    def insert(self, ranges: FloatArray, rel_pose: FloatArray, stamp: float = 0.0,
               free_range: float | None = None) -> int:
        """Add a scan (ranges with ``inf`` for no return) at ``rel_pose`` in the open segment.

        ``free_range`` caps this scan's free space along beams without a return (0: none).
        """
        if not self.segment_anchor:
            raise ValueError("open a segment before inserting scans")
        r = np.asarray(ranges, dtype=np.float64)
        if r.shape != (self.geometry.num_beams,):
            raise ValueError(f"expected {self.geometry.num_beams} ranges, got {r.shape}")
        hit = np.isfinite(r)
        reach = self.free_range if free_range is None else min(self.free_range, free_range)
        # Vertices piled up on the scanner would make the polygon touch itself: "no free
        # space" keeps a 2 cm fan around the scanner instead.
        free = np.where(hit, r, max(reach, 0.02))
        pts = np.stack([free * self._cos, free * self._sin], axis=-1)
        self._points.append(pts)
        self._hits.append(np.packbits(hit))
        self._rel.append(rel_pose)
        self._segment.append(len(self.segment_anchor) - 1)
        return self._stamp.append(stamp)

    def restore(self, segment_anchor: list[int], segment_end: list, points: NDArray,
                hits: NDArray, rel: NDArray, segment: NDArray, stamps: NDArray) -> None:
        """Fill an empty map from stored arrays (see :mod:`vmp.mapfile`)."""
        if len(self):
            raise ValueError("restore into an empty map only")
        self.segment_anchor = [int(a) for a in segment_anchor]
        self.segment_end = [None if e is None else (int(e[0]), np.asarray(e[1], dtype=float))
                            for e in segment_end]
        for grow, arr in ((self._points, points), (self._hits, hits), (self._rel, rel),
                          (self._segment, segment), (self._stamp, stamps)):
            grow.a = np.array(arr, dtype=grow.a.dtype, copy=True)
            grow.n = len(arr)
        seg = self.segments
        self.segment_start = np.searchsorted(seg, np.arange(len(segment_anchor))).tolist()
        self._by_anchor = {}
        for g, a in enumerate(self.segment_anchor):
            self._by_anchor.setdefault(a, []).append(g)

    # ---- corrections -------------------------------------------------------------------------

    def spread(self, first: int, correction: FloatArray) -> None:
        """Re-place scans ``first..`` (of the open segment) by a correction spread along them.

        ``correction`` (a pose in the anchor frame, applied on the left) is what the last scan
        needs; earlier scans get the share of it their travelled distance since scan ``first``
        gives them, so the map bends smoothly instead of tearing at the correction.
        """
        rel = self._rel.view
        seg = self._segment.view
        last = len(self) - 1
        first = max(first, 0)
        while first <= last and seg[first] != seg[last]:
            first += 1
        if first > last:
            return
        block = rel[first:last + 1]
        step = np.hypot(*np.diff(block[:, :2], axis=0).T) + np.abs(np.diff(block[:, 2])) * 0.1
        travel = np.concatenate([[0.0], np.cumsum(step)])
        if travel[-1] > 0:
            frac = travel / travel[-1]
        else:  # no motion: evenly, and the last scan (maybe the only one) takes all of it
            frac = np.linspace(0.0, 1.0, len(block)) if len(block) > 1 else np.ones(1)
        c = np.asarray(correction, dtype=np.float64)
        share = frac[:, None] * np.array([c[0], c[1], wrap_angle(c[2])])[None, :]
        rel[first:last + 1] = compose(share, block)

    # ---- reading -----------------------------------------------------------------------------

    @property
    def rel_poses(self) -> FloatArray:
        return self._rel.view

    @property
    def segments(self) -> NDArray[np.int32]:
        return self._segment.view

    @property
    def stamps(self) -> FloatArray:
        return self._stamp.view

    @property
    def end_points(self) -> NDArray[np.float32]:
        """End points ``(S, N, 2)`` in each scan's own frame."""
        return self._points.view

    @property
    def hits(self) -> NDArray[np.bool_]:
        """``(S, N)``: True where a beam hit something."""
        return np.unpackbits(self._hits.view, axis=1, count=self.geometry.num_beams).astype(bool)

    @property
    def packed_hits(self) -> NDArray[np.uint8]:
        return self._hits.view

    def world_poses(self, anchor_poses: FloatArray) -> FloatArray:
        """Scan poses ``(S, 3)`` in the map frame, given each milestone's pose (by id).

        A closed segment hangs between its anchor and the next one: if the two moved relative
        to each other since the segment was recorded, the difference is spread along the
        segment by travelled distance (the paper's figure 16, milestones assembling the map).
        """
        P = np.asarray(anchor_poses, dtype=np.float64)
        seg_anchor = np.array(self.segment_anchor, dtype=np.int64)
        anchors = P[seg_anchor]  # (G, 3)
        corrections = np.zeros((len(seg_anchor), 3))
        hop = np.zeros(len(seg_anchor))
        ends = [(g, e) for g, e in enumerate(self.segment_end) if e is not None]
        if ends:
            g = np.array([g for g, _ in ends])
            nxt = np.array([e[0] for _, e in ends])
            handover = np.array([e[1] for _, e in ends])
            now = relative(anchors[g], P[nxt])
            corrections[g] = compose(now, inverse(handover))
            hop_from = self._last_rel_of_segments()[g]
            hop[g] = np.hypot(*(handover[:, :2] - hop_from[:, :2]).T)
        rel = self.rel_poses
        seg = self.segments
        frac = self._travel_fraction(seg, rel, hop)
        share = frac[:, None] * corrections[seg]
        return compose(anchors[seg], compose(share, rel))

    def _last_rel_of_segments(self) -> FloatArray:
        out = np.zeros((len(self.segment_anchor), 3))
        seg = self.segments
        if len(seg):
            last = np.flatnonzero(np.r_[seg[1:] != seg[:-1], True])
            out[seg[last]] = self.rel_poses[last]
        return out

    @staticmethod
    def _travel_fraction(seg: NDArray, rel: FloatArray, hop: FloatArray) -> FloatArray:
        """Per scan, the share of its segment's length (up to the handover) travelled so far."""
        if len(seg) == 0:
            return np.zeros(0)
        step = np.zeros(len(seg))
        same = seg[1:] == seg[:-1]
        d = np.hypot(*np.diff(rel[:, :2], axis=0).T) + 0.1 * np.abs(wrap_angle(np.diff(rel[:, 2])))
        step[1:] = np.where(same, d, 0.0)
        cum = np.cumsum(step)
        start = np.flatnonzero(np.r_[True, ~same])
        cum -= np.repeat(cum[start], np.diff(np.r_[start, len(seg)]))
        total = np.zeros(hop.shape)
        last = np.flatnonzero(np.r_[~same, True])
        total[seg[last]] = cum[last]
        total = total + hop
        return np.where(total[seg] > 0, cum / np.where(total[seg] > 0, total[seg], 1.0), 0.0)

    def no_echo(self) -> NDArray[np.bool_]:
        """``(S, N)``: hits at the reading the scanner writes for "no echo", where the data show
        one (:mod:`vmp.saturation`). The views below draw them as beams without a return;
        registration and the loop search see the stored scans as they are."""
        hits = self.hits
        ranges = np.hypot(self.end_points[..., 0], self.end_points[..., 1])
        level = no_echo_level(np.where(hits, ranges, np.inf))
        return hits & (ranges >= level) if level is not None else np.zeros_like(hits)

    def world_points(self, poses: FloatArray) -> FloatArray:
        """Hit points ``(K, 2)`` in the map frame, less "no echo" readings."""
        keep = self.no_echo()
        np.logical_xor(self.hits, keep, out=keep)  # the hits that are not "no echo"
        return transform_points(poses, self.end_points.astype(np.float64))[keep]

    def polygons(self, poses: FloatArray) -> FloatArray:
        """Scan polygons ``(S, V, 2)`` in the map frame: origin then end points in angle order.

        A beam without a return (or with a "no echo" reading, :meth:`no_echo`) marks free
        space as far as it was stored to reach, but no farther than the farther of the hits
        on either side of it in its scan: through a window or an open door the scanner saw
        the frame, not what lies beyond (fr079's and the Intel lab's windows would put 10 m of
        free space all round the building). A scan without a hit keeps its reach. A
        full-circle scan's polygon is its end points alone (the origin lies inside). Worked
        out :data:`BLOCK` scans at a time, so that only the result is of the whole map's size.
        """
        poses = np.asarray(poses, dtype=np.float64)
        silent_all = self.no_echo()
        full = self.geometry.full_circle
        n = self.geometry.num_beams
        out = np.empty((len(self), n if full else n + 1, 2))
        for k in range(0, len(self), BLOCK):
            local = self.end_points[k:k + BLOCK].astype(np.float64)
            ranges = np.hypot(local[..., 0], local[..., 1])
            hits = np.unpackbits(self._hits.view[k:k + BLOCK], axis=1, count=n).astype(bool)
            silent = silent_all[k:k + BLOCK]
            hits &= ~silent
            reach = np.where(silent, max(self.free_range, 0.02), ranges)
            reach = np.where(hits, ranges, np.minimum(reach, _beside(ranges, hits, reach)))
            local *= (reach / np.maximum(ranges, 1e-9))[..., None]
            pts = transform_points(poses[k:k + BLOCK], local)
            if self.geometry.angle_increment < 0:
                pts = pts[:, ::-1]
            if full:
                out[k:k + BLOCK] = pts
            else:
                out[k:k + BLOCK, 0] = poses[k:k + BLOCK, :2]
                out[k:k + BLOCK, 1:] = pts
        return out

    @property
    def bytes_per_scan(self) -> float:
        """Bytes of storage one scan takes (end points, hit bits, pose, segment, stamp)."""
        per = (self._points.a.itemsize * self._points.a[0].size
               + self._hits.a[0].size + 3 * 8 + 4 + 8)
        return float(per)


def _beside(ranges: FloatArray, hits: NDArray[np.bool_], otherwise: FloatArray) -> FloatArray:
    """``(S, N)``: per beam, the larger range of the nearest hits before and after it in its
    scan, or ``otherwise`` where the scan has no hit on either side."""
    n = ranges.shape[1]
    beam = np.arange(n, dtype=np.int32)
    before = np.maximum.accumulate(np.where(hits, beam, -1), axis=1)
    after = np.minimum.accumulate(np.where(hits, beam, n)[:, ::-1], axis=1)[:, ::-1]
    near = np.where(before >= 0, np.take_along_axis(ranges, np.maximum(before, 0), axis=1),
                    -np.inf)
    np.maximum(near, np.where(after < n, np.take_along_axis(ranges, np.minimum(after, n - 1),
                                                            axis=1), -np.inf), out=near)
    return np.where(np.isfinite(near), near, otherwise)
