"""The SICK LMS 2xx driver: connect at 9600, switch baud, set variant and units, stream scans.

The handshake follows sicktoolbox: find the rate the LMS listens at (9600 after power-up,
or the rate a previous session left), stop any stream, switch to the working rate (answered
at the old rate), set the variant (angle and resolution), make sure the configuration holds
the wanted units (installation mode and ``77`` only if it does not), then ask for continuous
output of all values (``20 24``). Every telegram's CRC is checked; a telegram that fails it
is never decoded, and a scan whose value count or units differ from what was set is refused.
SICK's CRC shifts its register one bit per byte, so it misses a bit error followed ``k`` bytes
later by the same error shifted ``k`` bits up: a few in ten thousand telegrams corrupted at
0.1 % still pass it, and nothing else in a ``B0`` telegram can tell.
"""

from __future__ import annotations

import math
import struct
import time

import numpy as np

from drivers.serial_scanner import DeviceError, ScanDriver
from drivers.sick_protocol import Telegram, TelegramReceiver, decode_scan, request
from vmp.types import BeamGeometry, FloatArray

__all__ = ["SickLms2xx"]

BAUD_CODES = {9600: 0x42, 19200: 0x41, 38400: 0x40, 500000: 0x48}
UNITS = {"cm": 0, "mm": 1, "dm": 2}
VARIANTS = {(180, 100), (180, 50), (100, 100), (100, 50), (100, 25)}
PASSWORD = b"SICK_LMS"
UNITS_AT = 6  # units byte in the configuration block's data (payload offset 7)


