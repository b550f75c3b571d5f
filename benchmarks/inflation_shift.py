"""Inflation is a margin on the value: V∞[l − r] = V∞[l] − r for the true value function (a constant
passes through the min over time and the sup / inf over controls and disturbances).  Per test scenario
of an experiment, both targets solved with the experiment's solver settings; prints how far the solver's
V∞[l − r] is from V∞[l] − r, and how often the two agree on safe / unsafe (README, "Inflation").

    .venv/bin/python benchmarks/inflation_shift.py --experiment single --grid 32,32,9,16 --samples 2 \\
        > benchmarks/results/inflation_shift/single32_r0.23.md
"""

import argparse
import time

import numpy as np
from hjrno_ros.solver import solve

from hjrno_ros import dataset


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--experiment", default="single", help="a car experiment (config/experiments/NAME.yaml)")
    parser.add_argument("--grid", default=None, help="grid override, e.g. 32,32,9,16")
    parser.add_argument("--samples", type=int, default=2, help="test scenarios to solve (each twice)")
    parser.add_argument("--inflation", type=float, default=0.23, help="r, m")
    args = parser.parse_args()
    config = dataset.load_config(args.experiment)
    if args.grid:
        config = dataset.ExperimentConfig(**{**config.as_dict(), "grid": [int(n) for n in args.grid.split(",")]})
    r = np.float32(args.inflation)
    print(f"`{args.experiment}` test scenarios on {'x'.join(map(str, config.grid))}, r = {args.inflation} m, "
          f"solver {config.solver}, {time.strftime('%Y-%m-%d')}\n")
    print("| scenario | max \\|V∞[l − r] − (V∞[l] − r)\\| m | mean m | sign agreement | both converged |")
    print("|---|---|---|---|---|")
    for i in range(args.samples):
        scenario = config.scenario("test", i)
        grid = scenario.grid(config.grid)
        target = scenario.target(grid)
        plain, rep_plain = solve(scenario.dynamics(), grid, target, **config.solver)
        grown, rep_grown = solve(scenario.dynamics(), grid, target - r, **config.solver)
        diff = np.abs(grown - (plain - r))
        agree = np.mean((grown > 0) == (plain > r))
        print(f"| {args.experiment}/{scenario.seed} | {diff.max():.4f} | {diff.mean():.1e} | {agree:.5f} "
              f"| {rep_plain.converged and rep_grown.converged} |", flush=True)


if __name__ == "__main__":
    main()
