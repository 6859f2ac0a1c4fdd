"""The mapper's parts: vector map, fusion filter, registration, pose graph."""

import math
from dataclasses import replace

import numpy as np
import pytest
import shapely

from drivers.scenario import load_scenario, parse_scenario
from drivers.simulator import Simulator
from vmp.fusion import PoseFilter, pose_residual
from vmp.pose_graph import PoseGraph
from vmp.registration import Reference, RegistrationConfig, register
from vmp.types import ScanFrame, compose, relative
from vmp.vector_map import BeamGeometry, VectorMap

SICK = BeamGeometry(181, -math.pi / 2, math.radians(1), 8.0)


def frame(r):
    return ScanFrame(0.0, r, SICK.angle_min, SICK.angle_increment, SICK.max_range)


# --- vector map ----------------------------------------------------------------------------

def test_scan_polygons_are_valid_even_with_no_returns_and_odd_values():
    vm = VectorMap(SICK)
    vm.new_segment(0)
    rng = np.random.default_rng(0)
    for _ in range(50):
        r = rng.uniform(0.05, 7.9, 181)
        r[rng.random(181) < 0.3] = np.inf  # no return: free to max range, not an obstacle
        vm.insert(r, rng.normal(0, 1, 3))
    polys = shapely.polygons(vm.polygons(vm.world_poses(np.zeros((1, 3)))))
    assert shapely.is_valid(polys).all()
    assert vm.hits.sum() < 50 * 181 and vm.hits.sum() > 0


def test_a_scan_may_mark_no_free_space_along_beams_without_a_return():
    vm = VectorMap(SICK)
    vm.new_segment(0)
    r = np.full(181, 2.0)
    r[60:120] = np.inf
    vm.insert(r, np.zeros(3))
    vm.insert(r, np.zeros(3), free_range=0.0)  # a sensor whose no-return may be an error
    polys = vm.polygons(vm.world_poses(np.zeros((1, 3))))
    reach = np.hypot(polys[..., 0], polys[..., 1])
    beams = slice(61, 121)  # vertex 0 is the scanner
    assert np.allclose(reach[0, beams], SICK.max_range, atol=1e-5)
    assert np.allclose(reach[1, beams], 0.02, atol=1e-5)  # a 2 cm fan keeps it valid
    areas = shapely.area(shapely.polygons(polys))
    assert areas[1] < areas[0] and shapely.is_valid(shapely.polygons(polys)).all()


def test_full_circle_scans_make_valid_polygons_without_the_origin():
    geom = BeamGeometry(360, -math.pi, math.radians(1), 8.0)
    vm = VectorMap(geom)
    vm.new_segment(0)
    vm.insert(np.full(360, 2.0), np.zeros(3))
    poly = vm.polygons(vm.world_poses(np.zeros((1, 3))))
    assert poly.shape == (1, 360, 2)
    assert shapely.Polygon(poly[0]).is_valid
    assert math.isclose(shapely.Polygon(poly[0]).area, math.pi * 4, rel_tol=1e-3)


def test_storage_is_float32_and_under_1_5_kb_per_scan():
    vm = VectorMap(SICK)
    vm.new_segment(0)
    vm.insert(np.full(181, 3.0), np.zeros(3))
    assert vm.end_points.dtype == np.float32
    assert vm.bytes_per_scan <= 1536


def test_moving_a_milestone_moves_its_segment():
    vm = VectorMap(SICK)
    vm.new_segment(0)
    vm.insert(np.full(181, 3.0), [1.0, 0.0, 0.0])
    vm.new_segment(1, handover=None)
    vm.insert(np.full(181, 3.0), [0.5, 0.0, 0.0])
    anchors = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]])
    np.testing.assert_allclose(vm.world_poses(anchors), [[1, 0, 0], [5.5, 0, 0]], atol=1e-12)
    anchors[1] = [5.0, 2.0, math.pi / 2]
    np.testing.assert_allclose(vm.world_poses(anchors)[1], [5.0, 2.5, math.pi / 2], atol=1e-12)
    np.testing.assert_allclose(vm.world_poses(anchors)[0], [1, 0, 0], atol=1e-12)


def test_spread_bends_the_scans_since_the_last_correction():
    vm = VectorMap(SICK)
    vm.new_segment(0)
    for x in np.arange(5):
        vm.insert(np.full(181, 3.0), [float(x), 0.0, 0.0])
    vm.spread(1, [0.0, 0.4, 0.0])  # the last scan is 0.4 m too far right
    y = vm.rel_poses[:, 1]
    np.testing.assert_allclose(y, [0.0, 0.0, 0.4 / 3, 0.8 / 3, 0.4], atol=1e-12)


def test_closed_segment_hangs_between_its_two_milestones():
    vm = VectorMap(SICK)
    vm.new_segment(0)
    for x in (0.0, 0.5, 1.0, 1.5):
        vm.insert(np.full(181, 3.0), [x, 0.0, 0.0])
    vm.new_segment(1, handover=[2.0, 0.0, 0.0])
    vm.insert(np.full(181, 3.0), [0.0, 0.0, 0.0])
    # The graph moved milestone 1 up by 0.2 m: the segment bends to meet it.
    poses = vm.world_poses(np.array([[0.0, 0.0, 0.0], [2.0, 0.2, 0.0]]))
    np.testing.assert_allclose(poses[:4, 1], [0.0, 0.05, 0.1, 0.15], atol=1e-9)
    np.testing.assert_allclose(poses[4], [2.0, 0.2, 0.0], atol=1e-12)


