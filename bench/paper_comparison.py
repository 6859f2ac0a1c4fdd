"""Repeat the paper's experiment (section V, figure 15) on the lab scenario and on Intel scans.

Run: python bench/paper_comparison.py      (needs the `bench` extra: matplotlib)

Part 1, figure 15: a landmark signature is recorded at a home pose and searched for in scans
from four nearby positions (translated and rotated). For each method (ED, CCA, and DCT and
HWT at equal compression) the matching error is plotted against the rotation tried; the global
minimum should sit at the true heading difference.

Part 2, identification against compression: landmarks recorded about a metre apart along a
path; every query is a scan from near one landmark (a few tenths of a metre away, turned).
A query is identified when its best match over all landmarks, searching +-60 degrees of
heading, is its own landmark. Accuracy is given for raw ED and CCA and for DCT and HWT
keeping 100 % down to 5 % of the coefficients.

Writes docs/paper_comparison.md and docs/paper_fig15_lab.png, docs/paper_fig15_intel.png.
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from report import machine

from drivers.carmen import read_carmen
from drivers.scenario import load_scenario
from drivers.simulator import Simulator
from milestones.methods import CCA, DCT, ED, HWT, Method
from milestones.signature import make_signature, sample_step
from vmp.fileio import atomic_write
from vmp.types import relative

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
INTEL = ROOT.parent / "shared" / "data" / "intel" / "intel-first5505.clf.gz"
L = 180
CLAMP = 15.0
MAX_HEADING = math.radians(60)


def equal_compression_methods() -> list[Method]:
    hwt = HWT(L, 3)  # 184 / 8 = 23 approximation coefficients
    return [ED(L), CCA(L), DCT(L, hwt.num_features), hwt]


def error_curves(method: Method, landmark: np.ndarray, samples: np.ndarray, step: float):
    """Per sample: rotations tried (deg), error there, and the best rotation (deg)."""
    k = math.ceil(MAX_HEADING / step)
    out = []
    for s in samples:
        m = method.search(s, method.encode(landmark[None]), max_shift=k)
        curve = m.curve[0]
        if method.name != "CCA":
            curve = curve**2  # the paper compares mean square errors
        out.append((m.shifts * math.degrees(step), curve, math.degrees(m.refined[0] * step)))
    return out


def figure15(title: str, landmark, samples, true_dtheta, step, png: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = equal_compression_methods()
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    rows = []
    for ax, method in zip(axes.flat, methods, strict=True):
        label = method.name if method.name in ("ED", "CCA") else \
            f"{method.name} ({method.num_features} coeff., {method.compression:.0%} compression)"
        for j, (deg, curve, best) in enumerate(error_curves(method, landmark, samples, step)):
            line, = ax.plot(deg, curve, label=f"position {j + 1}")
            ax.axvline(math.degrees(true_dtheta[j]), color=line.get_color(), ls=":", lw=1)
            rows.append((method.name, j + 1, math.degrees(true_dtheta[j]), best,
                         float(curve.min())))
        ax.set_title(label)
        ax.set_ylabel("1 - rho" if method.name == "CCA" else "mean square error (m^2)")
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("rotation tried (deg); dotted: true heading difference")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(png, dpi=80)
    plt.close(fig)
    lines = ["| method | position | true heading diff (deg) | found (deg) | error at best |",
             "|---|---|---|---|---|"]
    lines += [f"| {m} | {j} | {t:+.1f} | {b:+.1f} | {e:.4f} |" for m, j, t, b, e in rows]
    return lines


def identification(landmarks: np.ndarray, queries: np.ndarray, source: np.ndarray,
                   step: float) -> list[tuple[str, str, float]]:
    """Accuracy per method and compression: the best landmark is the query's own."""
    k = math.ceil(MAX_HEADING / step)
    methods: list[tuple[str, str, Method]] = [("ED", "0 %", ED(L)), ("CCA", "0 %", CCA(L))]
    for keep in (1.0, 0.5, 0.25, 0.2, 0.1, 0.05):
        dct = DCT(L, max(1, round(keep * L)))
        methods.append(("DCT", f"{dct.compression:.0%}", dct))
    for level in range(0, 6):
        hwt = HWT(L, level)
        methods.append(("HWT", f"{hwt.compression:.1%}", hwt))
    out = []
    for name, comp, method in methods:
        feats = method.encode(landmarks)
        best = np.array([np.argmin(method.search(q, feats, max_shift=k).score)
                         for q in queries])
        out.append((name, comp, float((best == source).mean())))
    return out


