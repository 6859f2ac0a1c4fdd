"""Damaged and hostile input: one clear line and exit 2, or the data before the damage; never a
traceback. Hypothesis mutates real excerpts of every parser (bench/fuzz.py does the same at
scale) and the command line must answer each with exit 0 or 2 and at most one error line."""

from __future__ import annotations

import gzip
import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import EXCERPTS, mapped, run_cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.formats import open_recording
from vmp.config import LIMITS, MappingConfig, config_to_dict, load_config
from vmp.errors import InputError
from vmp.folders import INCOMPLETE, new_results_dir
from vmp.mapfile import checksum, load_map, save_map

EXTREMES = ["nan", "inf", "-inf", "1e308", "-1e308", "0", "-1", "99999999999999999999999",
            "abc", "", "\udcff"]


def _intel_text(lines: int = 12) -> bytes:
    with gzip.open(EXCERPTS / "intel-excerpt.clf.gz", "rb") as f:
        return b"".join(f.readline() for _ in range(lines))


@st.composite
def byte_mutations(draw, data: bytes) -> bytes:
    """A truncation, flipped bytes, inserted bytes or a zeroed block of ``data``."""
    n = len(data)
    at = draw(st.integers(0, n - 1))
    kind = draw(st.sampled_from(["cut", "flip", "insert", "zero"]))
    if kind == "cut":
        return data[:at]
    if kind == "insert":
        return data[:at] + draw(st.binary(min_size=1, max_size=16)) + data[at:]
    b = bytearray(data)
    if kind == "flip":
        for i in draw(st.lists(st.integers(0, n - 1), min_size=1, max_size=8)):
            b[i] ^= 1 << draw(st.integers(0, 7))
    else:
        end = min(n, at + draw(st.integers(1, 512)))
        b[at:end] = bytes(end - at)
    return bytes(b)


@st.composite
def line_mutations(draw, text: bytes) -> bytes:
    """Words of ``text`` replaced by extreme numbers or junk, lines deleted or repeated."""
    lines = text.split(b"\n")
    for _ in range(draw(st.integers(1, 4))):
        i = draw(st.integers(0, len(lines) - 1))
        kind = draw(st.sampled_from(["word", "delete", "repeat"]))
        if kind == "word":
            words = lines[i].split(b" ")
            j = draw(st.integers(0, len(words) - 1))
            words[j] = draw(st.sampled_from(EXTREMES)).encode("utf-8", "surrogateescape")
            lines[i] = b" ".join(words)
        elif kind == "delete" and len(lines) > 1:
            del lines[i]
        else:
            lines.insert(i, lines[i])
    return b"\n".join(lines)


def _answers_in_one_line(capsys, argv: list[str]) -> None:
    """``vmp ARGV`` exits 0 or 2, and with 2 prints exactly one error line."""
    code = run_cli(argv)
    err = capsys.readouterr().err
    assert code in (0, 2), err
    if code == 2:
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err


FUZZ = settings(max_examples=60, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture])


@FUZZ
@given(st.data())
def test_damaged_recordings_are_read_to_the_damage_or_refused_in_one_line(
        tmp_path, capsys, data):
    text = _intel_text()
    packed = {"clf": text, "clf.gz": gzip.compress(text),
              "g2o.zip": _zip_bytes(text), "bag": (EXCERPTS / "demo-excerpt.bag").read_bytes()}
    suffix = data.draw(st.sampled_from(sorted(packed)))
    original = packed[suffix]
    if suffix == "clf" or (suffix != "bag" and data.draw(st.booleans())):
        inner = data.draw(line_mutations(text))
        mutated = (inner if suffix == "clf" else gzip.compress(inner) if suffix == "clf.gz"
                   else _zip_bytes(inner))
    else:
        mutated = data.draw(byte_mutations(original))
    path = tmp_path / f"case.{suffix}"
    path.write_bytes(mutated)
    _answers_in_one_line(capsys, ["info", str(path)])


@FUZZ
@given(st.data())
def test_mutated_configurations_are_refused_in_one_line_naming_file_and_key(
        tmp_path, capsys, data):
    import yaml

    text = yaml.safe_dump(config_to_dict(MappingConfig())).encode()
    path = tmp_path / "c.yaml"
    path.write_bytes(data.draw(line_mutations(text)))
    try:
        load_config(path)
    except InputError as exc:
        assert str(exc).startswith(str(path)) and "\n" not in str(exc)


def _zip_bytes(text: bytes) -> bytes:
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("log.g2o", text)
    return out.getvalue()


