"""How late a scan's stamp is against its odometry, learned from the scans' own turns.

A scan is stamped when it arrives, not when it was taken: a SICK LMS at 38,400 baud takes about
a tenth of a second to send its 361 bytes, and a logger may add its own delay. The odometry
stamped at the same moment then belongs to a robot that has already moved on, and at a turn
of one radian a second the wheels' increment between two scans is off by several degrees (what
looks like wheel slip). Raw odometry scores 0.86 deg on the ACES relations under a second;
the same odometry read 0.1 s earlier scores 0.44 deg (fr079: 1.90 and 0.90 deg).

:class:`Latency` keeps the recent odometry with its stamps and the heading increments that scan
registration measured between consecutive scans (which do not depend on the scanner's mount
or the wheels' scale). Every :data:`FIT_EVERY` new increments it finds the delay that makes
the odometry's heading increments, read that much earlier, agree best with the registered
ones, among 0 to :data:`MAX_LATENCY` in steps of :data:`STEP` (each with the heading scale that
fits it best, so that wheels turning a few per cent too far do not pass for a delay); a delay is
used only when the samples turned enough to tell (:data:`MIN_TURNING`) and it explains the
turns clearly better than none (:data:`GAIN`). Stamps that do not increase (the
Intel recording's bursts, stamps running backwards) say nothing about time: the history starts
again after one, so such a log keeps a delay of zero.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from vmp.types import FloatArray, wrap_angle

__all__ = ["Latency"]

MAX_LATENCY = 0.3  # the longest delay considered (s)
STEP = 0.005  # candidate delays are this far apart (s)
HISTORY = 400  # odometry samples kept
SAMPLES = 300  # registered increments fitted over ...
MIN_SAMPLES = 100  # ... at least this many
FIT_EVERY = 50  # refit after this many new increments
MIN_STEP = 1e-3  # stamps closer than this (s) are not increasing: the history restarts
# A delay is used when its robust disagreement with the registered turns is under this share
# of no delay's: the wheels' own noise leaves some disagreement at every delay.
GAIN = 0.8
HUBER = np.radians(2.0)  # disagreements beyond this count linearly (rad)
MIN_TURNING = np.radians(180.0)  # summed turns of the samples needed to fit at all (rad)


class Latency:
    """The delay of scan stamps behind the odometry, and the odometry at a delayed time."""

    def __init__(self) -> None:
        self.latency = 0.0  # seconds the scans are stamped late
        self._stamps: deque[float] = deque(maxlen=HISTORY)
        self._poses: deque[FloatArray] = deque(maxlen=HISTORY)
        self._headings: deque[float] = deque(maxlen=HISTORY)  # unwrapped
        self._samples: deque[tuple[float, float, float]] = deque(maxlen=SAMPLES)
        self._new = 0
        self.fits = 0  # how often the delay was fitted

    def odometry(self, stamp: float, pose: FloatArray) -> None:
        """The odometry ``pose`` of the scan stamped ``stamp``."""
        if self._stamps and not stamp >= self._stamps[-1] + MIN_STEP:
            self._stamps.clear()
            self._poses.clear()
            self._headings.clear()
            self._samples.clear()
        heading = float(pose[2])
        if self._headings:
            heading = self._headings[-1] + float(wrap_angle(heading - self._poses[-1][2]))
        self._stamps.append(float(stamp))
        self._poses.append(np.array(pose, dtype=np.float64))
        self._headings.append(heading)

    def at(self, stamp: float) -> FloatArray | None:
        """The odometry at ``stamp`` less the delay: linear between the two samples around it;
        None when the history does not reach back that far (or holds nothing)."""
        t = stamp - self.latency
        st = self._stamps
        if not st or t > st[-1] + 1e-9:
            return None
        if self.latency == 0.0 and t >= st[-1] - 1e-9:
            return self._poses[-1].copy()
        # The first sample at or after t, looked for from the newest: t lies at most the
        # delay (0.3 s) back, a few samples. (Copying the 400 stamps into an array to search
        # them would take half of this call: 10 us a scan, in mapping and tracking alike.)
        i = len(st) - 1
        while i > 0 and st[i - 1] >= t:
            i -= 1
        if i == 0:
            return None
        t0, t1 = st[i - 1], st[i]
        f = (t - t0) / (t1 - t0)
        a, b = self._poses[i - 1], self._poses[i]
        out = a + f * (b - a)
        out[2] = float(wrap_angle(a[2] + f * float(wrap_angle(b[2] - a[2]))))
        return out

    def registered(self, before: float, after: float, turn: float) -> None:
        """Scan registration measured ``turn`` (rad) between the scans stamped ``before`` and
        ``after``; refits the delay every :data:`FIT_EVERY` such increments."""
        self._samples.append((float(before), float(after), float(turn)))
        self._new += 1
        if self._new >= FIT_EVERY and len(self._samples) >= MIN_SAMPLES:
            self._new = 0
            self._fit()

    def _fit(self) -> None:
        if len(self._stamps) < 2:  # no odometry to read
            return
        times = np.fromiter(self._stamps, np.float64, len(self._stamps))
        headings = np.fromiter(self._headings, np.float64, len(self._headings))
        s = np.array(self._samples)
        # Only increments whose delayed ends all lie inside the history.
        inside = (s[:, 0] - MAX_LATENCY >= times[0]) & (s[:, 1] <= times[-1])
        s = s[inside]
        if len(s) < MIN_SAMPLES or np.abs(s[:, 2]).sum() < MIN_TURNING:
            return
        delays = np.arange(0.0, MAX_LATENCY + STEP / 2, STEP)
        start = np.interp(s[:, 0, None] - delays[None, :], times, headings)
        end = np.interp(s[:, 1, None] - delays[None, :], times, headings)
        wheels = end - start  # (samples, delays): the odometry's turns, read that much earlier
        # With its own heading scale at each delay: wheels that turn a few per cent too far
        # or too little (a common calibration error) must not pass for a delay.
        scale = (wheels * s[:, 2, None]).sum(axis=0) / np.maximum((wheels**2).sum(axis=0), 1e-12)
        miss = np.abs(s[:, 2, None] - scale * wheels)
        cost = np.where(miss <= HUBER, 0.5 * miss**2, HUBER * (miss - 0.5 * HUBER)).mean(axis=0)
        best = int(np.argmin(cost))
        self.fits += 1
        self.latency = float(delays[best]) if cost[best] < GAIN * cost[0] else 0.0
