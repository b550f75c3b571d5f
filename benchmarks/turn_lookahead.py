"""Prototype: pick the safe control's turn by looking ahead on the value function, not by ∂V/∂θ.

The learned filters' remaining indoor collisions are wrong turns: the sign of the learned ∂V/∂θ,
which picks κ* = ±κ_max, disagrees with the truth's for most of the 2 s before the car becomes
unsafe (README, closed-loop section).  This variant drives both turns (the safe control's
acceleration, κ = ±κ_max, Euler, no disturbance) for ``horizon`` seconds on the *value table* and
keeps the turn whose end state has the larger V (``--score end``) or whose lowest V along the way is
larger (``--score min``).  It needs V over the whole (v, θ) table, which ``hjrno simulate`` has and
the node (a 2 × 2 stencil around the state) does not, so this measures whether the idea is worth
that cost.  Same worlds, starts, goals and disturbance as ``hjrno simulate`` with the same seed.
Measured 2026-12-03: worse with the learned and with the true V (results/closed_loop_history/turn_lookahead/).

    .venv/bin/python benchmarks/turn_lookahead.py --data data/indoor32t_r23 --seed 5 --episodes 2000 \
        --horizons 0.5,1.0 --out benchmarks/results/closed_loop_history/turn_lookahead
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from hjrno_ros import closed_loop, held_out
from hjrno_ros.checkpoint import load_card
from hjrno_ros.closed_loop import EpisodeSettings, World
from hjrno_ros.dynamics import CarParams, car_optimal_control
from hjrno_ros.filter_study import TRUTH
from hjrno_ros.safety_filter import FilterSettings, filter_batch
from hjrno_ros.value_table import ValueTable

STEPS = 10  # Euler steps of each look-ahead rollout
MIN_SLOPE = 0.01 / (2 * np.pi / 8)  # m/rad: |∂V_gt/∂θ| below this (theta_difference.py's MIN_DIFF) leaves the turn moot


def rollout_score(params: CarParams, table: ValueTable, states: np.ndarray, accel: np.ndarray, turn: float,
                  horizon: float, score: str) -> np.ndarray:
    """V at the end (``end``) or its minimum along (``min``) a ``horizon``-second rollout at constant
    acceleration ``accel`` ``(n,)`` and curvature ``turn`` · κ_max."""
    x = np.array(states, float, copy=True)
    h = horizon / STEPS
    lowest = np.full(len(x), np.inf)
    for _ in range(STEPS):
        v = x[:, 2]
        x[:, 0] += h * v * np.cos(x[:, 3])
        x[:, 1] += h * v * np.sin(x[:, 3])
        x[:, 3] = np.angle(np.exp(1j * (x[:, 3] + h * v * turn * params.kappa_max)))
        x[:, 2] = np.clip(v + h * accel, params.v_min, params.v_max)
        lowest = np.minimum(lowest, table.value(x))
    return table.value(x) if score == "end" else lowest


def looked_ahead(params: CarParams, table: ValueTable, states: np.ndarray, grads: np.ndarray, horizon: float,
                 score: str) -> tuple[np.ndarray, np.ndarray]:
    """``grads`` with ∂V/∂θ's sign set to the turn whose rollout scores higher, and where it flipped."""
    accel = car_optimal_control(params, states, grads)[:, 0]
    left = rollout_score(params, table, states, accel, 1.0, horizon, score)
    right = rollout_score(params, table, states, accel, -1.0, horizon, score)
    learned_left = states[:, 2] * grads[:, 3] >= 0
    want_left = np.where(left == right, learned_left, left > right)
    out = grads.copy()
    magnitude = np.maximum(np.abs(grads[:, 3]), 1e-9)
    out[:, 3] = np.where(want_left, magnitude, -magnitude)
    return out, want_left != learned_left


