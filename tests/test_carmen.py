"""The CARMEN log the simulator records, line by line and read back."""

import dataclasses
import math

import numpy as np
import pytest

from drivers.carmen import read_carmen
from drivers.carmen_writer import write_carmen
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


def test_scans_sharing_a_stamp_keep_each_its_own_odometry(tmp_path):
    # A live run stamps the scans that arrive in one read alike, each with the odometry the
    # pose feed gave it; its replay must see the same (not the first one's for all).
    frames = list(Simulator(load_scenario("office"), max_scans=80))
    frames[40:43] = [dataclasses.replace(f, stamp=frames[40].stamp) for f in frames[40:43]]
    out = tmp_path / "live.clf"
    write_carmen(out, frames)
    back = list(read_carmen(out))
    for a, b in zip(frames, back, strict=True):
        np.testing.assert_allclose(b.odom, a.odom, atol=1e-6)


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
        list(read_carmen(p, strict=True))
    assert list(read_carmen(p)) == []  # skipped by default


def test_a_failed_write_leaves_no_file(tmp_path):
    out = tmp_path / "broken.clf"

    def frames():
        yield from Simulator(load_scenario("lab"), max_scans=3)
        raise RuntimeError("source died")

    with pytest.raises(RuntimeError):
        write_carmen(out, frames())
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


GOOD = "FLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 {t} host {t}\n"


def log_with(tmp_path, bad_line, name="bad.clf"):
    p = tmp_path / name
    p.write_text(GOOD.format(t=1.0) + bad_line + GOOD.format(t=3.0))
    return p


@pytest.mark.parametrize("bad_line, what", [
    ("FLASER 5 1.0 2.0 3.0 0 0 0 0 0 0 2.0 host 2.0\n", "declares 5 ranges but holds 3"),
    ("FLASER 3 1.0 2.0 3.0 0 nan 0 0 0 0 2.0 host 2.0\n", "the pose is not finite"),
    ("FLASER 3 1.0 -2.0 3.0 0 0 0 0 0 0 2.0 host 2.0\n", "a range is negative"),
    ("FLASER 3 1.0 nan 3.0 0 0 0 0 0 0 2.0 host 2.0\n", "a range is NaN"),
    ("FLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 2.0 host\n", "declares 3 ranges but holds 2"),
])
def test_a_bad_line_is_skipped_counted_and_reported_or_stops_strict(tmp_path, bad_line, what):
    from drivers.carmen import CarmenLog

    log = CarmenLog(log_with(tmp_path, bad_line))
    frames = list(log)
    assert [f.stamp for f in frames] == [1.0, 3.0]
    assert log.skipped == 1 and log.problems[0][0] == 2 and what in log.problems[0][1]
    assert "line 2" in log.report().summary("bad.clf")
    with pytest.raises(InputError, match=rf"bad\.clf:2: .*{what}"):
        list(CarmenLog(log_with(tmp_path, bad_line), strict=True))


def test_a_stamp_running_backwards_is_reported_and_kept(tmp_path):
    from drivers.carmen import CarmenLog

    log = CarmenLog(log_with(tmp_path, GOOD.format(t=0.5)))
    assert [f.stamp for f in log] == [1.0, 0.5, 3.0]  # kept in file order
    assert log.backwards == 1 and log.skipped == 0
    assert "runs backwards" in log.problems[0][1] and log.problems[0][0] == 2
    # --strict stops at unusable lines only: a stamp running backwards (a property of the
    # recording, the real Intel log has them) is kept and reported there too.
    strict = CarmenLog(log_with(tmp_path, GOOD.format(t=0.5)), strict=True)
    assert [f.stamp for f in strict] == [1.0, 0.5, 3.0] and strict.backwards == 1


def test_info_and_map_report_bad_lines(tmp_path, capsys):
    from vmp.cli import main

    clf = tmp_path / "lab.clf"
    assert main(["simulate", "lab", "--scans", "60", "--out", str(clf), "-q"]) == 0
    lines = clf.read_text().splitlines(keepends=True)
    k = next(i for i, ln in enumerate(lines) if ln.startswith("FLASER")) + 4
    lines.insert(k, "FLASER 181 1.0 2.0\n")  # claims 181 ranges, holds 2
    clf.write_text("".join(lines))
    assert main(["info", str(clf)]) == 0
    out = capsys.readouterr().out
    assert "scans         60" in out and "1 skipped" in out and f"line {k + 1}" in out
    assert main(["map", str(clf), "--out", str(tmp_path / "r"), "-q"]) == 0
    assert main(["map", str(clf), "--out", str(tmp_path / "r"), "-q", "--strict"]) == 2
    assert f"lab.clf:{k + 1}:" in capsys.readouterr().err
