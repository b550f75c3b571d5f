"""Prototype: pick the safe control's turn by looking ahead on the value function, not by ∂V/∂θ.

The learned filters' remaining indoor collisions are wrong turns: the sign of the learned ∂V/∂θ,
which picks κ* = ±κ_max, disagrees with the truth's for most of the 2 s before the car becomes
unsafe (README, closed-loop section).  This variant drives both turns (the safe control's
acceleration, κ = ±κ_max, RK4, no disturbance) for ``horizon`` seconds on the *value table* and
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
from hjrno_ros.checkpoint import load_card
from hjrno_ros.closed_loop import EpisodeSettings, World
from hjrno_ros.dynamics import CarParams, car_optimal_control
from hjrno_ros.filter_study import TRUTH
from hjrno_ros.safety_filter import FilterSettings, filter_batch
from hjrno_ros.value_table import ValueTable

from hjrno_ros import closed_loop, held_out

STEPS = 10  # RK4 steps of each look-ahead rollout
MIN_SLOPE = 0.01 / (2 * np.pi / 8)  # m/rad: |∂V_gt/∂θ| below this (theta_difference.py's MIN_DIFF) leaves the turn moot


def rollout(params: CarParams, states: np.ndarray, accel: np.ndarray, turn, horizon: float):
    """The states of a ``horizon``-second rollout (:data:`STEPS` RK4 steps of the car, no disturbance) at
    constant acceleration ``accel`` ``(n,)`` and curvature ``turn`` · κ_max (``turn``: ±1, scalar or ``(n,)``)."""
    u = np.column_stack([accel, np.broadcast_to(turn * params.kappa_max, accel.shape)])
    x, d = np.asarray(states, float), np.zeros((len(states), 2))
    for _ in range(STEPS):
        x = closed_loop.rk4(params, x, u, d, horizon / STEPS)
        yield x


def rollout_score(params: CarParams, table: ValueTable, states: np.ndarray, accel: np.ndarray, turn: float,
                  horizon: float, score: str) -> np.ndarray:
    """V at the end (``end``) or its minimum along (``min``) a :func:`rollout`."""
    values = [table.value(x) for x in rollout(params, states, accel, turn, horizon)]
    return values[-1] if score == "end" else np.min(values, axis=0)


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
    variants += [("model", h, sc) for _, h, sc in variants]
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
            row = rows.setdefault(key, {"results": [], "flips": [0, 0, 0, 0]})
            row["results"].append(closed_loop.run_episodes(
                world, eps, make_filter(world.params, fs, tables[src], world.truth, h, sc, row["flips"]), settings))
        print(f"world {w + 1}/{len(solved)} {s.name}: {time.perf_counter() - start:.0f} s", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    summary = {key: {**closed_loop.summarize(r["results"]), "flips": r["flips"],
                     "by_world": collisions_by_world(r["results"], solved)} for key, r in rows.items()}
    truth_rate = summary[f"{TRUTH} h=0"]["intervention_rate"]
    lines = [f"# Turn look-ahead on V ({time.strftime('%Y-%m-%d')})", "",
             f"`{' '.join(['benchmarks/turn_lookahead.py', *sys.argv[1:]])}`", "",
             f"{len(solved)} worlds ({args.data}), {per_world} episodes each, seed {args.seed}, mode {args.mode}; "
             f"ground truth ε = 0.1 m, {args.model} ε = {card['epsilon']:.3f} m (its card).", "",
             "| filter | episodes | collisions | intervention rate | vs ground truth h=0 | goals reached | "
             "turns changed (of acting decisions) | collisions by world |", "|" + " --- |" * 8]
    for key, r in summary.items():
        f = r["flips"]
        flips = f"{f[0]} / {f[1]}; where the true turn matters {f[2]} / {f[3]}" if f[1] else "-"
        lines.append(f"| {key} | {r['episodes']} | {r['collisions']} | {r['intervention_rate']:.3f} | "
                     f"{r['intervention_rate'] / truth_rate:.2f}× | {r['goals_reached']:.2f} | {flips} | "
                     f"{', '.join(f'{k} ({v})' for k, v in r['by_world'].items()) or '-'} |")
    (args.out / "turn_lookahead.md").write_text("\n".join(lines) + "\n")
    (args.out / "turn_lookahead.json").write_text(json.dumps(summary, indent=1))
    print("\n".join(lines))


def collisions_by_world(results: list[dict], solved: list) -> dict[str, int]:
    """Collisions per world name, the worlds without any left out."""
    counts = {s.name: int((r["outcome"] == "collision").sum()) for r, s in zip(results, solved, strict=True)}
    return {name: n for name, n in counts.items() if n}


if __name__ == "__main__":
    main()
