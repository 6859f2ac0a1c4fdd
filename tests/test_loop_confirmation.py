"""A loop the search finds joins the graph only when the next find corrects the map the same way."""

import math
from collections import Counter

import numpy as np

from milestones.manager import MilestoneManager
from vmp.backend import CONFIRM_XY, BackEnd
from vmp.config import MappingConfig
from vmp.matcher import Kind, Match, Seed
from vmp.registration import Registration
from vmp.types import compose
from vmp.view import NullView

PINNED = np.diag([1e-4, 1e-4, 1e-5])


def _backend(milestones: int) -> BackEnd:
    config = MappingConfig()
    stored = MilestoneManager(config.milestones)
    rng = np.random.default_rng(0)
    for k in range(milestones):
        stored.add(np.array([float(k), 0.0, 0.0]), rng.uniform(1.0, 5.0, 181), -math.pi / 2,
                   math.radians(1.0), 8.0, float(k))
    back = BackEnd(config, stored, lambda mid: None, NullView(), Counter())
    back.anchor = milestones - 1
    # The edge's measurement is not what is tested here: a fixed one.
    back.handover_edge = lambda m, pose: (np.zeros(3), np.eye(3) * 0.01)
    return back


def _find(milestone: int, pose: np.ndarray, correction: list[float]) -> Match:
    """A search find on ``milestone`` that moves the robot at ``pose`` by ``correction``."""
    reg = Registration(np.zeros(3), 0.02, 0.9, PINNED, 10, True)
    return Match(milestone, Kind.SIGNATURE, reg, compose(np.array(correction), pose), PINNED,
                 1.0, 0.1, 0.9, None, Seed.SEARCH)


def _loops(back: BackEnd) -> list[tuple[int, int]]:
    return [(e.i, e.j) for e in back.graph.edges if e.kind == "loop"]


def test_two_finds_that_agree_close_both_loops():
    back = _backend(30)
    back.anchor = 28
    pose = np.array([20.0, 1.0, 0.2])
    assert back.close_in_place([_find(2, pose, [0.5, -0.3, 0.05])], pose) is None
    assert _loops(back) == []  # one find is a guess
    back.anchor = 29  # the next milestone's search
    pose = compose(pose, np.array([1.0, 0.0, 0.0]))
    edge = back.close_in_place([_find(3, pose, [0.52, -0.31, 0.05])], pose)
    assert edge is not None
    assert _loops(back) == [(28, 2), (29, 3)]  # the earlier find joins too


def test_two_finds_of_one_search_do_not_confirm_each_other():
    # One scan in two submaps that share most of their segments is one look, however well
    # the two agree; the next search's find is the second look.
    back = _backend(30)
    back.anchor = 28
    pose = np.array([20.0, 1.0, 0.2])
    same_search = [_find(2, pose, [0.5, -0.3, 0.05]), _find(3, pose, [0.5, -0.3, 0.05])]
    assert back.close_in_place(same_search, pose) is None
    assert _loops(back) == []
    assert back.stats["loop finds awaiting confirmation"] == 2
    back.anchor = 29
    pose = compose(pose, np.array([1.0, 0.0, 0.0]))
    assert back.close_in_place([_find(4, pose, [0.51, -0.3, 0.05])], pose) is not None
    assert _loops(back) == [(28, 2), (29, 4)]


def test_finds_that_disagree_close_nothing():
    back = _backend(30)
    pose = np.array([20.0, 1.0, 0.2])
    back.close_in_place([_find(2, pose, [0.5, -0.3, 0.05])], pose)
    back.anchor = 29
    # Another look-alike place: the map would move another way.
    assert back.close_in_place([_find(9, pose, [0.5 + 3 * CONFIRM_XY, -0.3, 0.05])],
                               pose) is None
    assert _loops(back) == []
    assert back.stats["loop finds awaiting confirmation"] == 2
