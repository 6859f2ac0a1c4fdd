"""Hostile input, one test per class: what is not a regular file, lines longer than any record,
impossible values, nonsense geometry, degenerate scans, configurations that would exhaust the
parser or mean nothing physical. Each ends in one line naming the file or setting, exit 2."""

from __future__ import annotations

import gzip
import os
import stat

import numpy as np
import pytest
from conftest import EXCERPTS, run_cli

from drivers.formats import open_recording
from drivers.textlog import MAX_LINE
from vmp.config import load_config
from vmp.errors import InputError
from vmp.fileio import atomic_write, writable_target
from vmp.types import MAX_BEAMS, ScanFrame

INTEL = EXCERPTS / "intel-excerpt.clf.gz"


def _lines() -> list[str]:
    return gzip.open(INTEL, "rt").read().splitlines()


def _flaser(lines: list[str]) -> list[int]:
    return [i for i, line in enumerate(lines) if line.startswith("FLASER")]


def _odometry_set(line: str, x: str, y: str, theta: str) -> str:
    """A FLASER line with its odometry (the three values after the laser pose) replaced."""
    parts = line.split()
    n = int(parts[1])
    parts[5 + n:8 + n] = [x, y, theta]
    return " ".join(parts)


def _error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    return err[0]


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this platform")
def test_an_output_that_is_a_fifo_or_a_folder_is_refused_and_a_symlink_written_through(
        tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    for target in (fifo, tmp_path):
        with pytest.raises(InputError, match="not a regular file; refusing to replace it"):
            with atomic_write(target, "w") as f:
                f.write("x")
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)  # still a FIFO
    real = tmp_path / "real.txt"
    link = tmp_path / "link.txt"
    link.symlink_to(real)
    with atomic_write(link, "w") as f:
        f.write("through")
    assert link.is_symlink() and real.read_text() == "through"
    assert writable_target(tmp_path / "new.txt") == tmp_path / "new.txt"


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this platform")
def test_a_log_that_is_a_fifo_or_a_device_is_refused_without_reading_it(tmp_path, capsys):
    fifo = tmp_path / "log.clf"
    os.mkfifo(fifo)  # with no writer, reading would block for ever
    assert run_cli(["info", str(fifo)]) == 2
    assert "a FIFO; a recording is a regular file" in _error_line(capsys)
    assert run_cli(["map", str(fifo), "--out", str(tmp_path)]) == 2
    assert "a FIFO" in _error_line(capsys)
    if os.path.exists("/dev/zero"):
        assert run_cli(["info", "/dev/zero", "--format", "carmen"]) == 2
        assert "a character device" in _error_line(capsys)


def test_a_line_longer_than_any_record_ends_the_reading_with_what_came_before(tmp_path):
    lines = _lines()
    path = tmp_path / "huge.clf.gz"
    with gzip.open(path, "wt") as f:
        f.write("\n".join(lines[:20]) + "\n")
        f.write("X" * (MAX_LINE + 10) + "\n")  # held whole, a line like this exhausts memory
        f.write("\n".join(lines[20:]) + "\n")
    log = open_recording(path)
    frames = list(log)
    assert 0 < len(frames) < len(_flaser(lines))
    assert "longer than 4 MB" in log.report().damaged
    with pytest.raises(InputError, match="longer than 4 MB"):
        list(open_recording(path, strict=True))


def test_impossible_stamps_and_odometry_are_skipped_as_bad_lines(tmp_path):
    lines = _lines()
    scans = _flaser(lines)
    spike, far, reset = scans[3], scans[5], scans[12:]
    lines[spike] = _odometry_set(lines[spike], "1e308", "0", "0")
    lines[far] = _odometry_set(lines[far], "1.2", "507216", "0.3")
    for k, stamp in ((6, "9760527911594970.0"), (7, "1000.0")):  # 300 million years on;
        parts = lines[scans[k]].split()  # 31 years back
        parts[-3] = stamp
        lines[scans[k]] = " ".join(parts)
    for i in reset:  # the wheels' count starting again 3 km off: kept, its increment unknown
        p = lines[i].split()
        n = int(p[1])
        p[5 + n] = str(float(p[5 + n]) + 3000.0)
        lines[i] = " ".join(p)
    path = tmp_path / "bad.clf"
    path.write_text("\n".join(lines) + "\n")
    log = open_recording(path)
    frames = list(log)
    said = " ".join(what for _, what in log.problems)
    assert "beyond any robot's" in said and "faster than 50 m/s" in said
    assert "past the year 2100" in said and "from the scan before" in said
    assert len(frames) == len(scans) - 5  # the four above and the first of the restart
    assert frames[-len(reset) + 1].odom is None  # the restart: no increment across it
    stamps = np.array([f.stamp for f in frames])
    assert stamps.max() - stamps.min() < 1e4


