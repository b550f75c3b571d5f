"""How far a grid table overstates the clearance: per solved scenario, the largest excess of the
multilinearly interpolated grid target over the exact clearance (the plain target l sampled at the
nodes, and the target as stored, which is l − inflation for an inflated dataset), and how much of the
obstacles' interior the stored V∞ calls safe (V∞ > 0 where the exact clearance is ≤ 0).  Points: a
fine x-y lattice (STEP m) at the table's speeds and headings.  Explains why a filter on the plain
32 × 32 × 9 × 16 tables let the car into small clutter and wall ends (README, "Inflation").

    .venv/bin/python benchmarks/grid_target_excess.py --data data/indoor32t_r23 \\
        > benchmarks/results/grid_target_excess/indoor32t_r23.md
"""

import argparse

import numpy as np
from hjrno_ros.geometry import union_sdf
from hjrno_ros.value_table import ValueTable

from hjrno_ros import held_out

STEP = 0.025  # m


def excess(s: held_out.Solved) -> tuple[float, float, float, float, float]:
    """(inflation, max excess of the plain target, max excess of the stored target, max V∞ inside
    obstacles, share of obstacle states with V∞ > 0)."""
    g = s.grid
    xs, ys = (np.arange(g.lo[i], g.hi[i] + 1e-9, STEP) for i in range(2))
    pts = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)
    exact = union_sdf(s.scenario.shapes, pts)
    plain = s.scenario.target(g)
    inflation = float(np.median(plain - s.target))
    at = lambda v, th: np.column_stack([pts, np.full(len(pts), v), np.full(len(pts), th)])  # noqa: E731
    l_plain, l_stored = (ValueTable(g, t).value(at(g.lo[2], 0.0)) - exact for t in (plain, s.target))
    table, inside = ValueTable(g, s.value), exact <= 0
    worst, safe = -np.inf, []
    for v in g.axis(2)[:: max(1, g.shape[2] // 3)]:
        for th in g.axis(3)[:: max(1, g.shape[3] // 4)]:
            val = table.value(at(v, th))[inside]
            worst, safe = max(worst, float(val.max())), safe + [float((val > 0).mean())]
    return inflation, float(l_plain.max()), float(l_stored.max()), worst, float(np.mean(safe))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", required=True, help="comma-separated dataset folders (whole test splits)")
    args = parser.parse_args()
    solved = held_out.load([f for f in args.data.split(",") if f], "all", unconverged=True)
    print(f"Per test scenario of {args.data} ({len(solved)}; x-y lattice step {STEP} m)\n")
    print("| scenario | inflation m | max (interp. plain l − exact l) m | max (interp. stored target − exact l) m "
          "| max V∞ inside obstacles m | obstacle states with V∞ > 0 |")
    print("|---|---|---|---|---|---|")
    rows = []
    for s in solved:
        r = excess(s)
        rows.append(r)
        print(f"| {s.name} | {r[0]:.3f} | {r[1]:.3f} | {r[2]:.3f} | {r[3]:.3f} | {r[4]:.4f} |", flush=True)
    r = np.max(rows, axis=0)
    print(f"| max | {r[0]:.3f} | {r[1]:.3f} | {r[2]:.3f} | {r[3]:.3f} | {r[4]:.4f} |")


if __name__ == "__main__":
    main()
