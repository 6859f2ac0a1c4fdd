"""A simulated odometry feed: JSON lines of a scenario run's odometry on a pseudo-terminal.

It follows a scanner device's clock so that the odometry of scan k is sent half a scan period
before the scan itself, as a wheel encoder running ahead of the laser would.
"""

from __future__ import annotations

import json

from drivers.devices.pty_device import PtyDevice

__all__ = ["PoseFeedDevice"]


class PoseFeedDevice(PtyDevice):
    """Streams ``{"t", "x", "y", "theta"}`` lines of ``scanner.source`` on its own pty."""

    name = "pose-feed"

    def __init__(self, scanner: PtyDevice) -> None:
        super().__init__(scanner.source, speed=scanner.speed)
        self.scanner = scanner
        self._k = 0

    def tick(self) -> None:
        src = self.source
        if src is None or self._k >= len(src):
            return
        self._t0 = self.scanner._t0  # one clock for both devices
        if self.device_time() < (self._k - 0.5) * src.period:
            return
        x, y, th = (float(v) for v in src.odom(self._k))
        line = json.dumps({"t": self._k * src.period, "x": x, "y": y, "theta": th})
        self.send((line + "\n").encode())
        self._k += 1
