"""Readers of the classic recordings: excerpts committed in tests/data, the whole files in
../shared/data (VMP_DATA) where present, and format detection."""

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import EXCERPTS, shared_data

from drivers.breezyslam import BreezySlamLog
from drivers.dpslam import DpSlamLog
from drivers.formats import detect_format, open_recording
from vmp.errors import InputError


def test_dpslam_excerpt():
    log = DpSlamLog(EXCERPTS / "loop5-excerpt.log.gz")
    frames = list(log)
    assert len(frames) == 20 and log.skipped == 0
    f = frames[0]
    assert f.num_beams == 181 and math.isclose(f.angle_min, -math.pi / 2)
    assert math.isclose(f.angle_increment, math.radians(1))
    np.testing.assert_allclose(f.odom, [-2.424026, 4.800517, 2.590948])
    assert math.isclose(f.ranges[0], 0.642)
    assert frames[1].stamp > frames[0].stamp


def test_dpslam_bad_lines(tmp_path):
    p = tmp_path / "bad.log"
    p.write_text("Odometry 0 0 0\nLaser 3 1 2 3\nOdometry 0 nan 0\nLaser 3 1 2 3\n"
                 "Odometry 1 0 0\nLaser 4 1 2 3\nOdometry 2 0 0\nLaser 3 1 2 3\n")
    log = DpSlamLog(p)
    assert len(list(log)) == 2
    assert [no for no, _ in log.problems] == [3, 4, 6]
    with pytest.raises(InputError, match=r"bad\.log:3: bad Odometry line"):
        list(DpSlamLog(p, strict=True))


def test_breezyslam_excerpt_ticks_to_odometry():
    log = BreezySlamLog(EXCERPTS / "exp1-excerpt.dat.gz")
    frames = list(log)
    assert len(frames) == 60 and log.skipped == 0
    f = frames[0]
    assert f.num_beams == 682 and math.isclose(f.field_of_view, math.radians(240) * 682 / 681)
    assert 0.3 < f.returned.mean() < 0.8  # zeros are no return
    assert f.no_return_free == 0.0  # and prove no free space (a URG 0 is also an error code)
    assert (f.free_ranges()[~f.returned] == 0).all()
    assert np.nanmax(f.ranges[f.returned]) < 5.6
    np.testing.assert_allclose(f.odom, [0.145, 0.0, 0.0], atol=1e-12)  # laser ahead of axle
    steps = np.hypot(*np.diff(np.array([g.odom[:2] for g in frames]), axis=0).T)
    assert steps.max() < 0.2  # a plausible 10 Hz wheel odometry, not ticks as metres
    assert math.isclose(frames[1].stamp - frames[0].stamp, 0.1, abs_tol=0.02)


@pytest.mark.parametrize("name, fmt", [
    ("intel-excerpt.clf.gz", "carmen"),
    ("fhw-excerpt.log.gz", "carmen"),
    ("killian-excerpt.g2o.zip", "carmen"),
    ("loop5-excerpt.log.gz", "dpslam"),
    ("exp1-excerpt.dat.gz", "breezyslam"),
    ("demo-excerpt.bag", "rosbag"),
])
def test_formats_are_detected_by_content(name, fmt):
    assert detect_format(EXCERPTS / name) == fmt


@pytest.mark.parametrize("relpath, fmt", [
    ("intel/intel-first5505.clf.gz", "carmen"),
    ("aces/aces.clf.gz", "carmen"),
    ("fr079/fr079.clf.gz", "carmen"),
    ("radish_gmapping_corrected/fhw-corrected.log.gz", "carmen"),
    ("dpslam_duke_loop5/loop5.log", "dpslam"),
    ("breezyslam_mines/exp1.dat", "breezyslam"),
    ("ccny_hokuyo_rosbag/demo.bag", "rosbag"),
])
def test_whole_recordings_are_detected_by_content(relpath, fmt):
    assert detect_format(shared_data(relpath)) == fmt


