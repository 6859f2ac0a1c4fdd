"""The delay of scan stamps behind the odometry, learned from registered turns."""

import math

import numpy as np
import pytest

from vmp.latency import Latency
from vmp.types import wrap_angle


def _drive(delay: float, scans: int = 400, period: float = 0.2, burst: bool = False):
    """A robot weaving (turn rate varying in time); each scan is taken at ``k * period`` and
    stamped ``delay`` later, its odometry read at the stamp. Yields (stamp, odometry, the
    registered turn since the scan before: the true one)."""
    rng = np.random.default_rng(3)

    def heading(t):
        return 0.8 * math.sin(0.9 * t) + 0.3 * math.sin(2.3 * t)

    def odometry(t):
        return np.array([0.3 * t, 0.0, heading(t)])

    for k in range(scans):
        taken = k * period + (rng.uniform(0, 0.001) if burst and k % 2 else 0.0)
        stamp = taken + delay if not burst else (k // 2) * 2 * period + delay + 1e-4 * (k % 2)
        turn = heading(taken) - heading(taken - period) + rng.normal(0, math.radians(0.1))
        yield stamp, odometry(stamp), turn


def _learn(delay: float, **kw) -> Latency:
    lat = Latency()
    before = None
    for stamp, odom, turn in _drive(delay, **kw):
        lat.odometry(stamp, odom)
        if before is not None:
            lat.registered(before, stamp, turn)
        before = stamp
    return lat


@pytest.mark.parametrize("delay", [0.05, 0.1, 0.17])
def test_a_delay_is_learned_from_the_turns(delay):
    lat = _learn(delay)
    assert lat.fits > 0
    assert lat.latency == pytest.approx(delay, abs=0.011)


def test_no_delay_stays_none():
    assert _learn(0.0).latency == 0.0


def test_stamps_that_do_not_increase_say_nothing():
    # The Intel recording's bursts: pairs of scans stamped 0.1 ms apart.
    lat = _learn(0.1, burst=True)
    assert lat.latency == 0.0 and lat.fits == 0


def test_the_odometry_at_the_time_the_scan_was_taken():
    lat = Latency()
    lat.odometry(1.0, np.array([0.0, 0.0, 3.0]))
    lat.odometry(1.2, np.array([0.2, 0.1, -3.0]))  # the heading wraps past pi
    assert lat.at(1.2) is not None and np.allclose(lat.at(1.2), [0.2, 0.1, -3.0])
    lat.latency = 0.05
    got = lat.at(1.2)
    assert np.allclose(got[:2], [0.15, 0.075])
    assert got[2] == pytest.approx(float(wrap_angle(3.0 + 0.75 * (2 * math.pi - 6.0))))
    lat.latency = 0.3  # before the history
    assert lat.at(1.2) is None


def test_turns_without_odometry_fit_nothing():
    """A source without odometry (a live scanner with no pose feed) still registers its scans:
    the turns alone say nothing about a delay."""
    lat = Latency()
    for k in range(200):
        lat.registered(0.1 * k, 0.1 * (k + 1), 0.05)
    assert lat.latency == 0.0 and lat.fits == 0


def test_one_sample_does_not_reach_back():
    """With a single odometry sample, a time after it (within rounding) or before it has no
    odometry to interpolate: None, never a pose of NaNs (two samples at the same stamp)."""
    lat = Latency()
    lat.latency = 0.1
    lat.odometry(5.0, np.array([1.0, 2.0, 0.5]))
    assert lat.at(5.1 + 1e-10) is None
    assert lat.at(5.05) is None
    lat.odometry(5.2, np.array([2.0, 2.0, 0.5]))
    np.testing.assert_allclose(lat.at(5.2), [1.5, 2.0, 0.5])
