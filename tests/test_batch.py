"""vmp batch: many runs as Dask tasks (a local cluster, or a scheduler and worker started by
hand with Dask's own commands) give the same rows as one run after another."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import ROOT, run_cli

from vmp.cli.batch import TIMING, plan, run_batch
from vmp.errors import InputError

pytest.importorskip("distributed", reason="vmp batch needs the batch extra: "
                    "pip install 'vmp-slam[batch]'")

SOURCES = ["lab:1..2", "corridor"]
SCANS = 120


def _figures(rows: list[dict]) -> list[dict]:
    """The rows without what differs from run to run (times, folder names)."""
    return [{k: v for k, v in r.items() if k not in (*TIMING, "results")} for r in rows]


@pytest.fixture(scope="module")
def serial_rows(tmp_path_factory) -> list[dict]:
    out = tmp_path_factory.mktemp("serial")
    rows, cut = run_batch(plan(SOURCES, out=out, scans=SCANS), serial=True)
    assert not cut and all(r["status"] == "ok" for r in rows)
    return rows


def test_a_local_cluster_gives_the_rows_of_a_serial_run(tmp_path, serial_rows):
    rows, cut = run_batch(plan(SOURCES, out=tmp_path, scans=SCANS), workers=2)
    assert not cut
    assert _figures(rows) == _figures(serial_rows)
    assert [r["source"] for r in rows] == ["lab:1", "lab:2", "corridor"]
    assert all(r["scans"] == SCANS and r["ATE (m)"] < 0.2 for r in rows)
    for r, s in zip(rows, serial_rows, strict=True):  # the same results folder as serial
        for name in ("trajectory.tum", "map.vmpmap", "grid.npy", "contours.geojson"):
            assert (Path(r["results"]) / name).read_bytes() == \
                (Path(s["results"]) / name).read_bytes(), name


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_scheduler_and_worker_started_by_hand_run_the_same_batch(tmp_path, capsys,
                                                                   serial_rows):
    dask = shutil.which("dask") or str(Path(sys.executable).parent / "dask")
    if not os.path.exists(dask):
        pytest.skip("the 'dask' command of the batch extra is not on PATH")
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", str(port),
                               "--no-dashboard"], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)]
    try:
        time.sleep(1.0)
        procs.append(subprocess.Popen([dask, "worker", address, "--nworkers", "1",
                                       "--nthreads", "1", "--no-dashboard"], env=env,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        code = run_cli(["batch", *SOURCES, "--scans", str(SCANS), "--scheduler", address,
                        "--out", str(tmp_path), "-q"])
        assert code == 0, capsys.readouterr().err
        table = (tmp_path / "batch.csv").read_text().splitlines()
        assert len(table) == 4 and table[0].startswith("source,seed,scans")
        printed = capsys.readouterr().out
        for r in serial_rows:  # the same figures as the serial run, in the printed table
            assert f"| {r['source']} |" in printed and f"{r['ATE (m)']:.4g}" in printed
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            p.wait(timeout=30)


def test_a_failing_source_gets_its_error_in_its_row_and_the_others_go_on(tmp_path, capsys):
    missing = tmp_path / "nowhere.clf"
    assert run_cli(["batch", "lab", str(missing), "--scans", "60", "--serial",
                    "--out", str(tmp_path / "b"), "-q"]) == 1
    out = capsys.readouterr()
    rows = (tmp_path / "b" / "batch.csv").read_text().splitlines()
    assert len(rows) == 3 and ",ok," in rows[1] and "error: " in rows[2]
    assert "nowhere.clf: no such file" in rows[2] and "1 failed" in out.err


def test_sweeps_make_every_combination_and_typos_fail_before_any_work():
    jobs = plan(["office:1..2"], ["milestones.method=cca,dct", "loops.separation=5,8"])
    assert len(jobs) == 8
    assert {j.settings for j in jobs} == {
        (("milestones.method", m), ("loops.separation", s)) for m in ("cca", "dct")
        for s in (5, 8)}
    with pytest.raises(InputError, match=r"milestones\.methd: unknown key"):
        plan(["office"], ["milestones.methd=cca"])
    with pytest.raises(InputError, match=r"expected section\.key=V1,V2"):
        plan(["office"], ["method=cca"])
    with pytest.raises(InputError, match="runs backwards"):
        plan(["office:5..2"])
