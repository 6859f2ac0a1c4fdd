"""Trajectory accuracy: ATE after SE(2) alignment, RPE, and the Kümmerle relation metric.

The ATE and RPE follow evo's definitions (``evo_ape --align``, ``evo_rpe --delta N
--delta_unit f --all_pairs``), on poses matched by timestamp, so users can check our numbers
with evo; a test compares them with evo itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vmp.errors import InputError
from vmp.fileio import read_table
from vmp.types import FloatArray, compose, inverse, relative, wrap_angle

__all__ = ["ATE", "RPE", "RelationError", "align_se2", "associate", "ate", "read_relations",
           "relation_error", "relations_between", "rpe", "wrong_corrections"]


def associate(stamps_a: FloatArray, stamps_b: FloatArray,
              max_difference: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs of the nearest stamps within ``max_difference`` seconds (each b used once)."""
    a = np.asarray(stamps_a, dtype=np.float64)
    b = np.asarray(stamps_b, dtype=np.float64)
    order = np.argsort(b, kind="stable")
    bs = b[order]
    pos = np.clip(np.searchsorted(bs, a), 1, max(len(bs) - 1, 1))
    left = np.clip(pos - 1, 0, len(bs) - 1)
    right = np.clip(pos, 0, len(bs) - 1)
    pick = np.where(np.abs(bs[left] - a) <= np.abs(bs[right] - a), left, right)
    ok = np.abs(bs[pick] - a) <= max_difference
    ia = np.flatnonzero(ok)
    ib = order[pick[ok]]
    _, first = np.unique(ib, return_index=True)
    keep = np.sort(first)
    return ia[keep], ib[keep]


