"""Shared fixtures: the real recordings (found through VMP_DATA), excerpts, mapped scenarios."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
EXCERPTS = Path(__file__).resolve().parent / "data"
DATA = Path(os.environ.get("VMP_DATA", ROOT.parent / "shared" / "data"))

_RUNS: dict = {}


def shared_data(relpath: str) -> Path:
    """A real recording under VMP_DATA (default ../shared/data); skips the test without it."""
    path = DATA / relpath
    if not path.exists():
        pytest.skip(f"needs the real recording {relpath} under {DATA}; set VMP_DATA to the "
                    "folder holding the shared recordings (see ../shared/data/README.md)")
    return path


def mapped(name: str, scans: int | None = None, seed: int | None = None):
    """The result of mapping a built-in scenario with the defaults (computed once a session)."""
    from drivers import open_source
    from vmp.run import MappingRun

    key = (name, scans, seed)
    if key not in _RUNS:
        _RUNS[key] = MappingRun(open_source(name, scans=scans, seed=seed)).run()
    return _RUNS[key]


def run_cli(argv: list[str]) -> int:
    """Exit code of ``vmp ARGV``, whether argparse exits or ``main`` returns."""
    from vmp.cli import main

    try:
        return main(argv)
    except SystemExit as exc:
        return int(exc.code)
