"""Pose algebra and the scan frame."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from vmp.types import (
    ScanFrame,
    compose,
    compose_covariance,
    inverse,
    inverse_covariance,
    relative,
    rotate_covariance,
    rotation_matrix,
    transform_points,
    widest_direction,
    widest_variance,
    wrap_angle,
)

coord = st.floats(-1e3, 1e3, allow_nan=False)
angle = st.floats(-20.0, 20.0, allow_nan=False)
pose = st.tuples(coord, coord, angle).map(lambda p: np.array(p))
poses = arrays(np.float64, (5, 3), elements=st.floats(-50, 50, allow_nan=False))


def assert_pose_close(a, b, tol=1e-6):
    a, b = np.asarray(a), np.asarray(b)
    np.testing.assert_allclose(a[..., :2], b[..., :2], atol=tol)
    np.testing.assert_allclose(wrap_angle(a[..., 2] - b[..., 2]), 0.0, atol=tol)


@given(angle)
def test_wrap_lands_in_half_open_interval_and_keeps_direction(t):
    w = float(wrap_angle(t))
    assert -math.pi <= w < math.pi
    assert math.isclose(math.cos(w), math.cos(t), abs_tol=1e-9)
    assert math.isclose(math.sin(w), math.sin(t), abs_tol=1e-9)


def test_wrap_of_pi_is_minus_pi():
    assert wrap_angle(math.pi) == -math.pi
    assert wrap_angle(-math.pi) == -math.pi


@given(pose)
def test_compose_with_inverse_is_identity(p):
    assert_pose_close(compose(p, inverse(p)), [0, 0, 0], tol=1e-6)
    assert_pose_close(compose(inverse(p), p), [0, 0, 0], tol=1e-6)


@given(pose, pose, pose)
def test_compose_is_associative(a, b, c):
    assert_pose_close(compose(compose(a, b), c), compose(a, compose(b, c)), tol=1e-6)


@given(pose, pose)
def test_relative_undoes_compose(a, b):
    assert_pose_close(relative(a, compose(a, b)), b, tol=1e-6)
    assert_pose_close(relative(a, b), compose(inverse(a), b), tol=1e-6)


@given(poses, poses)
def test_vectorised_equals_one_by_one(a, b):
    batch = compose(a, b)
    for i in range(len(a)):
        np.testing.assert_allclose(batch[i], compose(a[i], b[i]))
    batch_rel = relative(a, b)
    for i in range(len(a)):
        np.testing.assert_allclose(batch_rel[i], relative(a[i], b[i]))


def test_compose_by_hand():
    # Robot at (1, 2) facing +y; a point 1 m ahead of it is at (1, 3).
    p = compose([1.0, 2.0, math.pi / 2], [1.0, 0.0, math.pi / 2])
    np.testing.assert_allclose(p, [1.0, 3.0, -math.pi], atol=1e-12)


@given(pose)
def test_transform_points_matches_rotation_matrix(p):
    pts = np.array([[1.0, 0.0], [0.0, 2.0], [-3.0, 0.5]])
    expected = pts @ rotation_matrix(p[2]).T + p[:2]
    np.testing.assert_allclose(transform_points(p, pts), expected, atol=1e-9)
    # A point transformed like a pose's position.
    q = compose(p, [pts[2, 0], pts[2, 1], 0.0])
    np.testing.assert_allclose(transform_points(p, pts)[2], q[:2], atol=1e-9)


def test_pose_shape_is_checked():
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        compose([1, 2], [1, 2, 3])


def frame(ranges, **kw):
    args = dict(stamp=0.0, ranges=ranges, angle_min=-math.pi / 2,
                angle_increment=math.pi / 2, max_range=8.0)
    args.update(kw)
    return ScanFrame(**args)


def test_scan_frame_marks_no_return_explicitly():
    f = frame([1.0, np.inf, 2.0])
    assert f.returned.tolist() == [True, False, True]
    np.testing.assert_allclose(f.free_ranges(), [1.0, 8.0, 2.0])
    np.testing.assert_allclose(f.points(), [[0.0, -1.0], [0.0, 2.0]], atol=1e-12)
    np.testing.assert_allclose(f.angles, [-math.pi / 2, 0.0, math.pi / 2])
    assert f.num_beams == 3


def test_scan_points_are_the_ranges_along_each_scanners_beams():
    # The beams' directions are kept per scanner: frames of two scanners, in turn, each get
    # their own, to the bit as worked out from the angles.
    rng = np.random.default_rng(3)
    for _ in range(3):
        for n, start, step in ((181, -math.pi / 2, math.pi / 180), (7, -1.0, 0.3)):
            ranges = rng.uniform(0.1, 7.9, n)
            ranges[rng.random(n) < 0.2] = np.inf
            f = frame(ranges, angle_min=start, angle_increment=step)
            a = f.angles[f.returned]
            r = f.ranges[f.returned]
            want = np.stack([r * np.cos(a), r * np.sin(a)], axis=-1)
            got = f.points()
            assert got.shape == want.shape and np.array_equal(got, want)
            got[:] = 0.0  # the caller's to change: the next frame's points are not
    assert frame([np.inf, np.inf, np.inf]).points().shape == (0, 2)


@pytest.mark.parametrize(
    "ranges, message",
    [([1.0, np.nan], "NaN"), ([1.0, 0.0], "positive"), ([1.0, -2.0], "positive"),
     ([1.0, 9.0], "max_range"), ([], "non-empty")],
)
def test_scan_frame_rejects_bad_ranges(ranges, message):
    with pytest.raises(ValueError, match=message):
        frame(ranges)


def test_scan_frame_is_immutable_and_checks_poses():
    f = frame([1.0, 2.0], odom=[0, 0, 0])
    with pytest.raises(ValueError):
        f.ranges[0] = 3.0
    with pytest.raises(ValueError, match="odom"):
        frame([1.0], odom=[0, np.nan, 0])


def test_interpolate_pose_between_around_and_outside():
    from vmp.types import interpolate_pose

    stamps = [0.0, 2.0]
    poses = [[0.0, 0.0, 3.0], [2.0, 4.0, -3.0]]
    mid = interpolate_pose(stamps, poses, 1.0)
    assert mid[:2].tolist() == [1.0, 2.0] and abs(abs(mid[2]) - np.pi) < 1e-9  # through pi
    assert interpolate_pose(stamps, poses, -1.0).tolist() == poses[0]
    assert interpolate_pose(stamps, poses, 5.0).tolist() == poses[1]
    assert interpolate_pose([], np.zeros((0, 3)), 1.0) is None


def _sampled_covariance(f, samples):
    out = np.array([f(x) for x in samples])
    mean = out.mean(axis=0)
    d = out - mean
    d[:, 2] = wrap_angle(d[:, 2])
    return d.T @ d / (len(out) - 1)


def test_compose_and_inverse_covariances_match_sampling():
    """First-order propagation agrees with the spread of sampled poses (small noise), and a
    spread along one frame's x turns with the heading (as the handover edge needs it)."""
    rng = np.random.default_rng(3)
    a, b = np.array([2.0, -1.0, 1.1]), np.array([1.5, 0.4, -0.7])
    cov_a = np.diag([0.02, 0.01, 0.004]) ** 2
    cov_b = np.array([[3e-4, 1e-4, 0.0], [1e-4, 2e-4, 2e-5], [0.0, 2e-5, 1e-5]])
    n = 20000
    sa = a + rng.multivariate_normal(np.zeros(3), cov_a, n)
    sb = b + rng.multivariate_normal(np.zeros(3), cov_b, n)
    mc = _sampled_covariance(lambda x: compose(x[0], x[1]), zip(sa, sb, strict=True))
    np.testing.assert_allclose(compose_covariance(a, cov_a, b, cov_b), mc, rtol=0.08,
                               atol=2e-6)
    mc_inv = _sampled_covariance(inverse, sb)
    np.testing.assert_allclose(inverse_covariance(b, cov_b), mc_inv, rtol=0.08, atol=2e-6)
    # Doubt along b's own x only, seen from a frame turned by 90 degrees: it lies along y.
    turned = compose_covariance(np.array([0.0, 0.0, math.pi / 2]), np.zeros((3, 3)),
                                np.zeros(3), np.diag([1.0, 0.0, 0.0]))
    np.testing.assert_allclose(turned, np.diag([0.0, 1.0, 0.0]), atol=1e-12)
    np.testing.assert_allclose(rotate_covariance(np.diag([1.0, 0.0, 0.0]), math.pi / 2), turned,
                               atol=1e-12)
    back = rotate_covariance(rotate_covariance(cov_b, 0.8), -0.8)
    np.testing.assert_allclose(back, cov_b, atol=1e-15)