def test_unknown_and_broken_files_get_one_clear_error(tmp_path):
    junk = tmp_path / "notes.txt"
    junk.write_text("hello world\n")
    with pytest.raises(InputError, match="not a recording this program knows"):
        open_recording(junk)
    mcap = tmp_path / "x.mcap"
    mcap.write_bytes(b"\x89MCAP0\r\n")
    with pytest.raises(InputError, match=r"x\.mcap: cannot open as a ROS 2 bag or MCAP file"):
        open_recording(mcap)  # a truncated MCAP: one line, no traceback
    with pytest.raises(InputError, match="no such file"):
        open_recording(tmp_path / "missing.clf")


BAG = "ccny_hokuyo_rosbag/demo.bag"


def test_a_ros1_bag_excerpt_yields_its_scans():
    from drivers.rosbag import RosBagLog, bag_topics

    path = EXCERPTS / "demo-excerpt.bag"
    assert bag_topics(path) == {"/scan": ("sensor_msgs/LaserScan", 8)}
    frames = list(RosBagLog(path))
    assert len(frames) == 8 and frames[0].num_beams == 681 and frames[0].odom is None
    assert frames[0].max_range == pytest.approx(5.6)


def test_demo_bag_opens_and_yields_its_scans():
    from drivers.rosbag import RosBagLog, bag_topics

    bag = shared_data(BAG)
    assert bag_topics(bag) == {"/scan": ("sensor_msgs/LaserScan", 360)}
    log = RosBagLog(bag)
    frames = list(log)
    assert len(frames) == 360 and log.skipped == 0
    f = frames[0]
    assert f.num_beams == 681 and f.odom is None
    assert math.isclose(math.degrees(f.angle_increment * (f.num_beams - 1)), 239.1, abs_tol=0.1)
    assert f.max_range == pytest.approx(5.6)
    assert 35.0 < frames[-1].stamp - frames[0].stamp < 36.0


def test_why_rosbags_alone_cannot_open_the_demo_bag():
    """Its IndexData records claim count * 20 bytes of data but hold count * 12."""
    import struct

    from drivers.rosbag import _records

    buf = shared_data(BAG).read_bytes()
    pos = 13
    (hlen,) = struct.unpack_from("<I", buf, pos)
    (dlen,) = struct.unpack_from("<I", buf, pos + 4 + hlen)
    records = _records(buf, pos + 8 + hlen + dlen, len(buf))
    chunk, _ = next(records)
    index, data = next(records)  # the IndexData record that follows the first chunk
    assert chunk[b"op"][0] == 5 and index[b"op"][0] == 4
    (count,) = struct.unpack("<I", index[b"count"])
    assert count == 278 and len(data) == count * 20  # rosbags expects count * 12


def test_a_truncated_bag_gets_a_clear_error(tmp_path):
    from drivers.rosbag import RosBagLog

    cut = tmp_path / "cut.bag"
    cut.write_bytes(shared_data(BAG).read_bytes()[:300_000])
    with pytest.raises(InputError, match=r"cut\.bag"):
        list(RosBagLog(cut))


def test_killian_g2o_zip_reads_its_robotlaser_lines():
    from drivers.carmen import CarmenLog

    path = EXCERPTS / "killian-excerpt.g2o.zip"
    assert detect_format(path) == "carmen"
    frames = list(itertools.islice(CarmenLog(path), 30))  # lazily, straight from the zip
    assert len(frames) == 30
    f = frames[0]
    assert f.num_beams == 180 and f.max_range == 50.0
    assert math.isclose(f.angle_min, -math.pi / 2, abs_tol=1e-5)
    assert math.isclose(f.angle_increment, math.radians(1), abs_tol=1e-5)
    assert np.isfinite(f.odom).all() and frames[-1].stamp > f.stamp


def _flaser(pose, stamp):
    ranges = " ".join(["2.0"] * 181)
    p = " ".join(f"{v:g}" for v in pose)
    return f"FLASER 181 {ranges} {p} {p} {stamp} host {stamp}\n"


def _odom(pose, stamp):
    p = " ".join(f"{v:g}" for v in pose)
    return f"ODOM {p} 0 0 0 {stamp} host {stamp}\n"


