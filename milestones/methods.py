"""The paper's four ways of comparing laser signatures, behind one interface.

Every method encodes signatures into features, measures the distance between features, and
searches the heading: the shift ``k`` (``q[i] ~ s[i + k]``, the query turned by ``k`` samples
against the stored signature) that matches best. Scores are "lower is better" for all four:

* ``ED``  equation 1, as the root mean square difference over the overlap (metres),
* ``CCA`` equation 2, ``1 - rho`` with rho the correlation over the overlap,
* ``DCT`` equations 3 and 4: the first F coefficients; distances between coefficient vectors;
  the heading search turns the query, compresses it and compares the restored signatures,
* ``HWT`` Haar approximation coefficients at level L, searched the same way.

Distances are normalised per sample (divided by the square root of the signature length, or of
the overlap in a heading search) so methods and overlaps of different size compare directly.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
import pywt
import scipy.fft
from numpy.typing import NDArray

from milestones.jit import kernel
from milestones.overlap import overlap_sums, shifts_for
from milestones.signature import FloatArray

__all__ = ["CCA", "DCT", "ED", "HWT", "METHODS", "Method", "ShiftMatch", "make_method"]


@dataclass(frozen=True)
class ShiftMatch:
    """Best heading shift of a query against each of ``M`` stored signatures."""

    shift: NDArray[np.int64]  # (M,) best shift in samples
    refined: FloatArray  # (M,) best shift with sub-sample (parabolic) refinement
    score: FloatArray  # (M,) score at the best shift, lower is better
    shifts: NDArray[np.int64]  # (K,) the shifts tried
    curve: FloatArray  # (M, K) score at every shift tried


def _best(curve: FloatArray, shifts: NDArray) -> ShiftMatch:
    i, score, delta = _minima(np.ascontiguousarray(curve, dtype=np.float64))
    return ShiftMatch(shifts[i], shifts[i] + delta, score, shifts, curve)


@kernel
def _minima(curve: FloatArray) -> tuple[NDArray, FloatArray, FloatArray]:
    """Per row: the index of the least score, the score, and the sub-sample offset of the
    parabola through it and its neighbours (0 at the ends of the row), within half a sample."""
    M, K = curve.shape
    index = np.empty(M, dtype=np.int64)
    score = np.empty(M)
    delta = np.zeros(M)
    for m in range(M):
        i = 0
        for k in range(1, K):
            if curve[m, k] < curve[m, i]:  # the first least, as argmin
                i = k
        index[m] = i
        score[m] = b = curve[m, i]
        if 0 < i < K - 1:
            a, c = curve[m, i - 1], curve[m, i + 1]
            den = a - 2.0 * b + c
            if den > 1e-15:
                delta[m] = min(max(0.5 * (a - c) / den, -0.5), 0.5)
    return index, score, delta


class Method(ABC):
    """Encode signatures ``(..., L)`` into features, compare features, search the heading."""

    name: str = ""

    def __init__(self, length: int) -> None:
        if length < 2:
            raise ValueError(f"signature length must be at least 2, got {length}")
        self.length = length

    def _check(self, sig: FloatArray) -> FloatArray:
        a = np.asarray(sig, dtype=np.float64)
        if a.shape[-1:] != (self.length,):
            raise ValueError(f"{self.name}: expected signatures of length {self.length}, "
                             f"got shape {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError(f"{self.name}: signatures must be finite (make_signature clamps "
                             "no-return beams)")
        return a

    @property
    def num_features(self) -> int:
        return self.length

    @property
    def compression(self) -> float:
        """Fraction of the signature's numbers the features leave out: ``1 - F / N``."""
        return 1.0 - self.num_features / self.length

    def encode(self, sig: FloatArray) -> FloatArray:
        """Features ``(..., F)`` of signatures ``(..., L)``."""
        return self._check(sig).copy()

    def decode(self, feats: FloatArray) -> FloatArray:
        """Signatures ``(..., L)`` restored from features (exact for ED and CCA)."""
        return np.asarray(feats, dtype=np.float64)

    def distance(self, a: FloatArray, b: FloatArray) -> FloatArray:
        """Distance per sample between features ``a`` ``(F,)`` and each row of ``b`` ``(M, F)``."""
        d = np.asarray(b, dtype=np.float64) - np.asarray(a, dtype=np.float64)
        return np.sqrt((d * d).sum(axis=-1) / self.length)

    @abstractmethod
    def curve(self, query: FloatArray, stored_feats: FloatArray, shifts: NDArray,
              circular: bool) -> FloatArray:
        """Score ``(M, K)`` of the query signature against stored features at every shift."""

    def search(self, query: FloatArray, stored_feats: FloatArray, *, max_shift: int,
               min_overlap: float = 0.5, circular: bool = False) -> ShiftMatch:
        """Best shift and score of the query signature ``(L,)`` against stored features ``(M, F)``.

        Shifts go up to ``max_shift`` samples either way while the signatures still share
        ``min_overlap`` of their samples (all of them for a circular, 360 degree, signature).
        """
        q = self._check(query)
        feats = np.atleast_2d(np.asarray(stored_feats, dtype=np.float64))
        if feats.shape[-1] != self.num_features:
            raise ValueError(f"{self.name}: expected stored features of length "
                             f"{self.num_features}, got shape {feats.shape}")
        shifts = shifts_for(self.length, max_shift, min_overlap, circular)
        return _best(self.curve(q, feats, shifts, circular), shifts)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(length={self.length}, features={self.num_features})"


