"""CARMEN log files read back (:mod:`drivers.carmen_writer` writes them).

Line formats (one message per line, ``#`` starts a comment)::

    PARAM name value ipc_hostname ipc_timestamp
    ODOM x y theta tv rv accel ipc_timestamp ipc_hostname logger_timestamp
    FLASER n r_1 .. r_n x y theta odom_x odom_y odom_theta
        ipc_timestamp ipc_hostname logger_timestamp
    ROBOTLASER1 laser_type start_angle fov angular_resolution max_range accuracy remission_mode
        n r_1 .. r_n n_rem rem_1 .. laser_x laser_y laser_theta robot_x robot_y robot_theta
        tv rv forward_safety_dist side_safety_dist turn_axis
        ipc_timestamp ipc_hostname logger_timestamp
    RAWLASER1 laser_type start_angle fov angular_resolution max_range accuracy remission_mode
        n r_1 .. r_n n_rem rem_1 .. ipc_timestamp ipc_hostname logger_timestamp

A RAWLASER line carries no pose: its frame has no odometry (a live run without a pose feed
is recorded this way). RAWLASER1 to RAWLASER4 name the laser; all read the same.

FLASER assumes a scan centred on the heading whose first and last beams lie at -fov/2 and
+fov/2, fov from the ``laser_front_laser_fov`` parameter (default 180 degrees): n beams are
``linspace(-fov/2, fov/2, n)``, so 181 beams step by 1 degree and 180 beams (the Intel
recording, whose source states beam_start -pi/2, beam_end +pi/2) by 180/179 degrees. A range at
or beyond the laser's maximum range means "no return".
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Iterator

import numpy as np

from drivers.textlog import DAMAGE, LineLog, LineTooLong, lines_of, open_text
from vmp.source import Reference, SourceReport, stack_reference
from vmp.types import ScanFrame, compose, interpolate_pose, relative

__all__ = ["CarmenLog", "parse_laser_line", "read_carmen"]

class CarmenLog(LineLog):
    """The scans of a CARMEN log (FLASER and ROBOTLASER1 lines), read lazily in file order.

    A bad line (fields that do not add up, a range that is NaN or negative, a pose that is
    not finite) is skipped and recorded in :attr:`problems` with its line number. A stamp that
    runs backwards is recorded too but the scan is kept in file order: real logs do this (the
    Intel recording's scans come in bursts whose stamps go back by up to a second), and the
    mapper follows odometry, not time. With ``strict`` the first of either raises
    :class:`InputError`. Memory does not grow with the file: lines are read one at a time
    (gzip too).

    Odometry: a FLASER or ROBOTLASER1 scan carries its own. A RAWLASER scan carries none; it
    gets the pose of the ODOM lines interpolated to its stamp (a log without ODOM lines gives
    scans without odometry). A FLASER scan whose odometry is exactly the last ODOM line's pose,
    stamped otherwise (ACES's logger copies it into every scan, up to 0.19 s old at the
    scan's stamp), gets the ODOM lines' pose interpolated to its own stamp too, where the ODOM
    lines' stamps say when their poses were taken: in a log whose ODOM stamps run backwards
    anywhere (the Intel recording's come in bursts, stamped on arrival) they do not, and every
    FLASER scan keeps its own pose (see :meth:`odometry_stamped`); one stamped with it keeps its
    own (:class:`~drivers.carmen_writer.CarmenWriter` writes them so, and several scans of a
    live run can share a stamp, each with the odometry it was mapped with); a logger that
    interpolates itself (fr079's) writes poses between the ODOM lines, which are kept. In a
    GMapping output log (one with ``NEFF`` lines, like the corrected Radish logs; they follow
    its first scan) the FLASER poses are GMapping's corrected estimates, not odometry:
    the raw odometry is rebuilt from the ODOM lines (see :meth:`_rebuild`) and the corrected
    poses are kept in :attr:`poses`, one per scan, to compare against (:meth:`reference`).
    """

    scan_words = (b"FLASER", b"ROBOTLASER1", b"RAWLASER")

    format_name = "CARMEN log"

    def __init__(self, path: str | os.PathLike[str], *, strict: bool = False) -> None:
        super().__init__(path, strict=strict)
        # GMapping's corrected poses (stamp, pose), one per scan, in a GMapping output log.
        self.poses: list[tuple[float, np.ndarray]] = []
        self.gmapping = False
        self.unknown_increments = 0
        self._odometry_stamped: bool | None = None

    def odometry_stamped(self) -> bool:
        """Whether the log's ODOM stamps tell when their poses were taken: they never run
        backwards (read once, up to the first that does). Stamps that run backwards were
        written on arrival, in bursts: interpolating poses by them puts a scan where the robot
        was at another time."""
        if self._odometry_stamped is None:
            self._odometry_stamped = True
            last = -math.inf
            try:
                with open_text(self.path) as f:
                    for line in lines_of(f):
                        if not line.startswith("ODOM"):
                            continue
                        odom = _odom_line(line.split())
                        if odom is None:
                            continue
                        if odom[0] < last:
                            self._odometry_stamped = False
                            break
                        last = odom[0]
            except (OSError, LineTooLong, *DAMAGE):
                pass  # the pass that maps reads up to the damage and reports it
        return self._odometry_stamped

    def reference(self) -> Reference | None:
        """GMapping's corrected poses, one per scan, in a GMapping output log (paired by
        order: such logs' stamps cannot be used); None in any other log."""
        if not self.gmapping:
            return None
        return stack_reference([p for _, p in self.poses], "GMapping's poses", truth=False)

    def report(self) -> SourceReport:
        out = super().report()
        if self.gmapping:
            out.counts["unknown odometry increments"] = self.unknown_increments
        return out

    def notes(self) -> list[tuple[str, str]]:
        if not self.gmapping:
            return []
        return [("note", f"GMapping output log: odometry rebuilt from its ODOM lines "
                 f"({self.unknown_increments} of {max(self.scans - 1, 0)} increments unknown); "
                 "its corrected poses are the reference")]

    def _frames(self, lines: Iterator[tuple[int, str]]) -> Iterator[ScanFrame]:
        self.poses, self.gmapping, self.unknown_increments = [], False, 0
        params: dict[str, str] = {}
        odom_t: list[float] = []  # recent ODOM lines: stamps and poses
        odom_p: list[np.ndarray] = []
        # Scans waiting for the ODOM line after their stamp, in file order: (line, frame,
        # whether its odometry is read from the ODOM lines).
        pending: list[tuple[int, ScanFrame, bool]] = []
        no_odometry = False
        prev: tuple[np.ndarray, np.ndarray] | None = None  # (corrected pose, rebuilt odom)
        self._odom_lines = 0  # ODOM lines since the last FLASER
        flasers = 0
        stamped = self.odometry_stamped()

        def release(upto: float) -> Iterator[ScanFrame]:
            """The waiting scans stamped up to ``upto``, in order."""
            while pending and (pending[0][1].stamp <= upto or len(pending) > MAX_WAITING):
                lno, f, interpolate = pending.pop(0)
                self._line = lno
                if interpolate and odom_t:  # beyond the last ODOM line its pose holds
                    f = _with_odom(f, interpolate_pose(odom_t, odom_p, f.stamp))
                yield f

        for no, line in lines:
            parts = line.split()
            if not parts or parts[0].startswith("#"):
                continue
            kind = parts[0]
            if kind == "PARAM" and len(parts) >= 3:
                params[parts[1]] = parts[2]
                continue
            if kind == "NEFF":
                self.gmapping = True
                continue
            if kind == "ODOM":
                pose = _odom_line(parts)
                if pose is None:
                    self._bad(no, "bad ODOM line: expected x y theta tv rv accel timestamp")
                    continue
                odom_t.append(pose[0])
                odom_p.append(pose[1])
                self._odom_lines += 1
                if len(odom_t) > ODOM_HISTORY:
                    del odom_t[0], odom_p[0]
                yield from release(odom_t[-1])
                continue
            if kind not in _LASER_WORDS:
                continue
            try:
                frame = _parse_laser(kind, parts, params, self.scans + len(pending))
            except (ValueError, IndexError) as exc:
                self._bad(no, f"bad {kind} line: {exc}")
                continue
            if frame.odom is None and not no_odometry:
                # A RAWLASER line: odometry comes from the ODOM lines around its stamp.
                pending.append((no, frame, True))
                if not odom_t and len(pending) > 50:
                    no_odometry = True  # a log without ODOM lines: scans carry none
                    for lno, f, _ in pending:
                        self._line = lno
                        yield f
                    pending.clear()
                continue
            if kind == "FLASER" and frame.odom is not None:
                stale = (not self.gmapping and flasers >= NOT_GMAPPING and bool(odom_p)
                         and stamped
                         and frame.stamp != odom_t[-1]
                         and np.array_equal(frame.odom, odom_p[-1]))
                flasers += 1
                if stale or pending:
                    pending.append((no, frame, stale))
                    if odom_t:
                        yield from release(odom_t[-1])
                    continue
                frame, prev = self._rebuild(frame, odom_p, prev)
                self._odom_lines = 0
            elif pending:
                pending.append((no, frame, False))
                continue
            self._line = no
            yield frame
        for lno, f, interpolate in pending:  # after the last ODOM line: the last pose holds
            self._line = lno
            yield _with_odom(f, interpolate_pose(odom_t, odom_p, f.stamp)) if interpolate else f
        if not self.gmapping:
            self.poses = []

    def _rebuild(self, frame: ScanFrame, odom_p: list[np.ndarray],
                 prev: tuple[np.ndarray, np.ndarray] | None
                 ) -> tuple[ScanFrame, tuple[np.ndarray, np.ndarray]]:
        """In a GMapping output log, replace the corrected pose by rebuilt raw odometry.

        GMapping writes each keyframe with its corrected pose P_k (as pose and as odometry),
        then an ODOM line with P_k, then dead-reckoned ODOM lines continuing from P_k. The raw
        increment to keyframe k+1 is ``inverse(P_k) (+) (last ODOM line before it)``; chained
        from P_0 these give the robot's own odometry. P_k is kept in :attr:`poses`.
        Where no dead-reckoned ODOM line lies between two keyframes (only GMapping's copy of
        P_k) the increment is unknown: that scan gets no odometry (counted in
        :attr:`unknown_increments`) and the chain goes on from the next known increment.
        """
        corrected = frame.odom
        assert corrected is not None
        if self.gmapping or not self.poses:  # the first in case NEFF lines follow
            self.poses.append((frame.stamp, corrected.copy()))
        if not self.gmapping or prev is None or not odom_p:
            return frame, (corrected, corrected)
        if self._odom_lines <= 1:
            self.unknown_increments += 1
            return _with_odom(frame, None), (corrected, prev[1])
        odom = compose(prev[1], relative(prev[0], odom_p[-1]))
        return _with_odom(frame, odom), (corrected, odom)


def _odom_line(parts: list[str]) -> tuple[float, np.ndarray] | None:
    try:
        pose = np.array(parts[1:4], dtype=np.float64)
        stamp = float(parts[7])
    except (ValueError, IndexError):
        return None
    if len(pose) != 3 or not (np.isfinite(pose).all() and math.isfinite(stamp)):
        return None
    return stamp, pose


def _with_odom(frame: ScanFrame, odom: np.ndarray | None) -> ScanFrame:
    return dataclasses.replace(frame, odom=odom)


def read_carmen(path: str | os.PathLike[str], strict: bool = False) -> Iterator[ScanFrame]:
    """Iterate the scans of a CARMEN log, skipping bad lines (``strict``: the first raises).

    Use :class:`CarmenLog` itself to see what was skipped.
    """
    return iter(CarmenLog(path, strict=strict))


ODOM_HISTORY = 64  # ODOM lines kept to interpolate scans at their stamps
MAX_WAITING = 64  # scans waiting for an ODOM line beyond this go on with what they have
NOT_GMAPPING = 3  # FLASER lines without a NEFF line after them: not a GMapping output log
_SICK_NO_RETURN_MM = np.array([8191.0, 16383.0, 32767.0])
_LASER_WORDS = ("FLASER", "ROBOTLASER1", "RAWLASER1", "RAWLASER2", "RAWLASER3", "RAWLASER4")


def parse_laser_line(line: str, params: dict[str, str], index: int = -1) -> ScanFrame:
    """The frame of one FLASER, ROBOTLASER1 or RAWLASER line (``params``: the PARAMs so far).

    Raises ValueError on a line that does not parse.
    """
    parts = line.split()
    if not parts or parts[0] not in _LASER_WORDS:
        raise ValueError(f"not a laser line: {line[:40]!r}")
    try:
        return _parse_laser(parts[0], parts, params, index)
    except IndexError as exc:
        raise ValueError(f"bad {parts[0]} line: too few fields") from exc


def _parse_laser(kind: str, parts: list[str], params: dict[str, str], index: int) -> ScanFrame:
    odom: np.ndarray | None
    if kind == "FLASER":
        n = int(parts[1])
        if n < 1:
            raise ValueError(f"declares {n} ranges")
        if len(parts) != 2 + n + 9:
            raise ValueError(f"declares {n} ranges but holds {len(parts) - 11} "
                             f"(expected {2 + n + 9} fields, got {len(parts)})")
        ranges = np.array(parts[2:2 + n], dtype=np.float64)
        tail = parts[2 + n:]
        poses = np.array(tail[0:6], dtype=np.float64)
        odom = poses[3:6]
        stamp = float(tail[6])
        fov = math.radians(float(params.get("laser_front_laser_fov", "180")))
        inc = fov / (n - 1) if n > 1 else fov
        angle_min = -fov / 2.0
        max_range = float(params.get("robot_front_laser_max", "81.83"))
    else:  # ROBOTLASER1 and RAWLASER: same head; only ROBOTLASER1 carries poses after it
        angle_min, _fov, inc, max_range = (float(v) for v in parts[2:6])
        n = int(parts[8])
        ranges = np.array(parts[9:9 + n], dtype=np.float64)
        n_rem = int(parts[9 + n])
        tail = parts[10 + n + n_rem:]
        raw = kind.startswith("RAWLASER")
        if len(ranges) != n or len(tail) != (3 if raw else 14):
            raise ValueError(f"declares {n} ranges and {n_rem} remissions but the field "
                             "count does not match")
        poses = np.zeros(3) if raw else np.array(tail[0:6], dtype=np.float64)
        odom = None if raw else poses[0:3]
        stamp = float(tail[0 if raw else 11])
    if np.isnan(ranges).any():
        raise ValueError("a range is NaN")
    if (ranges < 0).any():
        raise ValueError(f"a range is negative ({float(ranges.min())})")
    if not np.isfinite(poses).all():
        raise ValueError(f"the pose is not finite ({' '.join(f'{v:g}' for v in poses)})")
    if not math.isfinite(stamp):
        raise ValueError("the timestamp is not finite")
    no_return = (ranges >= max_range) | (ranges <= 0)
    if kind == "FLASER" and "robot_front_laser_max" not in params:
        # Without the laser's range limit, a SICK's no-return codes (8.191, 16.383 and
        # 32.767 m in its 8, 16 and 32 m mm-modes: all bits of the range set) are not ranges.
        no_return |= np.isin(np.round(np.minimum(ranges, 1e6) * 1000.0), _SICK_NO_RETURN_MM)
    ranges = np.where(no_return, np.inf, ranges)
    return ScanFrame(stamp=stamp, ranges=ranges, angle_min=angle_min, angle_increment=inc,
                     max_range=max_range, odom=odom, index=index)
