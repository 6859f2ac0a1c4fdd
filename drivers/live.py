"""A serial scanner as a source: frames as they arrive, recorded as they go.

Every scan is written to a CARMEN log first and yielded as read back from the line just
written, so ``vmp map`` on that log reproduces the live run bit for bit. Odometry comes from a
JSON-lines pose feed when one is given; otherwise scans carry none and the run relies on scan
registration alone (the report says which).
"""

from __future__ import annotations

import dataclasses
import queue
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

from drivers.carmen import parse_laser_line
from drivers.carmen_writer import CarmenWriter
from drivers.devices.pty_device import PtyDevice
from drivers.pose_feed import PoseFeed
from drivers.serial_scanner import ScanDriver
from vmp.errors import InputError
from vmp.source import Reference, SourceReport
from vmp.types import BeamGeometry, ScanFrame

__all__ = ["LiveSource"]

QUEUE = 1000  # frames waiting for the mapper before the oldest is dropped
FLUSH_EVERY = 1.0  # seconds between flushes of the recording
FIRST_SCAN_WARNING = 5.0  # seconds without a first scan before saying so


class _Reader:
    """Reads the driver in its own thread so that a slow mapping step never stalls the port.

    A serial port's buffer holds a few kilobytes: a mapper that stops reading for a second
    (a graph adjustment) would lose bytes and scans. Frames wait in a queue instead; when
    it is full the oldest is dropped and counted.
    """

    _END = object()

    def __init__(self, driver: ScanDriver, size: int = QUEUE) -> None:
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


class LiveSource:
    """Frames of a serial scanner, recorded to ``record_to`` as they arrive.

    ``odometry`` names a pose feed (port, pipe or file); ``duration`` ends the stream after so
    many seconds; ``devices`` are simulated devices feeding the driver (the stream ends when
    the first has sent its whole run, and they are closed with the source); ``length`` is how
    many frames to expect, when known.
    """

    def __init__(self, driver: ScanDriver, record_to: Path, *, odometry: str | None = None,
                 duration: float | None = None, devices: tuple[PtyDevice, ...] = (),
                 length: int | None = None, name: str | None = None) -> None:
        self.driver = driver
        self.record_to = Path(record_to)
        self.odometry = odometry
        self.duration = duration
        self.devices = devices
        self.length = length
        self.name = name or f"live-{driver.name}"
        self._stop = threading.Event()
        self._reader = _Reader(driver)
        self._feed = PoseFeed(odometry) if odometry else None
        self._writer: CarmenWriter | None = None
        self._frames: Iterator[ScanFrame] | None = None
        self._first: ScanFrame | None = None
        self._mapped = 0
        self._waiting = 0  # scans that came before the first odometry
        self._shut = False

    @property
    def geometry(self) -> BeamGeometry:
        """The beams of the first scan (waits for it)."""
        if self._first is None:
            if self._frames is None:
                self._frames = self._stream()
            self._first = next(self._frames, None)
            if self._first is None:
                d = self.driver
                raise InputError(f"{d.port}: no scan arrived from the {d.name} "
                                 f"({d.last_error or d.stats.summary()})")
        return self._first.geometry

    def __iter__(self) -> Iterator[ScanFrame]:
        self.geometry  # noqa: B018 - waits for the first frame
        assert self._first is not None and self._frames is not None
        yield self._first
        yield from self._frames

    def _stream(self) -> Iterator[ScanFrame]:
        if self._feed is not None:
            self._feed.start()
        self._writer = CarmenWriter(self.record_to, atomic=False,
                                    comment=f"vmp live, {self.driver.name} on {self.driver.port}")
        threading.Thread(target=self._watch, name="live-watchdog", daemon=True).start()
        last_flush = time.monotonic()
        try:
            for frame in self._reader.frames():
                if self._feed is not None:
                    odom = self._feed.pose_at(frame.stamp)
                    if odom is None:
                        self._waiting += 1  # no odometry yet: the scan cannot be placed
                        continue
                    frame = dataclasses.replace(frame, odom=odom)
                line = self._writer.write(frame)
                frame = parse_laser_line(line, self._writer.params, index=self._mapped)
                self._mapped += 1
                if time.monotonic() - last_flush > FLUSH_EVERY:
                    self._writer.flush()
                    last_flush = time.monotonic()
                yield frame
        finally:
            self.shutdown()

    def _watch(self) -> None:
        """End the stream (which only wakes up on data) when it is due; warn on silence."""
        started = time.monotonic()
        warned = False
        while not self._stop.wait(0.05):
            if not warned and not self._mapped and time.monotonic() - started > \
                    FIRST_SCAN_WARNING:
                warned = True
                why = self.driver.last_error or "no answer yet"
                print(f"live: no scan from {self.driver.name} on {self.driver.port} after "
                      f"{FIRST_SCAN_WARNING:g} s ({why}); still trying, Ctrl-C to stop",
                      file=sys.stderr, flush=True)
            over = self.duration is not None and time.monotonic() - started > self.duration
            done = bool(self.devices) and self.devices[0].finished.is_set()
            if over or done:
                if done:
                    time.sleep(0.5)  # let the last scans arrive
                self.close()
                return

    def close(self) -> None:
        """End the stream at its next frame; safe from a signal handler or another thread."""
        self._stop.set()
        self.driver.close()

    def shutdown(self) -> None:
        """Close the stream, the recording, the pose feed and the simulated devices."""
        self.close()
        if self._shut:
            return
        self._shut = True
        if self._writer is not None:
            self._writer.close()
        if self._feed is not None:
            self._feed.close()
            if self._feed.bad or self._feed.error:
                print(self._feed.summary(), file=sys.stderr)
            self._feed = None
        for d in self.devices:
            d.close()

    def reference(self) -> Reference | None:
        return None

    def report(self) -> SourceReport:
        s = self.driver.stats
        odometry = (f"pose feed {self.odometry}" if self.odometry
                    else "none: scan registration only")
        return SourceReport(item="scan", counts={
            "odometry": odometry,
            "link: scans received": s.scans,
            "link: checksum errors": s.checksum_errors,
            "link: framing errors": s.framing_errors,
            "link: rejected": s.rejected,
            "link: silences": s.timeouts,
            "link: stalls": s.stalls,
            "link: reconnects": s.reconnects,
            "scans waiting for odometry": self._waiting,
            "scans dropped (mapping fell behind)": self._reader.dropped,
        }, status=(f"errors {s.errors()} (checksum {s.checksum_errors}), silences "
                   f"{s.timeouts}, queued {self._reader.queue.qsize()}"))
