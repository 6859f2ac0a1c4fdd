"""Checkpoints: a run killed (even by SIGKILL) goes on with --resume to the uninterrupted result;
the state codec rebuilds the pipeline exactly and nothing but the program's own classes."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT, run_cli

from drivers import open_source
from vmp.checkpoint import CHECKPOINT, Every
from vmp.errors import InputError
from vmp.pipeline import Pipeline
from vmp.run import MappingRun
from vmp.state import StateError, decode, encode


def test_a_pipeline_rebuilt_from_its_state_goes_on_exactly_as_the_original():
    frames = list(open_source("office", scans=500))
    original = Pipeline(frames[0].geometry)
    for f in frames[:250]:
        original.step(f)
    tree, arrays = encode(original, {"view": original.view})
    copy = decode(json.loads(json.dumps(tree)), dict(arrays), {"view": original.view})
    assert copy is not original and copy.back.milestones is copy.milestones  # shared stays
    for f in frames[250:]:
        original.step(f)
        copy.step(f)
    original.finish()
    copy.finish()
    np.testing.assert_array_equal(copy.trajectory(), original.trajectory())
    assert len(copy.back.graph.edges) == len(original.back.graph.edges)


def test_a_state_naming_a_class_outside_the_program_is_refused():
    tree = {"$obj": "os:_wrap_close", "ref": 0, "state": {}}
    with pytest.raises(StateError, match="may not be rebuilt"):
        decode(tree, {})
    with pytest.raises(StateError, match="cannot be written"):
        encode({"f": open(os.devnull)})


def test_a_run_resumed_from_its_checkpoint_ends_as_the_uninterrupted_run(tmp_path):
    whole = MappingRun(open_source("office", scans=400)).run()
    check = tmp_path / CHECKPOINT
    # The first run "dies" after 260 scans; its last checkpoint is at 200.
    MappingRun(open_source("office", scans=260), checkpoint=check, every=Every(scans=100)).run()
    resumed = MappingRun(open_source("office", scans=400), resume=check).run()
    np.testing.assert_array_equal(resumed.trajectory, whole.trajectory)
    np.testing.assert_array_equal(resumed.stamps, whole.stamps)
    np.testing.assert_array_equal(resumed.online, whole.online)
    with pytest.raises(InputError, match="not the one the checkpoint ended at"):
        MappingRun(open_source("office", scans=400, seed=99), resume=check).run()
    with pytest.raises(InputError, match="a checkpoint of office, not of lab"):
        MappingRun(open_source("lab", scans=400), resume=check)


def test_every_parses_seconds_scans_and_off():
    assert Every.parse("60s") == Every(seconds=60.0)
    assert Every.parse("500") == Every(scans=500)
    assert Every.parse("off") is None
    for bad in ("0", "-5", "1m", "s"):
        with pytest.raises(InputError, match="--checkpoint-every"):
            Every.parse(bad)


def _wait_for(path_glob: Path, pattern: str, proc: subprocess.Popen, limit: float) -> Path:
    deadline = time.monotonic() + limit
    while time.monotonic() < deadline:
        found = sorted(path_glob.glob(pattern))
        if found:
            return found[0]
        if proc.poll() is not None:
            pytest.fail(f"the run ended (code {proc.returncode}) before {pattern} appeared")
        time.sleep(0.05)
    pytest.fail(f"no {pattern} within the time limit")


def test_sigkill_then_resume_gives_the_uninterrupted_runs_trajectory(tmp_path, capsys):
    assert run_cli(["map", "office", "--scans", "360", "--out", str(tmp_path / "whole"), "-q",
                    "--checkpoint-every", "off"]) == 0
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "vmp", "map", "office", "--scans", "360",
                             "--out", str(tmp_path / "killed"), "-q",
                             "--checkpoint-every", "120"], env=env)
    try:
        check = _wait_for(tmp_path / "killed", f"*/{CHECKPOINT}", proc, 120)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait()
    folder = check.parent
    assert (folder / "INCOMPLETE").exists() and not (folder / "trajectory.tum").exists()
    assert run_cli(["map", "office", "--scans", "360", "--resume", str(folder), "-q"]) == 0
    assert not (folder / "INCOMPLETE").exists() and not (folder / CHECKPOINT).exists()
    whole = np.loadtxt(tmp_path / "whole" / "latest" / "trajectory.tum")
    np.testing.assert_array_equal(np.loadtxt(folder / "trajectory.tum"), whole)
    # --resume with settings that would change the run, or a folder without a checkpoint.
    capsys.readouterr()
    assert run_cli(["map", "office", "--resume", str(folder), "--method", "dct"]) == 2
    assert "leave out --method" in capsys.readouterr().err
    assert run_cli(["map", "office", "--resume", str(folder)]) == 2
    assert "no checkpoint.npz here" in capsys.readouterr().err


def test_a_second_session_resumed_from_its_checkpoint_ends_as_the_uninterrupted_one(tmp_path):
    from vmp.config import config_to_dict
    from vmp.mapfile import load_map, save_map

    first = MappingRun(open_source("lab", scans=700)).run()
    p = first.pipeline
    save_map(tmp_path / "a.vmpmap", p.map, p.milestones, p.back.graph,
             config_to_dict(first.config), first.trajectory)
    whole = MappingRun(open_source("lab", seed=4, scans=400),
                       saved=load_map(tmp_path / "a.vmpmap")).run()
    check = tmp_path / CHECKPOINT
    MappingRun(open_source("lab", seed=4, scans=260), saved=load_map(tmp_path / "a.vmpmap"),
               checkpoint=check, every=Every(scans=100)).run()
    resumed = MappingRun(open_source("lab", seed=4, scans=400), resume=check).run()
    np.testing.assert_array_equal(resumed.trajectory, whole.trajectory)
    np.testing.assert_array_equal(resumed.stamps, whole.stamps)
    assert resumed.pipeline.stats["scans before localized in the saved map"] == \
        whole.pipeline.stats["scans before localized in the saved map"]


def _mapping_office(out: Path) -> subprocess.Popen:
    """``vmp map office`` of 2,000 scans as its own process, once its results folder exists."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "vmp", "map", "office", "--scans", "2000",
                             "--out", str(out), "-q"], env=env, stderr=subprocess.PIPE,
                            text=True)
    try:
        _wait_for(out, "*/INCOMPLETE", proc, 120)
    except BaseException:
        proc.kill()
        proc.wait()
        raise
    return proc


