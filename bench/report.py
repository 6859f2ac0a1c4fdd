"""Shared by the benchmark scripts: put a section of figures into docs/benchmarks.md."""

from __future__ import annotations

import platform
import re
import resource
import statistics
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import numpy as np

from vmp.fileio import atomic_write

DOC = Path(__file__).resolve().parent.parent / "docs" / "benchmarks.md"
R = TypeVar("R")  # a run's result (vmp.results.Result, vmp.localization.LocalizationResult)
HEADER = "# Benchmarks\n\nFigures written by the scripts in `bench/`; each section says how to " \
         "rerun it.\nTimes are medians of repeated runs on the machine named in the section.\n"


def machine() -> str:
    import os

    return (f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
            f"NumPy {np.__version__}")


def whole(result: R) -> R:
    """``result`` of a run, or the bench ends: a run that Ctrl-C or SIGTERM stopped early
    returns the scans so far, and figures from a part of a log would be wrong ones."""
    if getattr(result, "interrupted", None):
        raise SystemExit(f"bench: a run was interrupted by {result.interrupted}; no figures "
                         "written")
    return result


def median_time(fn: Callable[[], object], repeat: int) -> tuple[float, list[float]]:
    """Median wall time of ``repeat`` calls and all the times."""
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), times


def run_timed(cmd: list[str]) -> tuple[float, float]:
    """Run a whole command; its wall time and the CPU (user + system) of it and everything it
    started, in seconds. Its output is dropped; a failure ends the bench with its stderr."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"bench: '{' '.join(cmd)}' failed ({done.returncode}):\n"
                         f"{done.stderr.strip()[-2000:]}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def write_section(name: str, body: str) -> None:
    """Replace (or append) the section ``name`` of docs/benchmarks.md with ``body``."""
    text = DOC.read_text() if DOC.exists() else HEADER
    start, end = f"<!-- bench:{name} -->", f"<!-- /bench:{name} -->"
    block = f"{start}\n{body.rstrip()}\n{end}"
    pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.S)
    text = pattern.sub(lambda _: block, text) if pattern.search(text) else \
        text.rstrip() + "\n\n" + block + "\n"
    with atomic_write(DOC, "w") as f:
        f.write(text)
