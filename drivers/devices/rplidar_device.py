"""A simulated Slamtec RPLIDAR A1 on a pseudo-terminal (legacy protocol, SCAN mode).

It answers STOP, RESET, GET_INFO, GET_HEALTH, GET_SAMPLERATE, SET_MOTOR_PWM, SCAN and
FORCE_SCAN; any request ends a running scan. After power-on or a RESET it is deaf for
``boot_time`` seconds of device time, prints a plain-text boot banner like the real firmware
and waits idle for commands. While scanning it sends one turn per source scan: the nodes in
increasing device angle (clockwise degrees, theta = -angle) from 0 degrees, the first with
S = 1, one node per beam at the beam's centre plus a small angle jitter; a beam without a
return has distance 0.
"""

from __future__ import annotations

import math
import struct
import time

import numpy as np

from drivers import rplidar_protocol as rp
from drivers.devices.pty_device import Corruption, PtyDevice, ScanSource
from drivers.scenario import SensorModel
from vmp.types import BeamGeometry

__all__ = ["RplidarDevice"]

BANNER = b"RP LIDAR System.\r\nFirmware Ver 1.29 - rc0, HW Ver 7\r\nModel: 18\r\n"


class RplidarDevice(PtyDevice):
    """An RPLIDAR A1 (model 0x18, firmware 1.29, hardware 7) streaming a :class:`ScanSource`.

    ``source`` must use :meth:`sensor_model` geometry. ``health`` is the (status, error code)
    GET_HEALTH reports; a RESET clears an error state unless ``fault_survives_reset``.
    ``jitter`` is the angle noise of each node as a fraction of a beam. ``turns_sent``
    counts turns, ``commands`` lists the command bytes received, ``motor_pwm`` is the last PWM.
    """

    name = "rplidar"
    QUALITY = 47

    def __init__(self, source: ScanSource | None, *, corruption: Corruption | float = 0.0,
                 seed: int = 0, speed: float = 1.0, boot_time: float = 0.3,
                 health: tuple[int, int] = (0, 0), fault_survives_reset: bool = False,
                 jitter: float = 0.1, serial_number: bytes = bytes(range(16))) -> None:
        if source is not None:
            expect = self.sensor_model(source.sensor.rate_hz,
                                       source.sensor.geometry.num_beams).geometry
            got = source.sensor.geometry
            if not (math.isclose(got.angle_min, expect.angle_min)
                    and math.isclose(got.angle_increment, expect.angle_increment)):
                raise ValueError("the scan source must use RplidarDevice.sensor_model geometry "
                                 f"(angle_min {expect.angle_min:.6f}, increment "
                                 f"{expect.angle_increment:.6f}), got {got.angle_min:.6f}, "
                                 f"{got.angle_increment:.6f}")
        if len(serial_number) != 16:
            raise ValueError("the serial number has 16 bytes")
        if not 0 <= jitter < 0.5:
            raise ValueError(f"jitter must lie in [0, 0.5), got {jitter}")
        super().__init__(source, corruption=corruption, seed=seed, speed=speed)
        self.boot_time = boot_time
        self.health = health
        self.fault_survives_reset = fault_survives_reset
        self.jitter = jitter
        self.serial_number = serial_number
        self.scanning = False
        self.motor_pwm = 0
        self.commands: list[int] = []
        self.turns_sent = 0
        self._rx = bytearray()
        self._banner_at: float | None = None
        self._node_rng = np.random.default_rng(seed + 1)

    @staticmethod
    def sensor_model(rate_hz: float = 10.0, beams: int = 360) -> SensorModel:
        """The geometry the device ray-casts: the driver's beams, 12 m, 1 cm noise."""
        angle_min, inc = rp.beam_layout(beams)
        return SensorModel(BeamGeometry(beams, angle_min, inc, 12.0), range_noise=0.01,
                           rate_hz=rate_hz, dropout=0.0)

    # -- PtyDevice hooks ---------------------------------------------------------------------
    def boot(self) -> None:
        """Power-up or RESET: idle, deaf until the banner has been printed."""
        self.scanning = False
        self.motor_pwm = 0
        self._rx.clear()
        self._banner_at = time.monotonic() + self.boot_time / self.speed

    def receive(self, data: bytes) -> None:
        if self._banner_at is not None:  # still booting: the bytes are lost
            return
        self._rx += data
        while True:
            k = self._rx.find(rp.SYNC)
            if k < 0:
                self._rx.clear()
                return
            del self._rx[:k]
            if len(self._rx) < 2:
                return
            cmd = self._rx[1]
            if not cmd & 0x80:
                del self._rx[:2]
                self._command(cmd, b"")
                continue
            if len(self._rx) < 3:
                return
            total = 3 + self._rx[2] + 1
            if len(self._rx) < total:
                return
            pkt = bytes(self._rx[:total])
            del self._rx[:total]
            if rp.xor_checksum(pkt[:-1]) == pkt[-1]:  # a bad checksum is ignored
                self._command(cmd, pkt[3:-1])

    def tick(self) -> None:
        if self._banner_at is not None:
            if time.monotonic() < self._banner_at:
                return
            self._banner_at = None
            self.send(BANNER)
        if not self.scanning:
            return
        while (k := self.next_scan()) is not None:
            self._send_turn(k)

    # -- the protocol ------------------------------------------------------------------------
    def _command(self, cmd: int, payload: bytes) -> None:
        self.commands.append(cmd)
        self.scanning = False  # any request ends a scan session
        if cmd == rp.RESET:
            if not self.fault_survives_reset:
                self.health = (rp.HEALTH_GOOD, 0)
            self.boot()
        elif cmd in (rp.SCAN, rp.FORCE_SCAN):
            self.send(rp.SCAN_DESCRIPTOR)
            self.rewind_clock()
            self.scanning = True
        elif cmd == rp.GET_INFO:
            self.send(rp.INFO_DESCRIPTOR + bytes([0x18, 29, 1, 7]) + self.serial_number)
        elif cmd == rp.GET_HEALTH:
            self.send(rp.HEALTH_DESCRIPTOR + struct.pack("<BH", *self.health))
        elif cmd == rp.GET_SAMPLERATE:
            per = 1e6 / (self.source.sensor.rate_hz * self.source.sensor.geometry.num_beams) \
                if self.source is not None else 500.0
            self.send(rp.SAMPLERATE_DESCRIPTOR + struct.pack("<HH", round(per), round(per / 2)))
        elif cmd == rp.SET_MOTOR_PWM and len(payload) == 2:
            (self.motor_pwm,) = struct.unpack("<H", payload)
        # STOP and unknown commands: no answer

    def turn_bytes(self, ranges: np.ndarray) -> tuple[bytes, np.ndarray]:
        """Wire bytes of one turn of ``ranges`` (m, beam order) and distance_q2 per beam."""
        beams = ranges.size
        finite = np.isfinite(ranges)
        q2 = np.zeros(beams, dtype=np.uint16)
        q2[finite] = np.clip(np.rint(ranges[finite] * 4000.0), 1, 0xFFFF)
        j = np.arange(beams)  # node order: device angle j * 360 / beams
        jit = self._node_rng.uniform(-self.jitter, self.jitter, beams)
        angle_q6 = np.clip(np.rint((j + jit) * (rp.ANGLE_FULL_Q6 / beams)), 0,
                           rp.ANGLE_FULL_Q6 - 1).astype(np.uint16)
        beam = (beams // 2 - j) % beams
        dist = q2[beam]
        quality = np.where(dist > 0, self.QUALITY, 0)
        return rp.encode_nodes(j == 0, quality, angle_q6, dist), q2

    def _send_turn(self, k: int) -> None:
        assert self.source is not None
        data, q2 = self.turn_bytes(self.source.ranges(k))
        self.turns_sent += 1
        self.send(data, scan=(k, q2))
