"""What the serial driver tests share: a driver run on a thread, clean RPLIDAR turns."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np

from drivers import rplidar_protocol as rp
from drivers.rplidar_protocol import encode_nodes
from drivers.serial_scanner import ScanDriver


class Session:
    """A driver's frames collected on a thread; waits fail instead of hanging."""

    def __init__(self, driver: ScanDriver) -> None:
        self.driver = driver
        self.frames: list = []
        self.crash: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        try:
            for frame in self.driver.frames():
                self.frames.append(frame)
        except BaseException as exc:  # reported by the test
            self.crash = exc

    def wait(self, cond: Callable[[], bool], timeout: float, what: str) -> None:
        deadline = time.monotonic() + timeout
        while not cond():
            assert self.crash is None, repr(self.crash)
            assert time.monotonic() < deadline, (f"timed out waiting for {what}: "
                                                 f"{self.driver.stats.summary()}; "
                                                 f"{self.driver.last_error}")
            time.sleep(0.02)

    def stop(self) -> None:
        self.driver.close()
        self.thread.join(timeout=5.0)
        assert not self.thread.is_alive(), "the driver did not stop"
        assert self.crash is None, repr(self.crash)


def turn(n: int = 360, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Start flags, angle_q6 and dist_q2 of one clean revolution: walls 1.2 to 2.8 m away,
    5 % of the nodes without a return."""
    rng = np.random.default_rng(seed)
    start = np.arange(n) == 0
    angle = np.rint(np.arange(n) * (rp.ANGLE_FULL_Q6 / n)).astype(np.uint16)
    mm = 2000 + 800 * np.sin(np.arange(n) * (4 * np.pi / n) + seed) + rng.normal(0, 5, n)
    dist = np.rint(mm * 4).astype(np.uint16)
    dist[rng.random(n) < 0.05] = 0
    return start, angle, dist


def wire(start, angle, dist) -> bytes:
    return encode_nodes(start, np.where(dist > 0, 47, 0), angle, dist)
