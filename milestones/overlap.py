"""Sums over the overlap of a query and many stored signatures, for every shift at once.

Shift ``k`` pairs ``q[i]`` with ``s[i + k]``: the query is the stored signature turned by ``k``
samples. Without wrap-around (a field of view under 360 degrees) only the overlapping samples
are paired; a circular signature pairs all of them. The cross term comes from one batched FFT
correlation; the others are prefix sums, compiled (a query is ~40 NumPy calls on (32, 181)
arrays otherwise, each costing more in overhead than in arithmetic).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft
from numpy.typing import NDArray

from milestones.jit import kernel

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
        return _rms(self.n, self.sqq, self.sss, self.sqs)

    def rho(self) -> FloatArray:
        """Pearson correlation over the overlap (the paper's equation 2); 0 where flat."""
        return _rho(self.n, self.sq, self.sqq, self.ss, self.sss, self.sqs)


@kernel
def _rms(n: FloatArray, sqq: FloatArray, sss: FloatArray, sqs: FloatArray) -> FloatArray:
    """``sqrt(max(sum (q - s)^2, 0) / n)`` per stored signature and shift, from the sums."""
    M, K = sss.shape
    out = np.empty((M, K))
    for m in range(M):
        for k in range(K):
            ssd = sqq[0, k] + sss[m, k] - 2.0 * sqs[m, k]
            out[m, k] = np.sqrt(max(ssd, 0.0) / n[0, k])
    return out


@kernel
def _rho(n: FloatArray, sq: FloatArray, sqq: FloatArray, ss: FloatArray, sss: FloatArray,
         sqs: FloatArray) -> FloatArray:
    """Pearson's correlation per stored signature and shift, from the sums; 0 where flat."""
    M, K = ss.shape
    out = np.empty((M, K))
    for m in range(M):
        for k in range(K):
            cov = n[0, k] * sqs[m, k] - sq[0, k] * ss[m, k]
            var_q = max(n[0, k] * sqq[0, k] - sq[0, k] * sq[0, k], 0.0)
            var_s = max(n[0, k] * sss[m, k] - ss[m, k] * ss[m, k], 0.0)
            den = np.sqrt(var_q * var_s)
            # Relative floor: a flat signature (walls all at one range) has no defined
            # correlation.
            flat = den <= 1e-12 * max(n[0, k] * sqq[0, k], 1e-300)
            out[m, k] = 0.0 if flat else cov / den
    return out


@kernel
def _moments(q: FloatArray, s: FloatArray, shifts: NDArray
             ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Overlap size and sums of ``q``, ``q^2``, ``s`` and ``s^2`` at every shift (without
    wrap-around), each from one prefix sum."""
    L = q.shape[0]
    M = s.shape[0]
    K = shifts.shape[0]
    cq = np.zeros(L + 1)
    cqq = np.zeros(L + 1)
    for i in range(L):
        cq[i + 1] = cq[i] + q[i]
        cqq[i + 1] = cqq[i] + q[i] * q[i]
    n = np.empty((1, K))
    sq = np.empty((1, K))
    sqq = np.empty((1, K))
    for k in range(K):
        a = max(0, -shifts[k])
        b = min(L, L - shifts[k])
        n[0, k] = b - a
        sq[0, k] = cq[b] - cq[a]
        sqq[0, k] = cqq[b] - cqq[a]
    ss = np.empty((M, K))
    sss = np.empty((M, K))
    cs = np.zeros(L + 1)
    css = np.zeros(L + 1)
    for m in range(M):
        for i in range(L):
            cs[i + 1] = cs[i] + s[m, i]
            css[i + 1] = css[i] + s[m, i] * s[m, i]
        for k in range(K):
            a = max(0, -shifts[k]) + shifts[k]
            b = min(L, L - shifts[k]) + shifts[k]
            ss[m, k] = cs[b] - cs[a]
            sss[m, k] = css[b] - css[a]
    return n, sq, sqq, ss, sss


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
    n, sq, sqq, ss, sss = _moments(q, s, shifts.astype(np.int64))
    return OverlapSums(shifts, n, sq, sqq, ss, sss, sqs)
