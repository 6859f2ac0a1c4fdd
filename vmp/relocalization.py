"""Where in a saved map a scan may have been taken, with no pose to start from.

The milestone signatures propose places: a global query over every stored milestone (any of
the four comparison methods) gives the few best distinct milestones and, for each, the heading
offset of the live scan. Each is verified the way the loop search verifies a loop: a
branch-and-bound search (:mod:`vmp.branch_bound`) of the live scan over the milestone's submap,
in a window around the node, turned as the milestone faces or by the signature's heading
offset, then ICP against the map.
A proposal that scores well and fits closely is a place the robot may be; which of them it is
the localizer (:mod:`vmp.localizer`) decides over the following scans.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Collection
from dataclasses import dataclass

import numpy as np

from vmp.branch_bound import Match, search, search_points
from vmp.config import RegistrationConfig
from vmp.places import Place, Places
from vmp.registration import MIN_POINTS, Registration, register
from vmp.types import FloatArray, ScanFrame, compose, relative

__all__ = ["Proposal", "propose"]

CANDIDATES = 4  # distinct places verified per search, best signatures first ...
SHORTLIST = 32  # ... from this many milestones of the signature query
DISTINCT = 1.5  # milestones nearer each other than this are one place (m)
WINDOW_XY = 2.0  # the search window around the node, either way (m) ...
WINDOW_THETA = math.radians(20.0)  # ... and around the signature's heading
MIN_SCORE = 0.55  # mean likelihood of the live points at a proposal
MAX_SHIFT = 0.3  # ICP may move this far from the search's pose (m) ...
MAX_TURN = math.radians(5.0)  # ... and turn this much


@dataclass(frozen=True)
class Proposal:
    """A place the scan may have been taken: its pose in the map frame and the evidence."""

    pose: FloatArray  # (3,) in the map frame
    milestone: int  # whose submap it was found in
    score: float  # the search's mean likelihood
    signature: float  # the signature score of the milestone (lower is better)
    registration: Registration  # the refinement, in the map frame


def propose(places: Places, frame: ScanFrame, registration: RegistrationConfig,
            stats: Counter[str], known: list[FloatArray] = (),
            candidates: int = CANDIDATES,
            tried: Collection[int] = ()) -> tuple[list[Proposal], list[int]]:
    """The verified places of one scan, best signatures first, and the milestones searched.

    Left out are the milestones whose search window holds one of the ``known`` poses (map
    frame), the places already followed, and those ``tried`` (searched lately, from about
    here): search after search looks farther down the signatures' list. (ACES, its second
    half: the robot stands still for 170 scans where the right milestone ranks 30th, and the
    same failing candidates above it would be searched again every time, each hiding its
    neighbours as one place.)"""
    points = frame.points()
    if len(points) < MIN_POINTS:
        return [], []
    ranked = places.milestones.query(frame.ranges, frame.angle_min, frame.angle_increment,
                                     frame.max_range, max_candidates=SHORTLIST)
    live = search_points(points)
    out: list[Proposal] = []
    chosen: list[FloatArray] = []
    searched: list[int] = []
    for cand in ranked:  # a few dozen at most
        if len(chosen) >= candidates:
            break
        if cand.id in tried:
            continue
        if any(math.hypot(*(cand.pose[:2] - p[:2])) < DISTINCT for p in chosen):
            continue
        if any(_covers(cand.pose, cand.heading_offset, p) for p in known):
            continue
        chosen.append(cand.pose)
        searched.append(cand.id)
        place = places.place(cand.id)
        if place is None:
            continue
        stats["places searched"] += 1
        best = _search(place, live, cand.heading_offset, places.milestones.config.record_turn)
        if best is None:
            continue
        found = compose(place.pose, best.pose)
        reg = register(places.reference, points, found)
        shift = relative(found, reg.pose)
        if (not places.fits(reg, points, registration)
                or math.hypot(shift[0], shift[1]) > MAX_SHIFT
                or abs(shift[2]) > MAX_TURN):
            continue
        stats["places verified"] += 1
        out.append(Proposal(reg.pose, cand.id, best.score, cand.score, reg))
    return out, searched


def _search(place: Place, live: FloatArray, offset: float, record_turn: float) -> Match | None:
    """The best pose of the live points in ``place``'s submap near its milestone: turned by
    the signature's heading ``offset``, or as the milestone faces (within ``record_turn``, the
    turn after which the mapper records a new milestone: a robot that passed here facing this
    way has a milestone near it within that turn). The signature's offset alone misses where
    the signatures of a cluttered place change over the metre between milestones (ACES, where
    its first half ends: the right milestone's best offset 27 degrees off, its signature at
    the true heading the worst of its curve)."""
    best = search(place.grid, live, np.zeros(3), WINDOW_XY, record_turn, MIN_SCORE)
    if abs(offset) > record_turn - WINDOW_THETA:
        other = search(place.grid, live, np.array([0.0, 0.0, offset]), WINDOW_XY,
                       WINDOW_THETA, MIN_SCORE if best is None else best.score)
        if other is not None and (best is None or other.score > best.score):
            best = other
    return best


def _covers(node: FloatArray, offset: float, pose: FloatArray) -> bool:
    """Whether the search window around ``node`` turned by ``offset`` holds ``pose``."""
    turn = (pose[2] - node[2] - offset + math.pi) % (2 * math.pi) - math.pi
    return math.hypot(pose[0] - node[0], pose[1] - node[1]) <= WINDOW_XY and \
        abs(turn) <= WINDOW_THETA
