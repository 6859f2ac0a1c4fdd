"""A logger's "no echo" written as the largest reading is found in the data and drawn as a beam
without a return, without touching what is stored."""

import math

import numpy as np

from vmp.saturation import no_echo_level
from vmp.types import BeamGeometry
from vmp.vector_map import VectorMap

LONG = BeamGeometry(180, -math.pi / 2, math.radians(1), 80.0)


def _ranges(rng: np.random.Generator, scans: int = 400, spike: float | None = 50.0,
            share: float = 0.01) -> np.ndarray:
    """Indoor-like ranges (most within 10 m, a tail to 45 m), and in ``share`` of the beams,
    in every direction, the logger's ``spike``."""
    r = np.minimum(rng.gamma(2.0, 2.0, (scans, 180)), 45.0)
    r[rng.random(r.shape) < 0.02] = np.inf  # marked as no return, as most logs do
    if spike is not None:
        r[rng.random(r.shape) < share] = spike
    return r


def test_a_spike_at_the_largest_reading_is_no_echo():
    rng = np.random.default_rng(1)
    level = no_echo_level(_ranges(rng))
    assert level is not None and 49.98 <= level <= 50.0
    assert no_echo_level(_ranges(rng, spike=51.15, share=0.06)) > 51.1


def test_long_returns_that_thin_out_are_real():
    rng = np.random.default_rng(2)
    assert no_echo_level(_ranges(rng, spike=None)) is None
    assert no_echo_level(np.full((0, 180), np.inf)) is None


def test_a_robot_standing_still_repeats_its_largest_reading_in_one_direction_only():
    rng = np.random.default_rng(3)
    r = _ranges(rng, spike=None)
    r[:, 90] = 48.0  # the far end of a corridor, seen in every scan by one beam
    assert no_echo_level(r) is None


def test_a_round_room_is_not_all_no_echo():
    assert no_echo_level(np.full((100, 180), 2.0)) is None


def test_no_echo_beams_are_drawn_as_beams_without_a_return():
    rng = np.random.default_rng(4)
    vm = VectorMap(LONG, free_range=10.0)
    vm.new_segment(0)
    scans = _ranges(rng, scans=300)
    for r in scans:
        vm.insert(r, np.zeros(3))
    silent = vm.no_echo()
    assert silent.sum() == np.count_nonzero(scans == 50.0)
    poses = vm.world_poses(np.zeros((1, 3)))
    reach = np.hypot(*vm.polygons(poses)[:, 1:].transpose(2, 0, 1))
    # As far as a beam without a return: the no-return reach, or the farther hit beside it.
    for k, j in zip(*np.nonzero(silent), strict=True):
        seen = np.isfinite(scans[k]) & ~silent[k]
        left = scans[k][:j][seen[:j]][-1:] if seen[:j].any() else np.array([])
        right = scans[k][j + 1:][seen[j + 1:]][:1] if seen[j + 1:].any() else np.array([])
        beside = np.concatenate([left, right]).max()
        assert abs(reach[k, j] - min(10.0, beside)) < 1e-4
    assert reach[~silent].max() <= 45.0 + 1e-3
    assert np.hypot(*vm.world_points(poses).T).max() <= 45.0 + 1e-3  # not an obstacle
    # What is stored, and what registration sees, stays the reading.
    assert np.allclose(np.hypot(*vm.end_points[silent].T), 50.0, atol=1e-4)
