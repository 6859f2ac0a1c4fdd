"""A loop the search finds joins the graph only when the next find corrects the map the same way,
and no other pair of recent finds puts it elsewhere."""

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


def test_one_stray_find_beside_an_agreeing_pair_does_not_hold_the_loop_back():
    back = _backend(40)
    pose = np.array([20.0, 1.0, 0.2])
    right, stray = [0.5, -0.3, 0.05], [0.5 + 7.5, -0.3, 0.05]
    back.anchor = 35
    back.close_in_place([_find(5, pose, right), _find(9, pose, stray)], pose)
    back.anchor = 36
    assert back.close_in_place([_find(14, pose, right)], pose) is not None
    assert _loops(back) == [(35, 5), (36, 14)]
    assert back.stats["loop finds as well confirmed elsewhere"] == 0


def test_a_pair_of_finds_waits_while_another_pair_puts_the_map_elsewhere():
    # Two searches in a row find one place, the next two a stretch of corridor 7.5 m along
    # (ACES with the wheels' heading drifting): each pair agrees, which place the robot came
    # back to is a guess.
    back = _backend(40)
    pose = np.array([20.0, 1.0, 0.2])
    right, along = [0.5, -0.3, 0.05], [0.5 + 7.5, -0.3, 0.05]
    # The first search finds the right place; the second finds it and the look-alike (the
    # first of its finds is the look-alike, so the right find waits behind it).
    back.anchor = 36
    back.close_in_place([_find(5, pose, right)], pose)
    back.anchor = 37
    back.close_in_place([_find(3, pose, along), _find(14, pose, right)], pose)
    back.anchor = 38  # the next search confirms the look-alike, but the right pair stands
    assert back.close_in_place([_find(17, pose, along)], pose) is None
    assert _loops(back) == []
    assert back.stats["loop finds as well confirmed elsewhere"] == 1
