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
import signal
import threading
import time
from collections.abc import Callable, Iterator

import numpy as np

from vmp.config import MappingConfig
from vmp.errors import InputError
from vmp.localizer import Localizer, State
from vmp.mapfile import MapData
from vmp.pipeline import Pipeline
from vmp.places import Places
from vmp.progress import Progress
from vmp.results import Result
from vmp.source import Source, reference_for
from vmp.types import BeamGeometry, ScanFrame
from vmp.view import View

__all__ = ["MappingRun", "StoppableRun", "stop_on_signals"]

SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def stop_on_signals(on_signal: Callable[[str], None]) -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM call ``on_signal(name)`` once; a second one raises
    KeyboardInterrupt. Outside the main thread (where Python takes no signals) it does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    seen: list[str] = []

    def handler(signum: int, _frame: object) -> None:
        if seen:
            raise KeyboardInterrupt
        seen.append(signal.Signals(signum).name)
        on_signal(seen[0])

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
    the odometry's).
    """

    def __init__(self, source: Source, config: MappingConfig | None = None,
                 view: View | None = None, *, scans: int | None = None,
                 progress: Progress | None = None, label: str | None = None,
                 saved: MapData | None = None) -> None:
        if saved is not None:
            saved.check_beams(source.geometry, label or source.name)
        self.saved = saved
        self.source = source
        self.config = config or MappingConfig()
        self.view = view
        self.scans = scans
        self.progress = progress
        self.label = label or source.name
        self.interrupted: str | None = None

    def run(self) -> Result:
        """Map until the source ends, ``scans`` are mapped, or :meth:`stop`; finish the map."""
        return super().run()

    def _run(self) -> Result:
        geometry = self.source.geometry
        saved = self.saved
        before = 0 if saved is None else len(saved.map)  # the saved map's scans
        old = (np.zeros(0), np.zeros((0, 3))) if saved is None else (
            saved.map.stamps[:before].copy(), saved.trajectory[:before].copy())
        pipeline = None if saved is not None else Pipeline(geometry, self.config, self.view)
        localizer = (None if saved is None else
                     Localizer(Places(saved.map, saved.milestones, saved.trajectory), self.config,
                               wheels=False))
        unplaced = 0  # scans before the robot was localized in the saved map
        stamps: list[float] = []
        online: list[np.ndarray] = []
        odometry: list[np.ndarray] = []
        started = time.perf_counter()
        try:
            for frame in self.source:
                if frame.geometry != geometry:
                    raise InputError(f"{self.label}: scan {len(stamps)} has other beams "
                                     f"({frame.geometry}) than the first ({geometry})")
                if pipeline is None:
                    unplaced += 1
                    pipeline = self._place(localizer, frame, geometry)
                else:
                    pipeline.step(frame)
                    stamps.append(frame.stamp)
                    online.append(pipeline.pose.copy())
                    odometry.append(pipeline.front.odom_pose.copy())
                if self.progress is not None:
                    self.progress.status = self.source.report().status
                    self.progress.update()
                if self.interrupted or (self.scans is not None
                                         and unplaced + len(stamps) >= self.scans):
                    break
        finally:
            self.source.close()
            if self.progress is not None:
                self.progress.close()
        if not stamps:
            why = f" (interrupted by {self.interrupted})" if self.interrupted else ""
            if saved is not None:
                raise InputError(f"{self.label}: not localized in the saved map in {unplaced} "
                                 f"scans{why}: nothing to go on from (is it the same "
                                 "building?)")
            raise InputError(f"{self.label}: no scans to map{why}")
        if saved is not None:
            pipeline.stats["scans before localized in the saved map"] = unplaced
        pipeline.finish()
        trajectory = pipeline.trajectory()
        elapsed = time.perf_counter() - started
        reference = reference_for(self.source, len(stamps)) if saved is None else None
        return Result(self.label, self.config, pipeline, np.r_[old[0], stamps], trajectory,
                      np.vstack([old[1], *online]), np.vstack([old[1], *odometry]), reference,
                      self.source.report(), elapsed, self.interrupted)

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
