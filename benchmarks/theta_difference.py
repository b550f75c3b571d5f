"""How well a model learns V's change with heading θ, the quantity that picks the safe control's
turn (its sign decides κ = ±κ_max): per dataset and model, the relative L2 error of the θ-difference
V(θ_{k+1}) − V(θ_k) over the whole grid, and the sign agreement of the central difference
V(θ_{k+1}) − V(θ_{k−1}) with the ground truth's on states near the zero level set
(|V_gt| < BAND m, where the filter acts) whose true difference is not negligible.  With ``--steps``
the model's sign is also taken from V(θ_k + δ) − V(θ_k − δ), evaluated off the grid's headings
(the heading enters as cos θ, sin θ channels, so any θ can be queried), against the same truth;
with ``--spatial`` from the turn toward V's spatial gradient (the heading's left normal · ∇ₓV, of the
model's V and of the truth's), a geometric stand-in for ∂V/∂θ.

    .venv/bin/python benchmarks/theta_difference.py models/default out/models/X \\
        --data data/indoor32c,data/single32 > benchmarks/results/theta_difference/NAME.md
"""

import argparse
import sys
from dataclasses import replace

import numpy as np

from hjrno_ros import held_out

BAND = 0.3  # m: |V_gt| below this counts as near the zero level set
MIN_DIFF = 0.01  # m: true central differences smaller than this have no reliable sign


def step(a: np.ndarray, shift: int) -> np.ndarray:
    """V(θ_{k+shift}) − V(θ_k) on a (Nx, Ny, Nv, Nθ) table, periodic in θ."""
    return np.roll(a, -shift, 3) - a


def turned(solved: list[held_out.Solved], delta: float) -> list[held_out.Solved]:
    """The scenarios with the grid's heading axis (the last) moved by ``delta`` rad."""
    def move(bounds: tuple[float, ...]) -> tuple[float, ...]:
        return (*bounds[:-1], bounds[-1] + delta)
    return [replace(s, grid=replace(s.grid, lo=move(s.grid.lo), hi=move(s.grid.hi))) for s in solved]


def toward_gradient(values: np.ndarray, solved: held_out.Solved) -> np.ndarray:
    """(−sin θ, cos θ) · ∇ₓV on a (Nx, Ny, Nv, Nθ) table: > 0 where turning left points the car up V's slope."""
    vx, vy = np.gradient(values, *solved.grid.spacings[:2], axis=(0, 1))
    theta = solved.grid.axis(3)
    return -np.sin(theta) * vx + np.cos(theta) * vy


def scores(pred: list[np.ndarray], solved: list[held_out.Solved]) -> tuple[float, float, int]:
    """(rel. L2 of the forward θ-difference, sign agreement near V = 0, states scored) over a folder."""
    num = den = 0.0
    for p, s in zip(pred, solved, strict=True):
        dp, dg = step(p, 1), step(s.value, 1)
        num, den = num + float(((dp - dg) ** 2).sum()), den + float((dg**2).sum())
    central = [step(p, 1) - step(p, -1) for p in pred]  # V(θ_{k+1}) − V(θ_{k−1})
    return (float(np.sqrt(num / max(den, 1e-12))), *agreement(central, solved))


def scored(solved: held_out.Solved) -> tuple[np.ndarray, np.ndarray]:
    """The truth's central θ-difference V(θ_{k+1}) − V(θ_{k−1}) and the states whose sign is scored
    (near V = 0, the difference not negligible)."""
    cg = step(solved.value, 1) - step(solved.value, -1)
    return cg, (np.abs(solved.value) < BAND) & (np.abs(cg) > MIN_DIFF)


def agreement(turns: list[np.ndarray], solved: list[held_out.Solved]) -> tuple[float, int]:
    """(How often ``turns``' sign is the truth's central difference's near V = 0, states scored)."""
    agree = total = 0
    for t, s in zip(turns, solved, strict=True):
        cg, near = scored(s)
        agree, total = agree + int((np.sign(t[near]) == np.sign(cg[near])).sum()), total + int(near.sum())
    return agree / max(total, 1), total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="+", help="model stems")
    parser.add_argument("--data", default="data/indoor32c,data/single32,data/two32,data/windows32",
                        help="comma-separated dataset folders (their whole test split is scored)")
    parser.add_argument("--steps", default="", help="comma-separated δ, rad: also take the model's sign from "
                                                     "V(θ + δ) − V(θ − δ) off the grid's headings")
    parser.add_argument("--spatial", action="store_true", help="also take the sign from the turn toward ∇ₓV")
    args = parser.parse_args()
    folders = [f for f in args.data.split(",") if f]
    solved = {f: held_out.load([f], "all", unconverged=True) for f in folders}
    print(f"`{' '.join(['benchmarks/theta_difference.py', *sys.argv[1:]])}`\n")
    print(f"θ-difference of V on test splits (all samples); sign scored where |V_gt| < {BAND} m and "
          f"|ΔV_gt| > {MIN_DIFF} m\n")
    print("| model | data | scenarios | rel. L2 of ΔθV | turn sign from | sign agreement near V = 0 | states |")
    print("|---|---|---|---|---|---|---|")
    for stem in args.models:
        for f, part in solved.items():
            pred = held_out.predict(stem, part)
            rel, agree, n = scores(pred, part)
            spacing = part[0].grid.spacings[-1]
            print(f"| {stem} | {f} | {len(part)} | {rel:.4f} | grid, ±{spacing:.3f} rad | {agree:.3f} | {n} |",
                  flush=True)
            for delta in (float(d) for d in args.steps.split(",") if d):
                plus, minus = (held_out.predict(stem, turned(part, sign * delta)) for sign in (1, -1))
                agree, n = agreement([a - b for a, b in zip(plus, minus, strict=True)], part)
                print(f"| {stem} | {f} | {len(part)} | | ±{delta:.3f} rad | {agree:.3f} | {n} |", flush=True)
            if args.spatial:
                for whose, tables in (("model's", pred), ("truth's", [s.value for s in part])):
                    agree, n = agreement([toward_gradient(t, s) for t, s in zip(tables, part, strict=True)], part)
                    print(f"| {stem} | {f} | {len(part)} | | turn toward the {whose} ∇ₓV | {agree:.3f} | {n} |",
                          flush=True)


if __name__ == "__main__":
    main()