# --- fusion ----------------------------------------------------------------------------------

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


# --- registration ------------------------------------------------------------------------------

def test_registration_recovers_a_known_motion():
    sim = Simulator(load_scenario("office"))
    rng = np.random.default_rng(4)
    errors = []
    for i in range(0, 1000, 50):
        a = sim.true_poses[i]
        b = a + [rng.normal(0, 0.2), rng.normal(0, 0.2), rng.normal(0, 0.05)]
        r = sim.ranges_at(np.vstack([a, b]), rng=rng)
        reg = register(Reference(frame(r[0]).points()), frame(r[1]).points(),
                       relative(a, b) + [0.1, -0.1, 0.03])
        e = relative(relative(a, b), reg.pose)
        errors.append((math.hypot(e[0], e[1]), abs(e[2])))
    errors = np.array(errors)
    assert np.median(errors[:, 0]) < 0.01 and np.median(errors[:, 1]) < math.radians(0.2)


def test_a_corridor_leaves_its_axis_unconstrained():
    doc = {"walls": [{"polyline": [[-50, -1], [50, -1]]}, {"polyline": [[-50, 1], [50, 1]]}],
           "trajectory": {"waypoints": [[0, 0], [1, 0]]}, "sensor": {"range_noise": 0.0}}
    sim = Simulator(parse_scenario(doc, "corridor"))
    r = sim.ranges_at(np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0]]))
    reg = register(Reference(frame(r[0]).points()), frame(r[1]).points(), np.zeros(3))
    sx, sy = np.sqrt(np.diag(reg.covariance)[:2])
    assert sx > 10.0 and sy < 0.02  # nothing along the walls, much across them


def test_corner_points_find_the_position_along_a_rack_aisle():
    """Between two rows of pallets the faces leave the aisle's axis free; the rack uprights
    matched point to point find it (the warehouse's milestones, issue 4)."""
    sim = Simulator(load_scenario("warehouse"))
    rng = np.random.default_rng(2)
    lines_only = replace(RegistrationConfig(), corner_weight=0.0)
    err_lines, err_corners, used = [], [], []
    for x in np.arange(12.0, 34.0, 0.7):  # the middle aisle, driven towards -x
        a = np.array([x, 11.0, math.pi])
        b = a + [-0.3, 0.0, 0.0]
        r = sim.ranges_at(np.vstack([a, b]), rng=rng)
        ref = Reference(frame(r[0]).points())
        guess = relative(a, b) + [0.15, 0.0, 0.0]  # 15 cm off along the aisle
        lines = register(ref, frame(r[1]).points(), guess, lines_only)
        assert math.sqrt(lines.covariance[0, 0]) > 10.0  # the axis is free for lines
        both = register(ref, frame(r[1]).points(), guess)
        err_lines.append(abs(relative(relative(a, b), lines.pose)[0]))
        err_corners.append(abs(relative(relative(a, b), both.pose)[0]))
        used.append(both.by_corners)
    assert all(used)
    # Lines alone leave a fifth of the fits 10 cm off (measured 0.097 m); corners 2 cm.
    p80_lines, p80_corners = np.percentile(err_lines, 80), np.percentile(err_corners, 80)
    assert p80_corners < 0.03 < p80_lines, (p80_lines, p80_corners)
    assert np.mean(err_corners) < 0.7 * np.mean(err_lines)


def test_corners_are_not_used_where_lines_constrain_everything():
    sim = Simulator(load_scenario("office"))
    rng = np.random.default_rng(5)
    a = sim.true_poses[300]
    b = a + [0.1, 0.05, 0.02]
    r = sim.ranges_at(np.vstack([a, b]), rng=rng)
    reg = register(Reference(frame(r[0]).points()), frame(r[1]).points(), relative(a, b))
    assert not reg.by_corners and np.sqrt(np.diag(reg.covariance)).max() < 0.05


def test_unrelated_scans_fit_poorly():
    sim = Simulator(load_scenario("office"))
    r = sim.ranges_at(np.array([[6.0, 6.0, 0.0], [6.0, 10.5, math.pi / 2]]))
    reg = register(Reference(frame(r[0]).points()), frame(r[1]).points(), np.zeros(3))
    assert reg.inliers < 0.5 or reg.rms > 0.05


# --- pose graph -----------------------------------------------------------------------------

