"""The one mapping run: its loop over any source, its result, interruption, the results folder."""

import json
import os
import signal
import threading

import numpy as np
import pytest
from conftest import mapped

from drivers import open_source
from vmp.errors import InputError
from vmp.folders import link_latest, new_results_dir
from vmp.run import MappingRun
from vmp.source import Source

FILES = ("trajectory.tum", "online.tum", "odometry.tum", "ground_truth.tum", "map.vmpmap",
         "milestones.npz", "grid.yaml", "grid.pgm", "grid.png", "grid.npy", "contours.geojson",
         "graph.json", "config.yaml", "metrics.json")


def test_every_source_is_a_source(tmp_path):
    from conftest import EXCERPTS

    for text in ("lab", str(EXCERPTS / "intel-excerpt.clf.gz")):
        assert isinstance(open_source(text), Source)


def test_a_result_holds_one_pose_per_scan_and_writes_every_file(tmp_path):
    r = mapped("lab", scans=200)
    assert r.scans == 200 and r.trajectory.shape == r.online.shape == r.odometry.shape
    assert r.reference is not None and r.reference.truth and len(r.reference.poses) == 200
    metrics = r.write(tmp_path)
    for name in FILES:
        assert (tmp_path / name).is_file(), name
    saved = json.loads((tmp_path / "metrics.json").read_text())
    assert saved["scans"] == 200 and saved["ATE (m)"] == pytest.approx(metrics["ATE (m)"])
    assert metrics["ATE (m)"] < metrics["ATE odometry alone (m)"]


def test_scans_limits_the_run_and_the_source_is_closed():
    source = open_source("lab")
    r = MappingRun(source, scans=30).run()
    assert r.scans == 30 and source._closed


class _Signalling:
    """A scenario's frames; after ``after`` of them the process gets ``signum``."""

    def __init__(self, after: int, signum: int) -> None:
        self.sim = open_source("lab", scans=400)
        self.name, self.after, self.signum = "signalling", after, signum
        self.geometry, self.length = self.sim.geometry, self.sim.length

    def __iter__(self):
        for k, frame in enumerate(self.sim):
            if k == self.after:
                os.kill(os.getpid(), self.signum)
            yield frame

    def reference(self):
        return self.sim.reference()

    def report(self):
        return self.sim.report()

    def close(self) -> None:
        self.sim.close()


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_ends_the_run_with_what_was_mapped(signum):
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signals reach the main thread only")
    before = signal.getsignal(signum)
    r = MappingRun(_Signalling(50, signum)).run()
    assert r.interrupted == signal.Signals(signum).name
    assert 50 <= r.scans <= 52  # the scan under way is finished, then the run ends
    assert r.metrics()["interrupted by"] == signal.Signals(signum).name
    assert signal.getsignal(signum) == before  # the handlers are put back


def test_a_source_without_scans_is_one_clear_error(tmp_path):
    empty = tmp_path / "empty.clf"
    empty.write_text("PARAM robot_front_laser_max 8 host 0\nODOM 0 0 0 0 0 0 1.0 host 1.0\n")
    with pytest.raises(InputError, match=r"empty\.clf: no laser scans"):
        MappingRun(open_source(str(empty))).run()


def test_other_beams_mid_run_are_refused():
    from vmp.types import ScanFrame

    sim = open_source("lab", scans=20)

    class Mixed:
        name, geometry, length = "mixed", sim.geometry, None

        def __iter__(self):
            for k, f in enumerate(sim):
                yield f if k < 10 else ScanFrame(f.stamp, f.ranges[:90], f.angle_min,
                                                 f.angle_increment, f.max_range, f.odom)

        def reference(self):
            return None

        def report(self):
            return sim.report()

        def close(self):
            pass

    with pytest.raises(InputError, match="scan 10 has other beams"):
        MappingRun(Mixed()).run()


def test_latest_moves_only_when_asked(tmp_path):
    a = new_results_dir(tmp_path, "x")
    assert not (tmp_path / "latest").exists()
    link_latest(a)
    b = new_results_dir(tmp_path, "x")
    assert (tmp_path / "latest").resolve() == a.resolve() and a != b
    link_latest(b)
    assert (tmp_path / "latest").resolve() == b.resolve()


def test_gmapping_poses_are_the_reference_of_a_radish_log():
    from conftest import EXCERPTS

    r = MappingRun(open_source(str(EXCERPTS / "fhw-excerpt.log.gz"))).run()
    assert r.reference is not None and not r.reference.truth and r.reference.stamps is None
    m = r.metrics()
    assert np.isfinite(m["ATE vs GMapping's poses (m)"])
    assert m["unknown odometry increments"] == 0