@pytest.mark.slow
@pytest.mark.parametrize(("signum", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_at_a_random_moment_leaves_a_complete_folder_with_a_loadable_map(
        tmp_path, signum, code):
    """``vmp map`` as its own process, signalled somewhere in its mapping: it finishes what
    it mapped, writes every file, says so and exits 128 + the signal."""
    from vmp.mapfile import load_map

    # After the folder appears the scenario is built and the compiled ICP loaded (about
    # 0.5 s, more on a loaded machine) before the first scan is mapped.
    delay = float(np.random.default_rng(int(signum)).uniform(1.2, 3.0))
    proc = _mapping_office(tmp_path)
    try:
        time.sleep(delay)
        assert proc.poll() is None, "the run ended before the signal: give it more scans"
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode == code, err
    assert "interrupted" in err
    folder = (tmp_path / "latest").resolve()
    assert not (folder / "INCOMPLETE").exists()
    saved = load_map(folder / "map.vmpmap")
    mapped = len(np.loadtxt(folder / "trajectory.tum", ndmin=2))  # one scan: one row
    assert 0 < mapped < 2000
    assert len(saved.map) == mapped


def test_a_saved_map_another_run_has_mapped_on_is_refused_clearly(tmp_path):
    """A run maps on in the saved map it is given; given the same one again, a run would
    find more scans than poses in it (a NumPy broadcast error deep in the localizer)."""
    from vmp.errors import InputError
    from vmp.localization import LocalizationRun
    from vmp.mapfile import load_map, save_map

    first = MappingRun(open_source("lab", scans=300)).run()
    p = first.pipeline
    save_map(tmp_path / "a.vmpmap", p.map, p.milestones, p.back.graph, {}, first.trajectory)
    saved = load_map(tmp_path / "a.vmpmap")
    second = MappingRun(open_source("lab", seed=4, scans=200), saved=saved).run()
    assert second.pipeline.stats["scans before localized in the saved map"] < 200
    for again in (lambda: MappingRun(open_source("lab", seed=5, scans=50), saved=saved),
                  lambda: LocalizationRun(saved, open_source("lab", seed=5, scans=50))):
        with pytest.raises(InputError, match="load it again"):
            again()
    MappingRun(open_source("lab", seed=5, scans=50), saved=load_map(tmp_path / "a.vmpmap"))


def test_ctrl_c_pressed_three_times_keeps_the_results(tmp_path):
    """Ctrl-C three times 0.05 s apart: the first ends the run, the others change nothing
    (they may say that the results are kept, or come together with the first, as signals
    arriving during one long computation are taken once); every file is written and the map
    loads."""
    from vmp.mapfile import load_map

    proc = _mapping_office(tmp_path)
    try:
        time.sleep(1.5)
        assert proc.poll() is None, "the run ended before the signal: give it more scans"
        for _ in range(3):
            proc.send_signal(signal.SIGINT)
            time.sleep(0.05)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "interrupted by SIGINT" in err
    folder = (tmp_path / "latest").resolve()
    assert not (folder / "INCOMPLETE").exists()
    assert len(load_map(folder / "map.vmpmap").map) > 0
