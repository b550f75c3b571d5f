"""Closed-loop collisions compared room by room (the unit that varies), from a ``hjrno simulate`` result:
per filter mode, each model's total against a reference model, the rooms where it collides less / more,
the sign-test and Wilcoxon signed-rank p-values over rooms, and each filter's collisions in the rooms
whose ground-truth solve converged.

    .venv/bin/python benchmarks/room_comparison.py benchmarks/results/closed_loop_indoor16_v5_v6_v8_seed5 \\
        --data data/indoor32t --reference v5 > .../room_comparison.md
"""

import argparse
import json
from pathlib import Path

from hjrno_ros.dataset import load_split
from scipy import stats


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("result", help="folder with closed_loop.json")
    parser.add_argument("--data", required=True, help="the simulated dataset folders, comma-separated")
    parser.add_argument("--reference", default="v5", help="model label the others are compared with")
    args = parser.parse_args()
    study = json.loads((Path(args.result) / "closed_loop.json").read_text())
    worlds, by_world = study["worlds"], study["collisions_by_world"]
    converged = set()
    for folder in args.data.split(","):
        split = load_split(Path(folder) / "test.h5", converged_only=False, warn=lambda m: None)
        converged |= {f"{split.config.name}/{s.seed}" for s, ok in zip(split.scenarios, split.converged, strict=True)
                      if ok}
    counts = {row["filter"]: [by_world.get(row["filter"], {}).get(w, 0) for w in worlds] for row in study["rows"]}
    print(f"{len(worlds)} rooms, {study['episodes_per_world']} episodes each ({args.result})\n")
    print("| filter | collisions | in the converged rooms |\n|---|---|---|")
    for name, c in counts.items():
        print(f"| {name} | {sum(c)} | {sum(n for n, w in zip(c, worlds, strict=True) if w in converged)} |")
    print(f"\n| mode | model | collisions ({args.reference} → model) | rooms fewer / more | sign test p "
          "| Wilcoxon p |\n|---|---|---|---|---|---|")
    for row in study["rows"]:
        name, mode = row["filter"], row["mode"]
        ref = [r["filter"] for r in study["rows"] if r["filter"].startswith(args.reference) and r["mode"] == mode
               and "no model margin" not in r["filter"]]
        if "eps=" not in name or "no model margin" in name or name in ref or not ref:
            continue
        a, b = counts[ref[0]], counts[name]
        diff = [x - y for x, y in zip(a, b, strict=True)]
        fewer, more = sum(d > 0 for d in diff), sum(d < 0 for d in diff)
        sign = stats.binomtest(fewer, fewer + more).pvalue if fewer + more else 1.0
        print(f"| {mode} | {name} | {sum(a)} → {sum(b)} | {fewer} / {more} | {sign:.3f} "
              f"| {stats.wilcoxon(a, b).pvalue:.3f} |")


if __name__ == "__main__":
    main()
