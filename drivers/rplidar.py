"""Slamtec RPLIDAR A1/A2 driver (legacy SCAN mode) on a serial port.

The handshake stops any running scan, checks the health (an error state gets a RESET, after
which the device prints a plain-text boot banner that is waited for and flushed), reads the
device info, starts the motor (A1: DTR cleared; A2: ``SET_MOTOR_PWM``) and starts a SCAN.
Nodes are grouped into turns by :class:`drivers.rplidar_protocol.TurnAssembler`, which
refuses implausible turns, and each turn is binned into ``beams`` equal beams over 360 degrees.

Beam convention: RPLIDAR angles are clockwise seen from above; frame angles are
counter-clockwise, theta = -angle. Beams run in increasing theta from ``angle_min =
-(beams // 2) * 2 pi / beams`` (-pi for an even count), so beam ``beams // 2`` looks along the
device's 0 degree mark. A node goes to the nearest beam; when several land in one beam the
nearest range wins; a beam without a node, or whose nodes all read 0, is ``inf``. Choose
``beams`` at or below the nodes per turn of the device (A1 at 5.5 Hz: about 360), or some
beams stay empty. A turn is complete when the next one starts, so a frame is stamped at the
arrival of the next turn's first node; when the stream pauses after a turn that already
covers the circle (a STOP, a power cut, the next start node lost), the turn is delivered
then, stamped at the arrival of its own last node.

The nodes carry no checksum: a node whose distance bits were hit passes every check and
shows as a wrong range in an otherwise plausible turn. The driver cannot see it; the
serial-integrity benchmark measures how often it happens.
"""

from __future__ import annotations

import struct
import time
from typing import Any

import numpy as np

from drivers import rplidar_protocol as rp
from drivers.rplidar_protocol import DeviceInfo, Health, TurnAssembler
from drivers.serial_scanner import DeviceError, ScanDriver
from vmp.types import BeamGeometry, FloatArray

__all__ = ["RplidarDriver"]


