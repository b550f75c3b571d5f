"""The ground-truth solver warm-started from an operator's prediction: how fast it settles, how close
it comes to V∞, and whether its turn (the sign of ∂V/∂θ) and its filter are the truth's.

``solve(..., initial=V_pred + offset)`` runs the backward reachable tube from min(V_pred + offset, l)
instead of from l.  The tube only lowers V and V∞ is the largest fixed point below l, so its limit is
≤ V∞, and V∞ if the start was ≥ V∞ everywhere (``offset`` > 0 raises the start toward that, at the
cost of a longer way down).  After a finite time the table lies between its start and that limit:
still above V∞ where the prediction was optimistic (the false-safe column), below where it was
pessimistic (false-unsafe).  Per stage of simulated time the table gives the rel. L2 error against V∞, the
false-safe and false-unsafe rates, the sign agreement of ∂V/∂θ near V = 0 (theta_difference.py's
score) and the solve's wall time, against the cold solve's (from l, stored in the dataset).  With
``--episodes`` the settled tables also drive ``hjrno simulate``'s closed loop (same worlds, starts,
goals, disturbance; blend mode) beside the ground truth and the model.

    .venv/bin/python benchmarks/warm_start.py models/default --data data/indoor32t_r23 \\
        --offsets 0 --stages 2,4,8,16 --loop-stages 4,8,16 --seeds 5,6 --episodes 2000 --cold 2 \\
        --out benchmarks/results/warm_start
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from hjrno_ros.checkpoint import load_card
from hjrno_ros.closed_loop import EpisodeSettings, World
from hjrno_ros.dataset import load_split
from hjrno_ros.filter_study import FilterChoice, make_filter
from hjrno_ros.safety_filter import FilterSettings
from hjrno_ros.solver import solve
from hjrno_ros.stop_zone import StopZoneSettings
from hjrno_ros.value_table import ValueTable
from theta_difference import agreement, step

from hjrno_ros import closed_loop, held_out

TRUTH_EPSILON = 0.1  # m: the ground-truth filter's margin in the closed-loop table


def scores(values: list[np.ndarray], solved: list[held_out.Solved]) -> dict[str, float]:
    """Rel. L2 against V∞, false-safe / false-unsafe rates (all states) and ∂V/∂θ sign agreement near V = 0."""
    num = den = 0.0
    false_safe = false_unsafe = total = 0
    for w, s in zip(values, solved, strict=True):
        num, den = num + float(((w - s.value) ** 2).sum()), den + float((s.value**2).sum())
        false_safe += int(((w > 0) & (s.value <= 0)).sum())
        false_unsafe += int(((w <= 0) & (s.value > 0)).sum())
        total += w.size
    sign, _ = agreement([step(w, 1) - step(w, -1) for w in values], solved)
    return {"rel_l2": float(np.sqrt(num / den)), "false_safe": false_safe / total,
            "false_unsafe": false_unsafe / total, "sign_agreement": sign}


def warm_solves(solved: list[held_out.Solved], pred: list[np.ndarray], offset: float, stages: list[float],
                solver: dict) -> list[dict]:
    """Per stage (cumulative simulated seconds): the tables, wall time so far and how many settled."""
    current = [p + offset for p in pred]
    settled = [False] * len(solved)
    wall, done, out = 0.0, 0.0, []
    for stage in stages:
        for i, s in enumerate(solved):
            if settled[i]:
                continue
            current[i], report = solve(s.scenario.dynamics(), s.grid, s.target, initial=current[i],
                                       accuracy=solver["accuracy"], tolerance=solver["tolerance"],
                                       criterion=solver["criterion"], chunk=min(1.0, stage - done),
                                       max_horizon=stage - done)
            wall += report.wall_time
            settled[i] = report.converged
        done = stage
        out.append({"horizon": stage, "wall_s": wall, "settled": sum(settled), "tables": list(current)})
    return out


def run_closed_loop(solved: list[held_out.Solved], tables: dict[str, tuple[list[np.ndarray], float]],
                    episodes: int, seed: int, mode: str) -> dict[str, dict]:
    """``hjrno simulate``'s episodes (turn_lookahead.py's draw) per table source: label → (tables, ε)."""
    settings = EpisodeSettings()
    worlds = [i for i, s in enumerate(solved) if closed_loop.has_safe_states(s.grid, s.value, settings)]
    per_world = -(-episodes // len(worlds))
    results: dict[str, list[dict]] = {label: [] for label in tables}
    for w, i in enumerate(worlds):
        s = solved[i]
        world = World(s.name, s.scenario.shapes, ValueTable(s.grid, s.value), s.scenario.dynamics_params())
        eps = closed_loop.draw_episodes(world, per_world, settings, seed=seed * 100003 + w, first=w * per_world)
        for label, (values, epsilon) in tables.items():
            choice = FilterChoice(label, "hj", label, mode, epsilon)
            filt = make_filter(choice, world, {label: ValueTable(s.grid, values[i])}, StopZoneSettings(),
                               settings.dt, FilterSettings.decay_rate)
            results[label].append(closed_loop.run_episodes(world, eps, filt, settings))
    return {label: closed_loop.summarize(r) for label, r in results.items()}


def cold_solves(solved: list[held_out.Solved], solver: dict) -> list[str]:
    """Lines timing the dataset's own solve (from l) of ``solved`` on this machine now."""
    lines = []
    for s in solved:
        _, report = solve(s.scenario.dynamics(), s.grid, s.target, **solver)
        lines.append(f"Cold solve of {s.name} here: {report.summary()}.")
        print(lines[-1], flush=True)
    return [*lines, ""] if lines else []


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", help="model stem")
    ap.add_argument("--data", required=True, help="one dataset folder (its whole test split)")
    ap.add_argument("--offsets", default="0,0.1", help="comma-separated m added to the prediction before the solve")
    ap.add_argument("--stages", default="1,2,4,8,16", help="cumulative simulated seconds to score at")
    ap.add_argument("--episodes", type=int, default=0, help="closed-loop episodes on the settled tables (0: none)")
    ap.add_argument("--seeds", default="5", help="comma-separated closed-loop seeds")
    ap.add_argument("--loop-stages", default="", help="comma-separated stages whose tables drive the closed loop "
                                                      "(default: the last)")
    ap.add_argument("--cold", type=int, default=0, help="also time this many cold solves (from l) here")
    ap.add_argument("--mode", default="blend")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    solved = held_out.load([args.data], "all", unconverged=True)
    split = load_split(Path(args.data) / "test.h5", converged_only=False)
    cold = sum(r["wall_time"] for r in split.reports)
    solver = split.config.solver
    card = load_card(args.model)
    pred = held_out.predict(args.model, solved)
    stages = [float(h) for h in args.stages.split(",")]
    lines = [f"# Warm-started solves ({time.strftime('%Y-%m-%d')})", "",
             f"`{' '.join(['benchmarks/warm_start.py', *sys.argv[1:]])}`", "",
             f"{len(solved)} scenarios of {args.data}, grid {'x'.join(map(str, solved[0].grid.shape))}, "
             f"solver {solver}; their cold solves (from l) took {cold:.0f} s in all when the dataset was generated.",
             "",
             *cold_solves(solved[:args.cold], solver),
             "| start | simulated s | settled | wall s (all scenarios) | rel. L2 | false-safe | false-unsafe | "
             "∂V/∂θ sign near V = 0 |", "|" + " --- |" * 8]
    base = scores(pred, solved)
    lines.append(f"| {args.model} | 0 | - | - | {base['rel_l2']:.4f} | {base['false_safe']:.2e} | "
                 f"{base['false_unsafe']:.2e} | {base['sign_agreement']:.3f} |")
    summary: dict = {"prediction": base, "runs": {}}
    settled_tables = {}
    for offset in (float(o) for o in args.offsets.split(",")):
        label = f"warm {args.model} + {offset:g} m"
        runs = warm_solves(solved, pred, offset, stages, solver)
        for r in runs:
            sc = scores(r["tables"], solved)
            summary["runs"].setdefault(label, []).append({k: v for k, v in r.items() if k != "tables"} | sc)
            lines.append(f"| {label} | {r['horizon']:g} | {r['settled']}/{len(solved)} | {r['wall_s']:.0f} | "
                         f"{sc['rel_l2']:.4f} | {sc['false_safe']:.2e} | {sc['false_unsafe']:.2e} | "
                         f"{sc['sign_agreement']:.3f} |")
            print(lines[-1], flush=True)
        looped = [float(h) for h in args.loop_stages.split(",") if h] or stages[-1:]
        settled_tables |= {f"{label}, {r['horizon']:g} s": (r["tables"], TRUTH_EPSILON)
                           for r in runs if r["horizon"] in looped}
    tables = {"ground_truth": ([s.value for s in solved], TRUTH_EPSILON),
              args.model: (pred, float(card["epsilon"])),
              f"{args.model}, ε = {TRUTH_EPSILON} m": (pred, TRUTH_EPSILON), **settled_tables}
    for seed in (int(x) for x in args.seeds.split(",") if args.episodes):
        loop = run_closed_loop(solved, tables, args.episodes, seed, args.mode)
        summary.setdefault("closed_loop", {})[seed] = loop
        truth_rate = loop["ground_truth"]["intervention_rate"]
        lines += ["", f"Closed loop ({args.mode}, seed {seed}; ε: ground truth and warm starts "
                  f"{TRUTH_EPSILON} m, {args.model} {card['epsilon']:.3f} m, its card):", "",
                  "| filter | episodes | collisions | intervention rate | vs ground truth | goals reached |",
                  "|" + " --- |" * 6]
        lines += [f"| {label} | {r['episodes']} | {r['collisions']} | {r['intervention_rate']:.3f} | "
                  f"{r['intervention_rate'] / truth_rate:.2f}× | {r['goals_reached']:.2f} |"
                  for label, r in loop.items()]
        print("\n".join(lines[-len(loop) - 4:]), flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "warm_start.md").write_text("\n".join(lines) + "\n")
    (args.out / "warm_start.json").write_text(json.dumps(summary, indent=1))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