class ED(Method):
    """Euclidean distance (equation 1) on raw signatures, per sample over the overlap."""

    name = "ED"

    def curve(self, query, stored_feats, shifts, circular):
        return overlap_sums(query, stored_feats, shifts, circular).rms()

    @staticmethod
    def euclidean(x: FloatArray, y: FloatArray) -> FloatArray:
        """Equation 1 literally: ``sqrt(sum_i (x_i - y_i)^2)``."""
        d = np.asarray(x, dtype=np.float64) - np.asarray(y, dtype=np.float64)
        return np.sqrt((d * d).sum(axis=-1))


class CCA(Method):
    """Normalised cross correlation over every delay (equation 2); score ``1 - rho``."""

    name = "CCA"

    def distance(self, a, b):
        return 1.0 - self.rho(a, b)

    @staticmethod
    def rho(a: FloatArray, b: FloatArray) -> FloatArray:
        """Correlation coefficient at zero delay of ``a`` ``(L,)`` with each row of ``b``."""
        x = np.asarray(a, dtype=np.float64)
        y = np.atleast_2d(np.asarray(b, dtype=np.float64))
        x = x - x.mean()
        y = y - y.mean(axis=-1, keepdims=True)
        den = np.sqrt((x * x).sum() * (y * y).sum(axis=-1))
        return np.where(den > 0, (y @ x) / np.where(den > 0, den, 1.0), 0.0)

    def curve(self, query, stored_feats, shifts, circular):
        return 1.0 - overlap_sums(query, stored_feats, shifts, circular).rho()


class DCT(Method):
    """The first ``coefficients`` DCT-II coefficients (equation 3); restored by equation 4."""

    name = "DCT"

    def __init__(self, length: int, coefficients: int) -> None:
        super().__init__(length)
        if not 1 <= coefficients <= length:
            raise ValueError(f"DCT: coefficients must be in 1..{length}, got {coefficients}")
        self.coefficients = coefficients

    @property
    def num_features(self) -> int:
        return self.coefficients

    def encode(self, sig):
        x = self._check(sig)
        return scipy.fft.dct(x, type=2, norm="ortho", axis=-1)[..., : self.coefficients]

    def decode(self, feats):
        f = np.asarray(feats, dtype=np.float64)
        full = np.zeros((*f.shape[:-1], self.length))
        full[..., : self.coefficients] = f
        return scipy.fft.idct(full, type=2, norm="ortho", axis=-1)

    def curve(self, query, stored_feats, shifts, circular):
        return _compressed_curve(self, query, stored_feats, shifts, circular)


