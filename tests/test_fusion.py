"""The fusion filter (filterpy's EKF with wrapped headings) and the motion noise model."""

import math

import numpy as np
import pytest

from vmp.config import MotionNoise
from vmp.fusion import FLOOR_THETA, FLOOR_XY, PoseFilter, motion_covariance, pose_residual


def test_filter_predicts_by_composition_and_grows_uncertainty():
    f = PoseFilter([1.0, 2.0, math.pi / 2], np.eye(3) * 1e-4)
    f.predict([1.0, 0.0, 0.0])
    np.testing.assert_allclose(f.pose, [1.0, 3.0, math.pi / 2], atol=1e-12)
    assert np.trace(f.covariance) > 3e-4


def test_update_across_pi_takes_the_short_way_and_wraps():
    f = PoseFilter([0.0, 0.0, math.pi - 0.01], np.diag([0.01, 0.01, 0.01]))
    f.update([0.0, 0.0, -math.pi + 0.01], np.diag([0.01, 0.01, 0.01]))
    # Halfway between the two is pi itself, not zero.
    assert abs(abs(f.pose[2]) - math.pi) < 1e-6
    assert -math.pi <= f.pose[2] < math.pi
    np.testing.assert_allclose(pose_residual([0, 0, 3.1], [0, 0, -3.1]), [0, 0, 6.2 - 2 * math.pi],
                               atol=1e-12)


def test_motion_noise_grows_with_distance_and_turn_from_a_floor():
    noise = MotionNoise()
    still = motion_covariance(np.zeros(3), noise)
    assert still[0, 0] == pytest.approx(FLOOR_XY**2) and still[2, 2] == pytest.approx(
        FLOOR_THETA**2)
    ahead = motion_covariance(np.array([2.0, 0.0, 0.0]), noise)
    assert ahead[0, 0] == pytest.approx(noise.trans_per_m**2 * 2 + FLOOR_XY**2)
    turn = motion_covariance(np.array([0.0, 0.0, -math.pi / 2]), noise)
    assert turn[0, 0] == pytest.approx(FLOOR_XY**2)  # turning on the spot: no translation noise
    assert turn[2, 2] == pytest.approx(noise.rot_per_rad**2 * math.pi / 2 + FLOOR_THETA**2)
