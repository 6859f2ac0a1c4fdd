"""What ``vmp map`` and ``vmp live`` share: run options, the view, mapping and writing results."""

from __future__ import annotations

import argparse
import signal
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from vmp.cli.args import cell_size
from vmp.errors import InputError

# The mapper's modules (SciPy, Shapely, the pipeline: about 0.6 s to import) are imported by
# the functions that map, not when the parser is built: 'vmp --help', 'vmp scenarios' and
# 'vmp batch' (whose runs import them in the workers) do not wait for them.
if TYPE_CHECKING:
    from vmp.checkpoint import Every
    from vmp.config import MappingConfig
    from vmp.mapfile import MapData
    from vmp.results import Result
    from vmp.source import Source

__all__ = ["add_run_options", "finish", "map_and_write", "mapping_config", "open_view"]


def add_run_options(p: argparse.ArgumentParser) -> None:
    """Options of every command that maps: where results go, configuration, views."""
    p.add_argument("--out", type=Path, default=Path("results"),
                   help="folder that receives the dated results folder (default: results)")
    p.add_argument("--config", type=Path, help="mapping configuration YAML (default: "
                   "built-in; every result holds the one it used as config.yaml)")
    p.add_argument("--resolution", type=cell_size, default=0.05,
                   help="occupancy grid cell size in metres (default: 0.05)")
    p.add_argument("--rerun", metavar="TARGET",
                   help="watch in Rerun: a .rrd file to save (open it later with 'rerun "
                   "FILE.rrd'; 'pip install rerun-sdk' gives the viewer), 'spawn' (the native "
                   "viewer, now) or 'serve' (the web viewer on localhost; prints its address)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress, no table")
    p.add_argument("-v", "--verbose", action="store_true",
                   help="print every figure of the run, grouped (default: the headline "
                   "figures; metrics.json holds them all)")


def mapping_config(path: Path | None) -> MappingConfig:
    from vmp.config import MappingConfig, load_config

    return load_config(path) if path else MappingConfig()


def open_view(target: str | None, quiet: bool):
    """The Rerun view asked for with ``--rerun``, or None."""
    if not target:
        return None
    from viz.rerun_view import open_rerun

    try:
        view, where = open_rerun(target)
    except ValueError as exc:
        raise InputError(str(exc)) from exc
    if not quiet:
        print(f"rerun: {where}")
    return view


def map_and_write(source: Source, config: MappingConfig, args: argparse.Namespace,
                  out: Path, label: str, scans: int | None = None,
                  saved: MapData | None = None, every: Every | None = None,
                  resume: Path | None = None) -> tuple[Result, int]:
    """Map ``source`` into the results folder ``out`` and print what happened.

    Ctrl-C or SIGTERM while mapping end the run: what was mapped so far is finished, written
    and reported, and the exit code (128 + the signal's number) says it was interrupted.
    With ``saved``, mapping goes on in that map (:class:`~vmp.run.MappingRun`). With
    ``every``, a checkpoint is written into ``out`` that often (removed once the results are
    written); ``resume`` (a checkpoint file) starts from one. Returns the result and the exit
    code.
    """
    from vmp.checkpoint import CHECKPOINT, remove_checkpoint
    from vmp.folders import remove_if_empty
    from vmp.progress import Progress
    from vmp.run import MappingRun

    view = open_view(args.rerun, args.quiet)
    total = source.length if scans is None or source.length is None else min(scans,
                                                                              source.length)
    progress = Progress(total or scans, f"mapping {source.name}",
                        enabled=not args.quiet, tick=1.0)
    try:
        run = MappingRun(source, config, view, scans=scans, progress=progress, label=label,
                         saved=saved, checkpoint=out / CHECKPOINT if every else None,
                         every=every, resume=resume)
        result = run.run()
    except BaseException:
        progress.close()
        remove_if_empty(out)  # nothing was mapped: no empty results folder
        raise

    def write() -> dict:
        metrics = result.write(out, args.resolution)
        remove_checkpoint(out)
        if view is not None:
            grid = result.grid(args.resolution)
            view.grid(grid.cells, grid.resolution, grid.origin)
        return metrics

    return result, finish(result, write, out, args, view, label)


def finish(result, write: Callable[[], dict], out: Path, args: argparse.Namespace,
           view, label: str, link: str = "latest") -> int:
    """Write a run's results folder (``write``), point the link ``link`` beside it at it and
    tell the user what it holds; returns the exit code (128 + the signal's number when one
    ended the run, or came while writing, which waits until everything is written).
    ``latest`` is the link to the newest map: a run that makes none names another link."""
    from vmp.folders import link_latest, mark_complete
    from vmp.results import format_metrics
    from vmp.run import stop_on_signals

    late: list[str] = []

    def later(name: str) -> None:
        late.append(name)
        print(f"vmp: {name}: writing the results first; they are kept", file=sys.stderr)

    with stop_on_signals(later):
        metrics = write()
        mark_complete(out)
        link_latest(out, link)
    summary = result.report.summary(label)
    if summary and (not args.quiet or result.report.damaged):  # damage is never kept quiet
        print(summary, file=sys.stderr)
    if not args.quiet:
        print(format_metrics(metrics, verbose=args.verbose))
        state = f"interrupted by {result.interrupted}; " if result.interrupted else ""
        print(f"\n{state}results in {out} (also {args.out / link}):")
        for line in _listing(out):
            print(f"  {line}")
    elif result.interrupted:
        print(f"vmp: interrupted by {result.interrupted} after {result.scans} scans; "
              f"results in {out}", file=sys.stderr)

    if view is not None:
        if args.rerun == "serve" and not result.interrupted:
            view.hold()
        view.close()
    ended = result.interrupted or (late[0] if late else None)
    return 128 + signal.Signals[ended].value if ended else 0


def _listing(folder: Path) -> list[str]:
    """Every file of a results folder, a line each, those of one name in other forms on the
    line of the first (``grid.npy (+ grid.pgm, grid.png, grid.yaml)``)."""
    by_stem: dict[str, list[str]] = {}
    for path in sorted(p for p in folder.iterdir() if p.is_file()):
        by_stem.setdefault(path.name.split(".")[0], []).append(path.name)
    width = max((len(stem) for stem in by_stem), default=0)
    return [f"{stem:<{width}}  {folder / names[0]}"
            + (f" (+ {', '.join(names[1:])})" if names[1:] else "")
            for stem, names in by_stem.items()]


def warn_if_incomplete(path: Path) -> None:
    """Say on stderr when ``path`` is (a file in) a results folder left incomplete."""
    from vmp.folders import is_incomplete

    folder = path if path.is_dir() else path.parent
    if is_incomplete(folder):
        print(f"vmp: warning: {folder} is an incomplete results folder (the run writing it "
              "stopped before every file was written); using what it holds", file=sys.stderr)
