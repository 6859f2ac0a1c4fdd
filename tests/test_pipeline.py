"""The whole mapper on the built-in scenarios: accuracy against the simulator's truth."""

import dataclasses

import numpy as np
import pytest
from conftest import mapped

from drivers import open_source
from vmp.evaluate import ate, wrong_corrections
from vmp.source import FrameList


def ate_of(result):
    ref = result.reference
    return (ate(result.stamps, result.trajectory, ref.stamps, ref.poses).rmse,
            ate(result.stamps, result.odometry, ref.stamps, ref.poses).rmse)


@pytest.mark.slow
def test_office_ate_is_under_5_cm_and_5_times_below_odometry():
    r = mapped("office")
    got, odom = ate_of(r)
    assert got <= 0.05 and got * 5 <= odom, (got, odom)
    assert r.pipeline.stats["loop edges"] >= 1 and len(r.pipeline.milestones) > 20
    assert wrong_corrections(r.corrections, r.reference.poses) == []


@pytest.mark.slow
def test_warehouse_ate_is_under_5_cm_and_5_times_below_odometry():
    got, odom = ate_of(mapped("warehouse"))
    assert got <= 0.05 and got * 5 <= odom, (got, odom)


@pytest.mark.slow
def test_corridor_never_corrects_wrongly():
    r = mapped("corridor")
    assert len(r.corrections) > 50
    assert wrong_corrections(r.corrections, r.reference.poses) == []


@pytest.mark.slow
def test_lab_is_mapped_to_a_centimetre():
    got, odom = ate_of(mapped("lab"))
    assert got < 0.01 < odom


def test_a_rejected_match_changes_nothing():
    p = mapped("lab", scans=200).pipeline
    frames = list(open_source("office", scans=3))
    pose, cov = p.front.pose.copy(), p.front.covariance.copy()
    p.matched_at = None  # as if the robot had moved since the last matched scan
    matches = p.match(frames[-1])  # a scan from another building
    assert matches and not any(m.accepted for m in matches)
    p.correct(matches)
    np.testing.assert_array_equal(p.front.pose, pose)
    np.testing.assert_array_equal(p.front.covariance, cov)


def test_a_robot_standing_still_is_matched_once():
    from vmp.run import MappingRun

    frames = list(open_source("lab", scans=61))
    p = MappingRun(FrameList(frames[:60], "lab")).run().pipeline  # its own: it is changed
    frame = frames[-1]
    p.matched_at = None
    counts = []
    for k in range(4):  # the same scan at the same odometry: the robot does not move
        still = dataclasses.replace(frame, stamp=frame.stamp + 0.1 * k)
        p.predict(still)
        counts.append(len(p.match(still)))
    assert counts[0] > 0 and counts[1:] == [0, 0, 0]
    assert p.stats["scans not matched (standing still)"] >= 3


def test_without_milestones_only_odometry_and_scan_matching_move_the_robot():
    from vmp.config import MappingConfig
    from vmp.run import MappingRun

    config = MappingConfig()
    config = dataclasses.replace(config, matching=dataclasses.replace(config.matching,
                                                                      enabled=False))
    r = MappingRun(open_source("lab", scans=150), config).run()
    assert len(r.pipeline.milestones) == 1 and r.corrections == []
    np.testing.assert_allclose(r.trajectory, r.online, atol=1e-9)  # nothing re-placed scans
