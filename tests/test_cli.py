"""The ``vmp`` command as a user meets it."""

import subprocess
import sys

import numpy as np
import pytest

from vmp import __version__
from vmp.cli import main
from vmp.tum import read_tum


@pytest.mark.parametrize("name", ["office", "corridor", "lab", "warehouse"])
def test_simulate_every_builtin_scenario(tmp_path, capsys, name):
    out = tmp_path / f"{name}.clf"
    assert main(["simulate", name, "--out", str(out)]) == 0
    text = out.read_text().splitlines()
    flaser = [ln.split() for ln in text if ln.startswith("FLASER")]
    assert len(flaser) > 500
    assert all(len(p) == 2 + int(p[1]) + 9 for p in flaser)
    stamps, poses = read_tum(out.with_suffix(".tum"))
    assert len(stamps) == len(flaser)
    assert np.isfinite(poses).all()
    said = capsys.readouterr().out
    assert f"{name}: {len(flaser)} scans" in said and str(out) in said


def test_same_seed_gives_identical_logs(tmp_path):
    a, b, c = (tmp_path / f"{k}.clf" for k in "abc")
    for path, seed in ((a, "4"), (b, "4"), (c, "5")):
        assert main(["simulate", "lab", "--scans", "200", "--seed", seed, "--out", str(path),
                     "-q"]) == 0
    assert a.read_bytes().replace(b"a.clf", b"") == b.read_bytes().replace(b"b.clf", b"")
    assert a.read_text() != c.read_text()
    assert a.with_suffix(".tum").read_bytes() == b.with_suffix(".tum").read_bytes()


def run_cli(argv):
    """Exit code of ``vmp ARGV``, whether argparse exits or ``main`` returns."""
    try:
        return main(argv)
    except SystemExit as exc:
        return exc.code


@pytest.mark.parametrize(
    "argv, message",
    [
        (["simulate", "atlantis"], "atlantis: no such scenario file, and not a built-in"),
        (["simulate", "office", "--laps", "0"], "--laps: expected a positive integer"),
        (["simulate", "corridor", "--laps", "3"], "laps need a closed trajectory"),
        (["simulate", "office", "--out", "x.clf", "--ground-truth", "x.clf"], "same file"),
        (["simulate", "office", "--frobnicate"], "unrecognized arguments: --frobnicate"),
    ],
)
def test_user_mistakes_get_one_line_and_exit_2(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    assert run_cli(argv) == 2
    err = capsys.readouterr().err
    assert message in err
    assert err.count("\n") == 1 and "Traceback" not in err


def test_missing_output_directory_is_created_and_unwritable_place_is_one_line(tmp_path, capsys):
    out = tmp_path / "deep" / "er" / "run.clf"
    assert main(["simulate", "lab", "--scans", "5", "--out", str(out), "-q"]) == 0
    assert out.exists()
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert main(["simulate", "lab", "--scans", "5", "--out", str(blocker / "x.clf"), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("vmp simulate: error:") and err.count("\n") == 1


def test_installed_command_help_version_and_errors(tmp_path):
    run = [sys.executable, "-m", "vmp"]
    v = subprocess.run([*run, "--version"], capture_output=True, text=True, check=True)
    assert __version__ in v.stdout
    h = subprocess.run([*run, "--help"], capture_output=True, text=True, check=True)
    assert "simulate" in h.stdout and "examples:" in h.stdout
    h = subprocess.run([*run, "simulate", "--help"], capture_output=True, text=True, check=True)
    assert "--out" in h.stdout and "vmp simulate office" in h.stdout
    bad = subprocess.run([*run, "simulate", str(tmp_path / "missing.yaml")],
                         capture_output=True, text=True, cwd=tmp_path)
    assert bad.returncode == 2
    assert "missing.yaml: no such scenario file" in bad.stderr
    assert "Traceback" not in bad.stderr


def test_outputs_get_the_usual_file_mode(tmp_path):
    import os

    out = tmp_path / "m.clf"
    assert main(["simulate", "lab", "--scans", "3", "--out", str(out), "-q"]) == 0
    mask = os.umask(0)
    os.umask(mask)
    assert (out.stat().st_mode & 0o777) == 0o666 & ~mask
