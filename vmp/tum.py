"""TUM trajectory files (``t x y z qx qy qz qw``), the format evo and most SLAM tools read."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vmp.errors import InputError
from vmp.fileio import atomic_write, read_table
from vmp.types import FloatArray, wrap_angle

__all__ = ["read_tum", "write_tum"]


def write_tum(path: str | Path, stamps: FloatArray, poses: FloatArray) -> None:
    """Write planar poses ``(N, 3)`` at ``stamps`` ``(N,)`` with z = 0 and a yaw quaternion."""
    stamps = np.asarray(stamps, dtype=np.float64)
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3 or len(stamps) != len(poses):
        raise ValueError(f"need stamps (N,) and poses (N, 3), got {stamps.shape}, {poses.shape}")
    half = poses[:, 2] / 2.0
    table = np.column_stack([
        stamps, poses[:, 0], poses[:, 1], np.zeros(len(poses)),
        np.zeros(len(poses)), np.zeros(len(poses)), np.sin(half), np.cos(half),
    ])
    with atomic_write(path, "w", encoding="ascii") as f:
        f.write("# timestamp x y z qx qy qz qw\n")
        np.savetxt(f, table, fmt=["%.6f"] + ["%.6f"] * 3 + ["%.9f"] * 4)


def read_tum(path: str | Path) -> tuple[FloatArray, FloatArray]:
    """Read a TUM file into stamps ``(N,)`` and planar poses ``(N, 3)``, yaw from the quaternion."""
    a = read_table(path, 8, "t x y z qx qy qz qw")
    q = a[:, 4:8]
    scale = np.abs(q).max(axis=1, initial=0.0)
    norm = scale * np.linalg.norm(q / np.maximum(scale, 1e-300)[:, None], axis=1)
    bad = np.flatnonzero(np.abs(norm - 1.0) > 0.01)
    if bad.size:
        raise InputError(f"{path}: pose {bad[0] + 1}: the quaternion's norm is "
                         f"{norm[bad[0]]:g}, expected 1 (t x y z qx qy qz qw)")
    qx, qy, qz, qw = (q / norm[:, None]).T
    yaw = np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy**2 + qz**2))
    return a[:, 0], np.column_stack([a[:, 1], a[:, 2], wrap_angle(yaw)])
