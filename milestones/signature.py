"""Laser signatures: the range profile of one scan, resampled to a fixed length.

Beams without a return (``inf``, ``nan``, zero or negative, or at least ``max_range``) are
*clamped to max_range*: "nothing within reach" is the farthest a profile can say, it keeps the
profile dense for the FFT and DCT, and two scans that both see open space there agree. A scan
must have at least one return; an empty or return-free scan raises ``ValueError``.

Sample ``i`` of a signature of length ``L`` looks along the beam angle
``angle_min + i * step`` with ``step = angle_increment * (N - 1) / (L - 1)`` for an ``N``-beam
scan (see :func:`sample_step`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

__all__ = ["DEFAULT_LENGTH", "make_signature", "sample_step"]

DEFAULT_LENGTH = 180


def make_signature(ranges: ArrayLike, max_range: float, length: int = DEFAULT_LENGTH,
                   circular: bool = False) -> FloatArray:
    """Signature ``(L,)`` of one scan, or ``(M, L)`` of a batch of scans ``(M, N)``.

    Linear interpolation over beam index maps the ``N`` beams onto ``length`` samples. A
    ``circular`` scan covers the full turn: its last beam neighbours its first.
    """
    r = np.asarray(ranges, dtype=np.float64)
    if r.ndim not in (1, 2):
        raise ValueError(f"ranges must be (N,) or (M, N), got shape {r.shape}")
    if r.shape[-1] < 2:
        raise ValueError(f"a signature needs a scan of at least 2 beams, got {r.shape[-1]}")
    if not (np.isfinite(max_range) and max_range > 0):
        raise ValueError(f"max_range must be positive and finite, got {max_range}")
    if length < 2:
        raise ValueError(f"signature length must be at least 2, got {length}")
    with np.errstate(invalid="ignore"):
        returned = np.isfinite(r) & (r > 0) & (r < max_range)
    if not returned.any(axis=-1).all():
        raise ValueError("scan without any return (all beams NaN, inf, <= 0 or >= max_range): "
                         "it has no signature")
    clamped = np.where(returned, r, max_range)
    n = r.shape[-1]
    if n == length:
        return clamped.copy()
    if circular:
        pos = np.arange(length) * (n / length)
        lo = pos.astype(np.int64)
        hi = (lo + 1) % n
    else:
        pos = np.linspace(0.0, n - 1, length)
        lo = np.minimum(pos.astype(np.int64), n - 2)
        hi = lo + 1
    frac = pos - lo
    return clamped[..., lo] * (1.0 - frac) + clamped[..., hi] * frac


def sample_step(num_beams: int, angle_increment: float, length: int = DEFAULT_LENGTH,
                circular: bool = False) -> float:
    """Angle between neighbouring signature samples (radians).

    A circular (360 degree) scan wraps around: its ``length`` samples share the full turn.
    """
    if circular:
        return float(2.0 * np.pi / length * np.sign(angle_increment))
    return angle_increment * (num_beams - 1) / (length - 1)