def test_the_widest_variance_is_the_larger_eigenvalue_of_the_position_block():
    rng = np.random.default_rng(7)
    for _ in range(200):
        a = rng.normal(size=(3, 3)) * rng.uniform(1e-4, 10.0)
        cov = a @ a.T
        want = np.linalg.eigvalsh(cov[:2, :2])[-1]
        assert math.isclose(widest_variance(cov), want, rel_tol=1e-12, abs_tol=1e-15)
    assert widest_variance(np.diag([0.5, 2.0, 9.0])) == 2.0  # the heading's is not a position's
    assert widest_variance(np.zeros((3, 3))) == 0.0
    assert widest_variance(np.diag([-1e-18, -2e-18, 0.0])) == 0.0  # rounding's, not a variance


def test_one_pose_takes_the_same_bits_as_the_arrays():
    """A single pose is composed in Python floats (a third of the time), to the bit what the
    arrays' path gives, headings at and around +-pi included; a heading that is not finite
    gives NaNs there too, not an error."""
    rng = np.random.default_rng(9)
    a = rng.uniform(-50, 50, (20000, 3))
    b = rng.uniform(-50, 50, (20000, 3))
    a[::7, 2] = rng.choice([math.pi, -math.pi, 0.0, math.pi / 2, 3 * math.pi,
                            np.nextafter(math.pi, 0)], len(a[::7]))
    b[::5, 2] = rng.choice([math.pi, -math.pi, 2 * math.pi], len(b[::5]))
    batch = compose(a, b), relative(a, b), inverse(a)
    one = (np.array([compose(p, q) for p, q in zip(a, b, strict=True)]),
           np.array([relative(p, q) for p, q in zip(a, b, strict=True)]),
           np.array([inverse(p) for p in a]))
    for got, want in zip(one, batch, strict=True):
        assert np.array_equal(got, want)
    with np.errstate(invalid="ignore"):
        assert np.isnan(compose([0.0, 0.0, math.inf], [1.0, 0.0, 0.0])).all()
        assert np.isnan(inverse([1.0, 0.0, math.nan])).all()


def test_the_widest_direction_is_the_eigenvector_of_the_widest_variance():
    rng = np.random.default_rng(7)
    for _ in range(200):
        a = rng.normal(size=(3, 3)) * rng.uniform(1e-4, 10.0)
        cov = a @ a.T
        want = np.linalg.eigh(cov[:2, :2])[1][:, -1]
        got = widest_direction(cov)
        assert math.isclose(np.linalg.norm(got), 1.0, rel_tol=1e-12)
        assert math.isclose(abs(got @ want), 1.0, rel_tol=1e-9)  # either sign
    np.testing.assert_allclose(abs(widest_direction(np.diag([0.5, 2.0, 9.0]))), [0.0, 1.0],
                               atol=1e-15)  # along y, whatever the heading's variance
