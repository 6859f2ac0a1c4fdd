"""ATE of scenarios over several simulation seeds, with the default or a given configuration.

Run: python bench/seeds.py warehouse corridor office lab [--count 8] [--jobs 2]
     python bench/seeds.py warehouse --seeds 5 1 2 [--config my.yaml]

With the default configuration and seeds, the table goes to docs/benchmarks.md (section seeds).

Per scenario it prints the ATE (RMSE after SE(2) alignment, against the simulator's truth) of
each seed, starting with the scenario's own, then the median and the maximum, and the number
of wrong corrections (ones that moved the estimate more than 10 cm away from the truth; issue 4
allows none on the corridor). One seed's result can flatter a change; this shows the spread.
The runs are `vmp batch`'s tasks (:func:`vmp.cli.batch.run_batch`: a local Dask cluster of
--jobs worker processes, or one after another with --jobs 1).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from report import machine, write_section

from drivers.scenario import load_scenario
from vmp.cli.batch import Job, run_batch
from vmp.config import load_config


def seeds_of(name: str, count: int) -> list[int]:
    """The scenario's own seed, then 1, 2, ... (without it) up to ``count`` seeds."""
    own = load_scenario(name).seed
    return [own] + [s for s in range(1, count + 1) if s != own][: count - 1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenarios", nargs="+")
    ap.add_argument("--seeds", type=int, nargs="+", help="these seeds for every scenario")
    ap.add_argument("--count", type=int, default=8, help="seeds per scenario (default 8)")
    ap.add_argument("--jobs", type=int, default=2, help="runs at once (default 2; 1: serial)")
    ap.add_argument("--config", type=Path, help="mapping configuration YAML")
    args = ap.parse_args()
    if args.config:
        load_config(args.config)  # a bad file fails here, once, with its message
    with tempfile.TemporaryDirectory(prefix="vmp-seeds-") as out:
        jobs = [Job(name, seed, out=out, config=str(args.config) if args.config else None)
                for name in args.scenarios
                for seed in (args.seeds or seeds_of(name, args.count))]
        rows, _ = run_batch(jobs, workers=args.jobs, serial=args.jobs == 1)
    failed = [r for r in rows if r is None or r["status"] != "ok"]
    if failed:
        raise SystemExit(f"runs failed: {[r and (r['source'], r['status']) for r in failed]}")
    results = [(j.source, j.seed, r["ATE (m)"], r["wrong corrections"])
               for j, r in zip(jobs, rows, strict=True)]
    table = ["| world | its own seed | median | worst | wrong corrections (seeds) |",
             "|---|---|---|---|---|"]
    for name in args.scenarios:
        mine = [r for r in results if r[0] == name]
        errors = [e for _, _, e, _ in mine]
        cells = " ".join(f"{seed}: {100 * e:.1f}" for _, seed, e, _ in mine)
        print(f"{name} (ATE cm by seed) {cells}")
        wrong = sum(w for *_, w in mine)
        print(f"  median {100 * statistics.median(errors):.2f} cm, max {100 * max(errors):.2f} "
              f"cm, wrong corrections {wrong} ({args.config or 'default configuration'})")
        which = ", ".join(str(seed) for _, seed, _, w in mine if w)
        table.append(f"| {name} | {100 * errors[0]:.2f} cm | "
                     f"{100 * statistics.median(errors):.2f} cm | {100 * max(errors):.2f} cm | "
                     f"{wrong}{f' ({which})' if which else ''} |")
    if args.config is None and args.seeds is None:
        write_section("seeds", "\n".join([
            "## Simulated worlds over several seeds", "",
            f"`python bench/seeds.py {' '.join(args.scenarios)} --count {args.count}` on "
            f"{machine()}: each world mapped with the default configuration from {args.count} "
            "simulation seeds, its own first. ATE: the RMSE after SE(2) alignment against the "
            "simulator's truth. A wrong correction moved the estimate more than 10 cm away "
            "from the truth.", "", *table]))


if __name__ == "__main__":
    main()
