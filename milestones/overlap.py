"""Sums over the overlap of a query and many stored signatures, for every shift at once.

Shift ``k`` pairs ``q[i]`` with ``s[i + k]``: the query is the stored signature turned by ``k``
samples. Without wrap-around (a field of view under 360 degrees) only the overlapping samples
are paired; a circular signature pairs all of them. The cross term comes from one batched FFT
correlation; the others are prefix sums.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

__all__ = ["OverlapSums", "overlap_sums", "shifts_for"]


def shifts_for(length: int, max_shift: int, min_overlap: float, circular: bool) -> NDArray:
    """The shifts to try: ``|k| <= max_shift`` leaving at least ``min_overlap`` of the samples."""
    if circular:
        k = min(max_shift, length // 2)
    else:
        k = min(max_shift, int(np.floor(length * (1.0 - min_overlap))))
    return np.arange(-k, k + 1)


@dataclass(frozen=True)
class OverlapSums:
    """Size and sums of the overlap per stored signature and shift (arrays ``(M, K)``)."""

    shifts: NDArray  # (K,)
    n: FloatArray  # (1, K)
    sq: FloatArray  # sum of q over the overlap, (1, K)
    sqq: FloatArray  # (1, K)
    ss: FloatArray  # sum of s over the overlap, (M, K)
    sss: FloatArray  # (M, K)
    sqs: FloatArray  # (M, K)

    def rms(self) -> FloatArray:
        """Root mean square difference over the overlap (Euclidean distance per sample)."""
        ssd = self.sqq + self.sss - 2.0 * self.sqs
        return np.sqrt(np.maximum(ssd, 0.0) / self.n)

    def rho(self) -> FloatArray:
        """Pearson correlation over the overlap (the paper's equation 2); 0 where flat."""
        cov = self.n * self.sqs - self.sq * self.ss
        var_q = np.maximum(self.n * self.sqq - self.sq**2, 0.0)
        var_s = np.maximum(self.n * self.sss - self.ss**2, 0.0)
        den = np.sqrt(var_q * var_s)
        # Relative floor: a flat signature (walls all at one range) has no defined correlation.
        flat = den <= 1e-12 * np.maximum(self.n * self.sqq, 1e-300)
        return np.where(flat, 0.0, cov / np.where(flat, 1.0, den))


def _window_sums(x: FloatArray, starts: NDArray, stops: NDArray) -> FloatArray:
    """Sums of ``x[..., a:b]`` for every ``(a, b)`` pair, from one prefix sum."""
    c = np.concatenate([np.zeros((*x.shape[:-1], 1)), np.cumsum(x, axis=-1)], axis=-1)
    return c[..., stops] - c[..., starts]


def overlap_sums(query: FloatArray, stored: FloatArray, shifts: NDArray,
                 circular: bool = False) -> OverlapSums:
    """Overlap sums of a query ``(L,)`` against stored signatures ``(M, L)`` at ``shifts``."""
    q = np.asarray(query, dtype=np.float64)
    s = np.atleast_2d(np.asarray(stored, dtype=np.float64))
    L = q.shape[-1]
    if s.shape[-1] != L:
        raise ValueError(f"signature lengths differ: query {L}, stored {s.shape[-1]}")
    shifts = np.asarray(shifts)
    if circular:
        spectrum = np.conj(scipy.fft.rfft(q))[None, :] * scipy.fft.rfft(s, axis=-1)
        corr = scipy.fft.irfft(spectrum, n=L, axis=-1)
        sqs = corr[:, shifts % L]
        n = np.full((1, len(shifts)), float(L))
        sq = np.full((1, len(shifts)), q.sum())
        sqq = np.full((1, len(shifts)), (q * q).sum())
        ss = np.repeat(s.sum(axis=-1, keepdims=True), len(shifts), axis=1)
        sss = np.repeat((s * s).sum(axis=-1, keepdims=True), len(shifts), axis=1)
        return OverlapSums(shifts, n, sq, sqq, ss, sss, sqs)
    nfft = scipy.fft.next_fast_len(2 * L - 1, real=True)
    spectrum = np.conj(scipy.fft.rfft(q, n=nfft))[None, :] * scipy.fft.rfft(s, n=nfft, axis=-1)
    corr = scipy.fft.irfft(spectrum, n=nfft, axis=-1)  # corr[k] = sum_i q[i] s[i + k]
    sqs = corr[:, shifts % nfft]
    q_start = np.maximum(0, -shifts)
    q_stop = np.minimum(L, L - shifts)
    s_start, s_stop = q_start + shifts, q_stop + shifts
    n = (q_stop - q_start).astype(np.float64)[None, :]
    sq = _window_sums(q, q_start, q_stop)[None, :]
    sqq = _window_sums(q * q, q_start, q_stop)[None, :]
    ss = _window_sums(s, s_start, s_stop)
    sss = _window_sums(s * s, s_start, s_stop)
    return OverlapSums(shifts, n, sq, sqq, ss, sss, sqs)
