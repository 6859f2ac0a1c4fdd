"""ATE of a scenario over several simulation seeds, with the default or a given configuration.

Run: python bench/seeds.py warehouse --seeds 5 1 2 [--config bench/configs/warehouse_submap.yaml]

Prints the ATE (RMSE after SE(2) alignment, against the simulator's truth) per seed, then the
median and the maximum. One seed's result can flatter a change; this shows the spread.
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

from drivers.scenario import load_scenario
from drivers.simulator import Simulator
from vmp.config import load_config
from vmp.evaluate import ate
from vmp.pipeline import Pipeline, PipelineConfig
from vmp.vector_map import BeamGeometry


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenario")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5, 6, 7, 8])
    ap.add_argument("--config", type=Path, help="mapping configuration YAML")
    args = ap.parse_args()
    config = load_config(args.config) if args.config else PipelineConfig()
    scenario = load_scenario(args.scenario)
    results = []
    for seed in args.seeds:
        sim = Simulator(scenario, seed=seed)
        s = sim.sensor
        p = Pipeline(BeamGeometry(s.beams, s.angle_min, s.angle_increment, s.max_range), config)
        for frame in sim:
            p.step(frame)
        p.finish()
        e = ate(sim.stamps, p.trajectory(), sim.stamps, sim.true_poses).rmse
        results.append(e)
        print(f"{args.scenario} seed {seed}: ATE {100 * e:.2f} cm", flush=True)
    print(f"median {100 * statistics.median(results):.2f} cm, max {100 * max(results):.2f} cm "
          f"over {len(results)} seeds ({args.config or 'default configuration'})")


if __name__ == "__main__":
    main()
