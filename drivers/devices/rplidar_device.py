"""A simulated Slamtec RPLIDAR A1 on a pseudo-terminal (legacy protocol, SCAN mode).

It answers STOP, RESET, GET_INFO, GET_HEALTH, GET_SAMPLERATE, SET_MOTOR_PWM, SCAN and
FORCE_SCAN; any request ends a running scan. After power-on or a RESET it is deaf for
``boot_time`` seconds of device time, prints a plain-text boot banner like the real firmware
and waits idle for commands.

While scanning it sends one turn per source scan: the nodes in increasing device angle
(clockwise degrees, theta = -angle) from about 0 degrees, the first with S = 1, each node at
its angle plus a small jitter; a node without a return has distance 0. As on the real
device the nodes stream continuously, each at its sample time (``continuous``; otherwise a
turn leaves at once), so a STOP or a power cut leaves a turn unfinished, and a SCAN starts
mid-revolution: the nodes up to the next 0 degree crossing carry no start flag and belong to
no scan. With ``rpm_jitter`` the motor speed, hence the node count of a turn, varies by up
to that fraction, and the first node of a turn lies anywhere within one node step of 0 degrees.
Like a real triangulation scanner it corrects each angle for the parallax between its laser
and its camera (``parallax``, mm): a point at distance ``d`` is reported ``atan(parallax / d)``
further round (past 360 degrees it reads from 0 again, before the next start flag), so where
the distance drops a near point can be reported behind the far point sampled before it, which
is why the Slamtec SDK sorts a turn by angle; a node without a return keeps its uncorrected
angle. A scan's recorded values are its
turn binned into the source's beams (:func:`drivers.rplidar_protocol.bin_nodes`).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np

from drivers import rplidar_protocol as rp
from drivers.devices.pty_device import Corruption, PtyDevice, ScanSource, SentScan
from drivers.scenario import SensorModel
from vmp.types import BeamGeometry

__all__ = ["RplidarDevice"]

BANNER = b"RP LIDAR System.\r\nFirmware Ver 1.29 - rc0, HW Ver 7\r\nModel: 18\r\n"


@dataclass
class _Turn:
    """A turn on its way out: its wire bytes (as corrupted), node count, sample clock and
    record."""

    data: bytes
    nodes: int
    t0: float  # device time of node 0
    sent: int  # nodes sent so far
    record: SentScan | None  # None: a partial revolution, no scan


class RplidarDevice(PtyDevice):
    """An RPLIDAR A1 (model 0x18, firmware 1.29, hardware 7) streaming a :class:`ScanSource`.

    ``source`` must use :meth:`sensor_model` geometry. ``health`` is the (status, error code)
    GET_HEALTH reports; a RESET clears an error state unless ``fault_survives_reset``.
    ``jitter`` is the angle noise of each node as a fraction of a node step. ``turns_sent``
    counts turns, ``commands`` lists the command bytes received, ``motor_pwm`` is the last PWM.
    """

    name = "rplidar"
    QUALITY = 47
    boot_on_start = True

    def __init__(self, source: ScanSource | None, *, corruption: Corruption | float = 0.0,
                 seed: int = 0, speed: float = 1.0, boot_time: float = 0.3,
                 health: tuple[int, int] = (0, 0), fault_survives_reset: bool = False,
                 jitter: float = 0.1, serial_number: bytes = bytes(range(16)),
                 continuous: bool = True, rpm_jitter: float = 0.01, parallax: float = 20.0,
                 line_rate: float | None = None, glitch: bool = True) -> None:
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
        if not 0 <= rpm_jitter < 0.5:
            raise ValueError(f"rpm_jitter must lie in [0, 0.5), got {rpm_jitter}")
        if parallax < 0:
            raise ValueError(f"parallax (mm) must be >= 0, got {parallax}")
        super().__init__(source, corruption=corruption, seed=seed, speed=speed,
                         boot_time=boot_time, line_rate=line_rate, glitch=glitch)
        self.health = health
        self.fault_survives_reset = fault_survives_reset
        self.jitter = jitter
        self.rpm_jitter = rpm_jitter
        self.parallax = parallax
        self.continuous = continuous
        self.serial_number = serial_number
        self.scanning = False
        self.motor_pwm = 0
        self.commands: list[int] = []
        self.turns_sent = 0
        self.turns_cut = 0  # turns left unfinished by a STOP, a new request or a power cut
        self._rx = bytearray()
        self._turn: _Turn | None = None
        self._node_rng = np.random.default_rng(seed + 1)

    @staticmethod
    def sensor_model(rate_hz: float = 10.0, beams: int = 360) -> SensorModel:
        """The geometry the device ray-casts: the driver's beams, 12 m, 1 cm noise."""
        angle_min, inc = rp.beam_layout(beams)
        return SensorModel(BeamGeometry(beams, angle_min, inc, 12.0), range_noise=0.01,
                           rate_hz=rate_hz, dropout=0.0)

    # -- PtyDevice hooks ---------------------------------------------------------------------
    def boot(self) -> None:
        """Power-up or RESET: idle, motor stopped, any turn on its way out lost."""
        self._end_scan()
        self.motor_pwm = 0
        self._rx.clear()

    def booted(self) -> None:
        self.send(BANNER)

    def receive(self, data: bytes) -> None:
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
                if self.booting:  # a RESET: what follows is lost
                    self._rx.clear()
                    return
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
        while self.scanning:
            if self._turn is None:
                k = self.next_scan()
                if k is None:
                    return
                self._start_turn(k)
            if not self._stream_turn():
                return

    # -- the protocol ------------------------------------------------------------------------
    def _end_scan(self) -> None:
        """The scan session ends: a turn not yet wholly sent never will be."""
        self.scanning = False
        t = self._turn
        if t is not None and t.sent < t.nodes and t.record is not None:
            t.record.intact = False
            self.turns_cut += 1
        self._turn = None

    def _command(self, cmd: int, payload: bytes) -> None:
        self.commands.append(cmd)
        self._end_scan()  # any request ends a scan session
        if cmd == rp.RESET:
            if not self.fault_survives_reset:
                self.health = (rp.HEALTH_GOOD, 0)
            self.reboot()
        elif cmd in (rp.SCAN, rp.FORCE_SCAN):
            self.send(rp.SCAN_DESCRIPTOR)
            self.rewind_clock()
            self.scanning = True
            self._start_mid_revolution()
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

    def turn_bytes(self, ranges: np.ndarray, nodes: int | None = None,
                   rng: np.random.Generator | None = None) -> tuple[bytes, np.ndarray]:
        """Wire bytes of one turn of ``ranges`` (m, beam order) and distance_q2 per beam.

        ``nodes`` (default: one per beam) are spread evenly over the turn from a first node
        within one step of 0 degrees (at 0 without ``rpm_jitter``); each takes the range of
        the beam it is sampled in, and a point with a return is reported at its angle
        corrected for ``parallax``. ``rng`` draws the jitter (default: the device's own).
        """
        rng = self._node_rng if rng is None else rng
        beams = ranges.size
        n = beams if nodes is None else nodes
        finite = np.isfinite(ranges)
        q2 = np.zeros(beams, dtype=np.uint16)
        q2[finite] = np.clip(np.rint(ranges[finite] * 4000.0), 1, 0xFFFF)
        step = rp.ANGLE_FULL_Q6 / n
        offset = rng.uniform(0.0, 0.9) if self.rpm_jitter else 0.0
        jit = rng.uniform(-self.jitter, self.jitter, n)
        sampled = (np.arange(n) + offset + jit) * step
        dist = q2[rp.bin_index(np.clip(np.rint(sampled), 0, rp.ANGLE_FULL_Q6 - 1), beams)]
        if self.parallax:
            mm = np.maximum(dist, 1) / 4.0
            sampled = sampled + np.where(dist > 0, np.degrees(np.arctan(self.parallax / mm)),
                                         0.0) * 64.0
        angle_q6 = (np.maximum(np.rint(sampled), 0) % rp.ANGLE_FULL_Q6).astype(np.uint16)
        quality = np.where(dist > 0, self.QUALITY, 0)
        data = rp.encode_nodes(np.arange(n) == 0, quality, angle_q6, dist)
        return data, rp.bin_nodes(angle_q6, dist, beams)

    def _nodes_per_turn(self, rng: np.random.Generator) -> int:
        assert self.source is not None
        beams = self.source.sensor.geometry.num_beams
        if not self.rpm_jitter:
            return beams
        return max(8, round(beams * (1 + rng.uniform(-self.rpm_jitter, self.rpm_jitter))))

    def _start_turn(self, k: int) -> None:
        """Turn ``k``: its nodes and their damage on the wire drawn for it alone, so that it
        is the same turn in every run, whatever the timing of the host that reads it."""
        assert self.source is not None
        rng = self.scan_rng(k, 1)
        n = self._nodes_per_turn(rng)
        data, q2 = self.turn_bytes(self.source.ranges(k), n, rng)
        wire, changed = self.corrupt_scan(data, k)
        record = self.record(k, q2)
        record.intact = not changed
        self.turns_sent += 1
        self._turn = _Turn(wire, n, k * self.source.period, 0, record)

    def _start_mid_revolution(self) -> None:
        """After SCAN: the rest of the revolution under way, without a start flag, no scan."""
        if self.source is None or not self.continuous:
            return
        period = self.source.period
        now = self.device_time()
        c = min(int(now / period), len(self.source) - 1)
        if c < 0 or c + 1 >= len(self.source):
            return
        rng = self.scan_rng(c, 2)
        n = self._nodes_per_turn(rng)
        data, _ = self.turn_bytes(self.source.ranges(c), n, rng)
        a = bytearray(data)
        a[0] = (a[0] & 0xFC) | 0b10  # S = 0 on the first node too
        first = min(n - 1, math.ceil((now - c * period) / period * n))  # one node at least
        wire, _ = self.corrupt_scan(bytes(a), c, 3)
        self._turn = _Turn(wire, n, c * period, first, None)
        self._next_scan = max(self._next_scan, c + 1)

    def _stream_turn(self) -> bool:
        """Send the nodes of the current turn that are due; whether the turn is done."""
        t = self._turn
        assert t is not None and self.source is not None
        if self.continuous:
            frac = (self.device_time() - t.t0) / self.source.period
            due = min(t.nodes, max(0, math.floor(frac * t.nodes) + 1))
        else:
            due = t.nodes
        if due > t.sent:  # the wire may have dropped or added bytes: their share of them
            size = len(t.data)
            self.send(t.data[size * t.sent // t.nodes:size * due // t.nodes], scan=t.record,
                      corrupt=False)
            t.sent = due
        if t.sent < t.nodes:
            return False
        self._turn = None
        return True
