"""One mapping run: open nothing, know nothing of formats; step the pipeline over a source.

``MappingRun(source, config, view).run()`` is the one loop over frames that steps the pipeline:
``vmp map``, ``vmp live``, the tests and every benchmark go through it. It records the
trajectories (the filter's pose, odometry alone) as it goes, finishes the map and returns a
:class:`~vmp.results.Result`, which writes the results folder.

Ctrl-C and SIGTERM end a run the same way: the current scan is finished, the source is
closed, the map is finished with what was mapped so far, and the result says which signal
ended it. A second signal aborts at once.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from milestones.jit import compile_seconds
from vmp.checkpoint import Every, fingerprint, load_checkpoint, save_checkpoint
from vmp.config import MappingConfig
from vmp.errors import InputError
from vmp.localizer import Localizer, State
from vmp.mapfile import MapData
from vmp.pipeline import Pipeline
from vmp.places import Places
from vmp.progress import Progress
from vmp.registration import MIN_POINTS
from vmp.results import Result
from vmp.source import Source, reference_for
from vmp.types import BeamGeometry, ScanFrame
from vmp.view import NullView, View

__all__ = ["MappingRun", "StoppableRun", "stop_on_signals"]

SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def stop_on_signals(on_signal: Callable[[str], None]) -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM call ``on_signal(name)`` once; later ones say,
    once, that the results are being kept, and change nothing: a user pressing Ctrl-C again
    and again must not lose what was mapped (aborting the writing would leave only a
    partial folder). Outside the main thread (where Python takes no signals) it does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    seen: list[str] = []

    def handler(signum: int, _frame: object) -> None:
        seen.append(signal.Signals(signum).name)
        if len(seen) == 1:
            on_signal(seen[0])
        elif len(seen) == 2:
            os.write(2, f"vmp: {seen[-1]} again: what was mapped is being finished and "
                        "written, and is kept (SIGKILL would lose what is not yet "
                        "written)\n".encode())

    previous = {s: signal.signal(s, handler) for s in SIGNALS}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


class StoppableRun:
    """A run over a source's frames that Ctrl-C, SIGTERM or :meth:`stop` end after the
    current scan; subclasses step their frames in ``_run``."""

    source: Source
    interrupted: str | None = None

    def stop(self, why: str = "stop") -> None:
        """End the run after the current scan; safe from a signal handler or another thread."""
        self.interrupted = self.interrupted or why
        self.source.close()

    def run(self):
        """Run until the source ends, its scan limit, or :meth:`stop`."""
        with stop_on_signals(self.stop):
            return self._run()

    def _run(self):
        raise NotImplementedError


class MappingRun(StoppableRun):
    """Map the frames of one source into a vector map with milestones.

    ``scans`` stops the run after that many frames; ``progress`` counts them; ``label`` names
    the source in the metrics (default: its name). With ``saved``, a map saved before, the
    run goes on mapping in it: the scans are localized in it first (:mod:`vmp.localizer`,
    no pose needed), and from the first localized scan on they are mapped into it, the new
    milestones joined to the old ones where the robot was found. The result holds both
    sessions' scans (before this one, the saved map's poses stand in for the filter's and
    the odometry's). The run maps on in ``saved`` itself: load the map again for another.

    With ``checkpoint`` (a file) and ``every``, the run writes its whole state there that
    often (:mod:`vmp.checkpoint`); with ``resume`` (such a file) it starts from that state,
    skipping the frames of the source it had used: the result is the uninterrupted run's.
    """

    def __init__(self, source: Source, config: MappingConfig | None = None,
                 view: View | None = None, *, scans: int | None = None,
                 progress: Progress | None = None, label: str | None = None,
                 saved: MapData | None = None, checkpoint: Path | None = None,
                 every: Every | None = None, resume: Path | None = None) -> None:
        if saved is not None:
            saved.check_beams(source.geometry, label or source.name)
            saved.check_as_loaded(label or source.name)
        self.saved = saved
        self.source = source
        self.config = config or MappingConfig()
        self.view = view
        self.scans = scans
        self.progress = progress
        self.label = label or source.name
        self.interrupted: str | None = None
        self.checkpoint = checkpoint
        self.every = every
        self.skip, self.last = 0, ""  # frames a resumed run skips; the last one's fingerprint
        self.state = self._resume(resume) if resume is not None else self._start()

    def run(self) -> Result:
        """Map until the source ends, ``scans`` are mapped, or :meth:`stop`; finish the map."""
        return super().run()

    def _start(self) -> dict:
        """The state of a run that has used no frame yet."""
        saved = self.saved
        before = 0 if saved is None else len(saved.map)  # the saved map's scans
        return {
            "pipeline": None if saved is not None else Pipeline(self.source.geometry,
                                                                 self.config, self.view),
            "old_stamps": np.zeros(0) if saved is None else saved.map.stamps[:before].copy(),
            "old_poses": np.zeros((0, 3)) if saved is None else saved.trajectory[:before].copy(),
            "unplaced": 0,  # scans before the robot was localized in the saved map
            "blind": 0,  # scans left out before the first with enough returns to begin at
            "stamps": [], "online": [], "odometry": [],
            "seconds": 0.0,  # mapping time before this process
        }

    def _resume(self, path: Path) -> dict:
        """The state a checkpoint holds; the frames it used are skipped when running."""
        state, self.skip, self.last, label = load_checkpoint(
            path, {"view": self.view or NullView()})
        if label != self.source.name:
            raise InputError(f"{path}: a checkpoint of {label}, not of {self.source.name}")
        self.config = state["pipeline"].config
        self.saved = None  # the pipeline holds the saved map already
        return state

    def _save(self, frames: int, frame: ScanFrame, seconds: float) -> None:
        s = dict(self.state, seconds=seconds)
        stats = s["pipeline"].stats
        stats["checkpoints written"] += 1
        t = time.perf_counter()
        save_checkpoint(self.checkpoint, s, frames, fingerprint(frame), self.source.name,
                        {"view": s["pipeline"].view})
        stats["checkpoint seconds"] += time.perf_counter() - t

    def _run(self) -> Result:
        geometry = self.source.geometry
        s = self.state
        stamps, online, odometry = s["stamps"], s["online"], s["odometry"]
        localizer = (None if s["pipeline"] is not None else
                     Localizer(Places(self.saved.map, self.saved.milestones,
                                      self.saved.trajectory), self.config))
        started = time.perf_counter()
        compiled_before = compile_seconds()
        saved_at = (started, len(stamps))  # when, and after how many scans, the last checkpoint
        frames = 0  # frames taken from the source
        try:
            for frame in self.source:
                frames += 1
                if frames <= self.skip:
                    if frames == self.skip and fingerprint(frame) != self.last:
                        raise InputError(f"{self.label}: frame {frames} is not the one the "
                                         "checkpoint ended at: another source, or changed")
                    if self.progress is not None:
                        self.progress.update()
                    continue
                if frame.geometry != geometry:
                    raise InputError(f"{self.label}: scan {len(stamps)} has other beams "
                                     f"({frame.geometry.describe()}, {frame.max_range:g} m) "
                                     f"than the first ({geometry.describe()}, "
                                     f"{geometry.max_range:g} m): every scan of a log must "
                                     "have the first scan's beams")
                pipeline = s["pipeline"]
                if (pipeline is not None and pipeline.back.anchor is None
                        and int(frame.returned.sum()) < MIN_POINTS):
                    # The map begins at a milestone, and a scan with so few returns makes none.
                    s["blind"] += 1
                    continue
                if pipeline is None:
                    s["unplaced"] += 1
                    s["pipeline"] = self._place(localizer, frame, geometry)
                else:
                    pipeline.step(frame)
                    stamps.append(frame.stamp)
                    online.append(pipeline.pose.copy())
                    odometry.append(pipeline.front.odom_pose.copy())
                if self.progress is not None:
                    self.progress.status = self.source.report().status
                    self.progress.update()
                if self.interrupted or (self.scans is not None
                                         and s["unplaced"] + len(stamps) >= self.scans):
                    break
                now = time.perf_counter()
                if (self.checkpoint is not None and self.every is not None
                        and s["pipeline"] is not None
                        and self.every.due(len(stamps) - saved_at[1], now - saved_at[0])):
                    self._save(frames, frame, s["seconds"] + now - started)
                    saved_at = (time.perf_counter(), len(stamps))
        finally:
            self.source.close()
            if self.progress is not None:
                self.progress.close()
        if frames < self.skip:
            raise InputError(f"{self.label}: the source ends after {frames} frames, before "
                             f"the {self.skip} the checkpoint had used")
        pipeline = s["pipeline"]
        unplaced = s["unplaced"]
        if not stamps:
            why = f" (interrupted by {self.interrupted})" if self.interrupted else ""
            if pipeline is None:
                raise InputError(f"{self.label}: not localized in the saved map in {unplaced} "
                                 f"scans{why}: nothing to go on from (is it the same "
                                 "building?)")
            if s["blind"]:
                raise InputError(f"{self.label}: no scan to begin the map at: none of its "
                                 f"{s['blind']} scans has {MIN_POINTS} returns or more{why}")
            raise InputError(f"{self.label}: no scans to map{why}")
        if len(s["old_stamps"]):
            pipeline.stats["scans before localized in the saved map"] = unplaced
        if s["blind"]:
            pipeline.stats["scans left out before the first with returns to begin at"] = s["blind"]
        pipeline.finish()
        trajectory = pipeline.trajectory()
        elapsed = s["seconds"] + time.perf_counter() - started
        reference = (reference_for(self.source, len(stamps)) if not len(s["old_stamps"])
                     else None)
        old_stamps, old_poses = s["old_stamps"], s["old_poses"]
        return Result(self.label, self.config, pipeline, np.r_[old_stamps, stamps], trajectory,
                      np.vstack([old_poses, *online]), np.vstack([old_poses, *odometry]),
                      reference, self.source.report(), elapsed, self.interrupted,
                      compiling_time=compile_seconds() - compiled_before)

    def _place(self, localizer: Localizer, frame: ScanFrame, geometry: BeamGeometry
               ) -> Pipeline | None:
        """Localize a scan in the saved map; once localized, the pipeline that maps on in it
        from there (None before)."""
        if localizer.step(frame).state is not State.LOCALIZED:
            return None
        pipeline = Pipeline(geometry, self.config, self.view, saved=self.saved)
        found = localizer.hypotheses[0]
        localizer.front.filter = found.filter
        pipeline.join(localizer.front, localizer.places.nearest(found.pose).milestone)
        return pipeline
