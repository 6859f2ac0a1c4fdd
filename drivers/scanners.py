"""The serial scanners by name: their drivers and their simulated devices."""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

from drivers.devices.pty_device import Corruption, PtyDevice, ScanSource
from drivers.live import LiveSource
from drivers.scenario import Scenario
from drivers.serial_scanner import ScanDriver
from vmp.errors import InputError

__all__ = ["SCANNERS", "open_live", "open_scanner", "simulated_scanner"]

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
                      corruption: float | Corruption = 0.0, seed: int = 0,
                      max_scans: int | None = None, **device_options: Any) -> PtyDevice:
    """A simulated device of ``name`` streaming ``scenario`` (not started); ``device_options``
    go to the device class (``boot_time``, ``paced``, ``scip1_on_boot``, ...)."""
    _check(name)
    device_cls = _load(SCANNERS[name][1])
    source = ScanSource(scenario, device_cls.sensor_model(), max_scans=max_scans)
    return device_cls(source, corruption=corruption, seed=seed, speed=speed, **device_options)


def open_live(name: str, where: str, record_to: Path, *, simulate: bool = False,
              odometry: str | None = None, no_odometry: bool = False,
              scans: int | None = None, duration: float | None = None, speed: float = 1.0,
              corruption: float = 0.0, silence: float = 1.0,
              baud: int | None = None) -> LiveSource:
    """A live source: scanner ``name`` on the serial port ``where``, or with ``simulate`` a
    simulated device streaming the scenario ``where`` on a pseudo-terminal (and, unless
    ``no_odometry`` or given ``odometry``, a simulated pose feed). Scans are recorded to
    ``record_to``.
    """
    from drivers.scenario import load_scenario

    _check(name)
    devices: list[PtyDevice] = []
    options: dict = {"silence": silence}
    if baud is not None:
        options["baudrate"] = baud
    length = scans
    try:
        if simulate:
            from drivers.devices.pose_feed_device import PoseFeedDevice

            device = simulated_scanner(name, load_scenario(where), speed=speed,
                                       corruption=corruption, max_scans=scans).start()
            devices.append(device)
            port = device.port
            length = length or len(device.source)
            if odometry is None and not no_odometry:
                feed = PoseFeedDevice(device).start()
                devices.append(feed)
                odometry = feed.port
        else:
            port = where
            if "://" not in port and not Path(port).exists():
                raise InputError(f"{port}: no such serial port (ls /dev/ttyUSB* /dev/ttyACM* "
                                 "lists the connected ones)")
        try:
            driver = open_scanner(name, port, **options)
        except ValueError as exc:
            raise InputError(str(exc)) from exc
    except BaseException:
        for d in devices:
            d.close()
        raise
    label = f"live-{name}" + (f"-{where}" if simulate else "")
    return LiveSource(driver, record_to, odometry=odometry, duration=duration,
                      devices=tuple(devices), length=length, name=label)
