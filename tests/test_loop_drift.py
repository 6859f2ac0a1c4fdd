"""The loop search's window spans the drift between a stored milestone and the robot: the path
edges between them compounded, not the sum of both map-frame covariances (which hold all the
drift since the start)."""

import math
from collections import Counter

import numpy as np

from milestones.manager import MilestoneManager
from vmp.backend import BackEnd
from vmp.config import MappingConfig
from vmp.types import compose, compose_covariance
from vmp.view import NullView

STEP = np.array([1.0, 0.0, 0.02])
STEP_COV = np.diag([0.01**2, 0.01**2, 0.005**2])
FAR_FROM_START = np.diag([1.0, 1.0, 0.05])  # a map-frame covariance after a long way round


def _chain(milestones: int, branch: bool = False) -> BackEnd:
    """Milestones one metre apart, each recorded from the one before (the last from the one
    before that when ``branch``: the robot backed up and went on), the anchor the last."""
    config = MappingConfig()
    stored = MilestoneManager(config.milestones)
    rng = np.random.default_rng(0)
    pose = np.zeros(3)
    for k in range(milestones):
        stored.add(pose.copy(), rng.uniform(1.0, 5.0, 181), -math.pi / 2, math.radians(1.0),
                   8.0, float(k))
        pose = compose(pose, STEP)
    back = BackEnd(config, stored, lambda mid: None, NullView(), Counter())
    for k in range(1, milestones):
        parent = k - 2 if branch and k == milestones - 1 else k - 1
        back.graph.add(parent, k, STEP if parent == k - 1 else compose(STEP, STEP),
                       STEP_COV, "path")
    back._abs_cov = [FAR_FROM_START.copy() for _ in range(milestones)]
    back.anchor = milestones - 1
    return back


def test_the_drift_to_a_recent_milestone_is_the_path_between_compounded():
    back = _chain(30)
    robot = compose(back.milestones.pose(29), np.array([0.4, 0.0, 0.0]))
    drift = back.drift_along_path(robot, 26)
    assert sorted(drift) == [26, 27, 28, 29]  # back as far as asked, no farther
    rel, cov = back.robot_in_anchor(robot)
    for _ in range(2):  # from the anchor back to milestone 27 by hand
        cov = compose_covariance(STEP, STEP_COV, rel, cov)
        rel = compose(STEP, rel)
    np.testing.assert_allclose(drift[27], cov, rtol=1e-6, atol=1e-12)  # edges kept as information
    # Centimetres, where the robot's and the milestone's map-frame covariances add to metres.
    summed = back.cov_via_anchor(robot) + back.milestone_cov(27)
    assert math.sqrt(np.linalg.eigvalsh(drift[27][:2, :2])[-1]) < 0.1
    assert math.sqrt(np.linalg.eigvalsh(summed[:2, :2])[-1]) > 1.0
    # The farther back, the wider.
    assert np.trace(drift[26]) > np.trace(drift[27]) > np.trace(drift[28])


def test_a_milestone_off_the_path_back_has_no_drift_along_it():
    back = _chain(30, branch=True)  # milestone 29 recorded from 27: 28 is a side branch
    drift = back.drift_along_path(back.milestones.pose(29), 25)
    assert 28 not in drift
    assert sorted(drift) == [25, 26, 27, 29]


def test_the_drift_compounded_at_once_is_the_drift_compounded_edge_by_edge():
    back = _chain(30, branch=True)
    robot = compose(back.milestones.pose(29), np.array([0.7, -0.3, 0.4]))
    drift = back.drift_along_path(robot, 0)
    rel, cov = back.robot_in_anchor(robot)
    node, by_hand = 29, {29: cov}
    while node > 0:  # the path back: 29 was recorded from 27, the rest one after another
        parent = 27 if node == 29 else node - 1
        step = compose(STEP, STEP) if node == 29 else STEP
        cov = compose_covariance(step, STEP_COV, rel, cov)
        rel = compose(step, rel)
        node = parent
        by_hand[node] = cov
    assert sorted(drift) == sorted(by_hand)
    for mid, expected in by_hand.items():
        np.testing.assert_allclose(drift[mid], expected, rtol=1e-6, atol=1e-12)