def test_gmapping_log_gets_its_raw_odometry_rebuilt(tmp_path):
    """FLASER poses of a GMapping output log are corrected; ODOM lines hold the raw motion."""
    from drivers.carmen import CarmenLog

    log = tmp_path / "corrected.log"
    # keyframe 0 at the origin; the wheels then say 1 m ahead, GMapping says (1.1, 0.2).
    # keyframe 2: no dead-reckoned ODOM line before it (only GMapping's copy): unknown.
    # keyframe 3: 0.5 m ahead of keyframe 2 by the wheels.
    log.write_text(
        _odom((0, 0, 0), 0.0) + _flaser((0, 0, 0), 0.1) + _odom((0, 0, 0), 0.1) + "NEFF 30\n"
        + _odom((0.5, 0, 0), 0.5) + _odom((1.0, 0, 0), 0.9)
        + _flaser((1.1, 0.2, 0.1), 1.0) + _odom((1.1, 0.2, 0.1), 1.0) + "NEFF 29\n"
        + _flaser((2.0, 0.3, 0.1), 2.0) + _odom((2.0, 0.3, 0.1), 2.0)
        + _odom((2.0 + 0.5 * math.cos(0.1), 0.3 + 0.5 * math.sin(0.1), 0.1), 2.5)
        + _flaser((2.6, 0.4, 0.15), 3.0))
    reader = CarmenLog(log)
    frames = list(reader)
    assert reader.gmapping and reader.unknown_increments == 1
    np.testing.assert_allclose(frames[0].odom, [0, 0, 0])
    np.testing.assert_allclose(frames[1].odom, [1.0, 0, 0], atol=1e-12)  # the wheels' 1 m
    assert frames[2].odom is None
    # the chain continues from keyframe 1's odometry by keyframe 2 -> 3's raw increment
    np.testing.assert_allclose(frames[3].odom, [1.5, 0.0, 0.0], atol=1e-5)  # %g in the log
    ref = reader.reference().poses
    np.testing.assert_allclose(ref[:, 0], [0, 1.1, 2.0, 2.6])


def test_rawlaser_scans_take_odometry_interpolated_from_odom_lines(tmp_path):
    from drivers.carmen import CarmenLog

    ranges = " ".join(["2.0"] * 5)
    raw = "RAWLASER1 0 -1.5708 3.1416 0.7854 8 0.01 0 5 {r} 0 {t} host {t}\n"
    log = tmp_path / "raw.log"
    log.write_text(_odom((0, 0, 3.0), 1.0) + raw.format(r=ranges, t=1.5)
                   + raw.format(r=ranges, t=1.75) + _odom((1, 2, -3.0), 2.0)
                   + raw.format(r=ranges, t=2.5))
    frames = list(CarmenLog(log))
    assert len(frames) == 3
    np.testing.assert_allclose(frames[0].odom[:2], [0.5, 1.0])
    assert abs(abs(frames[0].odom[2]) - math.pi) < 1e-9  # the short way through pi
    np.testing.assert_allclose(frames[1].odom[:2], [0.75, 1.5])
    np.testing.assert_allclose(frames[2].odom, [1, 2, -3.0])  # after the last ODOM: it holds
    assert [f.index for f in frames] == [0, 1, 2]


def test_flaser_scans_that_copy_the_last_odom_line_are_read_at_their_stamp(tmp_path):
    """ACES's logger writes into each scan the last ODOM line's pose, up to 0.19 s older than
    the scan; such scans take the ODOM lines' pose at their own stamp. A scan whose pose lies
    between the ODOM lines (fr079's logger interpolates) keeps it, and the order of the
    scans holds."""
    from drivers.carmen import CarmenLog

    lines = ""
    for k in range(6):  # ODOM at t = k, the robot 1 m/s along x; scans at k + 0.5
        lines += _odom((k, 0, 0), float(k)) + _flaser((k, 0, 0), k + 0.5)
    lines += _flaser((5.75, 0, 0), 5.8)  # between the ODOM lines: its own pose
    lines += _odom((6, 0, 0), 6.0) + _flaser((6, 0, 0), 6.5)  # after the last ODOM: it holds
    log = tmp_path / "stale.log"
    log.write_text(lines)
    frames = list(CarmenLog(log))
    assert [f.stamp for f in frames] == [0.5, 1.5, 2.5, 3.5, 4.5, 5.5, 5.8, 6.5]
    xs = [float(f.odom[0]) for f in frames]
    # The first scans are read as written until the log is known not to be GMapping's.
    np.testing.assert_allclose(xs[3:], [3.5, 4.5, 5.5, 5.75, 6.0])


