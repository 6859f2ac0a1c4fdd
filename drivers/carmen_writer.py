"""Writing CARMEN logs: scan frames as FLASER (or ROBOTLASER1, or RAWLASER1 without
odometry) and ODOM lines, in the line formats :mod:`drivers.carmen` reads back."""

from __future__ import annotations

import math
import os
from collections.abc import Iterable
from pathlib import Path
from typing import IO

import numpy as np

from vmp import __version__
from vmp.fileio import atomic_write, writable_target
from vmp.types import ScanFrame, wrap_angle

__all__ = ["CarmenWriter", "write_carmen"]

HOST = "vmp"


def _is_flaser_geometry(n: int, angle_min: float, inc: float) -> bool:
    """True when the beams are centred on the heading, so FLASER describes them exactly."""
    return abs(angle_min + inc * (n - 1) / 2.0) < 1e-9 and inc > 0


class CarmenWriter:
    """Write frames to a CARMEN log as they come; the file appears under its name on ``close``.

    With ``atomic=False`` lines go straight to the named file and are flushed every second,
    so a recording of a live run survives a crash up to its last flush.
    """

    def __init__(self, path: str | os.PathLike[str], *, comment: str = "",
                 atomic: bool = True) -> None:
        self.path = Path(path)
        self._ctx = atomic_write(self.path, "w", encoding="ascii") if atomic else None
        self._f: IO[str] = (self._ctx.__enter__() if self._ctx is not None
                            else open(writable_target(self.path), "w", encoding="ascii"))
        self._geometry: tuple[int, float, float, float] | None = None
        self._last: tuple[float, np.ndarray] | None = None
        self._f.write("# CARMEN Logfile\n# file format is one message per line\n")
        self._f.write("# message_name [message contents] ipc_timestamp ipc_hostname "
                      "logger_timestamp\n"
                      "# message formats defined: PARAM ODOM FLASER ROBOTLASER1 RAWLASER1\n")
        self.params: dict[str, str] = {}
        self._f.write(f"# written by vmp-slam {__version__}{': ' + comment if comment else ''}\n")
        self.count = 0

    def _params(self, frame: ScanFrame) -> None:
        n, inc = frame.num_beams, frame.angle_increment
        self._geometry = (n, frame.angle_min, inc, frame.max_range)
        self._flaser = _is_flaser_geometry(n, frame.angle_min, inc)
        fov = math.degrees(inc * (n - 1))
        for name, value in (
            ("robot_front_laser_max", f"{frame.max_range:g}"),
            ("laser_front_laser_fov", f"{fov:.6g}"),
            ("laser_front_laser_resolution", f"{math.degrees(inc):.6g}"),
        ):
            self._f.write(f"PARAM {name} {value} {HOST} {frame.stamp:.6f}\n")
            self.params[name] = value

    def flush(self) -> None:
        self._f.flush()

    def write(self, frame: ScanFrame) -> str:
        """Write the frame (and its ODOM line); returns the laser line as written.

        A frame without odometry becomes a RAWLASER1 line.
        """
        if self._geometry is None:
            self._params(frame)
        elif self._geometry != (frame.num_beams, frame.angle_min, frame.angle_increment,
                                frame.max_range):
            raise ValueError(f"frame {frame.index}: laser geometry changed within the log")
        t = frame.stamp
        r = np.where(frame.returned, frame.ranges, frame.max_range)
        ranges = " ".join(np.char.mod("%.3f", r).tolist())
        stamp = f"{t:.6f} {HOST} {t:.6f}"
        fov = frame.angle_increment * (frame.num_beams - 1)
        head = (f"0 {frame.angle_min:.9f} {fov:.9f} {frame.angle_increment:.9f} "
                f"{frame.max_range:g} 0.01 0 {frame.num_beams} {ranges} 0")
        if frame.odom is None:
            line = f"RAWLASER1 {head} {stamp}\n"
            self._f.write(line)
            self.count += 1
            return line
        x, y, th = frame.odom
        tv = rv = 0.0
        if self._last is not None and t > self._last[0]:
            dt = t - self._last[0]
            prev = self._last[1]
            tv = math.hypot(x - prev[0], y - prev[1]) / dt
            rv = float(wrap_angle(th - prev[2])) / dt
        self._last = (t, frame.odom)
        pose = f"{x:.6f} {y:.6f} {th:.6f}"
        self._f.write(f"ODOM {pose} {tv:.6f} {rv:.6f} 0.000000 {stamp}\n")
        if self._flaser:
            line = f"FLASER {frame.num_beams} {ranges} {pose} {pose} {stamp}\n"
        else:
            line = f"ROBOTLASER1 {head} {pose} {pose} {tv:.6f} {rv:.6f} 0 0 0 {stamp}\n"
        self._f.write(line)
        self.count += 1
        return line

    def close(self, ok: bool = True) -> None:
        """Finish the file; with ``ok=False`` (an error) an atomic writer discards it."""
        if self._ctx is not None:
            if ok:
                self._ctx.__exit__(None, None, None)
            else:
                err = RuntimeError("recording aborted")
                self._ctx.__exit__(RuntimeError, err, None)
            self._ctx = None
        else:
            self._f.close()

    def __enter__(self) -> CarmenWriter:
        return self

    def __exit__(self, et, ev, tb) -> None:
        self.close(ok=et is None)


def write_carmen(path: str | os.PathLike[str], frames: Iterable[ScanFrame], *,
                 comment: str = "") -> int:
    """Write all frames to a CARMEN log atomically; returns the number of scans written."""
    with CarmenWriter(path, comment=comment) as w:
        for frame in frames:
            w.write(frame)
    return w.count
