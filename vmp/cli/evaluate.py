"""``vmp evaluate``: score a trajectory against ground truth or Kümmerle relations."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from vmp.cli.args import positive_int
from vmp.cli.common import warn_if_incomplete
from vmp.errors import InputError

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    ev = sub.add_parser(
        "evaluate", help="score a trajectory: ATE, RPE, Kuemmerle relations",
        description="Score a result's trajectory (or any TUM file) against ground truth (ATE "
        "after SE(2) alignment, and RPE, as evo computes them) or against a relations file "
        "(Kuemmerle et al. 2009: mean and std of translational and rotational error).",
        epilog="examples:\n  vmp evaluate results/latest --ground-truth office.tum\n"
        "  vmp evaluate results/latest --relations ../shared/data/intel/intel.relations\n",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    ev.add_argument("result", type=Path, help="a results folder (its trajectory.tum is "
                    "scored) or a TUM trajectory file")
    ev.add_argument("--ground-truth", type=Path, metavar="TUM",
                    help="true poses as a TUM file (t x y z qx qy qz qw), paired with the "
                    "trajectory's by stamp: ATE and RPE (a simulated run writes its own as "
                    "ground_truth.tum)")
    ev.add_argument("--relations", type=Path, metavar="FILE",
                    help="Kuemmerle et al.'s relations file of the log (lines 'FIXED t1 t2 dx "
                    "dy 0 0 0 dtheta'): the mean and spread of the relation errors")
    ev.add_argument("--delta", type=positive_int, default=1,
                    help="RPE frame distance (default 1)")
    ev.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from vmp.evaluate import ate, read_relations, relation_error, relation_errors, rpe
    from vmp.tum import read_tum

    if not args.ground_truth and not args.relations:
        raise InputError("give --ground-truth TUM and/or --relations FILE")
    traj = args.result / "trajectory.tum" if args.result.is_dir() else args.result
    if not traj.is_file():
        raise InputError(f"{args.result}: no trajectory (expected a TUM file or a results "
                         "folder with trajectory.tum)")
    warn_if_incomplete(traj)
    stamps, poses = read_tum(traj)
    if args.ground_truth:
        gs, gp = read_tum(args.ground_truth)
        a = ate(stamps, poses, gs, gp)
        r = rpe(stamps, poses, gs, gp, delta=args.delta)
        print(f"ATE  rmse {a.rmse:.4f} m  mean {a.mean:.4f} m  max {a.max:.4f} m  "
              f"({a.pairs} poses, SE(2) aligned)")
        print(f"RPE  trans rmse {r.trans_rmse:.4f} m  rot rmse {math.degrees(r.rot_rmse):.4f} "
              f"deg  (delta {r.delta} frames, {r.pairs} pairs)")
    if args.relations:
        relations = read_relations(args.relations)
        rel = relation_error(stamps, poses, relations)
        print(f"relations  trans {rel.trans_mean:.4f} +- {rel.trans_std:.4f} m  rot "
              f"{math.degrees(rel.rot_mean):.3f} +- {math.degrees(rel.rot_std):.3f} deg  "
              f"({rel.used} of {rel.total} relations)")
        span, et, er = relation_errors(stamps, poses, relations)
        print("  by time between the two poses:")
        for lo, hi in ((0, 10), (10, 60), (60, 300), (300, math.inf)):
            m = (span >= lo) & (span < hi)
            if m.any():
                print(f"  {lo:>4}-{hi:<4g} s  {int(m.sum()):>5} relations  trans "
                      f"{et[m].mean():.4f} m  rot {math.degrees(er[m].mean()):.3f} deg  "
                      f"({et[m].sum() / et.sum():.0%} of the total error)")
    return 0
