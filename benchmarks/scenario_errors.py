"""Where a model's test error lies, per held-out scenario: the relative L2 error over the whole
grid (the paper's metric), the share of the squared error in free space (l > 0) and the relative
L2 there, and the mean |error| near the zero level set (|V_gt| < BAND m, where the filter acts).
Tells a few hard scenarios from an error spread over all of them, and error in free space from
error inside obstacles (where an unsettled solve keeps sinking).

    .venv/bin/python benchmarks/scenario_errors.py out/models/A out/models/B \\
        --data data/indoor32c > benchmarks/results/scenario_errors/NAME.md
"""

import argparse

import numpy as np

from hjrno_ros import held_out

BAND = 0.3  # m: |V_gt| below this counts as near the zero level set


def scores(pred: np.ndarray, solved: held_out.Solved) -> tuple[float, float, float, float]:
    """(rel. L2, share of squared error in free space, rel. L2 in free space, mean |e| near V = 0)."""
    err, v = pred - solved.value, solved.value
    free, near = solved.target > 0, np.abs(v) < BAND
    return (float(np.linalg.norm(err) / np.linalg.norm(v)), float((err[free] ** 2).sum() / (err**2).sum()),
            float(np.linalg.norm(err[free]) / np.linalg.norm(v[free])), float(np.abs(err[near]).mean()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="+", help="model stems")
    parser.add_argument("--data", default="data/indoor32c", help="comma-separated dataset folders (whole test split)")
    args = parser.parse_args()
    solved = held_out.load([f for f in args.data.split(",") if f], "all", unconverged=True)
    print(f"Per test scenario of {args.data} (all {len(solved)}; near V = 0: |V_gt| < {BAND} m)\n")
    print("| model | scenario | rel. L2 | share of squared error in free space | rel. L2 in free space "
          "| mean abs. error near V = 0 (m) |")
    print("|---|---|---|---|---|---|")
    for stem in args.models:
        rows = [scores(p, s) for p, s in zip(held_out.predict(stem, solved), solved, strict=True)]
        for s, r in zip(solved, rows, strict=True):
            print(f"| {stem} | {s.name} | {r[0]:.3f} | {r[1]:.2f} | {r[2]:.3f} | {r[3]:.3f} |")
        mean = np.mean(rows, axis=0)
        print(f"| {stem} | mean (sd of rel. L2 {np.std([r[0] for r in rows], ddof=1):.3f}) | {mean[0]:.4f} "
              f"| {mean[1]:.2f} | {mean[2]:.3f} | {mean[3]:.3f} |", flush=True)


if __name__ == "__main__":
    main()
