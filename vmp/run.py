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
from vmp.pipeline import Pipeline
from vmp.progress import Progress
from vmp.results import Result
from vmp.source import Source, reference_for
from vmp.view import View

__all__ = ["MappingRun", "stop_on_signals"]

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


class MappingRun:
    """Map the frames of one source into a vector map with milestones.

    ``scans`` stops the run after that many frames; ``progress`` counts them; ``label`` names
    the source in the metrics (default: its name).
    """

    def __init__(self, source: Source, config: MappingConfig | None = None,
                 view: View | None = None, *, scans: int | None = None,
                 progress: Progress | None = None, label: str | None = None) -> None:
        self.source = source
        self.config = config or MappingConfig()
        self.view = view
        self.scans = scans
        self.progress = progress
        self.label = label or source.name
        self.interrupted: str | None = None

    def stop(self, why: str = "stop") -> None:
        """End the run after the current scan; safe from a signal handler or another thread."""
        self.interrupted = self.interrupted or why
        self.source.close()

    def run(self) -> Result:
        """Map until the source ends, ``scans`` are mapped, or :meth:`stop`; finish the map."""
        with stop_on_signals(self.stop):
            return self._run()

    def _run(self) -> Result:
        geometry = self.source.geometry
        pipeline = Pipeline(geometry, self.config, self.view)
        stamps: list[float] = []
        online: list[np.ndarray] = []
        odometry: list[np.ndarray] = []
        started = time.perf_counter()
        try:
            for frame in self.source:
                if frame.geometry != geometry:
                    raise InputError(f"{self.label}: scan {len(stamps)} has other beams "
                                     f"({frame.geometry}) than the first ({geometry})")
                pipeline.step(frame)
                stamps.append(frame.stamp)
                online.append(pipeline.pose.copy())
                odometry.append(pipeline.front.odom_pose.copy())
                if self.progress is not None:
                    self.progress.status = self.source.report().status
                    self.progress.update()
                if self.interrupted or (self.scans is not None and len(stamps) >= self.scans):
                    break
        finally:
            self.source.close()
            if self.progress is not None:
                self.progress.close()
        if not stamps:
            why = f" (interrupted by {self.interrupted})" if self.interrupted else ""
            raise InputError(f"{self.label}: no scans to map{why}")
        pipeline.finish()
        trajectory = pipeline.trajectory()
        elapsed = time.perf_counter() - started
        return Result(self.label, self.config, pipeline, np.array(stamps), trajectory,
                      np.array(online), np.array(odometry), reference_for(self.source, len(stamps)),
                      self.source.report(), elapsed, self.interrupted)
