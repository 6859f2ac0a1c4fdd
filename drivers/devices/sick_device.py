"""A simulated SICK LMS 2xx on a pseudo-terminal.

It behaves as ``../shared/protocols.md`` section 1 and 6 describe: a power-up (or the reset
command ``10``) leaves it deaf for ``boot_time``, then it sends the ``90`` telegram and waits in
request mode at 9600 baud with the 180 degree / 0.5 degree variant, whatever rate and mode
it had before; every accepted telegram is answered with ``06`` and a reply telegram at the
rate in force; a baud change is answered at the old rate. With ``paced`` the bytes leave at
the line rate (baud / 10 bytes a second), so that a power cut truncates the telegram on the
line and, as on a real LMS, a scan that falls due while the line is still busy is not sent.
The units live in the configuration block (read with ``74``, written with ``77`` in
installation mode) and survive a power cycle, as the LMS's EEPROM does. The host's line
rate is read from the pty: while it differs from the device's, what either side sends
arrives as garbage, as on a real line.
"""

from __future__ import annotations

import math
import struct
import termios

import numpy as np

from drivers.devices.pty_device import Corruption, PtyDevice, ScanSource
from drivers.scenario import SensorModel
from drivers.sick_protocol import HOST, NAK, TelegramReceiver, encode_scan, reply
from vmp.types import BeamGeometry

__all__ = ["SickDevice"]

_BAUD_CODES = {0x42: 9600, 0x41: 19200, 0x40: 38400, 0x48: 500000}
_TERMIOS_BAUD = {getattr(termios, f"B{b}"): b for b in (9600, 19200, 38400, 500000)}
_UNIT_M = {0: 0.01, 1: 0.001, 2: 0.1}
PASSWORD = b"SICK_LMS"
TYPE = b"LMS200;301063;V02.10 "
CONFIG_LEN = 32  # our configuration block's data bytes; units at data offset 6
UNITS_AT = 6


