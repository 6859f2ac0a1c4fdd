"""A simulated Hokuyo URG-04LX speaking SCIP 2.0 on a pseudo-terminal.

It answers ``SCIP2.0`` (status ``0E``: it is already in SCIP 2.0), ``VV``, ``PP``, ``II``,
``BM``, ``QT``, ``RS``, ``TM0/1/2``, ``GD``/``GS`` (status ``10`` while the laser is off) and
``MD``/``MS`` (acknowledgement, then one reply per scan with the remaining-scan counter in its
echo, 64-character data lines with sums, values split across lines where they fall). Other
commands get status ``0E``. A power cycle is a reboot: the device is deaf for ``boot_time``
(device seconds), then silent with the laser off, nothing streaming and its timer at zero;
with ``scip1_on_boot`` it comes back speaking SCIP 1.1, as some URG-04LX firmware does,
and answers every line but ``SCIP2.0`` with status ``E`` until it is switched to SCIP 2.0.

Ranges come from a :class:`~drivers.devices.pty_device.ScanSource` in metres and leave as
millimetres; a beam without a return leaves as ``0`` (an URG error code, below DMIN).
Assumptions where the manual is not at hand: TM statuses 01-04, MD/GD parameter statuses
01-05, and MS values above 4095 sent as 4095.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drivers import scip2_protocol as scip
from drivers.devices.pty_device import Corruption, PtyDevice, ScanSource
from drivers.scenario import SensorModel
from vmp.types import BeamGeometry

__all__ = ["URG04LX", "HokuyoDevice"]

URG04LX = {"ARES": 1024, "AMIN": 44, "AMAX": 725, "AFRT": 384, "DMIN": 20, "DMAX": 5600,
           "SCAN": 600}
NO_RETURN = 0  # URG-04LX error code "possibly an object at about 22 m"


@dataclass
class _Stream:
    """An MD/MS request being served."""

    echo: bytes  # the command up to the scan count (13 characters)
    tag: bytes  # ``;string`` of the request, echoed after the count
    width: int
    first: int
    last: int
    cluster: int
    skip: int
    remaining: int  # 0: until QT
    counter: int = 0


class HokuyoDevice(PtyDevice):
    """An URG-04LX on a pty; ``source`` must use :meth:`sensor_model` geometry (682 beams)."""

    name = "hokuyo"

    def __init__(self, source: ScanSource | None, *, corruption: Corruption | float = 0.0,
                 seed: int = 0, speed: float = 1.0, boot_time: float = 0.5,
                 scip1_on_boot: bool = False, line_rate: float | None = None,
                 glitch: bool = True) -> None:
        super().__init__(source, corruption=corruption, seed=seed, speed=speed,
                         boot_time=boot_time, line_rate=line_rate, glitch=glitch)
        self.scip1_on_boot = scip1_on_boot
        self.scip1 = False
        self.params = dict(URG04LX)
        if source is not None:
            want = self.params["AMAX"] - self.params["AMIN"] + 1
            if source.sensor.geometry.num_beams != want:
                raise ValueError(f"the scan source has {source.sensor.geometry.num_beams} "
                                 "beams; an "
                                 f"URG-04LX has {want} (use HokuyoDevice.sensor_model())")
            self.params["SCAN"] = round(source.sensor.rate_hz * 60)
        self._rx = bytearray()
        self.laser_on = False
        self.stream: _Stream | None = None
        self.adjust_mode = False
        self._timer0 = 0.0
        self.commands: list[bytes] = []  # every command line received, for tests

    @staticmethod
    def sensor_model(rate_hz: float = 10.0) -> SensorModel:
        """The URG-04LX beam geometry: steps 44..725 of 1024 per turn, front at 384, 5.6 m."""
        p = URG04LX
        inc = 2 * math.pi / p["ARES"]
        beams = BeamGeometry(p["AMAX"] - p["AMIN"] + 1, (p["AMIN"] - p["AFRT"]) * inc, inc,
                             p["DMAX"] / 1000.0)
        return SensorModel(beams, range_noise=0.01, rate_hz=rate_hz, dropout=0.0)

    # -- device state ---------------------------------------------------------------------------
    def boot(self) -> None:
        """Power-up: laser off, nothing streaming, timer at zero, SCIP 1.1 or 2.0."""
        self.scip1 = self.scip1_on_boot and self.boots > 1  # not at start()
        self._rx.clear()
        self.laser_on = False
        self.stream = None
        self.adjust_mode = False
        self._timer0 = self.device_time()

    def time_ms(self) -> int:
        """The device's 24-bit millisecond timer."""
        return int((self.device_time() - self._timer0) * 1000) % (1 << 24)

    def values(self, k: int | None, first: int, last: int, cluster: int, width: int) -> np.ndarray:
        """Integer mm values of scan ``k`` for steps first..last grouped by ``cluster``.

        A group reports its smallest valid range, or the no-return code when none is valid.
        """
        p = self.params
        n = last - first + 1
        if self.source is None or k is None:
            mm = np.full(n, 1000, dtype=np.int64)
        else:
            r = self.source.ranges(k)[first - p["AMIN"]:last - p["AMIN"] + 1]
            mm = np.where(np.isfinite(r), np.round(np.nan_to_num(r, posinf=0.0) * 1000), NO_RETURN)
            mm = np.clip(mm, 0, 64 ** width - 1).astype(np.int64)
        c = max(cluster, 1)
        if c > 1:
            big = np.iinfo(np.int64).max
            pad = np.full(-n % c, NO_RETURN, dtype=np.int64)
            g = np.concatenate([mm, pad]).reshape(-1, c)
            valid = np.where(g >= p["DMIN"], g, big).min(axis=1)
            mm = np.where(valid == big, NO_RETURN, valid)
        return mm

    # -- host commands --------------------------------------------------------------------------
    def receive(self, data: bytes) -> None:
        self._rx += data.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
        *lines, rest = self._rx.split(b"\n")
        self._rx = bytearray(rest[-64:])
        for line in lines:
            if line:
                self.commands.append(bytes(line))
                self._command(bytes(line))

    def _command(self, line: bytes) -> None:
        body = line.split(b";", 1)[0]
        cmd, args = body[:2], body[2:]
        if self.scip1:  # SCIP 1.1: a one-character status, E for what it does not know
            ok = body == b"SCIP2.0"
            self.send(line + b"\n" + (b"0" if ok else b"E") + b"\n\n")
            self.scip1 = not ok
        elif body == b"SCIP2.0":
            self.send(scip.reply(line, b"0E"))
        elif cmd in (b"VV", b"PP", b"II") and not args:
            self.send(scip.reply(line, b"00", self._info(cmd)))
        elif cmd == b"BM" and not args:
            self.send(scip.reply(line, b"02" if self.laser_on else b"00"))
            self.laser_on = True
        elif cmd in (b"QT", b"RS") and not args:
            self.laser_on = False
            self.stream = None
            if cmd == b"RS":
                self.adjust_mode = False
                self._timer0 = self.device_time()
            self.send(scip.reply(line, b"00"))
        elif cmd == b"TM" and args in (b"0", b"1", b"2"):
            self._tm(line, args)
        elif cmd in (b"GD", b"GS"):
            self._gd(line, args, 3 if cmd == b"GD" else 2)
        elif cmd in (b"MD", b"MS"):
            self._md(line, args, 3 if cmd == b"MD" else 2)
        else:
            self.send(scip.reply(line, b"0E"))

    def _info(self, cmd: bytes) -> bytes:
        p = self.params
        items: list[tuple[str, object]]
        if cmd == b"VV":
            items = [("VEND", "Hokuyo Automatic Co., Ltd. (simulated)"), ("PROD", "URG-04LX"),
                     ("FIRM", "3.4.03 (vmp-slam simulator)"), ("PROT", "SCIP 2.0"),
                     ("SERI", "H0000001")]
        elif cmd == b"PP":
            items = [("MODL", "URG-04LX(Hokuyo Automatic Co.,Ltd.)")]
            items += [(k, p[k]) for k in ("DMIN", "DMAX", "ARES", "AMIN", "AMAX", "AFRT", "SCAN")]
        else:
            items = [("MODL", "URG-04LX"), ("LASR", "ON" if self.laser_on else "OFF"),
                     ("SCSP", f"Initial(=0{p['SCAN']}[rpm])"),
                     ("MESM", "Measuring" if self.laser_on else "Idle"),
                     ("SBPS", "19200[bps]"), ("TIME", f"{self.time_ms():06X}"),
                     ("STAT", "Sensor works well.")]
        return b"".join(scip.info_line(k, str(v)) for k, v in items)

    def _tm(self, line: bytes, arg: bytes) -> None:
        if arg == b"0":
            self.send(scip.reply(line, b"02" if self.adjust_mode else b"00"))
            self.adjust_mode = True
        elif arg == b"2":
            self.send(scip.reply(line, b"00" if self.adjust_mode else b"03"))
            self.adjust_mode = False
        elif not self.adjust_mode:
            self.send(scip.reply(line, b"04"))
        else:
            stamp = scip.encode(self.time_ms(), 4)
            self.send(scip.reply(line, b"00", stamp + scip.scip_sum(stamp) + b"\n"))

    def _steps(self, args: bytes, n: int) -> tuple[bytes, list[int]]:
        """Status ``00`` and the numbers of ``args`` (digit widths 4, 4, 2, 1, 2), or an error."""
        widths = (4, 4, 2, 1, 2)[:n]
        if len(args) != sum(widths):
            return b"0C", []  # a parameter of the wrong length
        nums, pos = [], 0
        for i, w in enumerate(widths):
            field = args[pos:pos + w]
            pos += w
            if not field.isdigit():
                return (b"01", b"02", b"03", b"06", b"07")[i], []
            nums.append(int(field))
        first, last = nums[0], nums[1]
        p = self.params
        if not p["AMIN"] <= first <= p["AMAX"] or not p["AMIN"] <= last <= p["AMAX"]:
            return b"04", []
        if last < first:
            return b"05", []
        return b"00", nums

    def _gd(self, line: bytes, args: bytes, width: int) -> None:
        status, nums = self._steps(args, 3)
        if status == b"00" and not self.laser_on:
            status = b"10"
        if status != b"00":
            self.send(scip.reply(line, status))
            return
        first, last, cluster = nums
        k = None
        if self.source is not None:
            k = min(int(self.device_time() / self.source.period), len(self.source) - 1)
        values = self.values(k, first, last, cluster, width)
        self.send(scip.scan_reply(line, b"00", self.time_ms(), values, width),
                  scan=(-1 if k is None else k, values))

    def _md(self, line: bytes, args: bytes, width: int) -> None:
        status, nums = self._steps(args, 5)
        if status != b"00":
            self.send(scip.reply(line, status))
            return
        first, last, cluster, skip, scans = nums
        self.send(scip.reply(line, b"00"))
        self.laser_on = True  # MD/MS switch the laser on themselves
        self.stream = _Stream(echo=line[:13], tag=line[15:], width=width, first=first, last=last,
                              cluster=cluster, skip=skip, remaining=scans)
        self.rewind_clock()

    # -- streaming --------------------------------------------------------------------------------
    def tick(self) -> None:
        s = self.stream
        if s is None:
            return
        k = self.next_scan()
        if k is None:
            return
        s.counter += 1
        if (s.counter - 1) % (s.skip + 1):
            return
        if s.remaining:
            s.remaining -= 1
            left = s.remaining
            if not left:
                self.stream = None
        else:
            left = 0
        values = self.values(k, s.first, s.last, s.cluster, s.width)
        echo = s.echo + f"{left:02d}".encode() + s.tag
        self.send(scip.scan_reply(echo, b"99", self.time_ms(), values, s.width), scan=(k, values))