def test_a_cut_off_gzip_log_is_read_up_to_the_cut_and_the_damage_reported(tmp_path, capsys):
    whole = (EXCERPTS / "intel-excerpt.clf.gz").read_bytes()
    cut = tmp_path / "cut.clf.gz"
    cut.write_bytes(whole[: len(whole) * 2 // 3])
    log = open_recording(cut)
    frames = list(log)
    assert 0 < len(frames) < len(list(open_recording(EXCERPTS / "intel-excerpt.clf.gz")))
    assert log.report().damaged.startswith("damaged after line")
    assert run_cli(["info", str(cut)]) == 0
    assert "damaged after line" in capsys.readouterr().out
    with pytest.raises(InputError, match=r"cut\.clf\.gz: damaged after line \d+"):
        list(open_recording(cut, strict=True))


def test_a_zip_cut_before_its_directory_is_read_from_its_first_member(tmp_path):
    text = _intel_text(40)
    packed = _zip_bytes(text)
    cut = tmp_path / "cut.g2o.zip"
    cut.write_bytes(packed[: len(packed) // 2])
    log = open_recording(cut)
    frames = list(log)
    whole = tmp_path / "whole.clf"
    whole.write_bytes(text)
    full = list(open_recording(whole))
    assert 0 < len(frames) < len(full)
    np.testing.assert_array_equal(frames[0].ranges, full[0].ranges)
    assert "ends inside its first member" in log.report().damaged


def test_a_map_file_with_a_changed_byte_or_a_bad_array_is_refused(tmp_path):
    r = mapped("lab", scans=60)
    p = r.pipeline
    path = tmp_path / "m.vmpmap"
    save_map(path, p.map, p.milestones, p.back.graph, {}, r.trajectory)
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(arrays["header"].tobytes().decode())

    def write(changed: dict, fix_checksum: bool, edit: dict | None = None) -> Path:
        out = dict(arrays, **changed)
        h = dict(header, **(edit or {}))
        if fix_checksum:
            h["checksum"] = checksum({k: v for k, v in out.items() if k != "header"}, h)
        out["header"] = np.frombuffer(json.dumps(h).encode(), dtype=np.uint8)
        bad = tmp_path / "bad.vmpmap"
        with open(bad, "wb") as f:  # a path would get ".npz" appended
            np.savez_compressed(f, **out)
        return bad

    trajectory = arrays["trajectory"].copy()
    trajectory[5, 0] = np.nan
    with pytest.raises(InputError, match="checksum does not match"):
        load_map(write({"trajectory": trajectory}, fix_checksum=False))
    with pytest.raises(InputError, match="'trajectory' holds a value that is not finite"):
        load_map(write({"trajectory": trajectory}, fix_checksum=True))
    segment = arrays["segment"] + 1
    with pytest.raises(InputError, match="segment numbers"):
        load_map(write({"segment": segment}, fix_checksum=True))
    # The header is inside the checksum, and every field of it is checked on load.
    with pytest.raises(InputError, match="checksum does not match"):
        load_map(write({}, fix_checksum=False, edit={"free_range": 3.0}))
    geometry = dict(header["geometry"], angle_increment=0.0)
    ms_config = dict(header["milestones"], config=[])
    signatures = arrays["milestones/signatures"].copy()
    signatures[0, 0] = np.nan
    for changed, edit, message in [
            ({}, {"free_range": float("nan")}, "free_range"),
            ({}, {"free_range": -5.0}, "free_range"),
            ({}, {"config": "garbage"}, "configuration is not a mapping"),
            ({}, {"config": {"motion": {"trans_per_m": -0.1}}}, "motion.trans_per_m"),
            ({}, {"geometry": geometry}, "angle step"),
            ({}, {"milestones": ms_config}, "configuration is not a mapping"),
            ({"milestones/signatures": signatures}, {}, "not finite")]:
        with pytest.raises(InputError, match=message):
            load_map(write(changed, fix_checksum=True, edit=edit))
    edges = arrays["edge_ij"].copy()
    edges[0, 1] = 10_000
    with pytest.raises(InputError, match="graph edge joins a milestone the map does not hold"):
        load_map(write({"edge_ij": edges}, fix_checksum=True))
    # A file of the first version (no checksum) still loads.
    header.pop("checksum")
    header["version"] = 1
    old = tmp_path / "old.vmpmap"
    with open(old, "wb") as f:
        np.savez_compressed(f, **dict(arrays, header=np.frombuffer(
            json.dumps(header).encode(), dtype=np.uint8)))
    np.testing.assert_array_equal(load_map(old).trajectory, r.trajectory)


def test_every_number_in_the_configuration_has_a_range_and_out_of_range_is_refused(tmp_path):
    numbers = {f"{section}.{key}": v for section, keys in config_to_dict(MappingConfig()).items()
               for key, v in keys.items()
               if isinstance(v, int | float) and not isinstance(v, bool)}
    assert set(numbers) == set(LIMITS)
    for key, default in numbers.items():
        low, high, _ = LIMITS[key]
        assert low <= default <= high, key
        section, name = key.split(".")
        (tmp_path / "c.yaml").write_text(f"{section}: {{{name}: {high * 2 + 1}}}\n")
        with pytest.raises(InputError, match=rf"{key}: expected a number"):
            load_config(tmp_path / "c.yaml")


@pytest.mark.parametrize("edit, message", [
    ("trajectory: {waypoints: [[1, 1], [7, 1]], speed: 1.0e-9}",
     "trajectory: expected a drive of at most 1,000,000 scans"),
    ("trajectory: {waypoints: [[1, 1], [7, 1]], closed: true, laps: 1000000}",
     "trajectory.laps: expected at most"),
    ("trajectory: {waypoints: [[1, 1], [7, 1]]}\nsensor: {beams: 10000000}",
     "sensor.beams: expected an integer <= 10,000"),
    ("trajectory: {waypoints: [[1, 1], [7, 1]]}\nsensor: {rate_hz: 1.0e+6}",
     "trajectory: expected a drive of at most"),
])
def test_a_scenario_that_would_run_unbounded_is_refused_with_the_figure(tmp_path, capsys,
                                                                        edit, message):
    path = tmp_path / "big.yaml"
    path.write_text("walls:\n  - polygon: [[0, 0], [8, 0], [8, 6], [0, 6]]\n" + edit + "\n")
    assert run_cli(["simulate", str(path), "--scans", "3", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1, err


def test_an_incomplete_results_folder_says_so_when_opened(tmp_path, capsys):
    r = mapped("lab", scans=60)
    out = new_results_dir(tmp_path, "lab")
    assert (out / INCOMPLETE).exists()
    p = r.pipeline
    save_map(out / "map.vmpmap", p.map, p.milestones, p.back.graph, {}, r.trajectory)
    assert run_cli(["export", str(out), "--png", str(tmp_path / "g.png")]) == 0
    assert "incomplete results folder" in capsys.readouterr().err
    assert run_cli(["map", "lab", "--scans", "20", "--out", str(tmp_path / "runs"), "-q"]) == 0
    done = (tmp_path / "runs" / "latest").resolve()
    assert not (done / INCOMPLETE).exists() and (done / "map.vmpmap").is_file()


def test_laps_asked_on_the_command_line_are_held_to_the_same_bound(tmp_path, capsys):
    assert run_cli(["simulate", "office", "--laps", "1000000", "--out",
                    str(tmp_path / "o.clf")]) == 2
    assert "more than the 1,000,000 a simulated run may make" in capsys.readouterr().err


def test_strict_stops_at_a_bad_line_but_keeps_stamps_that_run_backwards(tmp_path):
    text = _intel_text(40).split(b"\n")
    lasers = [i for i, line in enumerate(text) if line.startswith(b"FLASER")]
    a, b = lasers[3], lasers[4]
    text[a], text[b] = text[b], text[a]  # two scans swapped: the second's stamp runs back
    swapped = tmp_path / "swapped.clf"
    swapped.write_bytes(b"\n".join(text))
    log = open_recording(swapped, strict=True)
    assert len(list(log)) == len(lasers) and log.report().backwards >= 1
    text[lasers[6]] = b"FLASER 180 junk"
    bad = tmp_path / "bad.clf"
    bad.write_bytes(b"\n".join(text))
    with pytest.raises(InputError, match=rf"bad\.clf:{lasers[6] + 1}: "):
        list(open_recording(bad, strict=True))


def test_sigterm_ends_any_command_with_one_line_and_143(monkeypatch, capsys):
    import os
    import signal
    import time

    import vmp.survey

    def terminated(_log):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # the handler raises before this ends
        raise AssertionError("SIGTERM did not end the command")

    monkeypatch.setattr(vmp.survey, "survey", terminated)
    before = signal.getsignal(signal.SIGTERM)
    assert run_cli(["info", str(EXCERPTS / "intel-excerpt.clf.gz")]) == 143
    assert "terminated (SIGTERM)" in capsys.readouterr().err
    assert signal.getsignal(signal.SIGTERM) == before  # put back
