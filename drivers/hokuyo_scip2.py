"""Hokuyo URG scanners over a serial port (RS-232 or USB CDC-ACM) with SCIP 2.0.

The handshake stops any stream (``QT``), drains the input, switches to SCIP 2.0 (status ``00``,
or ``0E`` when the sensor already speaks it), reads the parameters (``PP``) and the version
(``VV``, optional) and starts a continuous 3-character ``MD`` stream, which switches the laser
on by itself. A sensor that answers ``QT`` with the SCIP 1.1 status ``E`` (an URG-04LX after
a power cycle) is switched to SCIP 2.0 the same way. Each scan reply is checked completely
(:func:`drivers.scip2_protocol.check_scan`) before it becomes ranges: values below DMIN (URG
error codes) are no return. The 6-bit line sums miss two flips of the same bit in one line,
and the sensor never reports more than DMAX: a scan with a value above ``implausible_above``
times DMAX has a corruption the sums missed and is refused; values above DMAX up to that
limit are no return.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from drivers import scip2_protocol as scip
from drivers.serial_scanner import DeviceError, ScanDriver
from vmp.types import BeamGeometry, FloatArray

__all__ = ["HokuyoScip2Driver"]

_PP_KEYS = ("DMIN", "DMAX", "ARES", "AMIN", "AMAX", "AFRT")
_WIDTH = 3  # MD: 3-character values


class HokuyoScip2Driver(ScanDriver):
    """A Hokuyo URG streaming ``MD`` scans of steps ``first_step..last_step`` (default: all).

    ``cluster`` groups that many neighbouring steps into one value (the sensor reports the
    nearest). ``reply_timeout`` and ``tries`` bound each handshake command.
    ``implausible_above`` (a multiple of DMAX, None: no limit) refuses scans holding a value
    the sensor cannot report. Other keyword arguments go to
    :class:`~drivers.serial_scanner.ScanDriver`. After :meth:`connect`,
    ``params`` holds the PP values and ``version`` the VV lines; ``device_time`` is the time
    stamp (ms) of the last scan delivered.
    """

    name = "hokuyo"
    baudrate = 19200  # RS-232 default after reset; USB ignores it

    def __init__(self, port: str, *, first_step: int | None = None,
                 last_step: int | None = None, cluster: int = 1, reply_timeout: float = 0.3,
                 tries: int = 3, implausible_above: float | None = 1.0,
                 **base_kwargs: Any) -> None:
        super().__init__(port, **base_kwargs)
        if implausible_above is not None and implausible_above < 1.0:
            raise ValueError(f"implausible_above is a multiple of DMAX >= 1, "
                             f"got {implausible_above}")
        self.implausible_above = implausible_above
        if not 1 <= cluster <= 99:
            raise ValueError(f"cluster must lie in 1..99, got {cluster}")
        self.first_step = first_step
        self.last_step = last_step
        self.cluster = cluster
        self.reply_timeout = reply_timeout
        self.tries = tries
        self.params: dict[str, int] = {}
        self.version: dict[str, str] = {}
        self.device_time = -1
        self._request = b""  # the MD line we stream with, without LF
        self._count = 0  # values per scan
        self._carry = b""  # what followed the MD acknowledgement during connect
        self._parser = scip.ReplyParser(())
        self._garbage_seen = 0
        self._skipped_seen = 0

    # -- handshake ------------------------------------------------------------------------------
    def _await(self, parser: scip.ReplyParser, timeout: float,
               accept: Callable[[scip.Reply], bool], log: bytearray | None = None
               ) -> scip.Reply | None:
        assert self.ser is not None
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            chunk = self.ser.read(max(1, self.ser.in_waiting))
            if log is not None:
                log += chunk
            for rep in parser.feed(chunk):
                if accept(rep):
                    return rep
        return None

    def _transact(self, line: bytes, check: Callable[[scip.Reply], Any]) -> Any:
        """Send ``line`` until ``check`` passes on its reply; ``check`` raises ScipError."""
        problem = "no reply"
        for _ in range(self.tries):
            self.write(line + b"\n")
            rep = self._await(scip.ReplyParser((line,)), self.reply_timeout,
                              lambda r: r.echo == line)
            if rep is None:
                problem = "no reply"
                continue
            try:
                return check(rep)
            except scip.StatusError as exc:
                raise DeviceError(f"{self.port}: {exc}") from exc
            except scip.ScipError as exc:
                problem = str(exc)
        raise DeviceError(f"{self.port}: {line.decode('ascii')} failed after {self.tries} "
                          f"tries: {problem}")

    def _drain(self, quiet: float = 0.05, limit: float = 0.5) -> None:
        assert self.ser is not None
        deadline = time.monotonic() + limit
        last = time.monotonic()
        while time.monotonic() < deadline and time.monotonic() - last < quiet:
            if self.ser.read(max(1, self.ser.in_waiting)):
                last = time.monotonic()

    def _stop_and_drain(self) -> None:
        """QT until it is answered (a streaming sensor keeps sending a while), then drain.

        Any complete reply counts: ``00P``, SCIP 1.1's ``E``, or a status garbled on the line.
        """
        heard = bytearray()
        for _ in range(2):
            self.write(b"QT\n")
            rep = self._await(scip.ReplyParser((b"QT",)), self.reply_timeout,
                              lambda r: r.echo == b"QT" and r.complete and bool(r.status),
                              heard)
            if rep is not None:
                break
        if not heard:
            raise DeviceError(f"{self.port}: no answer to QT")
        self._drain()

    @staticmethod
    def _scip2_status(rep: scip.Reply) -> bytes:
        if rep.complete and rep.status == b"0":  # SCIP 1.1 style one-character status
            return b"00"
        status = scip.check_status(rep.status)
        if status not in (b"00", b"0E"):
            raise scip.StatusError(status, f"SCIP2.0 answered status {status!r}")
        return status

    def _read_params(self, rep: scip.Reply) -> dict[str, int]:
        info = scip.parse_info(rep, b"PP")
        try:
            p = {k: int(info[k]) for k in _PP_KEYS}
        except (KeyError, ValueError) as exc:
            raise scip.FramingError(f"PP reply without a number for {exc}") from exc
        if not (0 <= p["DMIN"] < p["DMAX"] and 0 <= p["AMIN"] <= p["AFRT"] <= p["AMAX"]
                < p["ARES"]):
            raise scip.FramingError(f"implausible PP values {p}")
        scan = info.get("SCAN", "600")
        p["SCAN"] = int(scan) if scan.isdigit() and int(scan) > 0 else 600  # rpm
        return p

    def connect(self) -> BeamGeometry:
        """QT, drain, SCIP2.0, PP, VV, then MD streaming until QT; the beams from PP."""
        self._carry = b""
        self._stop_and_drain()
        self._transact(b"SCIP2.0", self._scip2_status)
        p = self._transact(b"PP", self._read_params)
        try:
            self.version = self._transact(b"VV", lambda r: scip.parse_info(r, b"VV"))
        except DeviceError:
            self.version = {}  # not needed for scanning
        first = p["AMIN"] if self.first_step is None else self.first_step
        last = p["AMAX"] if self.last_step is None else self.last_step
        if not p["AMIN"] <= first <= last <= p["AMAX"]:
            raise DeviceError(f"{self.port}: steps {first}..{last} outside the sensor's "
                              f"{p['AMIN']}..{p['AMAX']}")
        self.params = p
        self._count = -(-(last - first + 1) // self.cluster)
        self._request = scip.md_request(first, last, self.cluster).rstrip(b"\n")
        self.reset_decoder()  # the parser now expects this request's echo
        self._start_stream()
        inc = 2 * math.pi / p["ARES"]
        return BeamGeometry(num_beams=self._count, angle_min=(first - p["AFRT"]) * inc,
                            angle_increment=self.cluster * inc, max_range=p["DMAX"] / 1000.0)

    def _start_stream(self) -> None:
        """Send MD; its acknowledgement (or, if that was garbled, a scan) confirms it."""
        line = self._request
        period = 60.0 / self.params["SCAN"]

        def confirms(rep: scip.Reply) -> bool:
            try:
                status = scip.check_status(rep.status)
            except scip.ScipError:
                return False  # garbled: wait for the next reply
            if status not in (b"00", b"99"):
                raise DeviceError(f"{self.port}: {line.decode('ascii')} answered status "
                                  f"{status.decode('ascii', 'replace')!r}")
            return True

        for _ in range(self.tries):
            self.write(line + b"\n")
            got = bytearray()
            if self._await(scip.ReplyParser((line,)), self.reply_timeout + 3 * period,
                           confirms, got) is not None:
                self._carry = bytes(got)  # the ack and the first scans: decoded by decode()
                return
        raise DeviceError(f"{self.port}: no acknowledgement of {line.decode('ascii')}")

    # -- streaming ------------------------------------------------------------------------------
    def reset_decoder(self) -> None:
        """Forget partial replies; what followed the MD acknowledgement is kept for decode()."""
        self._parser = scip.ReplyParser((self._request,) if self._request else ())
        self._garbage_seen = 0
        self._skipped_seen = 0

    def decode(self, data: bytes) -> list[FloatArray]:
        """Ranges in metres (inf: no return) of every MD scan reply that passes every check."""
        if self._carry:
            data, self._carry = self._carry + data, b""
        out: list[FloatArray] = []
        st = self.stats
        for rep in self._parser.feed(data):
            if rep.complete and rep.status == b"00P" and not rep.lines:
                continue  # the acknowledgement of MD
            try:
                stamp, values = scip.check_scan(rep, echo=self._request, status=b"99",
                                                values=self._count, width=_WIDTH)
            except scip.ChecksumError as exc:
                st.checksum_errors += 1
                self.last_error = str(exc)
            except scip.StatusError as exc:
                st.rejected += 1
                self.last_error = str(exc)
            except scip.FramingError as exc:
                st.framing_errors += 1
                self.last_error = str(exc)
            else:
                limit = self.implausible_above
                if limit is not None and int(values.max(initial=0)) > limit * self.params["DMAX"]:
                    st.rejected += 1  # a corruption the line sums missed
                    self.last_error = "scan with a value above DMAX refused"
                    continue
                self.device_time = stamp
                out.append(self._ranges(values))
        p = self._parser
        st.framing_errors += p.garbage_runs - self._garbage_seen  # a reply lost its echo
        st.skipped_bytes += p.skipped_bytes - self._skipped_seen
        self._garbage_seen, self._skipped_seen = p.garbage_runs, p.skipped_bytes
        return out

    def _ranges(self, values: np.ndarray) -> FloatArray:
        p = self.params
        ok = (values >= p["DMIN"]) & (values <= p["DMAX"])
        return np.where(ok, values / 1000.0, np.inf)

    def stop_stream(self) -> None:
        """QT: stop streaming and switch the laser off."""
        if self.ser is not None:
            self.write(b"QT\n")