class HWT(Method):
    """Haar wavelet approximation coefficients at ``level``; restored with zero details.

    The Haar transform preserves Euclidean distance only while every level halves an even
    length, so signatures are padded at the end with zeros to a multiple of ``2**level``.
    Both signatures get the same padding, so their distance is unchanged by it.
    """

    name = "HWT"

    def __init__(self, length: int, level: int) -> None:
        super().__init__(length)
        if level < 0 or 2**level > length:
            raise ValueError(f"HWT: level must be in 0..{int(np.log2(length))} for length "
                             f"{length}, got {level}")
        self.level = level
        block = 2**level
        self.padded_length = -(-length // block) * block

    @property
    def num_features(self) -> int:
        return self.padded_length >> self.level

    def _pad(self, x: FloatArray) -> FloatArray:
        pad = [(0, 0)] * (x.ndim - 1) + [(0, self.padded_length - self.length)]
        return np.pad(x, pad)

    def coefficients(self, sig: FloatArray) -> list[FloatArray]:
        """All Haar coefficients ``[cA_L, cD_L, ..., cD_1]`` of the padded signatures."""
        x = self._pad(self._check(sig))
        if self.level == 0:
            return [x]
        return pywt.wavedec(x, "haar", mode="periodization", level=self.level, axis=-1)

    def encode(self, sig):
        return self.coefficients(sig)[0]

    def decode(self, feats):
        a = np.asarray(feats, dtype=np.float64)
        if self.level == 0:
            return a[..., : self.length]
        details = [np.zeros((*a.shape[:-1], self.padded_length >> j))
                   for j in range(self.level, 0, -1)]
        x = pywt.waverec([a, *details], "haar", mode="periodization", axis=-1)
        return x[..., : self.length]

    def curve(self, query, stored_feats, shifts, circular):
        return _compressed_curve(self, query, stored_feats, shifts, circular)


def _compressed_curve(method: Method, query: FloatArray, stored_feats: FloatArray,
                      shifts: NDArray, circular: bool) -> FloatArray:
    """Heading search in a compressed domain: turn the query, compress it, compare.

    For each shift the query is turned onto the stored signature's samples (samples it never
    saw are filled with its edge value), encoded and restored, then compared with the restored
    stored signatures over the overlap only. The three overlap sums are matrix products.
    """
    L = method.length
    src = np.arange(L)[None, :] - shifts[:, None]  # aligned[k, j] = q[j - k]
    if circular:
        valid = np.ones(src.shape)
        src = src % L
    else:
        valid = ((src >= 0) & (src < L)).astype(np.float64)
        src = np.clip(src, 0, L - 1)
    rq = method.decode(method.encode(query[src]))  # (K, L)
    rs = method.decode(stored_feats)  # (M, L)
    ssd = ((rq * rq * valid).sum(axis=1)[None, :] - 2.0 * rs @ (rq * valid).T
           + (rs * rs) @ valid.T)
    return np.sqrt(np.maximum(ssd, 0.0) / valid.sum(axis=1)[None, :])


METHODS = ("ed", "cca", "dct", "hwt")


def make_method(name: str, length: int, keep: float = 0.1) -> Method:
    """A method by name; ``keep`` is the fraction of coefficients DCT and HWT retain.

    HWT can only halve: its level is the one whose kept fraction is nearest ``keep``.
    """
    key = name.lower()
    if not 0 < keep <= 1:
        raise ValueError(f"keep must be in (0, 1], got {keep}")
    if key == "ed":
        return ED(length)
    if key == "cca":
        return CCA(length)
    if key == "dct":
        return DCT(length, max(1, round(keep * length)))
    if key == "hwt":
        max_level = int(np.floor(np.log2(length)))
        level = min(range(max_level + 1), key=lambda lv: abs(np.log2(keep) + lv))
        return HWT(length, level)
    raise ValueError(f"unknown method {name!r}; expected one of {', '.join(METHODS)}")