def align_se2(estimate: FloatArray, reference: FloatArray) -> FloatArray:
    """The rigid motion ``(x, y, theta)`` that best maps estimate positions onto the reference.

    Umeyama's least squares alignment without scale, in the plane.
    """
    p = np.asarray(estimate, dtype=np.float64)[:, :2]
    q = np.asarray(reference, dtype=np.float64)[:, :2]
    mp, mq = p.mean(axis=0), q.mean(axis=0)
    C = (q - mq).T @ (p - mp) / len(p)
    U, _, Vt = np.linalg.svd(C)
    S = np.diag([1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ S @ Vt
    t = mq - R @ mp
    return np.array([t[0], t[1], math.atan2(R[1, 0], R[0, 0])])


@dataclass(frozen=True)
class ATE:
    rmse: float  # m
    mean: float
    max: float
    pairs: int


def ate(est_stamps: FloatArray, est: FloatArray, ref_stamps: FloatArray, ref: FloatArray,
        align: bool = True, max_difference: float = 0.01) -> ATE:
    """Absolute trajectory error of positions (after SE(2) alignment unless ``align=False``)."""
    ia, ib = associate(est_stamps, ref_stamps, max_difference)
    if len(ia) < 2:
        raise InputError("fewer than 2 poses share a timestamp with the ground truth")
    e, r = np.asarray(est)[ia], np.asarray(ref)[ib]
    if align:
        e = compose(align_se2(e, r), e)
    d = np.hypot(*(e[:, :2] - r[:, :2]).T)
    return ATE(float(np.sqrt(np.mean(d**2))), float(d.mean()), float(d.max()), len(ia))


def ate_in_order(est: FloatArray, ref: FloatArray) -> float:
    """ATE RMSE with the i-th estimated pose paired to the i-th reference pose (for references
    whose stamps cannot be used, like those of the GMapping-corrected Radish logs)."""
    order = np.arange(len(ref), dtype=np.float64)
    return ate(order, est, order, ref).rmse


@dataclass(frozen=True)
class RPE:
    trans_rmse: float  # m per delta
    rot_rmse: float  # rad per delta
    delta: int
    pairs: int


def rpe(est_stamps: FloatArray, est: FloatArray, ref_stamps: FloatArray, ref: FloatArray,
        delta: int = 1, max_difference: float = 0.01) -> RPE:
    """Relative pose error over ``delta`` frames, every pair (evo_rpe ``--all_pairs``)."""
    ia, ib = associate(est_stamps, ref_stamps, max_difference)
    e, r = np.asarray(est)[ia], np.asarray(ref)[ib]
    if len(e) <= delta:
        raise InputError(f"need more than {delta} matched poses for the RPE")
    de = relative(e[:-delta], e[delta:])
    dr = relative(r[:-delta], r[delta:])
    err = relative(dr, de)
    t = np.hypot(err[:, 0], err[:, 1])
    return RPE(float(np.sqrt(np.mean(t**2))), float(np.sqrt(np.mean(err[:, 2] ** 2))), delta,
               len(err))


@dataclass(frozen=True)
class RelationError:
    trans_mean: float  # m
    trans_std: float
    rot_mean: float  # rad
    rot_std: float
    used: int
    total: int


def read_relations(path: str | Path) -> FloatArray:
    """Relations ``(K, 5)``: t1, t2, x, y, yaw from a ``t1 t2 x y z roll pitch yaw`` file."""
    a = read_table(path, 8, "t1 t2 x y z roll pitch yaw")
    return a[:, [0, 1, 2, 3, 7]]


def relation_errors(stamps: FloatArray, poses: FloatArray, relations: FloatArray,
                    max_difference: float = 1e-4) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Per relation whose stamps both match a pose: its time span (s), translational (m)
    and rotational (rad) error, as Kümmerle et al. define them."""
    i1, i2, ok = _stamped(stamps, relations, max_difference)
    if not ok.any():
        raise InputError("no relation has both of its stamps among the trajectory's stamps")
    p = np.asarray(poses, dtype=np.float64)
    delta = relative(p[i1[ok]], p[i2[ok]])
    rel = relations[ok][:, 2:5]
    err = compose(inverse(rel), delta)
    span = np.abs(relations[ok, 1] - relations[ok, 0])
    return span, np.hypot(err[:, 0], err[:, 1]), np.abs(wrap_angle(err[:, 2]))


def relations_between(stamps: FloatArray, relations: FloatArray,
                      max_difference: float = 1e-4) -> FloatArray:
    """The relations whose two stamps both match one of ``stamps`` (those the metric uses)."""
    return relations[_stamped(stamps, relations, max_difference)[2]]


def _stamped(stamps: FloatArray, relations: FloatArray, max_difference: float
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each relation the index of the stamp nearest each of its two stamps, and whether
    both lie within ``max_difference``."""
    s = np.asarray(stamps, dtype=np.float64)
    order = np.argsort(s, kind="stable")
    ss = s[order]

    def nearest(t: FloatArray) -> tuple[np.ndarray, np.ndarray]:
        pos = np.clip(np.searchsorted(ss, t), 1, len(ss) - 1)
        left, right = pos - 1, pos
        pick = np.where(np.abs(ss[left] - t) <= np.abs(ss[right] - t), left, right)
        return order[pick], np.abs(ss[pick] - t) <= max_difference

    i1, ok1 = nearest(relations[:, 0])
    i2, ok2 = nearest(relations[:, 1])
    return i1, i2, ok1 & ok2


def relation_error(stamps: FloatArray, poses: FloatArray, relations: FloatArray,
                   max_difference: float = 1e-4) -> RelationError:
    """Kümmerle et al.'s metric: error of each relative pose against its true relation."""
    _, t, r = relation_errors(stamps, poses, relations, max_difference)
    return RelationError(float(t.mean()), float(t.std()), float(r.mean()), float(r.std()),
                         len(t), len(relations))


def wrong_corrections(corrections: list[tuple[int, str, FloatArray, FloatArray]],
                      truth: FloatArray, limit: float = 0.10) -> list[tuple[int, str]]:
    """The corrections that moved the estimate more than ``limit`` (m) farther from the truth.

    ``corrections`` hold (scan index, kind, pose before, pose after), as
    ``Pipeline.corrections`` does; ``truth`` is the true pose ``(S, 3)`` of every scan.
    Returns (scan index, kind) of each wrong one.
    """
    if not corrections:
        return []
    t = np.asarray(truth, dtype=np.float64)
    k = np.minimum([c[0] for c in corrections], len(t) - 1)
    before = np.array([c[2][:2] for c in corrections])
    after = np.array([c[3][:2] for c in corrections])
    worse = (np.hypot(*(after - t[k, :2]).T) - np.hypot(*(before - t[k, :2]).T)) > limit
    return [(int(corrections[i][0]), corrections[i][1]) for i in np.flatnonzero(worse)]