def oracle_turn(truth: ValueTable, states: np.ndarray, grads: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``grads`` with ∂V/∂θ's sign set to the ground truth's (a diagnostic: is the turn all that is wrong?)."""
    out = grads.copy()
    truth_left = states[:, 2] * truth.gradient(states)[:, 3] >= 0
    magnitude = np.maximum(np.abs(grads[:, 3]), 1e-9)
    out[:, 3] = np.where(truth_left, magnitude, -magnitude)
    return out, truth_left != (states[:, 2] * grads[:, 3] >= 0)


def make_filter(params: CarParams, settings: FilterSettings, table: ValueTable, truth: ValueTable, horizon: float,
                score: str, flips: list):
    def filt(states: np.ndarray, nominal: np.ndarray):
        values, grads = table.value_and_gradient(states)
        if horizon > 0 or score == "oracle":
            acting = values <= settings.epsilon + settings.blend_width
            if acting.any():
                new, flipped = (oracle_turn(truth, states[acting], grads[acting]) if score == "oracle" else
                                looked_ahead(params, table, states[acting], grads[acting], horizon, score))
                grads[acting] = new
                matters = np.abs(truth.gradient(states[acting])[:, 3]) >= MIN_SLOPE
                flips[0] += int(flipped.sum())
                flips[1] += int(acting.sum())
                flips[2] += int((flipped & matters).sum())
                flips[3] += int(matters.sum())
        return filter_batch(params, settings, states, values, grads, nominal)
    return filt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="comma-separated dataset folders (their test splits)")
    ap.add_argument("--model", default="models/default")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--episodes", type=int, default=2000)
    ap.add_argument("--mode", default="blend")
    ap.add_argument("--horizons", default="0.5,1.0", help="look-ahead horizons, s (0: the plain filter)")
    ap.add_argument("--scores", default="end,min")
    ap.add_argument("--oracle", action="store_true", help="add the model with the ground truth's turn")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    settings = EpisodeSettings()
    solved = [s for s in held_out.load(args.data.split(","), "all", unconverged=True)
              if closed_loop.has_safe_states(s.grid, s.value, settings)]
    card = load_card(args.model)
    predicted = held_out.predict(args.model, solved)
    per_world = -(-args.episodes // len(solved))
    variants = [(TRUTH, 0.0, "end")] + [(TRUTH, float(h), sc) for h in args.horizons.split(",") if float(h) > 0
                                        for sc in args.scores.split(",")]
    variants += [(src, h, sc) for src in ("model",) for _, h, sc in variants]
    if args.oracle:
        variants.append(("model", 0.0, "oracle"))
    rows = {}
    start = time.perf_counter()
    for w, s in enumerate(solved):
        world = World(s.name, s.scenario.shapes, ValueTable(s.grid, s.value), s.scenario.dynamics_params())
        tables = {TRUTH: world.truth, "model": ValueTable(s.grid, predicted[w])}
        eps = closed_loop.draw_episodes(world, per_world, settings, seed=args.seed * 100003 + w,
                                        first=w * per_world)
        for src, h, sc in variants:
            epsilon = 0.1 if src == TRUTH else float(card["epsilon"])
            fs = FilterSettings(epsilon=epsilon, mode=args.mode, dt=settings.dt)
            key = f"{src} h={h:g}" + (f" {sc}" if h > 0 or sc == "oracle" else "")
            row = rows.setdefault(key, {"collisions": 0, "episodes": 0, "steps": 0, "interventions": 0,
                                        "goals": 0, "goal_episodes": 0, "flips": [0, 0, 0, 0], "by_world": {}})
            r = closed_loop.run_episodes(world, eps, make_filter(world.params, fs, tables[src], world.truth, h, sc,
                                                                     row["flips"]),
                                         settings)
            n_coll = int((r["outcome"] == "collision").sum())
            row["collisions"] += n_coll
            row["episodes"] += len(r["outcome"])
            row["steps"] += int(r["steps"].sum())
            row["interventions"] += int(r["interventions"].sum())
            goal = r["controller"] == "goal"
            row["goals"] += int((r["outcome"][goal] == "goal").sum())
            row["goal_episodes"] += int(goal.sum())
            if n_coll:
                row["by_world"][s.name] = n_coll
        print(f"world {w + 1}/{len(solved)} {s.name}: {time.perf_counter() - start:.0f} s", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    truth_rate = rows[f"{TRUTH} h=0"]["interventions"] / rows[f"{TRUTH} h=0"]["steps"]
    lines = [f"# Turn look-ahead on V ({time.strftime('%Y-%m-%d')})", "",
             f"`{' '.join(['benchmarks/turn_lookahead.py', *sys.argv[1:]])}`", "",
             f"{len(solved)} worlds ({args.data}), {per_world} episodes each, seed {args.seed}, mode {args.mode}; "
             f"ground truth ε = 0.1 m, {args.model} ε = {card['epsilon']:.3f} m (its card).", "",
             "| filter | episodes | collisions | intervention rate | vs ground truth h=0 | goals reached | "
             "turns changed (of acting decisions) | collisions by world |", "|" + " --- |" * 8]
    for key, r in rows.items():
        rate = r["interventions"] / r["steps"]
        f = r["flips"]
        flips = f"{f[0]} / {f[1]}; where the true turn matters {f[2]} / {f[3]}" if f[1] else "-"
        lines.append(f"| {key} | {r['episodes']} | {r['collisions']} | {rate:.3f} | {rate / truth_rate:.2f}× | "
                     f"{r['goals'] / max(r['goal_episodes'], 1):.2f} | {flips} | "
                     f"{', '.join(f'{k} ({v})' for k, v in r['by_world'].items()) or '-'} |")
    (args.out / "turn_lookahead.md").write_text("\n".join(lines) + "\n")
    (args.out / "turn_lookahead.json").write_text(json.dumps(rows, indent=1))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
