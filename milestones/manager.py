"""The milestone manager: when to record a laser milestone, and which stored one a live scan is.

A milestone is a node on the robot's path: its pose, the laser signature of the place (kept
whole and compressed) and the raw scan. Poses are ``(x, y, theta)`` in whatever frame the caller
uses; the manager only compares them.

Recording (:meth:`MilestoneManager.consider`) needs the robot to be away from every stored
milestone (``record_distance`` or ``record_turn``) and the place to be distinctive: enough beams
with a return, a signature with relief, and no stored milestone elsewhere that looks the same
(an aliased place, as along a featureless corridor, would only ever give wrong matches).

A query (:meth:`MilestoneManager.query`) with a predicted pose and covariance only considers
milestones that pass a Mahalanobis gate; without one it searches all of them. The search is
two-stage: a cheap distance between compressed features, minimised over coarse heading shifts,
picks a shortlist from one contiguous float32 matrix; the configured method then searches every
heading shift on the shortlist only.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np
from numpy.typing import ArrayLike, NDArray

from milestones.jit import kernel
from milestones.methods import METHODS, Method, make_method
from milestones.signature import FloatArray, make_signature, sample_step

__all__ = ["Candidate", "ManagerConfig", "MilestoneManager"]

CHI2_2DOF_99 = 9.21
CHI2_1DOF_99 = 6.63


# Inside the manager: values nobody should need to tune (lengths in metres, angles in radians).
MIN_RETURNED = 0.5  # fraction of beams that must have a return at a milestone
MIN_RELIEF = 0.1  # standard deviation of a milestone's signature (m); below it: flat
# A match elsewhere scoring under this (by method) marks a place as aliased.
ALIAS_SCORE = {"cca": 0.02, "ed": 0.06, "dct": 0.06, "hwt": 0.06}
DISTINCT_RADIUS = 2.0  # milestones closer than this are the same place
MIN_OVERLAP = 0.5  # fraction of samples a shifted comparison must share
SHORTLIST = 32  # candidates the exact search sees
COARSE_STEP = 3  # samples between the shifts of the shortlist search
HEADING_SIGMA = math.radians(3.0)  # heading error of a signature match


@dataclass(frozen=True)
class ManagerConfig:
    """Settings of the milestone manager; lengths in metres, angles in radians."""

    length: int = 180  # signature samples
    clamp_range: float = 15.0  # ranges beyond this (or no return) count as this far (m)
    method: str = "cca"  # exact comparison and heading search: ed, cca, dct, hwt
    compression: str = "dct"  # features for storage and the shortlist: dct or hwt
    keep: float = 0.1  # fraction of coefficients kept by DCT / HWT
    record_distance: float = 1.0  # record when this far from every milestone ...
    record_turn: float = math.radians(45.0)  # ... or turned this much from it
    max_heading: float = math.radians(60.0)  # heading search window, either way
    recognition_radius: float = 1.0  # how far from a node its signature still matches (m)

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if self.compression not in ("dct", "hwt"):
            raise ValueError(f"compression must be dct or hwt, got {self.compression!r}")
        if not 0 < self.keep <= 1:
            raise ValueError(f"keep must be in (0, 1], got {self.keep}")
        if self.length < 8:
            raise ValueError(f"length must be at least 8, got {self.length}")

    @property
    def alias_threshold(self) -> float:
        """Score under which a match elsewhere marks a place as aliased."""
        return ALIAS_SCORE[self.method]


@dataclass(frozen=True)
class Candidate:
    """A stored milestone that may be the place a live scan was taken."""

    id: int
    pose: FloatArray  # the milestone's pose
    heading_offset: float  # live heading minus the milestone's heading (rad)
    shift: float  # the same, in signature samples (sub-sample refined)
    score: float  # the method's score at the best shift; lower is better
    ratio: float  # score / best score of a candidate at another place (0: no rival)
    mahalanobis: float  # squared gate distance of the milestone's position (nan: no gate)


class _Rows:
    """Rows of one contiguous array that grows by doubling."""

    def __init__(self, width: int, dtype: type) -> None:
        self._a = np.zeros((16, width) if width else (16,), dtype=dtype)
        self.n = 0

    def _reserve(self, n: int) -> None:
        if n > len(self._a):
            size = max(n, 2 * len(self._a))
            grown = np.zeros((size, *self._a.shape[1:]), dtype=self._a.dtype)
            grown[: self.n] = self._a[: self.n]
            self._a = grown

    def append(self, row: ArrayLike) -> None:
        self._reserve(self.n + 1)
        self._a[self.n] = row
        self.n += 1

    def extend(self, rows: ArrayLike) -> None:
        rows = np.asarray(rows)
        self._reserve(self.n + len(rows))
        self._a[self.n:self.n + len(rows)] = rows
        self.n += len(rows)

    @property
    def view(self) -> NDArray:
        return self._a[: self.n]


@dataclass
class _Skips:
    """How many due milestones were not recorded, by reason."""

    few_returns: int = 0
    flat: int = 0
    aliased: int = 0


def _circular(beams: dict[str, float]) -> bool:
    return abs(abs(beams["angle_increment"]) * beams["num_beams"] - 2 * math.pi) < 1e-6


class MilestoneManager:
    """Records laser milestones along the path and finds the stored ones a live scan matches."""

    def __init__(self, config: ManagerConfig | None = None) -> None:
        self.config = config or ManagerConfig()
        c = self.config
        self.method: Method = make_method(c.method, c.length, c.keep)
        self.compressor: Method = make_method(c.compression, c.length, c.keep)
        # The beams of the first scan (count, first angle, increment, range limit): every
        # later scan must share them. Plain values, so that this package needs no geometry type.
        self.beams: dict[str, float] | None = None
        self._ids = _Rows(0, np.int64)
        self._poses = _Rows(3, np.float64)
        self._stamps = _Rows(0, np.float64)
        self._sigs = _Rows(c.length, np.float32)
        self._feats = _Rows(self.compressor.num_features, np.float32)
        self._feat_sq = _Rows(0, np.float32)
        self._scans: list[NDArray[np.float32]] = []
        self._next_id = 0
        self.skipped = _Skips()

    # ---- what is stored ----------------------------------------------------------------

    def __len__(self) -> int:
        return self._ids.n

    @property
    def ids(self) -> NDArray[np.int64]:
        return self._ids.view

    @property
    def poses(self) -> FloatArray:
        return self._poses.view

    @property
    def stamps(self) -> FloatArray:
        return self._stamps.view

    @property
    def signatures(self) -> NDArray[np.float32]:
        return self._sigs.view

    @property
    def features(self) -> NDArray[np.float32]:
        return self._feats.view

    def scan(self, milestone_id: int) -> NDArray[np.float32]:
        """The raw ranges recorded at a milestone (``inf`` for no return)."""
        return self._scans[self._row(milestone_id)]

    def pose(self, milestone_id: int) -> FloatArray:
        return self._poses.view[self._row(milestone_id)]

    def _row(self, milestone_id: int) -> int:
        ids = self._ids.view
        if len(ids):
            # Ids only ever increase, by one within a session: the row is usually the id's
            # distance from the first (asked for several times a scan, where a binary search
            # costs more than the rest of a pose look-up).
            row = milestone_id - int(ids[0])
            if 0 <= row < len(ids) and ids[row] == milestone_id:
                return int(row)
        row = int(np.searchsorted(ids, milestone_id))
        if row >= len(ids) or ids[row] != milestone_id:
            raise KeyError(f"no milestone with id {milestone_id}")
        return row

    def set_poses(self, poses: FloatArray) -> None:
        """Move the milestones (after a correction of the map); one pose per milestone."""
        poses = np.asarray(poses, dtype=np.float64)
        if poses.shape != (len(self), 3):
            raise ValueError(f"expected poses of shape ({len(self)}, 3), got {poses.shape}")
        self._poses.view[:] = poses

    # ---- signatures ----------------------------------------------------------------------

    def signature(self, ranges: NDArray, angle_min: float, angle_increment: float,
                  max_range: float) -> FloatArray:
        """The signature of a scan with this manager's length.

        The first scan fixes the beam geometry; a scan with other beams raises ``ValueError``.
        """
        r = np.asarray(ranges, dtype=np.float64)
        if r.ndim != 1:
            raise ValueError(f"ranges must be 1-D, got shape {r.shape}")
        beams = {"num_beams": len(r), "angle_min": float(angle_min),
                 "angle_increment": float(angle_increment), "max_range": float(max_range)}
        reach = min(float(max_range), self.config.clamp_range)
        sig = make_signature(r, reach, self.config.length, _circular(beams))
        if self.beams is None:
            self.beams = beams
        elif [beams[k] for k in ("num_beams", "angle_min", "angle_increment")] != [
                self.beams[k] for k in ("num_beams", "angle_min", "angle_increment")]:
            raise ValueError(f"scan beams {beams} differ from the milestones' {self.beams}")
        return sig

    @property
    def circular(self) -> bool:
        """Whether the scans cover the full circle (known after the first scan)."""
        if self.beams is None:
            raise ValueError("no scan seen yet: the beams are unknown")
        return _circular(self.beams)

    @property
    def step(self) -> float:
        """Angle between signature samples (radians)."""
        b = self.beams
        if b is None:
            raise ValueError("no scan seen yet: the signature step is unknown")
        return sample_step(int(b["num_beams"]), b["angle_increment"], self.config.length,
                           self.circular)

    def _max_shift(self) -> int:
        return max(1, math.ceil(self.config.max_heading / abs(self.step)))

    # ---- recording -------------------------------------------------------------------------

    def due(self, pose: FloatArray, among: ArrayLike | None = None) -> bool:
        """True when the pose is away by distance or turn from every stored milestone (or
        every one of the ids ``among``)."""
        if len(self) == 0:
            return True
        p = np.asarray(pose, dtype=np.float64)
        poses = self.poses if among is None else self.poses[
            np.searchsorted(self.ids, np.asarray(among, dtype=np.int64))]
        return not _any_near(np.ascontiguousarray(poses), float(p[0]), float(p[1]),
                             float(p[2]), self.config.record_distance, self.config.record_turn)

    def distinctiveness(self, sig: FloatArray, ranges: NDArray, pose: FloatArray,
                        max_range: float) -> str | None:
        """Why a place makes a poor milestone (``few_returns``, ``flat``, ``aliased``), or None."""
        c = self.config
        r = np.asarray(ranges, dtype=np.float64)
        reach = min(float(max_range), c.clamp_range)
        with np.errstate(invalid="ignore"):
            returned = np.isfinite(r) & (r > 0) & (r < reach)
        if returned.mean() < MIN_RETURNED:
            return "few_returns"
        if float(np.std(sig)) < MIN_RELIEF:
            return "flat"
        far = np.hypot(*(self.poses[:, :2] - np.asarray(pose)[:2]).T) > DISTINCT_RADIUS
        if far.any():
            rows = np.flatnonzero(far)
            best = self._search(sig, rows)
            if best is not None and float(best[1].min()) < c.alias_threshold:
                return "aliased"
        return None

    def consider(self, pose: FloatArray, ranges: NDArray, angle_min: float,
                 angle_increment: float, max_range: float, stamp: float = 0.0,
                 among: ArrayLike | None = None) -> int | None:
        """Record a milestone here if one is due (see :meth:`due`) and the place is
        distinctive; its id or None."""
        if not self.due(pose, among):
            return None
        if not self._has_returns(ranges, max_range):
            self.skipped.few_returns += 1
            return None
        sig = self.signature(ranges, angle_min, angle_increment, max_range)
        reason = self.distinctiveness(sig, ranges, pose, max_range)
        if reason is not None:
            setattr(self.skipped, reason, getattr(self.skipped, reason) + 1)
            return None
        return self._add(pose, sig, ranges, stamp)

    def _has_returns(self, ranges: NDArray, max_range: float) -> bool:
        """Whether any beam returns within the signature's reach."""
        r = np.asarray(ranges, dtype=np.float64)
        reach = min(float(max_range), self.config.clamp_range)
        with np.errstate(invalid="ignore"):
            return bool((np.isfinite(r) & (r > 0) & (r < reach)).any())

    def add(self, pose: FloatArray, ranges: NDArray, angle_min: float,
            angle_increment: float, max_range: float, stamp: float = 0.0) -> int:
        """Record a milestone unconditionally; returns its id."""
        sig = self.signature(ranges, angle_min, angle_increment, max_range)
        return self._add(pose, sig, ranges, stamp)

    def _add(self, pose: FloatArray, sig: FloatArray, ranges: NDArray, stamp: float) -> int:
        p = np.asarray(pose, dtype=np.float64)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise ValueError(f"pose must be a finite (x, y, theta), got {pose!r}")
        feat = self.compressor.encode(sig).astype(np.float32)
        mid = self._next_id
        self._next_id += 1
        self._ids.append(mid)
        self._poses.append(p)
        self._stamps.append(stamp)
        self._sigs.append(sig.astype(np.float32))
        self._feats.append(feat)
        self._feat_sq.append(float(np.dot(feat, feat)))
        self._scans.append(np.asarray(ranges, dtype=np.float32).copy())
        return mid

    # ---- queries ---------------------------------------------------------------------------

    def _shortlist(self, sig: FloatArray, rows: NDArray[np.int64]) -> NDArray[np.int64]:
        """Rows whose compressed features come nearest the query's at any coarse shift."""
        c = self.config
        if len(rows) <= SHORTLIST:
            return rows
        L = c.length
        k_max = self._max_shift()
        circular = self.circular
        if not circular:
            k_max = min(k_max, int(L * (1 - MIN_OVERLAP)))
        shifts = np.arange(-k_max, k_max + 1, COARSE_STEP)
        src = np.arange(L)[None, :] - shifts[:, None]
        src = src % L if circular else np.clip(src, 0, L - 1)
        q = self.compressor.encode(sig[src]).astype(np.float32)  # (K, F)
        feats = self._feats.view
        sq = self._feat_sq.view
        if len(rows) == len(self):
            cross = feats @ q.T  # (M, K), one contiguous float32 product
            fsq = sq
        else:
            cross = feats[rows] @ q.T
            fsq = sq[rows]
        d2 = fsq[:, None] - 2.0 * cross + (q * q).sum(axis=1)[None, :]
        best = d2.min(axis=1)
        keep = np.argpartition(best, SHORTLIST - 1)[:SHORTLIST]
        return rows[keep]

    def _search(self, sig: FloatArray, rows: NDArray[np.int64]):
        """Exact heading search on the shortlist of ``rows``: (rows, scores, shifts) or None."""
        if len(rows) == 0:
            return None
        rows = self._shortlist(sig, rows)
        return (rows, *self._exact(sig, rows))

    def _exact(self, sig: FloatArray, rows: NDArray[np.int64]) -> tuple[FloatArray, FloatArray]:
        """The method's heading search against the stored rows ``rows``: scores and refined
        shifts (in samples)."""
        stored = self.method.encode(self._sigs.view[rows].astype(np.float64))
        m = self.method.search(sig, stored, max_shift=self._max_shift(),
                               min_overlap=MIN_OVERLAP, circular=self.circular)
        return m.score, m.refined

    def query(self, ranges: NDArray, angle_min: float, angle_increment: float,
              max_range: float, predicted_pose: FloatArray | None = None,
              covariance: FloatArray | None = None, max_candidates: int = 5) -> list[Candidate]:
        """Ranked stored milestones that the live scan may be, best first.

        With ``predicted_pose`` and its 3x3 ``covariance``, milestones outside the Mahalanobis
        gate on position (widened by ``recognition_radius``) are not considered, nor are matches
        whose implied heading fails the heading gate. Without them the search is global.
        """
        if len(self) == 0 or not self._has_returns(ranges, max_range):
            return []  # nothing to compare: a scan that sees nothing within reach
        sig = self.signature(ranges, angle_min, angle_increment, max_range)
        c = self.config
        rows = np.arange(len(self))
        gate_d2 = np.full(len(self), np.nan)
        if predicted_pose is not None:
            if covariance is None:
                raise ValueError("a predicted pose needs its covariance")
            pred = np.asarray(predicted_pose, dtype=np.float64)
            cov = np.asarray(covariance, dtype=np.float64)
            if pred.shape != (3,) or cov.shape != (3, 3):
                raise ValueError("predicted_pose must be (3,) and covariance (3, 3)")
            # delta' S^-1 delta per milestone, S the position covariance widened by the
            # recognition radius (2 x 2: inverted by hand, NumPy's call costs more than this).
            r2 = c.recognition_radius**2
            a, b, d = cov[0, 0] + r2, cov[0, 1] + cov[1, 0], cov[1, 1] + r2
            dx = self.poses[:, 0] - pred[0]
            dy = self.poses[:, 1] - pred[1]
            gate_d2 = (d * dx * dx - b * dx * dy + a * dy * dy) / (a * d - cov[0, 1] * cov[1, 0])
            rows = np.flatnonzero(gate_d2 <= CHI2_2DOF_99)
        found = self._search(sig, rows)
        if found is None:
            return []
        rows, scores, shifts = found
        scores = np.maximum(scores, 0.0)  # rounding can leave a perfect match at -1e-16
        offsets = shifts * self.step
        poses = self.poses[rows]
        if predicted_pose is not None:
            implied = poses[:, 2] + offsets
            err = (implied - pred[2] + np.pi) % (2 * np.pi) - np.pi
            ok = err**2 / (cov[2, 2] + HEADING_SIGMA**2) <= CHI2_1DOF_99
            rows, scores, offsets, shifts, poses = (a[ok] for a in (rows, scores, offsets,
                                                                      shifts, poses))
        if len(scores) == 0:
            return []
        top = np.argsort(scores, kind="stable")[:max_candidates]
        # Each candidate's best rival: the best score of a milestone distinct from it.
        apart = poses[None, :, :2] - poses[top, None, :2]
        distinct = np.hypot(apart[..., 0], apart[..., 1]) > DISTINCT_RADIUS
        rivals = np.where(distinct, scores[None, :], np.inf).min(axis=1)
        out = []
        for i, rival in zip(top, rivals, strict=True):  # a handful of candidates
            ratio = float(scores[i] / rival) if np.isfinite(rival) and rival > 0 else 0.0
            out.append(Candidate(
                id=int(self.ids[rows[i]]), pose=poses[i].copy(),
                heading_offset=float((offsets[i] + np.pi) % (2 * np.pi) - np.pi),
                shift=float(shifts[i]), score=float(scores[i]), ratio=ratio,
                mahalanobis=float(gate_d2[rows[i]]),
            ))
        return out

    def rank(self, ranges: NDArray, angle_min: float, angle_increment: float,
             max_range: float, ids: ArrayLike) -> list[tuple[int, float, float]]:
        """The milestones ``ids`` ordered by how well the live scan's signature matches
        theirs, best first: (id, score, heading offset in rad); no pose is consulted."""
        ids = np.asarray(ids, dtype=np.int64)
        if len(ids) == 0 or not self._has_returns(ranges, max_range):
            return []
        sig = self.signature(ranges, angle_min, angle_increment, max_range)
        score, shifts = self._exact(sig, np.searchsorted(self.ids, ids))
        scores = np.maximum(score, 0.0)
        offsets = (shifts * self.step + np.pi) % (2 * np.pi) - np.pi
        order = np.argsort(scores, kind="stable")
        return [(int(ids[k]), float(scores[k]), float(offsets[k])) for k in order]

    # ---- for the store ---------------------------------------------------------------------

    def state(self) -> dict:
        """Everything needed to rebuild this manager, as arrays and plain values."""
        scans = self._scans
        return {
            "config": asdict(self.config),
            "geometry": None if self.beams is None else dict(self.beams),
            "next_id": self._next_id,
            "ids": self.ids.copy(),
            "poses": self.poses.copy(),
            "stamps": self.stamps.copy(),
            "signatures": self.signatures.copy(),
            "features": self.features.copy(),
            "scan_lengths": np.array([len(s) for s in scans], dtype=np.int64),
            "scans": (np.concatenate(scans) if scans else np.zeros(0, np.float32)),
        }

    @classmethod
    def from_state(cls, state: dict) -> MilestoneManager:
        """The inverse of :meth:`state`."""
        # A file may name a setting that is a constant, not a field: ignore such keys.
        known = {f.name for f in fields(ManagerConfig)}
        config = ManagerConfig(**{k: v for k, v in state["config"].items() if k in known})
        mgr = cls(config)
        if state["geometry"]:
            mgr.beams = {k: state["geometry"][k] for k in ("num_beams", "angle_min",
                                                           "angle_increment", "max_range")}
        mgr._ids.extend(state["ids"])
        mgr._poses.extend(state["poses"])
        mgr._stamps.extend(state["stamps"])
        mgr._sigs.extend(state["signatures"])
        feats = np.asarray(state["features"], dtype=np.float32)
        mgr._feats.extend(feats)
        mgr._feat_sq.extend(np.einsum("mf,mf->m", feats, feats))
        bounds = np.cumsum(state["scan_lengths"])[:-1]
        if len(state["ids"]):
            mgr._scans = [s.copy() for s in np.split(state["scans"], bounds)]
        mgr._next_id = int(state["next_id"])
        return mgr


@kernel
def _any_near(poses: FloatArray, x: float, y: float, theta: float, distance: float,
              turn: float) -> bool:
    """Whether a pose of ``poses`` ``(M, 3)`` lies within ``distance`` of (x, y) and within
    ``turn`` of ``theta`` (asked every scan: NumPy's half dozen calls on the milestones'
    poses cost more than the arithmetic)."""
    for k in range(poses.shape[0]):
        if math.hypot(poses[k, 0] - x, poses[k, 1] - y) < distance:
            if abs((poses[k, 2] - theta + math.pi) % (2 * math.pi) - math.pi) < turn:
                return True
    return False
