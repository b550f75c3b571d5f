"""Symmetry averaging: one forward pass per D4 element, or the 8 elements stacked into shared passes.

Median wall time of a symmetry-averaged prediction (models/default, CPU) per batch size, with
``max_stack`` 1 (one pass per element) and 8, 16, 32 (elements stacked while batch × elements fits):

    .venv/bin/python benchmarks/symmetry_stacking.py   # → benchmarks/results/symmetry_stacking.{md,json}
"""

import time
from pathlib import Path

import torch
from hjrno_ros.evaluation import median_ms

from hjrno_ros import benchmarks, checkpoint


def main(stem: str = "models/default", batches=(1, 2, 4, 8, 16), stacks=(1, 8, 16, 32)) -> int:
    averaged, card = checkpoint.load_model(stem, average=True)
    n = card["window"]["shape"][0]
    rows = []
    for batch in batches:
        x = torch.randn(batch, len(card["inputs"]["channels"]), n, n)
        row = {"batch": batch}
        for stack in stacks:
            averaged.max_stack = stack
            row[f"ms_max_stack_{stack}"] = round(median_ms(averaged, x, repeats=max(10, 160 // batch)), 2)
        rows.append(row)
        print(row, flush=True)
    note = (f"`benchmarks/symmetry_stacking.py` on {benchmarks.machine()}, {time.strftime('%Y-%m-%d')}, "
            f"torch threads {torch.get_num_threads()}: median ms of one symmetry-averaged prediction of {stem} "
            f"on a batch of {n} × {n} slices; max_stack 1 = one forward pass per element, k = elements stacked "
            "while batch × elements ≤ k.")
    return benchmarks.write_table(Path("benchmarks/results"), "symmetry_stacking", "Symmetry averaging: stacked passes",
                                 rows, note)


if __name__ == "__main__":
    raise SystemExit(main())
