"""The saved map's scans as views of the places along its path (:mod:`vmp.views`)."""

from __future__ import annotations

import math

import numpy as np
from conftest import mapped

from vmp.mapfile import MapData
from vmp.types import compose
from vmp.views import SavedViews


def _views() -> tuple[SavedViews, np.ndarray, np.ndarray]:
    """The warehouse's saved map as views, its scan poses and its scans' ranges."""
    r = mapped("warehouse")
    p = r.pipeline
    saved = MapData(p.map, p.milestones, p.back.graph, {}, r.stamps, r.trajectory)
    ranges = np.array([f.ranges for f in saved.frames()])
    return SavedViews(p.map, r.trajectory), r.trajectory, ranges


def test_a_stored_scan_agrees_with_its_own_view_and_not_with_the_bay_along_the_aisle():
    views, poses, ranges = _views()
    # A scan in the middle aisle, facing along it (the simulated warehouse's rack rows run
    # east-west; its bays are 2.5 m long and look alike by their end points).
    k = int(np.argmin(np.hypot(poses[:, 0] - 33.5, poses[:, 1] - 3.0)
                      + np.abs(np.angle(np.exp(1j * poses[:, 2])))))
    assert abs(poses[k, 2]) < math.radians(10) and np.hypot(*(poses[k, :2] - [33.5, 3.0])) < 0.5
    wrong, known = views.disagreement(ranges[k], poses[k])
    assert known >= 0.9 * ranges.shape[1] and wrong == 0
    for along in (-5.0, -2.5, 2.5, 5.0):
        wrong, known = views.disagreement(ranges[k], compose(poses[k], [along, 0.0, 0.0]))
        assert known >= 0.5 * ranges.shape[1], f"no view {along} m along the aisle"
        assert wrong / known > 0.03, f"the bay {along} m along looks the same"


def test_a_place_the_map_never_saw_has_no_view():
    views, poses, ranges = _views()
    assert views.disagreement(ranges[0], poses[0] + [100.0, 100.0, 0.0]) == (0, 0)
    # On the path but facing the other way: the stored scans there look elsewhere.
    assert views.disagreement(ranges[0], compose(poses[0], [0.0, 0.0, math.pi])) == (0, 0)