class SickLms2xx(ScanDriver):
    """Scans from an LMS 200/291 on ``port``.

    ``baudrate`` is the working rate (9600, 19200, 38400 or 500000); ``angle`` 100 or 180
    degrees; ``resolution`` 1, 0.5 or 0.25 degrees; ``units`` "mm" (8 m range), "cm"
    (80 m) or "dm". ``probe_timeout`` bounds the first, quick try of each rate.
    """

    name = "sick"

    def __init__(self, port: str, *, baudrate: int = 38400, angle: int = 180,
                 resolution: float = 1.0, units: str = "mm", probe_timeout: float = 0.15,
                 **kwargs) -> None:
        super().__init__(port, **kwargs)
        self.probe_timeout = probe_timeout
        if baudrate not in BAUD_CODES:
            raise ValueError(f"baud rate must be one of {sorted(BAUD_CODES)}, got {baudrate}")
        res = round(resolution * 100)
        if (angle, res) not in VARIANTS:
            raise ValueError(f"no LMS variant {angle} deg at {resolution} deg; choose 180 at "
                             f"1 or 0.5, or 100 at 1, 0.5 or 0.25")
        if units not in UNITS:
            raise ValueError(f"units must be one of {', '.join(UNITS)}, got {units!r}")
        self.work_baud = baudrate
        self.variant = (angle, res)
        self.units = UNITS[units]
        self.device_type = ""
        self._rx = TelegramReceiver()
        self._seen = (0, 0, 0)
        self._early: list[Telegram] = []

    # -- telegram exchange ---------------------------------------------------------------------
    def _ask(self, payload: bytes, answer: int, timeout: float = 0.5,
             rx: TelegramReceiver | None = None) -> Telegram:
        """Send a request and wait for the reply telegram with code ``answer``.

        Telegrams that arrive after the reply in the same read (the first scans after
        ``20 24``) are kept for :meth:`decode`; ``rx`` then is the streaming receiver, so a
        scan cut by the read goes on in it.
        """
        assert self.ser is not None
        rx = rx or TelegramReceiver()
        self.write(request(payload))
        found: list[Telegram] = []
        deadline = time.monotonic() + timeout
        while not found and not rx.naks and time.monotonic() < deadline:
            chunk = self.ser.read(max(1, self.ser.in_waiting))
            for t in rx.feed(chunk):
                if found:
                    self._early.append(t)
                elif t.command == answer:
                    found.append(t)
        if not found:
            why = "refused it (NAK)" if rx.naks else "did not answer"
            raise DeviceError(f"{self.port}: LMS {why} (request {payload[:1].hex()}, "
                              f"waited for {answer:02X})")
        return found[0]

    def _mode(self, data: bytes, what: str, rx: TelegramReceiver | None = None,
              timeout: float = 0.5) -> None:
        t = self._ask(bytes([0x20]) + data, 0xA0, timeout=timeout, rx=rx)
        if t.data[:1] != b"\x00":
            raise DeviceError(f"{self.port}: LMS refused {what} (A0 status {t.data[:1].hex()})")

    def _find_rate(self) -> int:
        """The rate the LMS answers at: 9600 after power-up, else what we left it at.

        Every rate is tried first with ``probe_timeout`` (an LMS in request mode answers
        within tens of milliseconds), then with the full half second (one busy sending a
        long telegram at a low rate answers after it).
        """
        assert self.ser is not None
        rates = dict.fromkeys((9600, self.work_baud, 38400, 19200, 500000))
        for timeout in (self.probe_timeout, 0.5):
            for rate in rates:
                self.ser.baudrate = rate
                self.ser.reset_input_buffer()
                try:
                    self._mode(b"\x25", "request mode", timeout=timeout)  # stops a stream
                    return rate
                except DeviceError:
                    continue
        raise DeviceError(f"{self.port}: no LMS answers at 9600, 19200, 38400 or 500000 baud")

    # -- ScanDriver hooks ----------------------------------------------------------------------
    def connect(self) -> BeamGeometry:
        assert self.ser is not None
        self._early: list[Telegram] = []
        rate = self._find_rate()
        self.device_type = self._ask(b"\x3A", 0xBA).data.decode("ascii", "replace").strip()
        if rate != self.work_baud:
            self._mode(bytes([BAUD_CODES[self.work_baud]]), f"{self.work_baud} baud")
            time.sleep(0.05)  # the LMS switches after its reply (sicktoolbox waits longer)
            self.ser.baudrate = self.work_baud
            self.ser.reset_input_buffer()
        angle, res = self.variant
        t = self._ask(b"\x3B" + struct.pack("<HH", angle, res), 0xBB)
        if t.data[:1] != b"\x01" or struct.unpack_from("<HH", t.data, 1) != self.variant:
            raise DeviceError(f"{self.port}: LMS refused the variant {angle} deg / "
                              f"{res / 100:g} deg")
        config = bytearray(self._ask(b"\x74", 0xF4).data)
        if len(config) <= UNITS_AT:
            raise DeviceError(f"{self.port}: configuration block of {len(config)} bytes")
        if config[UNITS_AT] != self.units:
            self._mode(b"\x00" + PASSWORD, "installation mode")
            config[UNITS_AT] = self.units
            t = self._ask(b"\x77" + bytes(config), 0xF7, timeout=1.0)
            if t.data[:1] != b"\x01":
                raise DeviceError(f"{self.port}: LMS refused the configuration (units)")
        self._early = []
        self._mode(b"\x24", "continuous output", rx=self._rx)
        n = angle * 100 // res + 1
        unit = {0: 0.01, 1: 0.001, 2: 0.1}[self.units]
        return BeamGeometry(num_beams=n, angle_min=-math.radians(angle / 2.0),
                            angle_increment=math.radians(res / 100.0),
                            max_range=0x1FFE * unit)

    def reset_decoder(self) -> None:
        self._rx = TelegramReceiver()
        self._seen = (0, 0, 0)

    def decode(self, data: bytes) -> list[FloatArray]:
        out = []
        assert self.geometry is not None
        early, self._early = self._early, []
        for t in early + self._rx.feed(data):
            if t.command != 0xB0:
                continue
            try:
                ranges, unit = decode_scan(t)
            except ValueError:
                self.stats.framing_errors += 1
                continue
            if ranges.size != self.geometry.num_beams or not math.isclose(
                    unit, {0: 0.01, 1: 0.001, 2: 0.1}[self.units]):
                self.stats.rejected += 1
                continue
            out.append(np.asarray(ranges))
        rx = self._rx
        seen = (rx.crc_errors, rx.bad_lengths, rx.skipped_bytes)
        self.stats.checksum_errors += seen[0] - self._seen[0]
        self.stats.framing_errors += seen[1] - self._seen[1]
        self.stats.skipped_bytes += seen[2] - self._seen[2]
        self._seen = seen
        return out

    def stop_stream(self) -> None:
        if self.ser is not None:
            self.write(request(b"\x20\x25"))
