"""What a command that catches Ctrl-C must tell CPython so that it exits as the command says."""

from __future__ import annotations

import ctypes

__all__ = ["handled_interrupt"]


def handled_interrupt() -> None:
    """Tell CPython the KeyboardInterrupt was handled. One that leaves code run by ``exec`` of
    a string (SciPy's statistics build their distributions that way while filterpy imports
    them, in the first second of a `vmp map`) marks the interpreter as interrupted, caught or
    not; run as a module (``python -m vmp``), it then kills itself with SIGINT at exit instead
    of returning 130 (CPython 3.11: exit status -2 in 2 of 16 Ctrl-Cs 0.2-0.45 s into a run)."""
    try:
        ctypes.c_int.in_dll(ctypes.pythonapi, "_Py_UnhandledKeyboardInterrupt").value = 0
    except (AttributeError, ValueError):  # an interpreter without that mark
        pass