def test_loop_closure_spreads_the_drift_and_keeps_node_zero():
    true = np.array([[0, 0, 0], [4, 0, math.pi / 2], [4, 4, math.pi], [0, 4, -math.pi / 2]],
                    dtype=float)
    g = PoseGraph()
    drifted = [true[0]]
    for a in range(3):
        z = relative(true[a], true[a + 1]) + [0.0, 0.0, 0.02]  # a heading bias per edge
        g.add(a, a + 1, z, np.diag([1e-4, 1e-4, 1e-4]), "path")
        drifted.append(compose(drifted[-1], z))
    g.add(3, 0, relative(true[3], true[0]), np.diag([1e-4, 1e-4, 1e-4]), "loop")
    drifted = np.array(drifted)
    fixed = g.optimize(drifted)
    err_before = np.hypot(*(drifted[:, :2] - true[:, :2]).T).max()
    err_after = np.hypot(*(fixed[:, :2] - true[:, :2]).T).max()
    assert err_after < err_before / 3
    np.testing.assert_array_equal(fixed[0], drifted[0])
    assert g.chi2(fixed) < g.chi2(drifted) / 10
    assert g.marginals is not None and np.all(g.marginals[0] == 0)


@pytest.mark.parametrize("kind", ["path", "loop"])
def test_edge_kinds(kind):
    g = PoseGraph()
    assert g.add(0, 1, np.zeros(3), np.eye(3), kind).kind == kind
    with pytest.raises(ValueError):
        g.add(0, 1, np.zeros(3), np.eye(3), "teleport")


def test_marginals_equal_the_dense_inverse_blocks():
    from scipy.sparse import csr_matrix
    from scipy.sparse import random as sparse_random

    from vmp.pose_graph import _marginals

    n = 40
    m = 3 * (n - 1)
    J = sparse_random(200, m, density=0.05, random_state=2) + csr_matrix(np.eye(200, m))
    cov = np.linalg.inv((J.T @ J).toarray() + np.eye(m) * 1e-9)
    got = _marginals(J, n, block=7)  # blocks that do not divide the node count
    idx = np.arange(n - 1)[:, None] * 3 + np.arange(3)
    np.testing.assert_allclose(got[1:], cov[idx[:, :, None], idx[:, None, :]], atol=1e-10)
    assert np.all(got[0] == 0)


def _room_scan(x: float) -> np.ndarray:
    """End points seen from (x, 0, 0) in a square room with walls 3 m from the origin."""
    angles = np.linspace(-math.pi, math.pi, 360, endpoint=False)
    r = np.full(angles.size, np.inf)
    for normal in (0.0, math.pi / 2, math.pi, -math.pi / 2):
        dist = 3.0 - x * math.cos(normal)
        cos = np.cos(angles - normal)
        with np.errstate(divide="ignore"):
            r = np.minimum(r, np.where(cos > 1e-6, dist / cos, np.inf))
    return np.stack([r * np.cos(angles), r * np.sin(angles)], axis=-1)


def test_scan_odometry_submap_holds_recent_keyframes_in_the_latest_frame():
    from vmp.fusion import MotionNoise
    from vmp.registration import RegistrationConfig
    from vmp.scan_odometry import ScanOdometry, ScanOdometryConfig

    odo = ScanOdometry(ScanOdometryConfig(submap_keyframes=3, keyframe_distance=0.25),
                       RegistrationConfig(), MotionNoise())
    odo.increment(_room_scan(0.0), None)
    for k in range(1, 12):  # the robot drives 0.1 m a step along x
        u, _ = odo.increment(_room_scan(0.1 * k), np.array([0.1, 0.0, 0.0]))
        np.testing.assert_allclose(u, [0.1, 0.0, 0.0], atol=2e-3)
    assert len(odo._keys) == 3  # the submap holds the last three keyframes
    newest = odo._keys[-1][0]
    assert all(relative(newest, pose)[0] < 0 for pose, _ in odo._keys[:-1])  # behind it


def test_turning_on_the_spot_may_carry_translation_noise():
    from vmp.fusion import MotionNoise, motion_covariance

    turn = np.array([0.0, 0.0, math.pi / 2])
    plain = motion_covariance(turn, MotionNoise())
    keyframes = motion_covariance(turn, MotionNoise(trans_per_rad=0.02))
    assert plain[0, 0] == pytest.approx(MotionNoise().floor_xy ** 2)
    assert keyframes[0, 0] == pytest.approx(0.02**2 * math.pi / 2 + MotionNoise().floor_xy**2)


def test_wheel_noise_adapts_when_the_wheels_disagree_with_good_registrations():
    from vmp.fusion import MotionNoise
    from vmp.registration import RegistrationConfig
    from vmp.scan_odometry import ScanOdometry, ScanOdometryConfig

    rng = np.random.default_rng(4)
    odo = {on: ScanOdometry(ScanOdometryConfig(adapt_noise=on, calibrate=False),
                            RegistrationConfig(), MotionNoise()) for on in (False, True)}
    for o in odo.values():
        o.increment(_room_scan(0.0), None)
    x = 0.0
    for _ in range(40):  # the wheels err by several cm a step, far beyond the model
        x += 0.02
        wheel = np.array([0.02 + rng.normal(0, 0.04), rng.normal(0, 0.04), 0.0])
        for o in odo.values():
            o.increment(_room_scan(x), wheel)
    assert odo[False].noise_scale.tolist() == [1.0, 1.0]
    assert odo[True].noise_scale[0] > 5.0  # the xy variance was scaled up from the data
