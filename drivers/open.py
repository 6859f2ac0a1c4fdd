"""Open a source by what a user types: a scenario, a recording, or a serial scanner."""

from __future__ import annotations

from pathlib import Path

from vmp.errors import InputError
from vmp.source import Source

__all__ = ["RECORDING_SUFFIXES", "open_source"]

RECORDING_SUFFIXES = (".clf", ".log", ".gz", ".txt", ".dat", ".bag", ".mcap", ".db3", ".zip")


def _is_recording(text: str, fmt: str | None) -> bool:
    """Whether ``text`` names a recording rather than a scenario (a name or a YAML file)."""
    from drivers.scenario import builtin_scenarios

    if text in builtin_scenarios():
        return False
    path = Path(text)
    if path.exists() and not (path.is_file() or path.is_dir()):
        return True  # a FIFO or a device: refused as a recording, by what it is
    return fmt is not None or path.suffix in RECORDING_SUFFIXES or path.is_dir() or (
        path.is_file() and path.suffix not in (".yaml", ".yml"))


def open_source(text: str, *, seed: int | None = None, scans: int | None = None,
                strict: bool = False, fmt: str | None = None, scan_topic: str | None = None,
                odom_topic: str | None = None, driver: str | None = None,
                **live: object) -> Source:
    """The scenario, recording or live scanner ``text`` names.

    With ``driver`` (sick, rplidar, hokuyo), ``text`` is a serial port, or with
    ``simulate=True`` a scenario streamed by a simulated device; ``live`` holds the options
    of :func:`drivers.scanners.open_live` (``record_to`` is required). Otherwise a built-in
    scenario's name or a scenario YAML file gives its simulator (``seed`` and ``scans`` apply
    to it), and anything else is a recording (``fmt`` forces its format; topics apply to ROS
    bags; ``strict`` stops at its first bad line).
    """
    if driver is not None:
        from drivers.scanners import open_live

        return open_live(driver, text, scans=scans, **live)  # type: ignore[arg-type]
    if not _is_recording(text, fmt):
        from drivers.scenario import load_scenario
        from drivers.simulator import Simulator

        try:
            return Simulator(load_scenario(text), seed=seed, max_scans=scans)
        except ValueError as exc:
            raise InputError(str(exc)) from exc
    if seed is not None:
        raise InputError("--seed applies to scenarios, not to recordings")
    from drivers.formats import open_recording

    return open_recording(text, fmt, strict, scan_topic=scan_topic, odom_topic=odom_topic)
