"""``vmp live``: map as scans arrive from a serial scanner (or a simulated one on a pty).

Every scan is written to a CARMEN log first and the mapper is fed the frame read back from
the line just written, so ``vmp map`` on that log reproduces the live run bit for bit.
Odometry comes from a JSON-lines pose feed when one is given; otherwise the run relies on
scan registration alone, and the summary says which.
"""

from __future__ import annotations

import dataclasses
import queue
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.carmen import CarmenWriter, parse_laser_line
from drivers.devices.pty_device import PtyDevice
from drivers.pose_feed import PoseFeed
from drivers.serial_scanner import ScanDriver
from vmp.errors import InputError
from vmp.pipeline import Pipeline, PipelineConfig
from vmp.progress import Progress
from vmp.results import new_results_dir, write_results
from vmp.types import ScanFrame
from vmp.vector_map import BeamGeometry
from vmp.view import View

__all__ = ["LiveOptions", "LiveRun", "run_live"]


@dataclass
class LiveOptions:
    """What a live run needs besides the driver: where odometry comes from, when to stop."""

    out: Path = Path("results")
    name: str = "live"
    odometry: str | None = None  # a pose feed (port, pipe or file); None: registration only
    scans: int | None = None  # stop after this many mapped scans
    duration: float | None = None  # stop after this many seconds
    resolution: float = 0.05
    quiet: bool = False


@dataclass
class LiveRun:
    """The outcome of a live run."""

    out: Path
    log: Path
    metrics: dict
    interrupted: bool
    odometry: str


class _Reader:
    """Reads the driver in its own thread so that a slow mapping step never stalls the port.

    A serial port's buffer holds a few kilobytes: a mapper that stops reading for a second
    (a graph adjustment) would lose bytes and scans. Frames wait in a queue instead; when
    it is full the oldest is dropped and counted.
    """

    _END = object()

    def __init__(self, driver: ScanDriver, size: int = 1000) -> None:
        self.driver = driver
        self.queue: queue.Queue = queue.Queue(maxsize=size)
        self.dropped = 0
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="live-reader", daemon=True)

    def _put(self, item: object) -> None:
        while True:
            try:
                self.queue.put_nowait(item)
                return
            except queue.Full:
                try:
                    self.queue.get_nowait()
                    self.dropped += 1
                except queue.Empty:
                    pass

    def _run(self) -> None:
        try:
            for frame in self.driver.frames():
                self._put(frame)
        except BaseException as exc:  # handed to the mapping thread, raised there
            self.error = exc
        finally:
            self._put(self._END)

    def frames(self) -> Iterator[ScanFrame]:
        self._thread.start()
        try:
            while True:
                item = self.queue.get()
                if item is self._END:
                    if self.error is not None:
                        raise self.error
                    return
                yield item
        finally:
            self.driver.close()
            self._thread.join(timeout=5.0)


def run_live(driver: ScanDriver, config: PipelineConfig, options: LiveOptions, *,
             devices: tuple[PtyDevice, ...] = (), view: View | None = None) -> LiveRun:
    """Map the scans of ``driver`` until a stop condition, Ctrl-C, or the simulated run ends.

    ``devices`` are simulated devices feeding the driver: when the first has sent its whole
    run the live run ends too.
    """
    out = new_results_dir(options.out, options.name)
    log_path = out / "live.clf"
    feed = PoseFeed(options.odometry).start() if options.odometry else None
    odometry = (f"pose feed {options.odometry}" if feed is not None
                else "none: scan registration only")
    writer = CarmenWriter(log_path, atomic=False,
                          comment=f"vmp live, {driver.name} on {driver.port}")
    stop = threading.Event()
    started = time.monotonic()
    stamps: list[float] = []

    def watchdog() -> None:  # ends the frame loop, which only wakes up on data
        warned = False
        while not stop.wait(0.05):
            if not warned and not stamps and time.monotonic() - started > 5.0:
                warned = True
                why = driver.last_error or "no answer yet"
                print(f"live: no scan from {driver.name} on {driver.port} after 5 s ({why}); "
                      "still trying, Ctrl-C to stop", file=sys.stderr, flush=True)
            over = options.duration is not None and time.monotonic() - started > options.duration
            done = bool(devices) and devices[0].finished.is_set()
            if over or done:
                if done:
                    time.sleep(0.5)  # let the last scans arrive
                driver.close()
                return

    threading.Thread(target=watchdog, name="live-watchdog", daemon=True).start()
    total = options.scans
    if total is None and devices and devices[0].source is not None:
        total = len(devices[0].source)
    progress = Progress(total, f"live {driver.name}", enabled=False if options.quiet else None)
    pipeline: Pipeline | None = None
    waiting = 0
    interrupted = False
    last_flush = time.monotonic()
    reader = _Reader(driver)
    try:
        for frame in reader.frames():
            if feed is not None:
                odom = feed.pose_at(frame.stamp)
                if odom is None:
                    waiting += 1  # no odometry yet: the scan cannot be placed
                    continue
                frame = dataclasses.replace(frame, odom=odom)
            line = writer.write(frame)
            frame = parse_laser_line(line, writer.params, index=len(stamps))
            if pipeline is None:
                geom = BeamGeometry(frame.num_beams, frame.angle_min, frame.angle_increment,
                                    frame.max_range)
                pipeline = Pipeline(geom, config, view)
            pipeline.step(frame)
            stamps.append(frame.stamp)
            s = driver.stats
            progress.status = (f"errors {s.errors()} (checksum {s.checksum_errors}), "
                               f"silences {s.timeouts}, queued {reader.queue.qsize()}")
            progress.update()
            if time.monotonic() - last_flush > 1.0:
                writer.flush()
                last_flush = time.monotonic()
            if options.scans is not None and len(stamps) >= options.scans:
                break
    except KeyboardInterrupt:
        interrupted = True
    finally:
        stop.set()
        driver.close()
        progress.close()
        writer.close()
        if feed is not None:
            feed.close()
    if pipeline is None:
        raise InputError(f"{driver.port}: no scan arrived from the {driver.name} "
                         f"({driver.last_error or driver.stats.summary()})")
    pipeline.finish()
    s = driver.stats
    pipeline.stats.update({
        "link: scans received": s.scans,
        "link: checksum errors": s.checksum_errors,
        "link: framing errors": s.framing_errors,
        "link: rejected": s.rejected,
        "link: silences": s.timeouts,
        "link: reconnects": s.reconnects,
        "scans waiting for odometry": waiting,
        "scans dropped (mapping fell behind)": reader.dropped,
    })
    metrics = write_results(out, pipeline, np.array(stamps), f"live {driver.name} {driver.port}",
                            options.resolution, extra={"odometry": odometry})
    if feed is not None and feed.bad:
        print(feed.summary(), file=sys.stderr)
    return LiveRun(out, log_path, metrics, interrupted, odometry)
