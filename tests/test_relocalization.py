"""Proposing places from the signatures: the milestone's own heading is searched besides the
signature's, and milestones searched from about here are not searched again."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import replace

import numpy as np
from conftest import mapped

from drivers import open_source
from vmp.config import RegistrationConfig
from vmp.places import Places
from vmp.relocalization import propose
from vmp.types import relative


def _lab(scan: int):
    """The lab's saved map as places, one frame of another run and its true pose."""
    result = mapped("lab")
    p = result.pipeline
    places = Places(p.map, p.milestones, result.trajectory)
    sim = open_source("lab", seed=5)
    frames = list(sim)
    return places, frames[scan], sim.reference().poses[scan]


def _found(proposals, truth) -> bool:
    return any(math.hypot(*relative(truth, p.pose)[:2]) < 0.3 for p in proposals)


def test_a_signature_heading_far_off_still_finds_the_place_as_the_milestone_faces():
    places, frame, truth = _lab(400)
    ms = places.milestones
    query = ms.query

    def turned(*args, **kwargs):  # every candidate's heading 50 degrees off
        return [replace(c, heading_offset=c.heading_offset + math.radians(50.0))
                for c in query(*args, **kwargs)]

    found, _ = propose(places, frame, RegistrationConfig(), Counter())
    assert _found(found, truth)
    ms.query = turned
    try:
        found, _ = propose(places, frame, RegistrationConfig(), Counter())
    finally:
        ms.query = query
    assert _found(found, truth)


def test_milestones_searched_from_here_are_left_out_and_the_search_goes_down_the_list():
    places, frame, _ = _lab(400)
    stats: Counter[str] = Counter()
    _, first = propose(places, frame, RegistrationConfig(), stats)
    assert first
    _, second = propose(places, frame, RegistrationConfig(), stats, tried=set(first))
    assert second and not set(first) & set(second)
    # Down the signatures' list: the best searched now ranks below the best tried.
    ranked = [c.id for c in places.milestones.query(frame.ranges, frame.angle_min,
                                                    frame.angle_increment, frame.max_range,
                                                    max_candidates=32)]
    assert min(ranked.index(m) for m in second) > min(ranked.index(m) for m in first)
    assert np.all(np.isin(second, ranked))
