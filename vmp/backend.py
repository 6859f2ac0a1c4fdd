"""The back end: the milestone graph, its edges and its adjustment.

Milestones are recorded along the path (the first where the run starts), each when the robot
has moved or turned enough from the anchor, the newest one; consecutive ones are joined by a
path edge, measured by registering their stored scans. The path stays one chain: coming back
to a place seen long ago, the robot keeps recording milestones of its own, and a clear match
on an old one closes the loop by a loop edge between the anchor and it, never by handing the
segment over (a handover would hang the map on a node a single match placed; a loop edge can
lose its pull in the robust adjustment when it is wrong). A loop edge that disagrees with the
graph has it adjusted (sparse least squares, :mod:`vmp.pose_graph`); the milestones move and
their segments with them. Every milestone keeps its covariance in the map frame, which gates
how far a return to it may disagree with the prediction.

Handing over to old milestones keeps ACES and fr079 far off on the Kuemmerle logs
(``python bench/kummerle.py``; figures in docs/benchmarks.md).
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Callable

import numpy as np

from milestones.manager import MilestoneManager
from vmp.config import MappingConfig
from vmp.fusion import motion_covariance
from vmp.matcher import Kind, Match, Seed, pins
from vmp.pose_graph import Edge, PoseGraph
from vmp.registration import MIN_POINTS, Reference, Registration, fits, register
from vmp.types import (
    FloatArray,
    ScanFrame,
    compose,
    compose_covariance,
    inverse,
    inverse_covariance,
    relative,
    rotate_covariance,
)
from vmp.view import View

__all__ = ["BackEnd", "corrections_agree", "fuse"]

# A loop the search found joins the graph when another found at most this many milestones
# later corrects the robot's pose the same way, within this distance and turn. (Four, not
# three: merging ACES's halves, two finds four milestones and 4.1 m apart agree on a 2.7 m
# correction to a few centimetres, the searches between them refining poorly; with three the
# loop between the halves stays open, 0.0476 m against 0.0355 in one go and 0.0360 with
# four.)
CONFIRM_WITHIN = 4
CONFIRM_XY = 0.3
CONFIRM_THETA = math.radians(3.0)
# Added to every milestone's covariance from the graph's marginals (m^2, m^2, rad^2).
MARGINAL_FLOOR = np.diag([1e-6, 1e-6, 1e-8])
# The covariance of a saved map's milestones when mapping goes on in it: the file keeps their
# adjusted poses, not their marginals (m^2, m^2, rad^2).
SAVED_COV = np.diag([0.05**2, 0.05**2, math.radians(1.0) ** 2])


def fuse(a: FloatArray, cov_a: FloatArray, b: FloatArray, cov_b: FloatArray
         ) -> tuple[FloatArray, FloatArray]:
    """Two estimates of one relative pose combined by their information."""
    info_a, info_b = np.linalg.inv(cov_a), np.linalg.inv(cov_b)
    cov = np.linalg.inv(info_a + info_b)
    d = np.asarray(a, dtype=np.float64) - b
    d[2] = (d[2] + np.pi) % (2 * np.pi) - np.pi
    return b + cov @ (info_a @ d), 0.5 * (cov + cov.T)


def corrections_agree(a: FloatArray, b: FloatArray, pose: FloatArray) -> bool:
    """Whether two corrections of the map frame (what two loop finds do to it) move ``pose``
    to within :data:`CONFIRM_XY` and :data:`CONFIRM_THETA` of each other: one confirms the
    other."""
    d = relative(compose(a, pose), compose(b, pose))
    return math.hypot(d[0], d[1]) <= CONFIRM_XY and abs(d[2]) <= CONFIRM_THETA


def _via(rel_a: FloatArray, cov_a: FloatArray, reg: Registration
         ) -> tuple[FloatArray, FloatArray]:
    """Milestone ``b`` in the anchor's frame through the robot: the robot in the anchor's frame
    (``rel_a``, ``cov_a``) and in ``b``'s (a registration, in ``b``'s frame)."""
    to_b = inverse(reg.pose)
    return compose(rel_a, to_b), compose_covariance(
        rel_a, cov_a, to_b, inverse_covariance(reg.pose, reg.covariance))


class BackEnd:
    """The milestones, the anchor of the open segment, the graph and its adjustment."""

    TRANSIENT = ("_record",)  # rebuilt from the graph's edges when needed (vmp.state)

    def __init__(self, config: MappingConfig, milestones: MilestoneManager,
                 reference: Callable[[int], Reference], view: View,
                 stats: Counter[str]) -> None:
        self.config = config
        self.milestones = milestones
        self.reference = reference  # a milestone's stored scan, ready to register against
        self.view = view
        self.stats = stats
        self.graph = PoseGraph()
        self.anchor: int | None = None
        # This scan's accepted registration against the anchor, if any.
        self.anchor_registration: Registration | None = None
        # Per milestone: its covariance in the map frame; None where the graph's marginals
        # hold it (solved when first asked for, see milestone_cov).
        self._abs_cov: list[FloatArray | None] = []
        # Per anchor, the milestones it closed a loop to without a handover.
        self._closed: dict[int, set[int]] = {}
        self._neighbours: dict[int, set[int]] = {}  # milestone -> the ones edges join it to
        # The loops the search found lately, waiting for others to agree, oldest first:
        # (anchor, milestone, z, covariance, correction of the map frame).
        self._finds: list[tuple[int, int, FloatArray, FloatArray, FloatArray]] = []
        # The path edge that recorded each milestone (see drift_along_path), and how many of
        # the graph's edges were looked at for them.
        self._record: dict[int, tuple[int, FloatArray, FloatArray]] | None = {}
        self._record_seen = 0

    def restore(self, graph: PoseGraph) -> None:
        """Take over a saved map's graph (its milestones are the manager's already)."""
        self.graph = graph
        self._abs_cov = [SAVED_COV.copy() for _ in range(int(self.milestones.ids.max()) + 1)]
        for e in graph.edges:
            self._neighbours.setdefault(e.i, set()).add(e.j)
            self._neighbours.setdefault(e.j, set()).add(e.i)
        self.stats["loop edges"] += sum(e.kind == "loop" for e in graph.edges)

    def join(self, place: int, first: int, cov: FloatArray) -> Edge:
        """A loop edge from a saved milestone to the first of a new session, where a localizer
        put the robot (``cov``: its covariance in the map frame)."""
        a = self.milestones.pose(place)
        z = relative(a, self.milestones.pose(first))
        edge = self._add_edge(place, first, z, rotate_covariance(cov, -a[2]) + SAVED_COV,
                              "loop")
        self.stats["loop edges"] += 1
        self.stats["sessions joined"] += 1
        return edge

    # ---- what the matcher needs to know ---------------------------------------------------

    def joined(self, mid: int) -> set[int]:
        """The milestones edges join milestone ``mid`` to."""
        return set(self._neighbours.get(mid, ()))

    def linked(self, tail: int = 3) -> set[int]:
        """The milestones loop edges join to the last ``tail`` milestones of the path."""
        out: set[int] = set()
        for mid in range(self.anchor - tail + 1, self.anchor + 1):
            out |= {j for j in self._neighbours.get(mid, ()) if abs(j - mid) > 1}
        return out

    def drift_along_path(self, pose: FloatArray, oldest: int) -> dict[int, FloatArray]:
        """The covariance of the robot at ``pose`` in the frame of each milestone on the path
        back from the anchor, as far back as ``oldest``: the edges that recorded the milestones,
        compounded from there to the robot. This is the drift between the two, where the
        map-frame covariances of both hold everything since the start; a loop closed in
        between would narrow it further.

        Compounded all at once (to first order, as :func:`vmp.types.compose_covariance` one
        edge at a time): in the anchor's frame each edge adds its covariance turned to its
        frame and swung about its node by the heading's doubt (by the lever from the node to
        the robot); the sums from the anchor back, turned into each milestone's frame, are
        the answers. One edge at a time in Python would take 2.97 s of fr079's 80 s."""
        parents = self._record_edges()
        rel, cov = self.robot_in_anchor(pose)
        chain, z, z_cov = [self.anchor], [], []
        node = self.anchor
        while node > oldest and node in parents:  # pointers only: the sums are vectorised
            parent, z_k, cov_k = parents[node]
            chain.append(parent)
            z.append(z_k)
            z_cov.append(cov_k)
            node = parent
        if not z:
            return {self.anchor: cov}
        z, z_cov = np.array(z), np.array(z_cov)
        # Each milestone on the chain in the anchor's frame: heading phi, position p.
        phi = np.concatenate([[0.0], -np.cumsum(z[:, 2])])
        c, s = np.cos(phi[1:]), np.sin(phi[1:])
        step = np.stack([c * z[:, 0] - s * z[:, 1], s * z[:, 0] + c * z[:, 1]], axis=1)
        p = np.concatenate([np.zeros((1, 2)), -np.cumsum(step, axis=0)])
        lever = rel[:2] - p[:-1]  # from each edge's child node to the robot
        M = np.zeros((len(z), 3, 3))
        M[:, 0, 0], M[:, 0, 1], M[:, 1, 0], M[:, 1, 1] = c, -s, s, c
        M[:, 0, 2], M[:, 1, 2], M[:, 2, 2] = -lever[:, 1], lever[:, 0], 1.0
        summed = cov + np.cumsum(np.einsum("kab,kbc,kdc->kad", M, z_cov, M), axis=0)
        back = np.zeros((len(z), 3, 3))  # into each milestone's frame
        back[:, 0, 0], back[:, 0, 1], back[:, 1, 0], back[:, 1, 1] = c, s, -s, c
        back[:, 2, 2] = 1.0
        turned = np.einsum("kab,kbc,kdc->kad", back, summed, back)
        turned = 0.5 * (turned + np.transpose(turned, (0, 2, 1)))
        out = {self.anchor: cov}
        out.update(zip(chain[1:], turned, strict=True))
        return out

    def _record_edges(self) -> dict[int, tuple[int, FloatArray, FloatArray]]:
        """Per milestone, the path edge that recorded it: its parent, pose and covariance
        there (the first path edge into it from an older milestone)."""
        edges = self.graph.edges
        if self._record is None or len(edges) < self._record_seen:  # resumed, or restored
            self._record, self._record_seen = {}, 0
        for e in edges[self._record_seen:]:
            if e.kind == "path" and e.i < e.j and e.j not in self._record:
                self._record[e.j] = (e.i, e.z, np.linalg.inv(e.information))
        self._record_seen = len(edges)
        return self._record

    def closed_from_anchor(self) -> set[int]:
        """The milestones the anchor has closed a loop to in place (see
        :meth:`close_in_place`): a new match on one of them changes nothing."""
        return self._closed.get(self.anchor, set())

    def milestone_cov(self, mid: int) -> FloatArray:
        """A milestone's covariance in the map frame."""
        cov = self._abs_cov[mid]
        if cov is None:
            cov = self._abs_cov[mid] = self.graph.marginals[mid] + MARGINAL_FLOOR
        return cov

    def cov_via_anchor(self, pose: FloatArray) -> FloatArray:
        """How uncertain the robot at ``pose`` is in the map frame through its anchor's chain."""
        rel = relative(self.milestones.pose(self.anchor), pose)
        return self._compound_cov(self.anchor, rel, np.zeros((3, 3)))

    # ---- milestones and edges ------------------------------------------------------------

    def begin(self, pose: FloatArray, cov: FloatArray, frame: ScanFrame) -> int:
        """Record the first milestone where the run starts; it anchors the first segment."""
        first = self.milestones.add(pose, frame.ranges, frame.angle_min,
                                    frame.angle_increment, frame.max_range, frame.stamp)
        self._abs_cov.append(cov.copy())
        self.anchor = first
        return first

    def record(self, pose: FloatArray, frame: ScanFrame) -> int | None:
        """Record a milestone here if one is due and the place is distinctive; it becomes the
        anchor, joined to the last by a path edge. Returns its id, or None. A scan with
        fewer than :data:`~vmp.registration.MIN_POINTS` returns makes none: it cannot be
        registered against."""
        if int(frame.returned.sum()) < MIN_POINTS:
            return None
        new = self.milestones.consider(pose, frame.ranges, frame.angle_min,
                                       frame.angle_increment, frame.max_range, frame.stamp,
                                       among=[self.anchor])
        if new is None:
            return None
        self.stats["milestones recorded"] += 1
        rel, cov = self._milestone_edge(self.anchor, new, self.robot_in_anchor(pose))
        self._add_edge(self.anchor, new, rel, cov, "path")
        self._abs_cov.append(self._compound_cov(self.anchor, rel, cov))
        self.view.milestone(new, self.milestones.pose(new))
        self.anchor = new
        return new

    def robot_in_anchor(self, pose: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The robot's pose in the anchor's frame and its covariance.

        The motion since the anchor bounds the uncertainty (odometry noise over that distance);
        this scan's registration against the anchor narrows it where it sees.
        """
        rel = relative(self.milestones.pose(self.anchor), pose)
        cov = motion_covariance(rel, self.config.motion)
        if self.anchor_registration is not None:
            return rel, fuse(rel, self.anchor_registration.covariance, rel, cov)[1]
        return rel, cov

    def _milestone_edge(self, a: int, b: int, fallback: tuple[FloatArray, FloatArray]
                        ) -> tuple[FloatArray, FloatArray]:
        """Milestone ``b`` in ``a``'s frame by registering their stored scans.

        ``fallback`` (pose and covariance, also the starting guess) stands when the two scans
        do not register well.
        """
        guess, cov = fallback
        reg = register(self.reference(a), self.reference(b).points, guess)
        if fits(reg, self.config.registration):
            self.stats["milestone edges registered"] += 1
            return fuse(reg.pose, reg.covariance, guess, cov)
        self.stats["milestone edges from the filter"] += 1
        return guess, cov

    def _add_edge(self, i: int, j: int, z: FloatArray, cov: FloatArray, kind: str) -> Edge:
        self._neighbours.setdefault(i, set()).add(j)
        self._neighbours.setdefault(j, set()).add(i)
        return self.graph.add(i, j, z, cov, kind)

    def _compound_cov(self, anchor: int, rel: FloatArray, cov: FloatArray) -> FloatArray:
        """Map-frame covariance of ``anchor (+) rel``, given the edge covariance ``cov``."""
        return compose_covariance(self.milestones.pose(anchor), self.milestone_cov(anchor), rel,
                                  cov)

    # ---- returns to stored milestones ------------------------------------------------------

    def handover_target(self, matches: list[Match], pose: FloatArray) -> Match | None:
        """The accepted signature match of the anchor's neighbour on the path (the robot
        backing up) nearer than the anchor, to hand the segment over to; None when there is
        none. Returns to older milestones are loops closed in place (:meth:`close_in_place`)."""
        d_anchor = float(np.hypot(*(self.milestones.pose(self.anchor)[:2] - pose[:2])))
        best = None
        for m in matches:
            if not m.accepted or m.kind is not Kind.SIGNATURE:
                continue
            if abs(m.milestone - self.anchor) != 1:
                continue
            if m.seed is not Seed.PREDICTION and pins(m.registration):
                # Registered from the node, not from the prediction (which, after a long way
                # round, may be metres off): how far the match puts the robot decides.
                d = float(np.hypot(*m.registration.pose[:2]))
            else:
                d = float(np.hypot(*(self.milestones.pose(m.milestone)[:2] - pose[:2])))
            if d + self.config.loops.switch_margin < d_anchor and (best is None or d < best[1]):
                best = (m, d)
        return None if best is None else best[0]

    def handover_edge(self, m: Match, pose: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The edge from the anchor to the milestone of match ``m``, the robot at ``pose``."""
        rel_a, cov_a = self.robot_in_anchor(pose)
        return self._milestone_edge(self.anchor, m.milestone, _via(rel_a, cov_a, m.registration))

    def hand_over(self, target: int, z: FloatArray, cov: FloatArray) -> Edge:
        """Join the anchor to ``target``, its neighbour on the path (see
        :meth:`handover_target`), by a path edge and make ``target`` the anchor."""
        edge = self._add_edge(self.anchor, target, z, cov, "path")
        self.stats["anchor switches"] += 1
        self.anchor = target
        return edge

    def close_in_place(self, matches: list[Match], pose: FloatArray) -> Edge | None:
        """A loop to a milestone seen long ago: an edge between the anchor and it, no
        handover; the edge, or None.

        A match that pins the pose closes the loop (once per pair of milestones). A match
        registered from the prediction needs a clear place (``retry_max_ratio``), as one
        registered from the node does: the Intel run passed such places, one after another,
        without closing a loop whenever the robot came back facing another way and recorded a
        milestone of its own there.
        """
        c = self.config
        for m in matches:
            if (not m.accepted or m.kind is not Kind.SIGNATURE
                    or (m.seed is Seed.PREDICTION and m.ratio > c.matching.retry_max_ratio)
                    or abs(m.milestone - self.anchor) <= c.loops.separation
                    or m.milestone in self._closed.get(self.anchor, ())
                    or not pins(m.registration)):
                continue
            z, cov = self.handover_edge(m, pose)
            self._closed.setdefault(self.anchor, set()).add(m.milestone)
            if m.seed is Seed.SEARCH and not self._confirmed(m, pose, z, cov):
                continue
            edge = self._add_edge(self.anchor, m.milestone, z, cov, "loop")
            self.stats["loop edges"] += 1
            self.stats["loop edges in place"] += 1
            return edge
        return None

    def _confirmed(self, m: Match, pose: FloatArray, z: FloatArray, cov: FloatArray) -> bool:
        """Whether a loop the search found agrees with the one it found just before (the same
        correction of the robot's pose, within :data:`CONFIRM_XY` and :data:`CONFIRM_THETA`,
        found at most :data:`CONFIRM_WITHIN` milestones back); then the earlier one joins the
        graph too. A find that agrees with none waits for the next.

        The search looks where the drift allows, among many look-alike places; one find is a
        guess, two from two searches that put the map the same way a few metres apart are a
        loop.
        """
        correction = compose(m.z, inverse(pose))  # what the find does to the map frame
        finds = [f for f in self._finds if self.anchor - f[0] <= CONFIRM_WITHIN]
        self._finds = [*finds, (self.anchor, m.milestone, z, cov, correction)]
        if any(f[0] == self.anchor for f in finds):
            # Another find of the same search: the same scan, in a submap that shares most
            # of its segments with the first one's (a milestone's neighbours are in both), is
            # no second look. On Radish acapulco two such finds 6.5 m off, scoring 0.57, made
            # a loop.
            self.stats["loop finds awaiting confirmation"] += 1
            return False
        # The first find of the last search before that found any.
        pending = next((f for f in finds if f[0] == finds[-1][0]), None) if finds else None
        if pending is None or not corrections_agree(pending[4], correction, pose):
            self.stats["loop finds awaiting confirmation"] += 1
            return False
        if self._agreed_elsewhere(correction, pose):
            self.stats["loop finds awaiting confirmation"] += 1
            self.stats["loop finds as well confirmed elsewhere"] += 1
            return False
        self._add_edge(*pending[:4], "loop")
        self.stats["loop edges"] += 1
        self.stats["loop edges in place"] += 1
        # The graph will move the map frame by this correction: the finds before it
        # corrected another frame.
        self._finds = []
        return True

    def _agreed_elsewhere(self, correction: FloatArray, pose: FloatArray) -> bool:
        """Whether two of the recent finds, of two searches, agree on a correction of the map
        frame other than ``correction``: then which of the two places the robot came back
        to is a guess. (On ACES with the wheels' heading drifting 2 deg every 10 m, the
        searches at two milestones in a row found the right place, and at the next two a
        stretch of corridor 7.5 m along, each pair agreeing.)"""
        others = [f for f in self._finds if not corrections_agree(f[4], correction, pose)]
        return any(a[0] != b[0] and corrections_agree(a[4], b[4], pose)
                   for k, a in enumerate(others) for b in others[k + 1:])

    def tie(self, new: int, old: int, reg: Registration) -> Edge:
        """A loop edge from milestone ``new`` to ``old``, where ``new``'s stored scan
        registered in ``old``'s submap (``reg``: the scan's pose in ``old``'s frame)."""
        rel = np.zeros(3)  # the scan is the milestone's own
        z, cov = _via(rel, motion_covariance(rel, self.config.motion), reg)
        edge = self._add_edge(new, old, z, cov, "loop")
        self.stats["loop edges"] += 1
        return edge

    def disagrees(self, edge: Edge) -> bool:
        """Whether the graph as it stands disagrees with a new edge enough to adjust it."""
        e = self.graph.error(self.milestones.poses, edge)
        return float(e @ edge.information @ e) > self.config.loops.adjust_chi2

    def adjust(self) -> FloatArray:
        """Adjust the milestone graph; the milestones move. Returns their new poses."""
        t = time.perf_counter()
        poses = self.graph.optimize(self.milestones.poses)
        self.milestones.set_poses(poses)
        if self.graph.marginals is not None:  # the loop has shrunk every milestone's doubt
            self._abs_cov = [None] * len(self.graph.marginals)
        self.stats["graph adjustments"] += 1
        self.stats["graph adjustment seconds"] += time.perf_counter() - t
        self.view.anchors_moved(self.milestones.ids, poses)
        return poses

    def finish(self) -> None:
        """Adjust the graph a last time (when loops were closed)."""
        if self.stats["loop edges"]:
            poses = self.graph.optimize(self.milestones.poses)
            self.milestones.set_poses(poses)
            self.view.anchors_moved(self.milestones.ids, poses)

    def poses_by_id(self) -> FloatArray:
        """Milestone poses indexed by id."""
        ids = self.milestones.ids
        out = np.zeros((int(ids.max()) + 1 if len(ids) else 0, 3))
        out[ids] = self.milestones.poses
        return out
