"""Where scans come from: the one interface of recorded logs, the simulator and live scanners.

The mapper cannot tell sources apart: each is iterated for its :class:`~vmp.types.ScanFrame`
objects, says its beam geometry and name, its length when it knows it, a reference trajectory
when it has one (the simulator's truth, a GMapping log's corrected poses), and what it skipped
on the way. ``drivers.open_source`` opens any of them from a name on the command line. This
module imports nothing of the project but :mod:`vmp.types`.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from vmp.types import BeamGeometry, FloatArray, ScanFrame

__all__ = ["FrameList", "Reference", "Source", "SourceReport", "reference_for",
           "stack_reference"]


@dataclass(frozen=True)
class Reference:
    """Poses to compare a run against, one per scan, in the source's scan order.

    ``truth`` says whether they are the true poses (a simulator's) or another system's
    estimate (GMapping's corrected poses in a Radish log); ``stamps`` is None where they cannot
    be used to pair poses, which are then paired by order.
    """

    poses: FloatArray  # (S, 3)
    label: str  # what they are, for metric names: "ground truth", "GMapping's poses"
    truth: bool
    stamps: FloatArray | None = None


@dataclass
class SourceReport:
    """What a source skipped or found odd while it was read, and what else it counted."""

    item: str = "line"  # what a problem's number counts: a line, a message, a scan
    skipped: int = 0  # items that could not be used
    backwards: int = 0  # stamps that ran backwards (the scans were kept)
    problems: list[tuple[int, str]] = field(default_factory=list)  # (item number, what)
    counts: dict[str, int | float | str] = field(default_factory=dict)  # join the metrics
    status: str = ""  # a few words on the source's state, for a progress line
    damaged: str = ""  # where the file was found damaged and reading stopped ('' if not)

    def summary(self, name: str) -> str:
        """One line on what was skipped, odd or damaged, with the first few places ('' if
        nothing)."""
        damaged = f"{name}: {self.damaged}" if self.damaged else ""
        if not self.problems:
            return damaged
        first = "; ".join(f"{self.item} {no}: {what}" for no, what in self.problems[:3])
        more = "; ..." if len(self.problems) > 3 else ""
        return (f"{name}: {self.skipped} bad {self.item}s skipped, {self.backwards} stamps "
                f"running backwards ({first}{more})" + (f"; {self.damaged}" if damaged else ""))


@runtime_checkable
class Source(Protocol):
    """Scan frames from anywhere: a recording, a simulated world, a serial scanner."""

    name: str  # a short name for results folders and tables ("office", "intel-first5505")

    @property
    def geometry(self) -> BeamGeometry:
        """The beams every frame of this source has."""

    @property
    def length(self) -> int | None:
        """How many frames iteration yields, when known beforehand."""

    def __iter__(self) -> Iterator[ScanFrame]:
        """The frames, in order."""

    def reference(self) -> Reference | None:
        """Poses to score a run against, one per frame yielded so far, or None."""

    def report(self) -> SourceReport:
        """What was skipped or found odd so far."""

    def close(self) -> None:
        """Stop yielding frames soon; safe to call from a signal handler or another thread."""


def stack_reference(poses: list[FloatArray], label: str, truth: bool,
                    stamps: list[float] | None = None) -> Reference | None:
    """A reference from poses gathered one per frame (None when there are none)."""
    if not poses:
        return None
    return Reference(np.array(poses, dtype=np.float64).reshape(-1, 3), label, truth,
                     None if stamps is None else np.array(stamps, dtype=np.float64))


def reference_for(source: Source, scans: int) -> Reference | None:
    """The source's reference poses for its first ``scans`` frames (None unless it has one
    each)."""
    ref = source.reference()
    # Poses paired by order must be one per scan; stamped ones may go on beyond the run.
    if ref is None or len(ref.poses) < scans or (ref.stamps is None
                                                  and len(ref.poses) != scans):
        return None
    return Reference(ref.poses[:scans], ref.label, ref.truth,
                     None if ref.stamps is None else ref.stamps[:scans])


class FrameList:
    """Frames already in memory as a source (to time the mapper alone, or in tests)."""

    def __init__(self, frames: Sequence[ScanFrame], name: str = "frames",
                 reference: Reference | None = None) -> None:
        if not frames:
            raise ValueError("a frame list needs at least one frame")
        self.frames, self.name, self._reference = frames, name, reference
        self._closed = False

    @property
    def geometry(self) -> BeamGeometry:
        return self.frames[0].geometry

    @property
    def length(self) -> int:
        return len(self.frames)

    def __iter__(self) -> Iterator[ScanFrame]:
        self._closed = False
        for frame in self.frames:
            yield frame
            if self._closed:
                return

    def reference(self) -> Reference | None:
        return self._reference

    def report(self) -> SourceReport:
        return SourceReport(item="scan")

    def close(self) -> None:
        self._closed = True
