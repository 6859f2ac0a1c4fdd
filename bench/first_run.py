"""The first run after an install against later ones: `vmp map office` with an empty kernel
cache (every kernel it calls compiled) and with a full one (loaded), run in turn.

Run: python bench/first_run.py [--repeat 3]

Each run is a whole process (`python -m vmp map office -q`), its cache folder named by
VMP_CACHE_DIR: a new empty one for a first run, one filled before the clock starts for a later
run. Medians of the wall times; the ratio is taken pair by pair.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from report import machine, write_section


def one_run(cache: Path, out: Path) -> float:
    env = {**os.environ, "VMP_CACHE_DIR": str(cache)}
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "vmp", "map", "office", "-q", "--out", str(out)],
                          env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    took = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"bench: vmp map office failed:\n{done.stderr[-2000:]}")
    return took


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="vmp-first-run-") as tmp:
        root = Path(tmp)
        warm = root / "warm"
        one_run(warm, root / "results")  # fills it
        firsts, laters, ratios = [], [], []
        for k in range(args.repeat):
            first = one_run(root / f"cold-{k}", root / "results")
            later = one_run(warm, root / "results")
            firsts.append(first)
            laters.append(later)
            ratios.append(first / later)
            print(f"pair {k + 1}: first run {first:.1f} s, later run {later:.1f} s")
        kernels = sum(1 for _ in (root / "cold-0").rglob("*.nbi"))
    first, later = statistics.median(firsts), statistics.median(laters)
    lines = [
        "## The first run after an install",
        "",
        f"`python bench/first_run.py --repeat {args.repeat}` on {machine()}: the whole process "
        "of `vmp map office` (2,221 scans), with an empty kernel cache and with a full one, "
        "in turn; medians.",
        "",
        "| run | wall time | |",
        "|---|---|---|",
        f"| first (compiles {kernels} kernels) | {first:.1f} s | x{statistics.median(ratios):.2f} "
        "of a later run |",
        f"| later (loads them) | {later:.1f} s | |",
        "",
        f"The first run spends about {first - later:.0f} s more, compiling.",
    ]
    print("\n".join(lines))
    write_section("first-run", "\n".join(lines))


if __name__ == "__main__":
    main()
