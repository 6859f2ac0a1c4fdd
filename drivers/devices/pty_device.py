"""A device served on a pseudo-terminal: the thread, the clock, corruption, silence, power cycles.

A subclass implements one protocol: :meth:`PtyDevice.boot` (what the device does on power-up),
:meth:`PtyDevice.receive` (bytes from the host) and :meth:`PtyDevice.tick` (streaming). It
sends with :meth:`PtyDevice.send`, marking scans with their sequence number so that a test can
tell which scans left the device intact.
"""

from __future__ import annotations

import dataclasses
import os
import select
import threading
import time
import tty
from dataclasses import dataclass, field

import numpy as np

from drivers.scenario import Scenario, SensorModel
from drivers.simulator import Simulator
from vmp.types import FloatArray

__all__ = ["Corruption", "PtyDevice", "ScanSource", "SentScan"]


@dataclass(frozen=True)
class Corruption:
    """Byte corruption on the wire: each byte is hit with probability ``rate``.

    A hit byte has one random bit flipped, is dropped, or starts a burst of ``burst`` random
    bytes that replace the following ones, in the proportions ``flip : drop : burst``.
    """

    rate: float = 0.0
    flip: float = 0.6
    drop: float = 0.2
    burst: float = 0.2
    burst_len: int = 8

    def __post_init__(self) -> None:
        if not 0.0 <= self.rate <= 1.0:
            raise ValueError(f"corruption rate must lie in [0, 1], got {self.rate}")

    def apply(self, data: bytes, rng: np.random.Generator) -> tuple[bytes, bool]:
        """The bytes as they arrive, and whether any was changed."""
        if self.rate == 0.0 or not data:
            return data, False
        a = np.frombuffer(data, dtype=np.uint8).copy()
        hit = np.flatnonzero(rng.random(a.size) < self.rate)
        if hit.size == 0:
            return data, False
        total = self.flip + self.drop + self.burst
        kind = rng.choice(3, size=hit.size, p=[self.flip / total, self.drop / total,
                                                 self.burst / total])
        flips = hit[kind == 0]
        a[flips] ^= (1 << rng.integers(0, 8, flips.size)).astype(np.uint8)
        for start in hit[kind == 2]:  # a handful per call at the rates that matter
            stop = min(a.size, start + self.burst_len)
            a[start:stop] = rng.integers(0, 256, stop - start, dtype=np.uint8)
        keep = np.ones(a.size, dtype=bool)
        keep[hit[kind == 1]] = False
        return a[keep].tobytes(), True


@dataclass
class SentScan:
    """What the device sent for one scan: its ranges in device units and whether it left intact."""

    seq: int
    values: np.ndarray
    intact: bool


class ScanSource:
    """Ranges of a scenario run as a device of the given geometry sees them, with the odometry.

    ``ranges(k)`` and ``odom(k)`` for k = 0 .. len-1; the scenario's own sensor geometry is
    replaced by the device's.
    """

    def __init__(self, scenario: Scenario, sensor: SensorModel, seed: int | None = None,
                 max_scans: int | None = None) -> None:
        self._args = (scenario, seed, max_scans)
        scenario = dataclasses.replace(scenario, sensor=sensor)
        self.sim = Simulator(scenario, seed=seed, max_scans=max_scans)
        self.sensor = sensor
        self._cache: dict[int, FloatArray] = {}
        self._rng = np.random.default_rng(self.sim.seed)

    def __len__(self) -> int:
        return len(self.sim)

    def with_sensor(self, sensor: SensorModel) -> ScanSource:
        """The same run seen by another sensor (same poses, same odometry)."""
        scenario, seed, max_scans = self._args
        return ScanSource(scenario, sensor, seed, max_scans)

    @property
    def period(self) -> float:
        return 1.0 / self.sensor.rate_hz

    def ranges(self, k: int) -> FloatArray:
        """Ranges in metres (``inf``: no return) of scan ``k`` (computed 16 at a time)."""
        if k not in self._cache:
            b0 = k - k % 16
            poses = self.sim.true_poses[b0:b0 + 16]
            r = self.sim.ranges_at(poses, self.sim.stamps[b0:b0 + 16], self._rng)
            self._cache = {b0 + i: row for i, row in enumerate(r)}
        return self._cache[k]

    def odom(self, k: int) -> FloatArray:
        return self.sim.odom_poses[k]

    def true_pose(self, k: int) -> FloatArray:
        return self.sim.true_poses[k]


@dataclass
class _Control:
    silent: bool = False
    power_cycle: bool = False
    stop: bool = False
    lock: threading.Lock = field(default_factory=threading.Lock)


class PtyDevice:
    """Base of the simulated scanners: serves the device on a pty from a thread.

    ``port`` is the path a driver opens. ``speed`` scales the device clock (2.0 streams twice
    as fast as the real device). ``corruption`` applies to every byte the device sends;
    ``seed`` makes it reproducible. ``sent`` lists every scan the device sent with whether it
    left intact; ``finished`` is set when the scan source is exhausted.
    """

    name = "device"

    def __init__(self, source: ScanSource | None = None, *, corruption: Corruption | float = 0.0,
                 seed: int = 0, speed: float = 1.0) -> None:
        self.source = source
        self.corruption = (corruption if isinstance(corruption, Corruption)
                           else Corruption(rate=float(corruption)))
        self.speed = speed
        self._rng = np.random.default_rng(seed)
        self._master, self._slave = os.openpty()
        tty.setraw(self._master)
        os.set_blocking(self._master, False)
        self.port = os.ttyname(self._slave)
        self._ctl = _Control()
        self.sent: list[SentScan] = []
        self.finished = threading.Event()
        self.bytes_sent = 0
        self.bytes_dropped = 0  # the host did not read fast enough
        self._thread = threading.Thread(target=self._run, name=f"{self.name}-sim", daemon=True)
        self._next_scan = 0
        self._t0 = time.monotonic()

    # -- control from the test or the CLI ---------------------------------------------------
    def start(self) -> PtyDevice:
        self.boot()
        self._thread.start()
        return self

    def close(self) -> None:
        self._ctl.stop = True
        self._thread.join(timeout=5.0)
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> PtyDevice:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def go_silent(self) -> None:
        """Power off: nothing is sent and what the host sends is lost until :meth:`power_on`."""
        with self._ctl.lock:
            self._ctl.silent = True

    def power_on(self) -> None:
        """Power back on: the device boots as after a power cycle."""
        with self._ctl.lock:
            self._ctl.silent = False
            self._ctl.power_cycle = True

    @property
    def silent(self) -> bool:
        return self._ctl.silent

    def device_time(self) -> float:
        """Seconds of device time since start (scaled by ``speed``)."""
        return (time.monotonic() - self._t0) * self.speed

    # -- for subclasses -------------------------------------------------------------------
    def boot(self) -> None:
        """Reset the protocol state as at power-up and send what the device sends then."""

    def receive(self, data: bytes) -> None:
        """Handle bytes from the host."""

    def tick(self) -> None:
        """Send whatever is due now (scans while streaming)."""

    def next_scan(self) -> int | None:
        """The index of the next scan to send when one is due by the device clock, else None.

        Scans are taken from the source in order at its rate; at the end ``finished`` is set.
        """
        if self.source is None:
            return None
        k = self._next_scan
        if k >= len(self.source):
            self.finished.set()
            return None
        if self.device_time() < k * self.source.period:
            return None
        self._next_scan += 1
        return k

    def rewind_clock(self) -> None:
        """Scans resume from the current device time (after a stop or a power cycle)."""
        if self.source is None:
            return
        due = int(self.device_time() / self.source.period)
        self._next_scan = max(self._next_scan, min(due, len(self.source)))

    def send(self, data: bytes, scan: tuple[int, np.ndarray] | None = None) -> None:
        """Send bytes through the corrupting wire; ``scan`` = (seq, values) records a scan."""
        if self._ctl.silent:
            return
        out, changed = self.corruption.apply(data, self._rng)
        record = None
        if scan is not None:
            record = SentScan(scan[0], scan[1], not changed)
            self.sent.append(record)
        view = memoryview(out)
        deadline = time.monotonic() + 0.5
        while view and not self._ctl.stop:
            try:
                n = os.write(self._master, view)
            except BlockingIOError:
                n = 0
            except OSError:
                return
            self.bytes_sent += n
            view = view[n:]
            if view:
                if time.monotonic() > deadline:  # nobody reads: the bytes are lost
                    self.bytes_dropped += len(view)
                    if record is not None:
                        record.intact = False
                    return
                select.select([], [self._master], [], 0.01)

    # -- the thread -----------------------------------------------------------------------
    def _run(self) -> None:
        while not self._ctl.stop:
            if self._ctl.power_cycle:
                with self._ctl.lock:
                    self._ctl.power_cycle = False
                self.boot()
                self.rewind_clock()
            try:
                ready, _, _ = select.select([self._master], [], [], 0.002)
            except (OSError, ValueError):
                return
            if ready:
                try:
                    data = os.read(self._master, 4096)
                except BlockingIOError:
                    data = b""
                except OSError:
                    data = b""
                if data and not self._ctl.silent:
                    self.receive(data)
            if not self._ctl.silent:
                self.tick()
