"""What every serial laser scanner driver shares: the port, the counters, reconnection.

A driver subclasses :class:`ScanDriver` with its protocol: :meth:`ScanDriver.connect` (the
handshake that leaves the device streaming and says its beam geometry),
:meth:`ScanDriver.decode` (bytes in, ranges of complete, checked scans out) and, where a scan
is only known to be complete once the next one begins, :meth:`ScanDriver.flush`. The base
class turns those into scan frames stamped on arrival. When the device falls silent (no byte
at all), or talks without a single scan getting through for much longer, it closes the port
and connects again with a growing back-off, counting each step in :class:`LinkStats`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass

import numpy as np
import serial

from vmp.types import BeamGeometry, FloatArray, ScanFrame

__all__ = ["DeviceError", "LinkStats", "ScanDriver"]


class DeviceError(Exception):
    """The device did not answer as its protocol says (during the handshake)."""


@dataclass
class LinkStats:
    """Counters of a serial session; nothing that arrives is dropped without being counted."""

    scans: int = 0  # delivered as frames
    checksum_errors: int = 0  # frames whose checksum failed (never decoded)
    framing_errors: int = 0  # bad lengths, characters out of range, broken line structure
    rejected: int = 0  # checked frames or turns refused as implausible
    skipped_bytes: int = 0  # garbage between frames
    timeouts: int = 0  # the device fell silent
    stalls: int = 0  # bytes kept coming, but no scan got through for ``stall`` seconds
    reconnects: int = 0  # handshakes attempted after the first
    failed_connects: int = 0

    def as_dict(self) -> dict[str, int]:
        return asdict(self)

    def errors(self) -> int:
        return self.checksum_errors + self.framing_errors + self.rejected

    def summary(self) -> str:
        return (f"{self.scans} scans, {self.checksum_errors} checksum errors, "
                f"{self.framing_errors} framing errors, {self.rejected} rejected, "
                f"{self.skipped_bytes} bytes skipped, {self.timeouts} silences, "
                f"{self.stalls} stalls, {self.reconnects} reconnects")


class ScanDriver:
    """Base of the serial scanner drivers: frames from a port, reconnecting when it goes quiet.

    ``port`` is a device path or a pyserial URL. ``silence`` is how long without a byte counts
    as a silent device (powered off, rebooted, no longer streaming). ``stall`` is how long
    bytes may keep coming without a complete scan before the link counts as broken (default:
    ten silences, at least 5 s): under heavy corruption many scans in a row may fail their
    checks, and reconnecting then would only lose the scans in flight. Reconnection waits
    ``backoff`` seconds, doubling up to ``backoff_max``. ``clock`` stamps frames on arrival
    (default: the wall clock); :meth:`close` (from any thread) ends :meth:`frames`.

    :meth:`reset_decoder` runs before each :meth:`connect`, not after it: bytes that the
    handshake read past its last reply (the first scan, often) may be kept for :meth:`decode`.
    """

    name = "scanner"
    baudrate = 9600

    def __init__(self, port: str, *, silence: float = 1.0, stall: float | None = None,
                 backoff: float = 0.1, backoff_max: float = 5.0,
                 clock: Callable[[], float] = time.time, read_timeout: float = 0.05) -> None:
        if silence <= 0:
            raise ValueError(f"silence must be positive, got {silence}")
        self.port = port
        self.silence = silence
        self.stall = max(5.0, 10.0 * silence) if stall is None else stall
        self.backoff = backoff
        self.backoff_max = backoff_max
        self.clock = clock
        self.read_timeout = read_timeout
        self.stats = LinkStats()
        self.geometry: BeamGeometry | None = None  # the beams, once connected
        self.last_error = ""
        self.ser: serial.Serial | None = None
        self._stop = False

    # -- protocol hooks ----------------------------------------------------------------------
    def connect(self) -> BeamGeometry:
        """Bring the device on ``self.ser`` to streaming scans; raise DeviceError if it won't."""
        raise NotImplementedError

    def decode(self, data: bytes) -> list[FloatArray]:
        """Feed received bytes; ranges in metres (``inf``: no return) of each complete scan."""
        raise NotImplementedError

    def flush(self) -> list[FloatArray]:
        """Ranges of scans held back for what follows them, now complete on their own (the
        stream paused: the last scan before a cut); none by default."""
        return []

    def stop_stream(self) -> None:
        """Ask the device to stop streaming (best effort, on close)."""

    def reset_decoder(self) -> None:
        """Forget partial frames (after a reconnect)."""

    # -- helpers for the handshake -----------------------------------------------------------
    def open_port(self, baudrate: int | None = None) -> serial.Serial:
        ser = serial.serial_for_url(self.port, baudrate=baudrate or self.baudrate,
                                    timeout=self.read_timeout, write_timeout=1.0)
        self.ser = ser
        return ser

    def read_for(self, seconds: float, until: Callable[[bytes], bool] | None = None) -> bytes:
        """Read what arrives within ``seconds`` (or until ``until(bytes so far)`` holds)."""
        assert self.ser is not None
        got = bytearray()
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            chunk = self.ser.read(max(1, self.ser.in_waiting))
            if chunk:
                got += chunk
                if until is not None and until(bytes(got)):
                    break
        return bytes(got)

    def write(self, data: bytes) -> None:
        assert self.ser is not None
        self.ser.write(data)
        self.ser.flush()

    # -- the session ---------------------------------------------------------------------------
    def close(self) -> None:
        """End :meth:`frames` at its next read; safe to call from another thread."""
        self._stop = True

    def _disconnect(self) -> None:
        if self.ser is None:
            return
        try:
            self.stop_stream()
        except (OSError, serial.SerialException):
            pass
        try:
            self.ser.close()
        except (OSError, serial.SerialException):
            pass
        self.ser = None

    def _connect_once(self) -> bool:
        try:
            self.open_port()
            self.reset_decoder()
            self.geometry = self.connect()
            return True
        except (OSError, serial.SerialException, DeviceError) as exc:
            self.last_error = str(exc)
            self.stats.failed_connects += 1
            self._disconnect()
            return False

    def frames(self) -> Iterator[ScanFrame]:
        """Scan frames as they arrive, stamped on arrival, until :meth:`close`."""
        delay = self.backoff
        first = True
        try:
            while not self._stop:
                if not first:
                    self.stats.reconnects += 1
                first = False
                if not self._connect_once():
                    time.sleep(delay)
                    delay = min(2 * delay, self.backoff_max)
                    continue
                delay = self.backoff
                yield from self._stream()
                self._disconnect()
        finally:
            self._disconnect()

    def _frame(self, ranges: FloatArray, stamp: float) -> ScanFrame:
        """The next frame: ``ranges`` (beyond the maximum range: no return) at ``stamp``."""
        lay = self.geometry
        assert lay is not None
        r = np.asarray(ranges, dtype=np.float64)
        r = np.where((r > 0) & (r <= lay.max_range), r, np.inf)
        frame = ScanFrame(stamp=stamp, ranges=r, angle_min=lay.angle_min,
                          angle_increment=lay.angle_increment, max_range=lay.max_range,
                          index=self.stats.scans)
        self.stats.scans += 1
        return frame

    def _stream(self) -> Iterator[ScanFrame]:
        """Frames until the device falls silent, stalls or the port fails; a scan held back
        for its successor is flushed (stamped when its last bytes came) whenever the bytes
        pause for a read timeout."""
        assert self.ser is not None and self.geometry is not None
        last_byte = last_scan = time.monotonic()
        arrived = self.clock()
        while not self._stop:
            try:
                data = self.ser.read(max(1, self.ser.in_waiting))
            except (OSError, serial.SerialException) as exc:
                self.last_error = str(exc)
                for ranges in self.flush():
                    yield self._frame(ranges, arrived)
                return
            now = time.monotonic()
            if data:
                arrived = self.clock()
                last_byte = now
                scans = self.decode(data)
            else:
                scans = self.flush()
            for ranges in scans:
                last_scan = time.monotonic()
                yield self._frame(ranges, arrived)
            if now - last_byte > self.silence:
                self.stats.timeouts += 1
                self.last_error = f"no byte for {self.silence:g} s"
                return
            if now - last_scan > self.stall:
                self.stats.stalls += 1
                self.last_error = f"no scan for {self.stall:g} s"
                return
