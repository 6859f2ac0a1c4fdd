"""The vector map: scan polygons in segments anchored at milestones, re-anchoring, spreading."""

import math

import numpy as np
import shapely

from vmp.types import BeamGeometry
from vmp.vector_map import VectorMap

SICK = BeamGeometry(181, -math.pi / 2, math.radians(1), 8.0)


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
    r[59], r[120] = 3.0, 2.5  # the frame of a window: what the scanner saw beside the gap
    vm.insert(r, np.zeros(3))
    vm.insert(r, np.zeros(3), free_range=0.0)  # a sensor whose no-return may be an error
    vm.insert(np.full(181, np.inf), np.zeros(3))  # nothing within range anywhere
    polys = vm.polygons(vm.world_poses(np.zeros((1, 3))))
    reach = np.hypot(polys[..., 0], polys[..., 1])
    beams = slice(61, 121)  # vertex 0 is the scanner
    assert np.allclose(reach[0, beams], 3.0, atol=1e-5)  # as far as the frame, not beyond
    assert np.allclose(reach[1, beams], 0.02, atol=1e-5)  # a 2 cm fan keeps it valid
    assert np.allclose(reach[2, 1:], SICK.max_range, atol=1e-5)
    areas = shapely.area(shapely.polygons(polys))
    assert areas[1] < areas[0] < areas[2] and shapely.is_valid(shapely.polygons(polys)).all()


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


def test_spread_over_one_scan_gives_it_the_whole_correction():
    """Corrected on consecutive scans, the block is the last scan alone: it must move (left
    where it is, it would make a one-scan jump in the trajectory)."""
    vm = VectorMap(SICK)
    vm.new_segment(0)
    for x in np.arange(3):
        vm.insert(np.full(181, 3.0), [float(x), 0.0, 0.0])
    vm.spread(2, [0.0, 0.3, 0.1])
    np.testing.assert_allclose(vm.rel_poses[2], [2 * math.cos(0.1), 0.3 + 2 * math.sin(0.1),
                                                 0.1], atol=1e-12)
    np.testing.assert_allclose(vm.rel_poses[:2, 1], [0.0, 0.0], atol=1e-12)


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