class RplidarDriver(ScanDriver):
    """An RPLIDAR A1/A2 streaming legacy SCAN nodes, as frames of ``beams`` beams.

    ``motor`` is ``"dtr"`` (A1 dev kit adapter: DTR cleared spins the motor; a port without
    modem lines, such as a pty, is tolerated and noted in ``motor_note``) or ``"pwm"``
    (A2: ``SET_MOTOR_PWM`` with ``pwm``, 0-1023). ``reply_timeout`` bounds each reply,
    ``reset_wait`` the boot after a RESET. ``turn_options`` go to :class:`TurnAssembler`. The
    other keywords are those of :class:`ScanDriver`.
    """

    name = "rplidar"
    baudrate = 115200

    def __init__(self, port: str, *, motor: str = "dtr", pwm: int = 660, beams: int = 360,
                 max_range: float = 12.0, reply_timeout: float = 0.5, stop_wait: float = 0.05,
                 reset_wait: float = 0.5, turn_options: dict[str, Any] | None = None,
                 **base_kwargs: Any) -> None:
        super().__init__(port, **base_kwargs)
        if motor not in ("dtr", "pwm"):
            raise ValueError(f"motor must be 'dtr' or 'pwm', got {motor!r}")
        if not 0 <= pwm <= 1023:
            raise ValueError(f"pwm must lie in 0..1023, got {pwm}")
        if beams < 1:
            raise ValueError(f"beams must be positive, got {beams}")
        self.motor = motor
        self.pwm = pwm
        self.beams = beams
        self.max_range = max_range
        self.reply_timeout = reply_timeout
        self.stop_wait = stop_wait
        self.reset_wait = reset_wait
        self.turn_options = dict(turn_options or {})
        self.info: DeviceInfo | None = None
        self.health: Health | None = None
        self.motor_note = ""
        self.resets = 0
        self._assembler = TurnAssembler(**self.turn_options)
        self._counted = (0, 0, 0)
        self._carry = b""

    # -- protocol hooks ----------------------------------------------------------------------
    def connect(self) -> BeamGeometry:
        """STOP, GET_HEALTH (RESET once if in error), GET_INFO, motor on, SCAN; the layout."""
        self._carry = b""
        self._stop_device()
        health = self._get_health()
        if health.status == rp.HEALTH_ERROR:
            self._reset_device()
            health = self._get_health()
            if health.status == rp.HEALTH_ERROR:
                raise DeviceError(f"RPLIDAR reports an error (code 0x{health.error_code:04X}) "
                                  "even after RESET")
        self.health = health
        self.info = rp.parse_info(self._query(rp.GET_INFO, rp.INFO_DESCRIPTOR, "GET_INFO"))
        self._set_motor(True)
        self.write(rp.request(rp.SCAN))
        # the nodes that follow are checked one by one, so a SCAN descriptor with one byte
        # damaged on the wire is taken (the other replies this driver asks for differ from it
        # in three bytes) rather than thrown away with the turns behind it
        self._carry = self._reply(rp.SCAN_DESCRIPTOR, 0, "SCAN", max_wrong=1)
        angle_min, inc = rp.beam_layout(self.beams)
        return BeamGeometry(self.beams, angle_min, inc, self.max_range)

    def decode(self, data: bytes) -> list[FloatArray]:
        """Ranges (m, ``inf`` = no return) of each complete, plausible turn in the stream."""
        if self._carry:
            data, self._carry = self._carry + data, b""
        turns = self._assembler.feed(data)
        self._count()
        return [self.bin_turn(t.angle_q6, t.dist_q2) for t in turns]

    def flush(self) -> list[FloatArray]:
        """The turn under way, if it already covers the circle (the stream has paused)."""
        turns = self._assembler.flush()
        self._count()
        return [self.bin_turn(t.angle_q6, t.dist_q2) for t in turns]

    def bin_turn(self, angle_q6: np.ndarray, dist_q2: np.ndarray) -> FloatArray:
        """Ranges of one turn's nodes in the beam layout (nearest node wins within a beam)."""
        q2 = rp.bin_nodes(angle_q6, dist_q2, self.beams)
        return np.where(q2 > 0, q2 / 4000.0, np.inf)

    def stop_stream(self) -> None:
        """STOP, then motor off."""
        if self.ser is None:
            return
        self.write(rp.request(rp.STOP))
        self._set_motor(False)

    def reset_decoder(self) -> None:
        """Forget partial nodes and turns (counters in ``stats`` stay)."""
        self._assembler.reset()

    @property
    def reject_reasons(self) -> dict[str, int]:
        """Rejected turns by reason."""
        return dict(self._assembler.reasons)

    # -- handshake steps -----------------------------------------------------------------------
    def _count(self) -> None:
        a = self._assembler
        now = (a.framing_errors, a.skipped_bytes, a.rejected)
        self.stats.framing_errors += now[0] - self._counted[0]
        self.stats.skipped_bytes += now[1] - self._counted[1]
        self.stats.rejected += now[2] - self._counted[2]
        self._counted = now

    def _flush(self) -> None:
        assert self.ser is not None
        self.ser.reset_input_buffer()

    def _stop_device(self) -> None:
        """STOP a scan that may be running and drop whatever was in flight."""
        self.write(rp.request(rp.STOP))
        self.read_for(self.stop_wait)
        self._flush()

    def _reset_device(self) -> None:
        """RESET, wait out the boot and its plain-text banner, flush."""
        self.resets += 1
        self.write(rp.request(rp.RESET))
        deadline = time.monotonic() + self.reset_wait
        quiet = max(0.02, self.reset_wait / 10)
        last = None
        while time.monotonic() < deadline:  # the banner, then quiet
            if self.read_for(quiet):
                last = time.monotonic()
            elif last is not None:
                break
        self._flush()

    def _reply(self, descriptor: bytes, size: int, what: str, max_wrong: int = 0) -> bytes:
        """Wait for ``descriptor`` (up to ``max_wrong`` bytes damaged) and ``size`` bytes after
        it (text before it is skipped); everything received after the descriptor."""
        head = descriptor[:2]

        def found(b: bytes) -> int:
            k = rp.find_descriptor(b, descriptor, max_wrong)
            return k if k >= 0 else b.find(head)

        def complete(b: bytes) -> bool:
            k = found(b)
            return k >= 0 and len(b) >= k + rp.DESCRIPTOR_SIZE + size

        got = self.read_for(self.reply_timeout, until=complete)
        k = found(got)
        if k < 0 or len(got) < k + rp.DESCRIPTOR_SIZE:
            raise DeviceError(f"no answer to {what}" + (f" (got {got[:40]!r})" if got else ""))
        desc = got[k:k + rp.DESCRIPTOR_SIZE]
        if rp.find_descriptor(desc, descriptor, max_wrong) < 0:
            raise DeviceError(f"unexpected {what} descriptor {desc.hex(' ').upper()}, "
                              f"expected {descriptor.hex(' ').upper()}")
        data = got[k + rp.DESCRIPTOR_SIZE:]
        if len(data) < size:
            raise DeviceError(f"{what} reply cut short: {len(data)} of {size} bytes")
        return data

    def _query(self, cmd: int, descriptor: bytes, what: str) -> bytes:
        """Send a single-response request; its data after checking the descriptor."""
        size = rp.parse_descriptor(descriptor).length
        self.write(rp.request(cmd))
        return self._reply(descriptor, size, what)[:size]

    def _get_health(self) -> Health:
        """GET_HEALTH, asked twice (the first request may meet a device still booting)."""
        try:
            data = self._query(rp.GET_HEALTH, rp.HEALTH_DESCRIPTOR, "GET_HEALTH")
        except DeviceError:
            self._stop_device()
            data = self._query(rp.GET_HEALTH, rp.HEALTH_DESCRIPTOR, "GET_HEALTH")
        return rp.parse_health(data)

    def _set_motor(self, on: bool) -> None:
        assert self.ser is not None
        if self.motor == "pwm":
            self.write(rp.request(rp.SET_MOTOR_PWM, struct.pack("<H", self.pwm if on else 0)))
            return
        try:
            self.ser.dtr = not on  # the adapter inverts: DTR cleared = motor spinning
        except OSError as exc:  # a pty has no modem lines
            self.motor_note = f"DTR motor control unavailable on {self.port}: {exc}"
