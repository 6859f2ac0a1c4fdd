"""The Rerun recording of a mapping run, read back with Rerun's own reader."""

import json
import shutil
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import pytest

from vmp.cli import main


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    out = tmp_path_factory.mktemp("rerun")
    rrd = out / "office.rrd"
    assert main(["map", "office", "--out", str(out / "res"), "--rerun", str(rrd), "-q"]) == 0
    metrics = json.loads((out / "res" / "latest" / "metrics.json").read_text())
    return rrd, metrics


def rerun_cli() -> str:
    return shutil.which("rerun") or str(Path(sys.executable).parent / "rerun")


def test_rerun_accepts_the_recording(recording):
    rrd, _ = recording
    done = subprocess.run([rerun_cli(), "rrd", "verify", str(rrd)], capture_output=True,
                          text=True, env={"RERUN_APP_ONLY": "true", "PATH": ""})
    assert done.returncode == 0, done.stderr


def chunks(rrd):
    from rerun.chunk import RrdReader

    return list(RrdReader(str(rrd)).stream().to_chunks())


def test_what_was_logged(recording):
    rrd, metrics = recording
    rows = defaultdict(int)
    for ch in chunks(rrd):
        rows[str(ch.entity_path)] += ch.num_rows
    for path in ("/world", "/world/path/estimate", "/world/path/odometry", "/world/path/truth",
                 "/world/robot", "/world/matches", "/world/milestones", "/world/grid",
                 "/metrics/innovation", "/metrics/covariance_trace", "/log"):
        assert rows.get(path, 0) > 0, path
    segments = {p for p in rows if p.startswith("/world/segments/") and p.count("/") == 3}
    assert len(segments) == metrics["segments"]  # one entity per segment
    scans = sum(n for p, n in rows.items() if p.endswith("/scans"))
    assert scans == metrics["scans"]  # every scan's polygon, once


def test_a_correction_moves_a_segment_by_one_transform(recording):
    rrd, metrics = recording
    assert metrics["graph adjustments"] >= 1  # a loop closure moved the milestones
    times = defaultdict(list)
    for ch in chunks(rrd):
        path = str(ch.entity_path)
        if not (path.startswith("/world/segments/") and path.count("/") == 3):
            continue
        batch = ch.to_record_batch()
        if "Transform3D:translation" in batch.schema.names and "scan" in batch.schema.names:
            times[path] += batch.column("scan").to_pylist()
    moved = [p for p, t in times.items() if len(t) >= 2 and max(t) > min(t)]
    assert moved, "no segment transform was updated after the segment was opened"
    # The scans themselves were logged once: moving a segment re-logs no polygons.
    polygons = defaultdict(int)
    for ch in chunks(rrd):
        if str(ch.entity_path).endswith("/scans"):
            polygons[str(ch.entity_path)] += ch.num_rows
    assert sum(polygons.values()) == metrics["scans"]


def test_rerun_flag_errors_are_one_line(tmp_path, capsys):
    assert main(["map", "lab", "--scans", "5", "--out", str(tmp_path), "--rerun",
                 str(tmp_path / "x.txt")]) == 2
    assert "--rerun expects a .rrd file" in capsys.readouterr().err


def test_localizing_shows_the_saved_map_the_places_followed_and_the_pose(tmp_path):
    assert main(["map", "lab", "--scans", "400", "--out", str(tmp_path / "m"), "-q"]) == 0
    rrd = tmp_path / "loc.rrd"
    assert main(["localize", "--map", str((tmp_path / "m" / "latest").resolve()), "lab",
                 "--seed", "3", "--scans", "60", "--out", str(tmp_path / "l"), "--rerun",
                 str(rrd), "-q"]) == 0
    metrics = json.loads((tmp_path / "l" / "latest-localization" / "metrics.json").read_text())
    rows = defaultdict(int)
    for ch in chunks(rrd):
        rows[str(ch.entity_path)] += ch.num_rows
    for path in ("/world/grid", "/world/milestones", "/world/hypotheses", "/world/robot",
                 "/world/path/estimate", "/world/path/truth", "/log"):
        assert rows.get(path, 0) > 0, path
    assert rows["/world/hypotheses"] == 60  # the places followed, after every scan
    localized = round(metrics["share of scans localized"] * 60)
    # One point per localized scan, besides the path's static style row.
    assert rows["/world/path/estimate"] - 1 == localized > 0
