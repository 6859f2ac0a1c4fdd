"""The one way the project compiles a kernel (``vmp.jit`` re-exports it): Numba in nopython
mode, without the GIL, cached in the user's cache folder and never inside the installed package.

The folder is ``$VMP_CACHE_DIR`` when set, else ``$NUMBA_CACHE_DIR`` when set, else the
platform's cache directory (``$XDG_CACHE_HOME`` or ``~/.cache`` on Linux, ``~/Library/Caches``
on macOS, ``%LOCALAPPDATA%`` on Windows) plus ``vmp-slam/kernels``. Where that folder cannot be
written, kernels are compiled in every process instead of cached. The first run after an install
compiles the kernels it calls (each when first called); later runs load them from the cache.

:func:`compile_seconds` tells how long this process has spent compiling (a progress line leaves
it out of its rate) and :func:`on_first_compile` names who to tell when compiling starts.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TypeVar

from numba import njit
from numba.core import config as numba_config
from numba.core import event

__all__ = ["CACHE_ENV", "cache_folder", "compile_seconds", "compiling", "kernel",
           "on_first_compile"]

F = TypeVar("F", bound=Callable)
CACHE_ENV = "VMP_CACHE_DIR"  # overrides where compiled kernels are cached


def _platform_cache() -> Path:
    """The platform's per-user cache directory."""
    home = Path.home()
    if sys.platform == "win32":
        return Path(os.environ.get("LOCALAPPDATA") or home / "AppData" / "Local")
    if sys.platform == "darwin":
        return home / "Library" / "Caches"
    return Path(os.environ.get("XDG_CACHE_HOME") or home / ".cache")


def _chosen_folder() -> Path:
    """Where kernels are to be cached (see the module's docstring)."""
    for name in (CACHE_ENV, "NUMBA_CACHE_DIR"):
        if os.environ.get(name):
            return Path(os.environ[name]).expanduser().absolute()
    return _platform_cache().absolute() / "vmp-slam" / "kernels"


def _writable(folder: Path) -> bool:
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=folder).close()
    except OSError:
        return False
    return True


_FOLDER: tuple[Path, bool] | None = None  # (the folder chosen, whether it can be written)


def cache_folder() -> tuple[Path, bool]:
    """The folder compiled kernels are cached in, and whether it can be written (decided once
    a process)."""
    global _FOLDER
    if _FOLDER is None:
        folder = _chosen_folder()
        _FOLDER = (folder, _writable(folder))
    return _FOLDER


@contextlib.contextmanager
def _numba_cache_dir(folder: Path) -> Iterator[None]:
    """Numba's cache folder set to ``folder`` while a kernel is declared: Numba fixes a
    function's cache path when it is declared, so other Numba users in the process keep
    theirs."""
    before = numba_config.CACHE_DIR
    numba_config.CACHE_DIR = str(folder)
    try:
        yield
    finally:
        numba_config.CACHE_DIR = before


def kernel(fn: F) -> F:
    """``fn`` compiled (see the module's docstring)."""
    folder, writable = cache_folder()
    if not writable:
        return njit(nogil=True)(fn)
    with _numba_cache_dir(folder):
        try:
            compiled = njit(cache=True, nogil=True)(fn)
        except RuntimeError:  # numba: "cannot cache function ...: no locator available"
            return njit(nogil=True)(fn)
    cache_path = Path(compiled._cache._cache_path)
    if folder not in cache_path.parents:  # Numba fell back to a folder of its own choosing
        compiled = njit(nogil=True)(fn)
    return compiled  # type: ignore[return-value]


class _CompileClock(event.Listener):
    """Numba's compile events: the seconds spent compiling, and the first compile told."""

    def __init__(self) -> None:
        self.seconds = 0.0
        self.depth = 0  # compiles nest: a kernel compiles the functions it calls
        self.started = 0.0
        self.tell: Callable[[str], None] | None = None
        self.told = False
        self.lock = threading.Lock()

    def on_start(self, event: event.Event) -> None:
        with self.lock:
            self.depth += 1
            if self.depth > 1:
                return
            self.started = time.perf_counter()
            tell, first = self.tell, not self.told
            self.told = True
        if tell is not None and first:
            tell(_first_compile_message())

    def on_end(self, event: event.Event) -> None:
        with self.lock:
            self.depth -= 1
            if self.depth == 0:
                self.seconds += time.perf_counter() - self.started


def _first_compile_message() -> str:
    folder, writable = cache_folder()
    if writable:
        return (f"compiling kernels once, cached in {folder} (the first run after an install "
                "takes longer)")
    return (f"compiling kernels: {folder} cannot be written, so every run compiles them "
            f"(set {CACHE_ENV} to a writable folder)")


_CLOCK = _CompileClock()
event.register("numba:compile", _CLOCK)


def compile_seconds() -> float:
    """Seconds this process has spent compiling kernels so far (a compile under way
    included)."""
    with _CLOCK.lock:
        ongoing = time.perf_counter() - _CLOCK.started if _CLOCK.depth else 0.0
        return _CLOCK.seconds + ongoing


def compiling() -> bool:
    """Whether a kernel is being compiled now."""
    return _CLOCK.depth > 0


def on_first_compile(tell: Callable[[str], None] | None) -> None:
    """Call ``tell`` with a line saying so when this process first compiles a kernel (and
    where it is cached); None: tell nobody."""
    _CLOCK.tell = tell
