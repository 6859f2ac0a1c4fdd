"""The ``vmp`` command as a user meets it."""

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest
from conftest import run_cli

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


def test_map_export_evaluate_commands(tmp_path, capsys):
    out = tmp_path / "res"
    assert main(["map", "lab", "--scans", "300", "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "ATE (m)" in said and "scans per second" in said
    latest = out / "latest"
    assert json.loads((latest / "metrics.json").read_text())["scans"] == 300
    for name in ("trajectory.tum", "online.tum", "odometry.tum", "ground_truth.tum",
                 "map.vmpmap", "milestones.npz", "grid.yaml", "grid.pgm", "grid.png",
                 "grid.npy", "contours.geojson", "graph.json", "config.yaml", "metrics.json"):
        assert (latest / name).is_file(), name
    grid = tmp_path / "g" / "map.yaml"
    assert main(["export", str(latest), "--grid", str(grid), "--resolution", "0.1",
                 "--png", str(tmp_path / "g.png"), "--npy", str(tmp_path / "g.npy")]) == 0
    assert (tmp_path / "g" / "map.pgm").is_file()
    assert np.load(tmp_path / "g.npy", allow_pickle=False).dtype == np.uint8
    assert main(["evaluate", str(latest), "--ground-truth",
                 str(latest / "ground_truth.tum")]) == 0
    said = capsys.readouterr().out
    rmse = float(said.split("ATE  rmse ")[1].split()[0])
    assert rmse < 0.02
    # The configuration written with a result maps the same way when given back.
    assert main(["map", "lab", "--scans", "50", "--out", str(out), "-q", "--config",
                 str(latest / "config.yaml")]) == 0
    assert main(["map", "lab", "--scans", "50", "--out", str(out), "-q", "--config",
                 str(latest / "config.yaml"), "--no-milestones", "--method", "dct"]) == 0
    metrics = json.loads((out / "latest" / "metrics.json").read_text())
    assert metrics["milestones"] == 1


@pytest.mark.parametrize("argv, message", [
    (["map", "nowhere.clf"], "nowhere.clf: no such file"),
    (["map", "lab", "--resolution", "-1"], "--resolution: expected a positive number"),
    (["map", "lab", "--seed", "2", "--scans", "0"], "--scans: expected a positive integer"),
    (["export", "."], "nothing to export"),
    (["evaluate", "."], "give --ground-truth"),
])
def test_mapping_mistakes_get_one_line(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    assert run_cli(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not (tmp_path / "results").exists() or not any((tmp_path / "results").iterdir())


def test_bad_config_names_file_and_key(tmp_path, capsys):
    bad = tmp_path / "c.yaml"
    bad.write_text("registration: {max_iteration: 3}\n")
    assert main(["map", "lab", "--scans", "5", "--config", str(bad), "--out",
                 str(tmp_path)]) == 2
    assert "c.yaml: registration.max_iteration: unknown key" in capsys.readouterr().err


def test_map_of_a_carmen_log(tmp_path, capsys):
    log = tmp_path / "lab.clf"
    assert main(["simulate", "lab", "--scans", "200", "--out", str(log), "-q"]) == 0
    assert main(["map", str(log), "--out", str(tmp_path / "r"), "-q"]) == 0
    assert main(["evaluate", str(tmp_path / "r" / "latest"), "--ground-truth",
                 str(log.with_suffix(".tum"))]) == 0
    rmse = float(capsys.readouterr().out.split("ATE  rmse ")[1].split()[0])
    assert rmse < 0.03
    assert math.isfinite(rmse)


def test_the_parser_needs_nothing_of_the_mapper():
    """'vmp --help', 'vmp scenarios' and a Dask 'vmp batch' (whose runs import the mapper in
    the workers) must not wait for SciPy, Shapely and the pipeline (about 0.6 s)."""
    probe = ("import sys; from vmp.cli.parser import build_parser; build_parser(); "
             "heavy = [m for m in ('scipy', 'shapely', 'filterpy', 'pywt', 'vmp.pipeline', "
             "'vmp.results', 'vmp.checkpoint', 'drivers.simulator') if m in sys.modules]; "
             "print(','.join(heavy))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == ""


def test_ctrl_c_inside_code_run_by_exec_still_ends_with_130(tmp_path):
    """A Ctrl-C while SciPy builds its distributions by ``exec`` (in the first second of
    ``python -m vmp map``) ended the process by SIGINT (-2), not with 130, though caught:
    CPython marks such an interrupt unhandled, and run as a module (``-m``) it checks the
    mark at exit."""
    (tmp_path / "interrupted_in_exec.py").write_text(
        "import vmp.cli.scenarios as s\n"
        "s.run = lambda args: exec('raise KeyboardInterrupt')\n"
        "from vmp.cli import main\n"
        "raise SystemExit(main(['scenarios']))\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(tmp_path), *filter(None, [os.environ.get("PYTHONPATH")])]))
    done = subprocess.run([sys.executable, "-m", "interrupted_in_exec"], capture_output=True,
                          text=True, timeout=120, env=env)
    assert done.returncode == 130, done.stderr
    assert "vmp scenarios: interrupted" in done.stderr


def test_output_to_a_reader_that_went_away_ends_quietly(monkeypatch, capsys):
    # 'vmp scenarios | head -1': the pipe's reader is gone before the command writes.
    import os
    import signal

    read_end, write_end = os.pipe()
    os.close(read_end)
    gone = os.fdopen(write_end, "w")
    monkeypatch.setattr("sys.stdout", gone)
    try:
        assert main(["scenarios"]) == 128 + signal.SIGPIPE.value
    finally:
        monkeypatch.undo()
        gone.close()
    assert capsys.readouterr().err == ""