class SickDevice(PtyDevice):
    """An LMS 200 serving scans of ``source`` (whose sensor is replaced by the variant in force).

    ``units`` is the units code stored in the configuration at start (0 cm, 1 mm, 2 10 cm).
    ``sent`` records the raw 13-bit values of every streamed scan.
    """

    name = "sick"

    def __init__(self, source: ScanSource | None, *, corruption: Corruption | float = 0.0,
                 seed: int = 0, speed: float = 1.0, units: int = 0, boot_time: float = 0.5,
                 paced: bool = False, glitch: bool = True) -> None:
        super().__init__(source, corruption=corruption, seed=seed, speed=speed,
                         boot_time=boot_time, glitch=glitch)
        self.paced = paced
        self.config = bytearray(CONFIG_LEN)
        self.config[UNITS_AT] = units
        self._sources: dict[tuple[int, int], ScanSource] = {}
        self.streamed = 0
        self.skipped = 0  # scans not sent because the line was busy (paced only)
        self._set_baud(9600)

    @staticmethod
    def sensor_model(angle: int = 180, resolution: int = 100,
                     rate_hz: float = 10.0) -> SensorModel:
        """The beams of a variant: angle in degrees, resolution in 1/100 degree.

        The first value is the scanner's 0 degree edge, to the right of the heading; beyond
        8 m (the 8 m measuring mode) there is no return.
        """
        n = angle * 100 // resolution + 1
        inc = math.radians(resolution / 100.0)
        return SensorModel(BeamGeometry(n, -math.radians(angle / 2.0), inc, 8.0),
                           range_noise=0.01, rate_hz=rate_hz)

    # -- power-up ---------------------------------------------------------------------------
    def boot(self) -> None:
        self._set_baud(9600)
        self.mode = "request"
        self.installation = False
        self.variant = (180, 50)
        self._rx = TelegramReceiver(address=HOST)

    def booted(self) -> None:
        self._send_telegram(bytes([0x90]) + TYPE, ack=False)

    def _set_baud(self, baud: int) -> None:
        self.baud = baud
        self.line_rate = baud / 10.0 if self.paced else None

    # -- the line -----------------------------------------------------------------------------
    def _host_baud(self) -> int | None:
        try:
            speed = termios.tcgetattr(self._master)[5]
        except termios.error:
            return None
        return _TERMIOS_BAUD.get(speed)

    def _line_ok(self) -> bool:
        host = self._host_baud()
        return host is None or host == self.baud

    def _send_telegram(self, payload: bytes, ack: bool = True, scan: tuple | None = None
                       ) -> None:
        data = reply(payload, ack=ack)
        if not self._line_ok():
            data = self._rng.integers(0, 256, len(data), dtype=np.uint8).tobytes()
        self.send(data, scan=scan)

    def receive(self, data: bytes) -> None:
        if not self._line_ok():
            return  # garbage at the wrong rate: nothing the LMS recognises
        for t in self._rx.feed(data):
            self._handle(t.command, t.data)

    # -- commands ---------------------------------------------------------------------------
    def _handle(self, cmd: int, data: bytes) -> None:
        if cmd == 0x10:  # reset: reply, reboot, then the power-on telegram at 9600
            self._send_telegram(bytes([0x91]))
            self.reboot()
        elif cmd == 0x20 and data:
            self._mode_change(data)
        elif cmd == 0x30 and data[:1] == b"\x01":
            if self.mode == "request":
                self._send_scan(ack=True)
        elif cmd == 0x31:
            self._send_telegram(bytes([0xB1]) + TYPE + bytes(16))
        elif cmd == 0x3A:
            self._send_telegram(bytes([0xBA]) + TYPE)
        elif cmd == 0x3B and len(data) == 4:
            angle, res = struct.unpack("<HH", data)
            ok = (angle, res) in ((180, 100), (180, 50), (100, 100), (100, 50), (100, 25))
            if ok:
                self.variant = (angle, res)
            a, r = self.variant
            self._send_telegram(bytes([0xBB, 1 if ok else 0]) + struct.pack("<HH", a, r))
        elif cmd == 0x74:
            self._send_telegram(bytes([0xF4]) + bytes(self.config))
        elif cmd == 0x77:
            ok = self.installation and len(data) == CONFIG_LEN and data[UNITS_AT] in _UNIT_M
            if ok:
                self.config[:] = data
            self._send_telegram(bytes([0xF7, 1 if ok else 0]) + bytes(self.config))
        else:
            self.send(bytes([NAK]))

    def _mode_change(self, data: bytes) -> None:
        code = data[0]
        if code == 0x00:
            ok = data[1:] == PASSWORD
            self.installation = ok
            self._send_telegram(bytes([0xA0, 0 if ok else 1]))
        elif code in _BAUD_CODES:
            self._send_telegram(bytes([0xA0, 0]))  # at the old rate, then switch
            self._set_baud(_BAUD_CODES[code])
        elif code == 0x24:
            self._send_telegram(bytes([0xA0, 0]))
            self.mode = "stream"
            self.rewind_clock()
        elif code == 0x25:
            self._send_telegram(bytes([0xA0, 0]))
            self.mode = "request"
            self.installation = False
        else:
            self.send(bytes([NAK]))

    # -- scans ------------------------------------------------------------------------------
    def _source(self) -> ScanSource | None:
        if self.source is None:
            return None
        key = self.variant
        if key not in self._sources:
            sensor = self.sensor_model(*key, rate_hz=self.source.sensor.rate_hz)
            self._sources[key] = self.source.with_sensor(sensor)
        return self._sources[key]

    def _values(self, k: int) -> np.ndarray:
        src = self._source()
        assert src is not None
        unit = _UNIT_M[self.config[UNITS_AT]]
        r = src.ranges(k)
        raw = np.where(np.isfinite(r), np.round(np.nan_to_num(r, posinf=0.0) / unit), 0x1FFF)
        raw = np.clip(raw, 1, 0x1FFF).astype(np.uint16)
        raw[~np.isfinite(r)] = 0x1FFF
        return raw

    def _send_scan(self, k: int | None = None, ack: bool = False) -> None:
        if self.source is None:
            return
        if k is None:  # on request: the scan of the current device time
            k = min(int(self.device_time() / self.source.period), len(self.source) - 1)
        values = self._values(k)
        self.streamed += 1
        self._send_telegram(encode_scan(values, self.config[UNITS_AT]), ack=ack,
                            scan=(k, values))

    def tick(self) -> None:
        if self.mode != "stream":
            return
        k = self.next_scan()
        if k is None:
            return
        if self.line_busy:  # the previous telegram is still on the line
            self.skipped += 1
            return
        self._send_scan(k)
