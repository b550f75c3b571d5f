"""How well a model learns V's change with heading θ, the quantity that picks the safe control's
turn (its sign decides κ = ±κ_max): per dataset and model, the relative L2 error of the θ-difference
V(θ_{k+1}) − V(θ_k) over the whole grid, and the sign agreement of the central difference
V(θ_{k+1}) − V(θ_{k−1}) with the ground truth's on states near the zero level set
(|V_gt| < BAND m, where the filter acts) whose true difference is not negligible.

    .venv/bin/python benchmarks/theta_difference.py models/default out/models/X \\
        --data data/indoor32c,data/single32 > benchmarks/results/theta_difference/NAME.md
"""

import argparse

import numpy as np

from hjrno_ros import held_out

BAND = 0.3  # m: |V_gt| below this counts as near the zero level set
MIN_DIFF = 0.01  # m: true central differences smaller than this have no reliable sign


def step(a: np.ndarray, shift: int) -> np.ndarray:
    """V(θ_{k+shift}) − V(θ_k) on a (Nx, Ny, Nv, Nθ) table, periodic in θ."""
    return np.roll(a, -shift, 3) - a


def scores(pred: list[np.ndarray], solved: list[held_out.Solved]) -> tuple[float, float, int]:
    """(rel. L2 of the forward θ-difference, sign agreement near V = 0, states scored) over a folder."""
    num = den = 0.0
    agree = total = 0
    for p, s in zip(pred, solved, strict=True):
        dp, dg = step(p, 1), step(s.value, 1)
        num, den = num + float(((dp - dg) ** 2).sum()), den + float((dg**2).sum())
        cp, cg = dp - step(p, -1), dg - step(s.value, -1)  # V(θ_{k+1}) − V(θ_{k−1})
        near = (np.abs(s.value) < BAND) & (np.abs(cg) > MIN_DIFF)
        agree, total = agree + int((np.sign(cp[near]) == np.sign(cg[near])).sum()), total + int(near.sum())
    return float(np.sqrt(num / max(den, 1e-12))), agree / max(total, 1), total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="+", help="model stems")
    parser.add_argument("--data", default="data/indoor32c,data/single32,data/two32,data/windows32",
                        help="comma-separated dataset folders (their whole test split is scored)")
    args = parser.parse_args()
    folders = [f for f in args.data.split(",") if f]
    solved = {f: held_out.load([f], "all", unconverged=True) for f in folders}
    print(f"θ-difference of V on test splits (all samples); sign scored where |V_gt| < {BAND} m and "
          f"|ΔV_gt| > {MIN_DIFF} m\n")
    print("| model | data | scenarios | rel. L2 of ΔθV | sign agreement near V = 0 | states |")
    print("|---|---|---|---|---|---|")
    for stem in args.models:
        for f, part in solved.items():
            rel, agree, n = scores(held_out.predict(stem, part), part)
            print(f"| {stem} | {f} | {len(part)} | {rel:.4f} | {agree:.3f} | {n} |", flush=True)


if __name__ == "__main__":
    main()
