"""Argument types shared by the commands: numbers checked where they are parsed."""

from __future__ import annotations

import argparse

__all__ = ["nonneg_int", "positive_float", "positive_int"]


def positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return v


def nonneg_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return v


# A grid cell from a millimetre to ten metres: finer than any laser measures, coarser than
# a room; outside, the grid is either too large to hold or one cell for the whole building.
CELL = (1e-3, 10.0)


def cell_size(text: str) -> float:
    """An occupancy grid's cell size in metres, within :data:`CELL`."""
    v = positive_float(text)
    if not CELL[0] <= v <= CELL[1]:
        raise argparse.ArgumentTypeError(f"expected a cell size from {CELL[0]:g} to "
                                         f"{CELL[1]:g} m, got {text!r}")
    return v


def positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not v > 0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return v
