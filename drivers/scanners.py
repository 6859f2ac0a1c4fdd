"""The serial scanners by name: their drivers and their simulated devices."""

from __future__ import annotations

import importlib

from drivers.devices.pty_device import PtyDevice, ScanSource
from drivers.scenario import Scenario
from drivers.serial_scanner import ScanDriver

__all__ = ["SCANNERS", "open_scanner", "simulated_scanner"]

# name: (driver class, device class), imported when asked for.
SCANNERS = {
    "sick": ("drivers.sick_lms2xx:SickLms2xx", "drivers.devices.sick_device:SickDevice"),
    "rplidar": ("drivers.rplidar:RplidarDriver", "drivers.devices.rplidar_device:RplidarDevice"),
    "hokuyo": ("drivers.hokuyo_scip2:HokuyoScip2Driver",
               "drivers.devices.hokuyo_device:HokuyoDevice"),
}


def _load(spec: str) -> type:
    module, name = spec.split(":")
    return getattr(importlib.import_module(module), name)


def _check(name: str) -> None:
    if name not in SCANNERS:
        raise ValueError(f"unknown scanner {name!r}; expected one of {', '.join(SCANNERS)}")


def open_scanner(name: str, port: str, **options) -> ScanDriver:
    """The driver ``name`` on ``port`` (a device path or pyserial URL)."""
    _check(name)
    return _load(SCANNERS[name][0])(port, **options)


def simulated_scanner(name: str, scenario: Scenario, *, speed: float = 1.0,
                      corruption: float = 0.0, seed: int = 0,
                      max_scans: int | None = None) -> PtyDevice:
    """A simulated device of ``name`` streaming ``scenario`` (not started)."""
    _check(name)
    device_cls = _load(SCANNERS[name][1])
    source = ScanSource(scenario, device_cls.sensor_model(), max_scans=max_scans)
    return device_cls(source, corruption=corruption, seed=seed, speed=speed)
