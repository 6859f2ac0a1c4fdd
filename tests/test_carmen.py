"""The CARMEN log the simulator records, line by line and read back."""

import math

import numpy as np
import pytest

from drivers.carmen import read_carmen, write_carmen
from drivers.scenario import load_scenario, parse_scenario
from drivers.simulator import Simulator
from vmp.errors import InputError


def test_every_flaser_line_holds_what_it_declares(tmp_path):
    sim = Simulator(load_scenario("office"), max_scans=150)
    out = tmp_path / "run.clf"
    assert write_carmen(out, sim) == 150
    flaser = odom = 0
    for line in out.read_text().splitlines():
        parts = line.split()
        if parts[0] == "FLASER":
            n = int(parts[1])
            assert len(parts) == 2 + n + 9, line[:60]
            [float(v) for v in parts[2:2 + n + 6]]
            flaser += 1
        elif parts[0] == "ODOM":
            assert len(parts) == 10
            odom += 1
        else:
            assert parts[0] in ("#", "PARAM")
    assert flaser == odom == 150


def test_round_trip_keeps_ranges_poses_and_no_returns(tmp_path):
    sim = Simulator(load_scenario("warehouse"), max_scans=60)
    frames = list(sim)
    out = tmp_path / "w.clf"
    write_carmen(out, frames)
    back = list(read_carmen(out))
    assert len(back) == len(frames)
    for a, b in zip(frames, back, strict=True):
        assert b.num_beams == a.num_beams
        assert math.isclose(b.angle_min, a.angle_min, abs_tol=1e-12)
        assert math.isclose(b.angle_increment, a.angle_increment, abs_tol=1e-12)
        np.testing.assert_array_equal(np.isinf(b.ranges), np.isinf(a.ranges))
        ok = np.isfinite(a.ranges)
        np.testing.assert_allclose(b.ranges[ok], a.ranges[ok], atol=5e-4)
        np.testing.assert_allclose(b.odom, a.odom, atol=1e-6)
        assert math.isclose(b.stamp, a.stamp, abs_tol=1e-6)
    assert any(np.isinf(a.ranges).any() for a in frames)  # no-returns were exercised


def test_other_geometry_is_written_as_robotlaser1(tmp_path):
    doc = {"walls": [{"polygon": [[0, 0], [4, 0], [4, 4], [0, 4]]}],
           "trajectory": {"waypoints": [[1, 1], [3, 1]]},
           "sensor": {"beams": 240, "angle_min_deg": -120, "angle_increment_deg": 1}}
    frames = list(Simulator(parse_scenario(doc, "wide"), max_scans=5))
    out = tmp_path / "wide.clf"
    write_carmen(out, frames)
    assert "ROBOTLASER1" in out.read_text()
    back = list(read_carmen(out))
    assert math.isclose(back[0].angle_min, math.radians(-120), abs_tol=1e-8)
    np.testing.assert_allclose(back[0].ranges, frames[0].ranges, atol=5e-4)


def test_a_short_line_names_file_and_line(tmp_path):
    p = tmp_path / "bad.clf"
    p.write_text("# comment\nFLASER 3 1.0 2.0 0 0 0 0 0 0 1.0 host 1.0\n")
    with pytest.raises(InputError, match=r"bad\.clf:2: .*declares 3 ranges but holds 2"):
        list(read_carmen(p))


def test_a_failed_write_leaves_no_file(tmp_path):
    out = tmp_path / "broken.clf"

    def frames():
        yield from Simulator(load_scenario("lab"), max_scans=3)
        raise RuntimeError("source died")

    with pytest.raises(RuntimeError):
        write_carmen(out, frames())
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []
