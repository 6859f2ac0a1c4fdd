"""A device served on a pseudo-terminal: the thread, the clock, the wire, power cycles.

A subclass implements one protocol: :meth:`PtyDevice.boot` (its state at power-up),
:meth:`PtyDevice.booted` (what it sends once booted), :meth:`PtyDevice.receive` (bytes from
the host) and :meth:`PtyDevice.tick` (streaming). It sends with :meth:`PtyDevice.send`,
marking scans with their sequence number so that a test can tell which scans left the
device intact.

The wire behaves as a serial line does. Bytes are corrupted (:class:`Corruption`), and a
burst of noise runs on into whatever is sent next. With a ``line_rate``, bytes leave no faster
than that, so a power cut truncates the telegram on the line. A power cycle (:meth:`go_silent`
then :meth:`power_on`) is a reboot. The device forgets its state, the line glitches at power-up,
and the device stays deaf and mute for ``boot_time``. Then it announces itself. Nothing it was
doing before the cut is resumed, and no scan that fell due while it was off is sent.
"""

from __future__ import annotations

import dataclasses
import os
import select
import threading
import time
import tty
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from drivers.scenario import Scenario, SensorModel
from drivers.simulator import Simulator
from vmp.types import FloatArray

__all__ = ["Corruption", "PtyDevice", "ScanSource", "SentScan"]


@dataclass(frozen=True)
class Corruption:
    """Byte corruption on the wire: each byte is hit with probability ``rate``.

    A hit byte has one random bit flipped, is dropped, has a random byte inserted before it,
    or starts a burst of ``burst_len`` random bytes that replace it and the following ones, in
    the proportions ``flip : drop : burst : insert``.
    """

    rate: float = 0.0
    flip: float = 0.6
    drop: float = 0.2
    burst: float = 0.2
    burst_len: int = 8
    insert: float = 0.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.rate <= 1.0:
            raise ValueError(f"corruption rate must lie in [0, 1], got {self.rate}")
        weights = (self.flip, self.drop, self.burst, self.insert)
        if min(weights) < 0 or sum(weights) <= 0:
            raise ValueError(f"corruption proportions must be >= 0 with a positive sum, "
                             f"got {weights}")
        if self.burst_len < 1:
            raise ValueError(f"burst_len must be positive, got {self.burst_len}")

    def apply(self, data: bytes, rng: np.random.Generator) -> tuple[bytes, bool]:
        """The bytes as they arrive, and whether any was changed."""
        out, changed, _ = self.corrupt(data, rng)
        return out, changed

    def corrupt(self, data: bytes, rng: np.random.Generator,
                carry: int = 0) -> tuple[bytes, bool, int]:
        """The bytes as they arrive, whether any was changed, and the burst still owed.

        ``carry`` is how many leading bytes belong to a burst that began in earlier data; the
        third value is the same for the data that follows these bytes on the wire.
        """
        if not data:
            return data, False, carry
        a = np.frombuffer(data, dtype=np.uint8).copy()
        changed = False
        if carry > 0:
            n = min(carry, a.size)
            a[:n] = rng.integers(0, 256, n, dtype=np.uint8)
            carry -= n
            changed = True
        if self.rate == 0.0:
            return a.tobytes(), changed, carry
        hit = np.flatnonzero(rng.random(a.size) < self.rate)
        if hit.size == 0:
            return a.tobytes(), changed, carry
        total = self.flip + self.drop + self.burst + self.insert
        kind = rng.choice(4, size=hit.size, p=[self.flip / total, self.drop / total,
                                                 self.burst / total, self.insert / total])
        flips = hit[kind == 0]
        a[flips] ^= (1 << rng.integers(0, 8, flips.size)).astype(np.uint8)
        for start in hit[kind == 2]:  # a handful per call at the rates that matter
            stop = min(a.size, start + self.burst_len)
            a[start:stop] = rng.integers(0, 256, stop - start, dtype=np.uint8)
            carry = max(carry, start + self.burst_len - a.size)
        keep = np.ones(a.size, dtype=bool)
        keep[hit[kind == 1]] = False
        ins = hit[kind == 3]
        if ins.size:
            a = np.insert(a, ins, rng.integers(0, 256, ins.size, dtype=np.uint8))
            keep = np.insert(keep, ins, True)
        return a[keep].tobytes(), True, carry


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
    powered: bool = True
    power_on: bool = False  # asked for, carried out by the device thread
    stop: bool = False
    lock: threading.Lock = field(default_factory=threading.Lock)


STALL = 0.5  # seconds a full pty may block the device before the bytes count as lost


class PtyDevice:
    """Base of the simulated scanners: serves the device on a pty from a thread.

    ``port`` is the path a driver opens. ``speed`` scales the device clock (2.0 streams twice
    as fast as the real device). ``corruption`` applies to every byte the device sends;
    ``seed`` makes it reproducible. ``line_rate`` (bytes per second of device time; None: as
    fast as the host reads) paces what the device sends. ``boot_time`` (device seconds) is how
    long a reboot keeps the device deaf and mute; ``glitch`` sends one random byte at every
    power-up, as a serial line does when the device's transmitter comes up. ``sent`` lists
    every scan the device sent with whether it left intact; ``finished`` is set when the scan
    source is exhausted. ``boots`` counts power-ups and resets.
    """

    name = "device"
    boot_on_start = False  # whether start() waits out boot_time, as a power-on does

    def __init__(self, source: ScanSource | None = None, *, corruption: Corruption | float = 0.0,
                 seed: int = 0, speed: float = 1.0, boot_time: float = 0.0,
                 line_rate: float | None = None, glitch: bool = True) -> None:
        if speed <= 0:
            raise ValueError(f"speed must be positive, got {speed}")
        if boot_time < 0:
            raise ValueError(f"boot_time must be >= 0, got {boot_time}")
        if line_rate is not None and line_rate <= 0:
            raise ValueError(f"line_rate must be positive, got {line_rate}")
        self.source = source
        self.corruption = (corruption if isinstance(corruption, Corruption)
                           else Corruption(rate=float(corruption)))
        self.speed = speed
        self.boot_time = boot_time
        self.line_rate = line_rate
        self.glitch = glitch
        self.seed = seed
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
        self.bytes_cut = 0  # on the line when the power went
        self.boots = 0
        self._thread = threading.Thread(target=self._run, name=f"{self.name}-sim", daemon=True)
        self._next_scan = 0
        self._t0 = time.monotonic()
        self._ready_at: float | None = None  # device time the boot ends
        self._burst = 0  # bytes a burst of noise still owes the wire
        self._out: deque[list] = deque()  # [memoryview, SentScan | None] waiting for the line
        self._allowance = 0.0
        self._paced_at = time.monotonic()
        self._stuck_since: float | None = None

    # -- control from the test or the CLI ---------------------------------------------------
    def start(self) -> PtyDevice:
        self._reboot(self.boot_time if self.boot_on_start else 0.0)
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
        """Power off: what is on the line is cut, nothing more is sent, what the host sends is
        lost, and the device's state is gone, until :meth:`power_on`."""
        with self._ctl.lock:
            self._ctl.powered = False
            self._ctl.power_on = False

    def power_on(self) -> None:
        """Power back on: the device reboots (see the class notes); returns at once."""
        with self._ctl.lock:
            self._ctl.power_on = True

    @property
    def silent(self) -> bool:
        """Powered off, or powered on but not yet rebooted by the device thread."""
        return not self._ctl.powered or self._ctl.power_on

    @property
    def booting(self) -> bool:
        return self._ready_at is not None

    def device_time(self) -> float:
        """Seconds of device time since start (scaled by ``speed``)."""
        return (time.monotonic() - self._t0) * self.speed

    # -- for subclasses -------------------------------------------------------------------
    def boot(self) -> None:
        """Reset the protocol state to what it is at power-up."""

    def booted(self) -> None:
        """Send what the device sends once it has booted (a banner, a power-on telegram)."""

    def receive(self, data: bytes) -> None:
        """Handle bytes from the host."""

    def tick(self) -> None:
        """Send whatever is due now (scans while streaming)."""

    def reboot(self) -> None:
        """Reboot now (a reset command): as a power cycle, without the glitch."""
        self._reboot(self.boot_time)

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

    def scan_rng(self, seq: int, stream: int) -> np.random.Generator:
        """Random numbers of scan ``seq`` alone (``stream`` tells its uses apart): a scan
        comes out the same whenever it is sent and however its bytes are cut up."""
        return np.random.default_rng((self.seed, seq, stream))

    def corrupt_scan(self, data: bytes, seq: int, stream: int = 0) -> tuple[bytes, bool]:
        """The whole of scan ``seq``'s bytes as the wire delivers them, and whether any was
        hit (the same for the same scan in every run; a burst still owed runs into it and
        on into what follows); ``stream`` as for :meth:`scan_rng`."""
        out, changed, self._burst = self.corruption.corrupt(data, self.scan_rng(seq, stream),
                                                            self._burst)
        return out, changed

    def record(self, seq: int, values: np.ndarray) -> SentScan:
        """Note a scan that starts to leave the device now (intact until a byte of it is hit)."""
        rec = SentScan(seq, values, True)
        self.sent.append(rec)
        return rec

    @property
    def line_busy(self) -> bool:
        """Bytes sent earlier are still waiting for the line (only with a ``line_rate``)."""
        return bool(self._out)

    def send(self, data: bytes, scan: tuple[int, np.ndarray] | SentScan | None = None,
             corrupt: bool = True) -> SentScan | None:
        """Send bytes through the corrupting wire; ``scan`` = (seq, values) records a scan,
        a :class:`SentScan` from an earlier call adds these bytes to it. The record.
        ``corrupt=False``: the bytes went through the wire's corruption already
        (:meth:`corrupt_scan`)."""
        rec = scan if isinstance(scan, SentScan) else None
        if not self._ctl.powered:
            if rec is not None:
                rec.intact = False
            return rec
        if corrupt:
            out, changed, self._burst = self.corruption.corrupt(data, self._rng, self._burst)
        else:
            out, changed = data, False
        if scan is not None and rec is None:
            rec = self.record(*scan)
        if rec is not None and changed:
            rec.intact = False
        if not out:
            return rec
        if self.line_rate is None:
            self._write_now(memoryview(out), rec)
        else:
            self._out.append([memoryview(out), rec])
            self._pump()
        return rec

    # -- the line ---------------------------------------------------------------------------
    def _write_now(self, view: memoryview, rec: SentScan | None) -> None:
        deadline = time.monotonic() + STALL
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
                    if rec is not None:
                        rec.intact = False
                    return
                select.select([], [self._master], [], 0.01)

    def _pump(self) -> None:
        """Put on the line what the line rate allows since the last call."""
        assert self.line_rate is not None
        now = time.monotonic()
        rate = self.line_rate * self.speed
        self._allowance = min(self._allowance + (now - self._paced_at) * rate,
                              max(64.0, rate * 0.01))
        self._paced_at = now
        while self._out and self._allowance >= 1.0:
            item = self._out[0]
            view, rec = item
            try:
                n = os.write(self._master, view[:int(self._allowance)])
            except BlockingIOError:
                n = 0
            except OSError:
                return
            if n == 0:  # the pty is full: the host is not reading
                if self._stuck_since is None:
                    self._stuck_since = now
                elif now - self._stuck_since > STALL:
                    self.bytes_dropped += len(view)
                    if rec is not None:
                        rec.intact = False
                    self._out.popleft()
                return
            self._stuck_since = None
            self.bytes_sent += n
            self._allowance -= n
            item[0] = view[n:]
            if not len(item[0]):
                self._out.popleft()

    def _cut(self) -> None:
        """The power went: what has not left yet never will."""
        for view, rec in self._out:
            self.bytes_cut += len(view)
            if rec is not None:
                rec.intact = False
        self._out.clear()
        self._burst = 0

    def _reboot(self, delay: float) -> None:
        self.boots += 1
        self.boot()
        self.rewind_clock()
        self._ready_at = self.device_time() + delay
        if delay <= 0:
            self._ready_at = None
            self.booted()

    # -- the thread -----------------------------------------------------------------------
    def _run(self) -> None:
        while not self._ctl.stop:
            with self._ctl.lock:
                on = self._ctl.power_on
                self._ctl.power_on = False
                if on:
                    self._ctl.powered = True
                powered = self._ctl.powered
            if (on or not powered) and self._out:
                self._cut()
            if on:
                if self.glitch:
                    self._write_now(memoryview(self._rng.integers(
                        0, 256, 1, dtype=np.uint8).tobytes()), None)
                self._reboot(self.boot_time)
            try:
                ready, _, _ = select.select([self._master], [], [], 0.002)
            except (OSError, ValueError):
                return
            data = b""
            if ready:
                try:
                    data = os.read(self._master, 4096)
                except OSError:  # BlockingIOError included
                    data = b""
            if not powered:
                continue  # what the host sends is lost
            if self._ready_at is not None:
                if self.device_time() < self._ready_at:
                    continue  # still booting: deaf and mute
                self._ready_at = None
                self.booted()
            if data:
                self.receive(data)
            self.tick()
            if self._out:
                self._pump()