def lab_data(rng: np.random.Generator):
    sim = Simulator(load_scenario("lab"))
    st = sim.scenario.stations
    home, samples = sim.station_ranges(rng=rng)
    sig = make_signature(np.vstack([home, samples]), min(8.0, CLAMP), L)
    fig = (sig[0], sig[1:], st.nearby[:, 2] - st.home[2])
    # Identification: landmarks every metre along the lab and office paths.
    lm_poses, lm_ranges, q_ranges, q_source = [], [], [], []
    for name, offset in (("lab", 0.0), ("office", 100.0)):
        s = Simulator(load_scenario(name))
        keep, last = [], None
        for i, p in enumerate(s.true_poses[: len(s) // 2]):  # the first lap
            if last is None or np.hypot(*(p[:2] - last[:2])) >= 1.0:
                keep.append(i)
                last = p
        poses = s.true_poses[keep]
        base = len(lm_poses)
        lm_poses += list(poses + [offset, 0, 0])
        lm_ranges.append(s.ranges_at(poses, rng=rng))
        # Four queries per landmark: 0.1-0.3 m away in a random direction, turned +-30 deg.
        n = len(poses)
        for _ in range(4):
            d = rng.uniform(0.1, 0.3, n)
            a = rng.uniform(-math.pi, math.pi, n)
            qp = poses + np.column_stack([d * np.cos(a), d * np.sin(a),
                                          rng.uniform(-math.radians(30), math.radians(30), n)])
            q_ranges.append(s.ranges_at(qp, rng=rng))
            q_source.append(base + np.arange(n))
    reach = min(8.0, CLAMP)
    landmarks = make_signature(np.vstack(lm_ranges), reach, L)
    queries = make_signature(np.vstack(q_ranges), reach, L)
    return fig, landmarks, queries, np.concatenate(q_source), sample_step(181, math.radians(1), L)


def displacement_tolerance(rng: np.random.Generator) -> list[str]:
    """Identification rate against the distance between query and landmark (figure 10)."""
    sims, lm_poses, lm_ranges = [], [], []
    for name in ("lab", "office"):
        s = Simulator(load_scenario(name))
        keep, last = [], None
        for i, p in enumerate(s.true_poses[: len(s) // 2]):
            if last is None or np.hypot(*(p[:2] - last[:2])) >= 1.0:
                keep.append(i)
                last = p
        sims.append((s, len(lm_poses), s.true_poses[keep]))
        lm_poses += list(s.true_poses[keep])
        lm_ranges.append(s.ranges_at(s.true_poses[keep], rng=rng))
    reach = min(8.0, CLAMP)
    landmarks = make_signature(np.vstack(lm_ranges), reach, L)
    step = sample_step(181, math.radians(1), L)
    k = math.ceil(MAX_HEADING / step)
    methods = [ED(L), CCA(L), DCT(L, 18), HWT(L, 3)]
    feats = [m.encode(landmarks) for m in methods]
    lines = ["| distance (m) | " + " | ".join(m.name for m in methods) + " |",
             "|---" * (len(methods) + 1) + "|"]
    for d in (0.0, 0.1, 0.2, 0.3, 0.5, 0.75, 1.0):
        queries, source = [], []
        for s, base, poses in sims:
            n = len(poses)
            a = rng.uniform(-math.pi, math.pi, n)
            qp = poses + np.column_stack([d * np.cos(a), d * np.sin(a),
                                          rng.uniform(-math.radians(20), math.radians(20), n)])
            queries.append(s.ranges_at(qp, rng=rng))
            source.append(base + np.arange(n))
        q = make_signature(np.vstack(queries), reach, L)
        src = np.concatenate(source)
        rates = []
        for m, f in zip(methods, feats, strict=True):
            best = np.array([np.argmin(m.search(x, f, max_shift=k).score) for x in q])
            rates.append((best == src).mean())
        lines.append(f"| {d:.2f} | " + " | ".join(f"{r:.0%}" for r in rates) + " |")
        print(f"  displaced {d:.2f} m: " + ", ".join(f"{m.name} {r:.0%}"
                                                  for m, r in zip(methods, rates, strict=True)))
    return lines


def intel_data(limit: int):
    frames = list(itertools.islice(read_carmen(INTEL), limit))
    odom = np.array([f.odom for f in frames])
    ranges = np.array([f.ranges for f in frames])
    reach = min(frames[0].max_range, CLAMP)
    step = sample_step(frames[0].num_beams, frames[0].angle_increment, L)
    # Figure 15: a landmark scan and the first scans 0.2, 0.4, 0.6 and 0.8 m further on.
    start = 400
    travelled = np.concatenate([[0], np.cumsum(np.hypot(*np.diff(odom[:, :2], axis=0).T))])
    picks = [int(np.searchsorted(travelled, travelled[start] + d)) for d in (0.2, 0.4, 0.6, 0.8)]
    sig = make_signature(ranges[[start, *picks]], reach, L)
    dtheta = relative(odom[start], odom[picks])[:, 2]
    fig = (sig[0], sig[1:], dtheta)
    # Identification: landmarks 1 m apart (odometry); each query is the scan 0.3 m after one.
    lm, last = [], None
    for i in range(len(frames)):
        if (last is None or travelled[i] - travelled[last] >= 1.0) and \
                travelled[-1] - travelled[i] > 0.5:
            lm.append(i)
            last = i
    q = [int(np.searchsorted(travelled, travelled[i] + 0.3)) for i in lm]
    landmarks = make_signature(ranges[lm], reach, L)
    queries = make_signature(ranges[q], reach, L)
    return fig, landmarks, queries, np.arange(len(lm)), step


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--intel-scans", type=int, default=2500,
                    help="how many Intel scans to use (default 2500)")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    DOCS.mkdir(exist_ok=True)
    doc = ["# The paper's experiment, repeated", "",
           "Written by `python bench/paper_comparison.py` on " + machine() + ".", "",
           "Signatures have 180 samples; no-return beams and ranges beyond 15 m count as the "
           "clamp range. Errors are mean square errors (per sample, over the overlap) for ED, "
           "DCT and HWT, and 1 - rho for CCA. The heading search tries every sample shift in "
           "+-60 degrees.", ""]
    results = {}
    for label, loader in (("lab scenario (simulated)", lambda: lab_data(rng)),
                          (f"Intel Research Lab (real, first {args.intel_scans} scans)",
                           lambda: intel_data(args.intel_scans))):
        (landmark, samples, dtheta), landmarks, queries, source, step = loader()
        key = "lab" if label.startswith("lab") else "intel"
        png = DOCS / f"paper_fig15_{key}.png"
        table = figure15(f"Figure 15 on the {label}", landmark, samples, dtheta, step, png)
        acc = identification(landmarks, queries, source, step)
        results[key] = acc
        doc += [f"## {label}", "", f"![figure 15, {key}]({png.name})", "",
                "Error against rotation for the four nearby positions (DCT and HWT at equal "
                "compression, 23 coefficients). Best rotation found per position:", "", *table,
                "", f"Identification: {len(landmarks)} landmarks, {len(queries)} queries.", "",
                "| method | compression | identified |", "|---|---|---|"]
        doc += [f"| {m} | {c} | {a:.1%} |" for m, c, a in acc]
        doc.append("")
        print(f"{label}:")
        for m, c, a in acc:
            print(f"  {m:4s} compression {c:>6s}: {a:.1%}")
    print("tolerance to displacement (lab and office landmarks):")
    doc += ["## Tolerance to displacement (the paper's figure 10)", "",
            "Landmarks every metre along the lab and office paths (simulated); each query is "
            "taken the given distance from its landmark in a random direction, turned by up to "
            "20 degrees. Share of queries whose best match is their own landmark (DCT 18 "
            "coefficients, HWT level 3):", "", *displacement_tolerance(rng), "",
            "Range profiles change quickly with position: beams grazing a wall and beams "
            "through doorways move by metres when the robot moves a few decimetres, and nearby "
            "landmarks shift in bearing (parallax). A signature match is therefore a place "
            "hypothesis and a heading seed; the mapper confirms it by registering the scans.",
            ""]
    doc += ["## At 10 % of the coefficients", "",
            "HWT can only halve, so its nearest levels to 10 % are 3 (23 coefficients, 12.8 %) "
            "and 4 (12 coefficients, 6.7 %). Percentage points against raw ED in brackets.", "",
            "| data | raw ED | DCT, 18 coefficients (90 %) | HWT level 3 (87.2 %) | "
            "HWT level 4 (93.3 %) |", "|---|---|---|---|---|"]
    for key, acc in results.items():
        get = {(m, c): a for m, c, a in acc}
        ed = get[("ED", "0 %")]

        def cell(v: float, ed: float = ed) -> str:
            return f"{v:.1%} ({100 * (v - ed):+.1f})"

        doc.append(f"| {key} | {ed:.1%} | {cell(get[('DCT', '90%')])} | "
                   f"{cell(get[('HWT', '87.2%')])} | {cell(get[('HWT', '93.3%')])} |")
    with atomic_write(DOCS / "paper_comparison.md", "w") as f:
        f.write("\n".join(doc) + "\n")


if __name__ == "__main__":
    main()
