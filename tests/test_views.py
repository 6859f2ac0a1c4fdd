"""The saved map's scans as views of the places along its path (:mod:`vmp.views`)."""

from __future__ import annotations

import math

import numpy as np
from conftest import mapped

from vmp.mapfile import MapData
from vmp.types import BeamGeometry, compose
from vmp.vector_map import VectorMap
from vmp.views import SavedViews


def _views() -> tuple[SavedViews, np.ndarray, np.ndarray]:
    """The warehouse's saved map as views, its scan poses and its scans' ranges."""
    r = mapped("warehouse")
    p = r.pipeline
    saved = MapData(p.map, p.milestones, p.back.graph, {}, r.stamps, r.trajectory)
    ranges = np.array([f.ranges for f in saved.frames()])
    return SavedViews(p.map, r.trajectory), r.trajectory, ranges


def _one(views: SavedViews, ranges: np.ndarray, pose: np.ndarray) -> tuple[int, int]:
    """The beams one live scan's view from one place contradicts, and those it knows."""
    wrong, known = views.disagreements(ranges[None], np.asarray(pose)[None])[0]
    return int(wrong), int(known)


def test_a_stored_scan_agrees_with_its_own_view_and_not_with_the_bay_along_the_aisle():
    views, poses, ranges = _views()
    # A scan in the middle aisle, facing along it (the simulated warehouse's rack rows run
    # east-west; its bays are 2.5 m long and look alike by their end points).
    k = int(np.argmin(np.hypot(poses[:, 0] - 33.5, poses[:, 1] - 3.0)
                      + np.abs(np.angle(np.exp(1j * poses[:, 2])))))
    assert abs(poses[k, 2]) < math.radians(10) and np.hypot(*(poses[k, :2] - [33.5, 3.0])) < 0.5
    wrong, known = _one(views, ranges[k], poses[k])
    assert known >= 0.9 * ranges.shape[1] and wrong == 0
    for along in (-5.0, -2.5, 2.5, 5.0):
        wrong, known = _one(views, ranges[k], compose(poses[k], [along, 0.0, 0.0]))
        assert known >= 0.5 * ranges.shape[1], f"no view {along} m along the aisle"
        assert wrong / known > 0.03, f"the bay {along} m along looks the same"


def test_a_place_the_map_never_saw_has_no_view():
    views, poses, ranges = _views()
    assert _one(views, ranges[0], poses[0] + [100.0, 100.0, 0.0]) == (0, 0)
    # On the path but facing the other way: the stored scans there look elsewhere.
    assert _one(views, ranges[0], compose(poses[0], [0.0, 0.0, math.pi])) == (0, 0)


def _one_scan_views(geometry: BeamGeometry, ranges: np.ndarray) -> SavedViews:
    """Views of a map of one scan, taken at the origin facing along x."""
    vm = VectorMap(geometry)
    vm.new_segment(0)
    vm.insert(ranges, np.zeros(3))
    return SavedViews(vm, np.zeros((1, 3)))


def test_a_beam_is_compared_with_its_neighbours_view_around_the_circle_only_where_there_is_one():
    """A live beam agrees with the view in its bearing or one beam either side. The first and
    last beams of a scanner that sweeps 180 degrees are no neighbours; those of one that
    sweeps the whole circle are."""
    stored = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    live = stored[[4, 1, 2, 3, 0]]  # the ends swapped: each reads what the other end saw
    half = BeamGeometry(5, -math.pi / 2, math.pi / 4, 8.0)
    assert _one(_one_scan_views(half, stored), live, np.zeros(3)) == (2, 5)
    circle = BeamGeometry(5, 0.0, 2 * math.pi / 5, 8.0)
    assert _one(_one_scan_views(circle, stored), live, np.zeros(3)) == (0, 5)


def test_many_places_are_looked_at_in_one_call_as_one_at_a_time():
    views, poses, ranges = _views()
    rng = np.random.default_rng(1)
    picked = rng.choice(len(poses), 40, replace=False)
    places = poses[picked] + rng.normal(0.0, [0.3, 0.3, 0.2], (40, 3))
    one_by_one = [_one(views, ranges[k], p) for k, p in zip(picked, places, strict=True)]
    together = views.disagreements(ranges[picked], places)
    assert [tuple(v) for v in together.tolist()] == one_by_one
    assert (together[:, 1] == 0).any() and (together[:, 1] > 0).any()  # some have no view
