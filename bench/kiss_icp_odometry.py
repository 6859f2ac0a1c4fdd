"""KISS-ICP odometry on a recording, as a peer to time vmp-slam against (whole process).

Run: python bench/kiss_icp_odometry.py LOG [--voxel 0.25] [--threads 2] [--out poses.tum]

Reads the recording with vmp-slam's readers (the same as `vmp map` does), turns every scan
into 3D points (z = 0) and registers it with KISS-ICP (kiss-icp in the bench extra), odometry
only: KISS-ICP has no loop closure. Writes the scanner poses as TUM when asked.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("log")
    ap.add_argument("--voxel", type=float, default=0.25)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out")
    args = ap.parse_args()
    from kiss_icp.config import KISSConfig
    from kiss_icp.kiss_icp import KissICP

    from drivers import open_source
    from vmp.tum import write_tum

    t = time.perf_counter()
    config = KISSConfig()
    config.data.deskew = False
    config.data.max_range = 100.0
    config.data.min_range = 0.0
    config.mapping.voxel_size = args.voxel
    config.registration.max_num_threads = args.threads
    odometry = KissICP(config=config)
    stamps, poses = [], []
    for frame in open_source(args.log):
        pts = frame.points()
        odometry.register_frame(np.column_stack([pts, np.zeros(len(pts))]), np.zeros(0))
        m = odometry.last_pose
        stamps.append(frame.stamp)
        poses.append([m[0, 3], m[1, 3], math.atan2(m[1, 0], m[0, 0])])
    if args.out:
        write_tum(args.out, np.array(stamps), np.array(poses))
    print(f"{len(stamps)} scans in {time.perf_counter() - t:.2f} s")


if __name__ == "__main__":
    main()
