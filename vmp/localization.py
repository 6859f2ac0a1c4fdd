"""One localization run in a saved map, and the results folder it writes.

``LocalizationRun(saved, source).run()`` steps a :class:`~vmp.localizer.Localizer` over the
frames of any source (a recording, a scenario, a live scanner), records what it knew after
each scan and returns a :class:`LocalizationResult`::

    results/localize-office-20261201-101500/
        trajectory.tum     the localized poses, in the saved map's frame (localized scans only)
        states.csv         per scan: stamp, state (searching, ambiguous, localized, lost),
                           pose when localized, hypotheses followed
        ground_truth.tum   the true poses, when the source knows them (simulation)
        metrics.json       the summary printed at the end

Ctrl-C and SIGTERM end a run as they end a mapping run (:mod:`vmp.run`): the scans so far
are written, and the result says which signal ended it.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from milestones.manager import MilestoneManager
from vmp import __version__
from vmp.config import MappingConfig
from vmp.errors import InputError
from vmp.fileio import atomic_write
from vmp.localizer import Localizer, State
from vmp.mapfile import MapData, load_map
from vmp.places import Places
from vmp.progress import Progress
from vmp.run import StoppableRun
from vmp.source import Reference, Source, SourceReport, reference_for
from vmp.tum import write_tum
from vmp.types import FloatArray
from vmp.view import NullView, View

__all__ = ["WRONG_FIX", "LocalizationResult", "LocalizationRun", "open_saved_map"]

WRONG_FIX = 0.5  # a localized pose this far from the truth (m) is a wrong fix


def open_saved_map(path: str | Path, method: str | None = None) -> MapData:
    """The map of a results folder (its ``map.vmpmap``) or a map file; ``method`` replaces
    the signature comparison its milestones were recorded with."""
    path = Path(path)
    file = path / "map.vmpmap" if path.is_dir() else path
    if path.is_dir() and not file.is_file():
        raise InputError(f"{path}: no map.vmpmap in this folder (give a results folder of "
                         "'vmp map' or a .vmpmap file)")
    data = load_map(file)
    if len(data.milestones) == 0:
        raise InputError(f"{file}: the map holds no milestones to localize against (it was "
                         "made with --no-milestones?)")
    if method is not None and method != data.milestones.config.method:
        state = data.milestones.state()
        state["config"] = dict(state["config"], method=method)
        data = replace(data, milestones=MilestoneManager.from_state(state))
    return data


@dataclass
class LocalizationResult:
    """What a localization run knew after each scan."""

    label: str
    map_path: str
    stamps: FloatArray  # (S,)
    states: list[State]
    poses: FloatArray  # (S, 3) the localized pose, NaN where not localized
    hypotheses: np.ndarray  # (S,) places followed after each scan
    reference: Reference | None
    report: SourceReport
    stats: dict
    time: float  # seconds of the run loop
    step_times: FloatArray  # (S,) seconds each scan took
    interrupted: str | None = None

    @property
    def scans(self) -> int:
        return len(self.stamps)

    @property
    def localized(self) -> np.ndarray:
        return np.array([s is State.LOCALIZED for s in self.states], dtype=bool)

    @property
    def declarations(self) -> np.ndarray:
        """The scans where a localized stretch begins: where a place was declared."""
        loc = self.localized
        return np.flatnonzero(loc & ~np.concatenate([[False], loc[:-1]]))

    def errors(self) -> FloatArray | None:
        """Distance of each localized pose from the truth (NaN elsewhere), when it is known.

        The truth is taken to be in the saved map's frame, as a scenario's maps are (the
        simulator's odometry starts at the true pose)."""
        ref = self.reference
        if ref is None or not ref.truth:
            return None
        return np.hypot(*(self.poses[:, :2] - ref.poses[: self.scans, :2]).T)

    def metrics(self) -> dict:
        loc = self.localized
        first = int(np.argmax(loc)) if loc.any() else None
        starts = self.declarations
        out: dict = {"source": self.label, "version": __version__, "map": self.map_path}
        out.update(self.report.counts)
        out["scans"] = self.scans
        out["scans until localized"] = first if first is not None else "never"
        out["share of scans localized"] = float(loc.mean()) if self.scans else 0.0
        out["times localized"] = len(starts)
        out["scans lost"] = sum(s is State.LOST for s in self.states)
        out["scans ambiguous"] = sum(s is State.AMBIGUOUS for s in self.states)
        out["places searched"] = self.stats.get("places searched", 0)
        out["scans standing still, left out"] = self.stats.get(
            "scans standing still, left out", 0)
        err = self.errors()
        if err is not None:
            out["wrong fixes"] = int((err[starts] > WRONG_FIX).sum())
            out["localized scans farther than 0.5 m"] = int((err[loc] > WRONG_FIX).sum())
            if loc.any():
                out["error of localized poses, RMS (m)"] = float(np.sqrt(np.mean(err[loc]**2)))
                out["error of localized poses, max (m)"] = float(err[loc].max())
        out["localization time (s)"] = self.time
        out["scans per second"] = self.scans / max(self.time, 1e-9)
        tracked = loc & np.concatenate([[False], loc[:-1]])  # localized before and after
        if tracked.any():
            out["tracking: scans per second"] = float(tracked.sum()
                                                      / max(self.step_times[tracked].sum(),
                                                            1e-9))
        if self.interrupted:
            out["interrupted by"] = self.interrupted
        return out

    def write(self, out: Path) -> dict:
        """Write the results folder ``out``; returns the metrics."""
        loc = self.localized
        write_tum(out / "trajectory.tum", self.stamps[loc], self.poses[loc])
        if self.reference is not None and self.reference.truth:
            write_tum(out / "ground_truth.tum", self.stamps,
                      self.reference.poses[: self.scans])
        with atomic_write(out / "states.csv", "w") as f:
            f.write("scan,stamp,state,x,y,theta,hypotheses\n")
            for k in range(self.scans):  # one line per scan, written once
                x, y, th = self.poses[k]
                pose = "," * 2 if math.isnan(x) else f"{x:.4f},{y:.4f},{th:.5f}"
                f.write(f"{k},{self.stamps[k]:.6f},{self.states[k].value},{pose},"
                        f"{self.hypotheses[k]}\n")
        metrics = self.metrics()
        with atomic_write(out / "metrics.json", "w") as f:
            json.dump(metrics, f, indent=1, default=float)
        return metrics


class LocalizationRun(StoppableRun):
    """Localize the frames of one source in a saved map."""

    def __init__(self, saved: MapData, source: Source, config: MappingConfig | None = None,
                 view: View | None = None, *, map_path: str = "", scans: int | None = None,
                 initial_pose: FloatArray | None = None, progress: Progress | None = None,
                 label: str | None = None) -> None:
        saved.check_beams(source.geometry, label or source.name)
        saved.check_as_loaded(label or source.name)
        self.saved, self.source = saved, source
        self.config = config or MappingConfig()
        self.view: View = view or NullView()
        self.map_path, self.scans = map_path, scans
        self.initial_pose, self.progress = initial_pose, progress
        self.label = label or source.name
        self.interrupted: str | None = None

    def run(self) -> LocalizationResult:
        """Localize until the source ends, ``scans`` are done, or :meth:`stop`."""
        return super().run()

    def _run(self) -> LocalizationResult:
        places = Places(self.saved.map, self.saved.milestones,
                        self.saved.trajectory)
        self.view.saved_milestones(self.saved.milestones.ids, self.saved.milestones.poses)
        localizer = Localizer(places, self.config, self.initial_pose)
        stamps: list[float] = []
        states: list[State] = []
        poses: list[FloatArray] = []
        counts: list[int] = []
        took: list[float] = []
        started = time.perf_counter()
        try:
            for frame in self.source:
                t = time.perf_counter()
                step = localizer.step(frame)
                took.append(time.perf_counter() - t)
                stamps.append(frame.stamp)
                states.append(step.state)
                poses.append(step.pose if step.pose is not None else np.full(3, np.nan))
                counts.append(len(step.hypotheses))
                self.view.localization(len(stamps) - 1, frame.stamp, step.state.value,
                                       step.pose, np.array(step.hypotheses).reshape(-1, 3),
                                       frame.true_pose)
                if self.progress is not None:
                    self.progress.status = step.state.value
                    self.progress.update()
                if self.interrupted or (self.scans is not None and len(stamps) >= self.scans):
                    break
        finally:
            self.source.close()
            if self.progress is not None:
                self.progress.close()
        if not stamps:
            why = f" (interrupted by {self.interrupted})" if self.interrupted else ""
            raise InputError(f"{self.label}: no scans to localize{why}")
        elapsed = time.perf_counter() - started
        return LocalizationResult(self.label, self.map_path, np.array(stamps), states,
                                  np.array(poses), np.array(counts),
                                  reference_for(self.source, len(stamps)),
                                  self.source.report(), dict(localizer.stats), elapsed,
                                  np.array(took), self.interrupted)
