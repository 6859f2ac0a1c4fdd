"""Map the real recordings in ../shared/data; score the Intel part on Kuemmerle's relations.

Run: python bench/recordings.py [--only intel]

For the Intel part it prints the translational and rotational relation errors (mean and std),
the wall time of the mapping, the real-time factor (data duration / wall time), milestones and
matches; then it maps every other recording and saves its grid as docs/maps/NAME.png. The
figures go to docs/benchmarks.md beside the anchors measured on this machine (issue 6).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from report import machine, write_section

from drivers import open_source
from vmp.config import MappingConfig, ScanOdometryConfig
from vmp.evaluate import read_relations, relation_error, relation_errors
from vmp.export import write_png
from vmp.results import Result
from vmp.run import MappingRun

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data"
MAPS = Path(__file__).resolve().parent.parent / "docs" / "maps"
OTHERS = [
    ("dpslam_loop5", "dpslam_duke_loop5/loop5.log", ""),
    ("breezyslam_exp1", "breezyslam_mines/exp1.dat", ""),
    ("breezyslam_exp2", "breezyslam_mines/exp2.dat", ""),
    ("ccny_demo_bag", "ccny_hokuyo_rosbag/demo.bag", "no odometry"),
    ("mit_killian", "mit_killian/killian.g2o.zip", ""),
] + [(f"radish_{n}", f"radish_gmapping_corrected/{n}-corrected.log.gz", "")
     for n in ("intel", "freiburg-079", "freiburg-101", "freiburg-campus", "infinite-corridor",
               "orebro", "belgioioso", "fhw", "edmonton", "acapulco")]


def run(path: Path, config: MappingConfig | None = None) -> tuple[Result, float]:
    """Map a recording; the result and the wall time of the whole run."""
    t = time.perf_counter()
    result = MappingRun(open_source(str(path)), config).run()
    return result, time.perf_counter() - t


def save_map(result: Result, name: str) -> Path:
    out = MAPS / f"{name}.png"
    write_png(out, result.grid(0.1))
    return out


def breakdown(r: Result) -> list[str]:
    """Where the Intel relation error comes from: by time span, the worst relations, loops."""
    relations = read_relations(DATA / "intel" / "intel.relations")
    stamps = r.stamps
    span, et, er = relation_errors(stamps, r.trajectory, relations)
    lines = ["Where the error comes from (time between the two poses of a relation):", "",
             "| span | relations | translational (m) | rotational (deg) | share of the error |",
             "|---|---|---|---|---|"]
    for lo, hi in ((0, 10), (10, 60), (60, 300), (300, math.inf)):
        m = (span >= lo) & (span < hi)
        if m.any():
            lines.append(f"| {lo}-{hi:g} s | {int(m.sum())} | {et[m].mean():.3f} | "
                         f"{math.degrees(er[m].mean()):.2f} | {et[m].sum() / et.sum():.0%} |")
    worst = np.argsort(et)[::-1][:int(0.05 * len(et))]
    rest = np.setdiff1d(np.arange(len(et)), worst)
    t0 = float(stamps.min())
    ends = relations[:, 1]
    ends = ends[(ends >= stamps.min()) & (ends <= stamps.max())]
    t2 = np.sort(np.abs(ends - t0))
    graph = [round(float(stamps[min(k, len(stamps) - 1)] - t0))
             for k, kind, _, _ in r.corrections if kind == "graph"]
    lines += ["", f"The worst 5 % of the relations ({len(worst)}) carry "
              f"{et[worst].sum() / et.sum():.0%} of the error; without them the mean is "
              f"{et[rest].mean():.3f} m. Graph adjustments after loop closures at "
              f"{', '.join(f'{g} s' for g in graph) or 'none'} into the run (relations end "
              f"up to {t2[-1]:.0f} s).", ""]
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", help="only this recording (intel, or a name from the list)")
    args = ap.parse_args()
    MAPS.mkdir(parents=True, exist_ok=True)
    lines = ["## Real recordings", "", f"`python bench/recordings.py` on {machine()}.", ""]
    if args.only in (None, "intel"):
        r, wall = run(DATA / "intel" / "intel-first5505.clf.gz")
        p = r.pipeline
        e = relation_error(r.stamps, r.trajectory,
                           read_relations(DATA / "intel" / "intel.relations"))
        duration = float(r.stamps.max() - r.stamps.min())
        acc = sum(v for k, v in p.stats.items() if "accepted" in k)
        rej = sum(v for k, v in p.stats.items() if "rejected" in k)
        print(f"intel: {e.trans_mean:.3f} +- {e.trans_std:.3f} m, {math.degrees(e.rot_mean):.2f} "
              f"+- {math.degrees(e.rot_std):.2f} deg on {e.used} relations; {wall:.1f} s for "
              f"{duration:.0f} s of data ({duration / wall:.0f}x real time); "
              f"{len(p.milestones)} milestones, {acc} matches accepted, {rej} rejected")
        save_map(r, "intel_part")
        wheels = MappingConfig(scan_odometry=ScanOdometryConfig(enabled=False))
        r_w, wall_w = run(DATA / "intel" / "intel-first5505.clf.gz", wheels)
        e_w = relation_error(r_w.stamps, r_w.trajectory,
                             read_relations(DATA / "intel" / "intel.relations"))
        print(f"intel without scan odometry: {e_w.trans_mean:.3f} +- {e_w.trans_std:.3f} m, "
              f"{math.degrees(e_w.rot_mean):.2f} deg; {wall_w:.1f} s")
        lines += [
            "Intel Research Lab, first 5,505 scans (1,089 s), Kuemmerle relations inside it:",
            "",
            "| system | translational error (m) | rotational error (deg) | time |",
            "|---|---|---|---|",
            f"| **vmp-slam** | {e.trans_mean:.3f} +- {e.trans_std:.3f} | "
            f"{math.degrees(e.rot_mean):.2f} +- {math.degrees(e.rot_std):.2f} | {wall:.1f} s "
            f"({duration / wall:.0f}x real time) |",
            f"| vmp-slam without scan odometry (`--no-scan-odometry`: the filter predicts "
            f"from the wheels alone) | {e_w.trans_mean:.3f} +- {e_w.trans_std:.3f} | "
            f"{math.degrees(e_w.rot_mean):.2f} +- {math.degrees(e_w.rot_std):.2f} | "
            f"{wall_w:.1f} s |",
            "| KISS-ICP 1.3.0, odometry only, best of 7 voxel sizes (this machine) | 0.166 | "
            "2.36 | 1.5 s |",
            "| BreezySLAM, best setting (this machine) | 0.50 | 3.6 | about 7 s |",
            "| raw odometry | 3.53 | 41.1 | - |",
            "| Cartographer, whole Intel run (published) | 0.0229 | 0.453 | - |",
            "| graph mapping, whole Intel run (published) | 0.031 | 1.3 | - |",
            "",
            f"vmp-slam: {e.used} relations, {len(p.milestones)} milestones, {acc} matches "
            f"accepted, {rej} rejected, {p.stats['loop edges']} loop edges. Map: "
            "[docs/maps/intel_part.png](maps/intel_part.png).",
            "",
        ] + breakdown(r)
    rows = []
    for name, rel, note in OTHERS:
        if args.only not in (None, name):
            continue
        r, wall = run(DATA / rel)
        p = r.pipeline
        png = save_map(r, name)
        m = r.metrics()
        ours = m.get("ATE vs GMapping's poses (m)")
        if ours is not None:  # paired by order
            unknown = m["unknown odometry increments"]
            odo = m["ATE of odometry vs GMapping's poses (m)"]
            note = (f"ATE vs GMapping {ours:.2f} m (raw odometry {odo:.2f} m)"
                    + (f"; {unknown} of {r.scans} odometry increments missing" if unknown
                       else ""))
        rows.append((name, rel, r.scans, wall, len(p.milestones), p.stats["loop edges"],
                     r.report.skipped, note, png.name))
        print(f"{name}: {r.scans} scans in {wall:.1f} s, {len(p.milestones)} milestones, "
              f"{p.stats['loop edges']} loop edges -> {png}")
    if rows:
        lines += ["Every other recording (maps at 0.1 m per cell in docs/maps). The Radish "
                  "logs are mapped from their raw odometry, rebuilt from the ODOM lines; "
                  "GMapping's corrected keyframe poses are its particle filter's estimate "
                  "(the best particle, which jumps when another takes over), not ground "
                  "truth:", "",
                  "| recording | scans | time | milestones | loop edges | bad lines | map | note |",
                  "|---|---|---|---|---|---|---|---|"]
        lines += [f"| {r[1]} | {r[2]} | {r[3]:.1f} s | {r[4]} | {r[5]} | {r[6]} | "
                  f"[{r[8]}](maps/{r[8]}) | {r[7]} |" for r in rows]
    if args.only is None:
        write_section("recordings", "\n".join(lines))


if __name__ == "__main__":
    main()