def test_flaser_scans_keep_their_pose_where_the_odom_stamps_run_backwards(tmp_path):
    """The Intel recording's ODOM lines are stamped on arrival, in bursts, some stamps running
    backwards: they do not say when their poses were taken, so scans that copy the last ODOM
    line's pose keep it rather than take the pose interpolated at their stamp."""
    from drivers.carmen import CarmenLog

    lines = ""
    for k in range(6):  # as the test above, but one ODOM line stamped before the one before it
        stamp = float(k) if k != 2 else 0.9
        lines += _odom((k, 0, 0), stamp) + _flaser((k, 0, 0), k + 0.5)
    log = tmp_path / "bursts.log"
    log.write_text(lines)
    reader = CarmenLog(log)
    frames = list(reader)
    assert not reader.odometry_stamped()
    np.testing.assert_allclose([float(f.odom[0]) for f in frames], [0, 1, 2, 3, 4, 5])


def test_reading_a_long_log_does_not_hold_it_in_memory(tmp_path):
    """Peak memory while iterating a log does not grow with its length (lines are streamed)."""
    import gzip
    import tracemalloc

    from drivers.carmen import CarmenLog

    def write(n: int) -> Path:
        path = tmp_path / f"log{n}.clf.gz"
        with gzip.open(path, "wt") as f:
            for k in range(n):
                f.write(_odom((0.01 * k, 0, 0), 0.1 * k) + _flaser((0.01 * k, 0, 0), 0.1 * k))
        return path

    def peak(path: Path) -> tuple[int, int]:
        tracemalloc.start()
        count = sum(1 for _ in CarmenLog(path))
        top = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        return count, top

    short, long_ = write(200), write(4000)
    n_short, m_short = peak(short)
    n_long, m_long = peak(long_)
    assert (n_short, n_long) == (200, 4000)
    assert m_long < 1.5 * m_short + 200_000  # 20 times the scans, about the same memory


@pytest.mark.parametrize("name", ["intel-excerpt.clf.gz", "fhw-excerpt.log.gz",
                                  "killian-excerpt.g2o.zip", "loop5-excerpt.log.gz",
                                  "exp1-excerpt.dat.gz", "demo-excerpt.bag"])
def test_a_recording_knows_how_many_scans_it_holds_before_it_is_read(name):
    log = open_recording(EXCERPTS / name)
    assert log.length is not None and log.length == len(list(log)) > 0


def test_scan_lines_are_counted_across_the_chunks_they_are_read_in(tmp_path):
    from drivers.textlog import count_lines_starting

    text = "".join(("FLASER 3 1 2 3\n" if k % 3 else "ODOM 0 0 0\n# FLASER in a comment\n")
                   for k in range(200))
    path = tmp_path / "run.clf"
    path.write_text(text)
    want = sum(line.startswith("FLASER") for line in text.splitlines())
    for chunk in (1, 5, 6, 7, 13, 1 << 20):  # every cut of a line's head
        assert count_lines_starting(path, (b"FLASER", b"ROBOTLASER1"), chunk=chunk) == want


def test_a_damaged_gzip_log_counts_the_scans_before_the_damage(tmp_path):
    import gzip

    from drivers.textlog import count_lines_starting

    whole = gzip.compress(b"FLASER 1 1\n" * 5000)
    path = tmp_path / "cut.clf.gz"
    path.write_bytes(whole[: len(whole) // 2])
    assert 0 < count_lines_starting(path, (b"FLASER",)) < 5000