@pytest.mark.parametrize("beams, angle_min, step, what", [
    (181, float("inf"), 0.01, "first beam"),
    (181, 1e300, 0.01, "first beam"),
    (181, -1.5, float("-inf"), "angle step"),
    (181, -1.5, 0.0, "angle step"),
    (181, -1.5, 1e30, "more than a full turn"),
    (100_000, -1.5, 0.01, "beams, expected 1 to"),
    (MAX_BEAMS, -1.5, 2 * np.pi / MAX_BEAMS, None),
])
def test_nonsense_beam_geometry_is_refused_where_every_reader_makes_its_scans(
        beams, angle_min, step, what):
    def frame():
        return ScanFrame(0.0, np.full(beams, 2.0), angle_min, step, 10.0)
    if what is None:
        assert frame().num_beams == beams  # the densest scanner still maps
    else:
        with pytest.raises(ValueError, match=what):
            frame()


def test_degenerate_scans_end_in_one_line_or_are_mapped_around(tmp_path, capsys):
    lines = _lines()
    scans = _flaser(lines)

    def with_ranges(k: int, ranges: list[str]) -> str:
        p = lines[k].split()
        n = int(p[1])
        return " ".join(["FLASER", str(len(ranges)), *ranges, *p[2 + n:]])

    few = list(lines)
    for k in scans:
        few[k] = with_ranges(k, ["1.0", "1.1", "1.2"])
    (tmp_path / "few.clf").write_text("\n".join(few) + "\n")
    assert run_cli(["map", str(tmp_path / "few.clf"), "--out", str(tmp_path), "-q"]) == 2
    assert "none of its" in _error_line(capsys)
    blind = list(lines)
    for k in scans[:3]:  # the first scans see nothing: the map begins after them
        n = int(lines[k].split()[1])
        blind[k] = with_ranges(k, ["0.0"] * n)
    (tmp_path / "blind.clf").write_text("\n".join(blind) + "\n")
    assert run_cli(["map", str(tmp_path / "blind.clf"), "--out", str(tmp_path), "-q"]) == 0
    dp = tmp_path / "loop.log"
    dp.write_text("Odometry 0 0 0\nLaser 1 2.5\nOdometry 0.1 0 0\nLaser 0\n")
    log = open_recording(dp)
    assert list(log) == [] and log.skipped == 2  # no division by a beam count of 1


@pytest.mark.parametrize("text, message", [
    ("motion: " + "[" * 5000 + "]" * 5000, "nested too deep"),
    ("motion: {trans_per_m: " + "9" * 5000 + "}", "thousands of digits"),
    ("motion: {trans_per_m: 0}", r"motion.trans_per_m: expected a number from 0.001 to 10 "
                                 r"\(m per m driven\)"),
    ("milestones: {record_distance: 1.0e-300}", r"from 0.01 to 1000 \(m\)"),
    ("milestones: {clamp_range: 1.0e-300}", "milestones.clamp_range"),
])
def test_a_configuration_the_parser_cannot_hold_or_out_of_its_physical_range_is_refused(
        tmp_path, text, message):
    path = tmp_path / "c.yaml"
    path.write_text(text + "\n")
    with pytest.raises(InputError, match=message):
        load_config(path)


def test_an_exponent_without_a_point_is_a_number(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("registration: {max_rms: 1e-02}\n")  # YAML 1.1 reads it as a string
    assert load_config(path).registration.max_rms == pytest.approx(0.01)
