"""Does the ensemble's disagreement on the turn tell where the learned turn is wrong, and can the filter use it?

The bundled default is three members, each averaged over two D4 frames: six predictions of V.  Offline
(the states that ``theta_difference.py`` scores: |V_gt| < 0.3 m, |ΔθV_gt| > 0.01 m), this scores the
sign of the central θ-difference of the mean, of each of the six, of their majority vote, and of the
mean where the six agree and where they split.  In closed loop (blend mode, the same worlds, starts and
disturbances as ``hjrno simulate`` with the same seed) it tries three uses of a split: drive straight
(κ = 0) with the safe control's acceleration, brake straight, or check the mean's turn on the map (the
other turn where the mean's hits an obstacle within 1 s and the other does not).

    .venv/bin/python benchmarks/turn_vote.py --data data/indoor32t_r23 --seed 5 \\
        > benchmarks/results/closed_loop_history/turn_vote/seed5.md
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
from hjrno_ros.closed_loop import EpisodeSettings, World
from hjrno_ros.dynamics import car_optimal_control
from hjrno_ros.evaluation import predict_table, sample_params
from hjrno_ros.safety_filter import FilterSettings, control_to_twist, filter_batch, nominal_weight
from hjrno_ros.slices import InputSpec
from hjrno_ros.value_table import ValueTable
from theta_difference import scored, step
from turn_lookahead import collisions_by_world, rollout

from hjrno_ros import checkpoint, closed_loop, held_out

VARIANTS = ("plain", "straight", "brake", "map check")
CHECK_S = 1.0  # s: the map check's rollout


def rollout_clearance(world: World, states: np.ndarray, accel: np.ndarray, turn: np.ndarray) -> np.ndarray:
    """Lowest clearance ``(n,)`` along a :data:`CHECK_S`-second :func:`turn_lookahead.rollout` on the world's
    exact obstacles."""
    return np.min([world.clearance(x) for x in rollout(world.params, states, accel, turn, CHECK_S)], axis=0)


def part_tables(stem: str, solved: list[held_out.Solved]) -> list[list[np.ndarray]]:
    """Per (member, frame) of the card's ``member_frames``: V on each scenario's grid, min'd with l − r."""
    card = checkpoint.load_card(stem)
    frames, spec = card["member_frames"], InputSpec.from_dict(card["inputs"])
    out = []
    for i, member_frames in enumerate(frames):
        for f in member_frames:
            model, _ = checkpoint.load_model(stem, frames=[[f]] * len(frames))
            model.members = torch.nn.ModuleList([model.members[i]])
            with torch.no_grad():
                out.append([np.minimum(predict_table(model, spec, s.grid, s.target, sample_params(spec, s.scenario)),
                                       s.target) for s in solved])
    return out


def offline(mean: list[np.ndarray], parts: list[list[np.ndarray]], solved: list[held_out.Solved]) -> dict:
    """Sign agreement with the truth's central θ-difference: (agreeing, scored) per predictor."""
    def cdiff(a: np.ndarray) -> np.ndarray:
        return step(a, 1) - step(a, -1)

    res = {k: [0, 0] for k in ("mean", "majority vote", *[f"part {k}" for k in range(len(parts))],
                               "mean where all six agree", "mean where they split")}
    for w, s in enumerate(solved):
        cg, near = scored(s)
        truth, cm = np.sign(cg[near]), np.sign(cdiff(mean[w])[near])
        signs = np.stack([np.sign(cdiff(p[w])[near]) for p in parts])
        votes = signs.sum(0)
        unanimous = np.abs(votes) == len(parts)
        picks = {"mean": (cm, slice(None)), "majority vote": (np.where(votes == 0, cm, np.sign(votes)), slice(None)),
                 **{f"part {k}": (signs[k], slice(None)) for k in range(len(parts))},
                 "mean where all six agree": (cm, unanimous), "mean where they split": (cm, ~unanimous)}
        for k, (sign, where) in picks.items():
            res[k][0] += int((sign == truth)[where].sum())
            res[k][1] += int(truth[where].size)
    return res


def make_filter(world: World, fs: FilterSettings, table: ValueTable, parts: list[ValueTable], variant: str,
                split_count: list):
    p = world.params

    def filt(states: np.ndarray, nominal: np.ndarray):
        values, grads = table.value_and_gradient(states)
        if variant == "plain":
            return filter_batch(p, fs, states, values, grads, nominal)
        w = nominal_weight(fs, values)
        u = car_optimal_control(p, states, grads)
        signs = np.stack([np.sign(states[:, 2] * t.gradient(states)[:, 3]) for t in parts])
        split, acting = np.abs(signs.sum(0)) < len(parts), w < 1
        split_count[0] += int((split & acting).sum())
        split_count[1] += int(acting.sum())
        if variant == "map check":  # where they split and the mean's turn hits within CHECK_S, the other if it does not
            turn = np.sign(u[split, 1])
            ours = rollout_clearance(world, states[split], u[split, 0], turn)
            other = rollout_clearance(world, states[split], u[split, 0], -turn)
            u[np.flatnonzero(split)[(ours <= 0) & (other > 0)], 1] *= -1
        else:
            u[split, 1] = 0.0
        if variant == "brake":
            u[split, 0] = np.where(states[split, 2] > p.v_min, -p.a_max, 0.0)
        return w[:, None] * nominal + (1 - w[:, None]) * control_to_twist(p, states, u, fs.dt), acting
    return filt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--model", default="models/default")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--episodes", type=int, default=2000)
    args = ap.parse_args()
    settings = EpisodeSettings()
    every = held_out.load(args.data.split(","), "all", unconverged=True)
    mean, parts = held_out.predict(args.model, every), part_tables(args.model, every)
    print(f"# Turn votes of {args.model}'s six (member, frame) predictions on {args.data}, seed {args.seed}\n")
    print("Offline, sign of ΔθV against the truth's where |V_gt| < 0.3 m and |ΔθV_gt| > 0.01 m "
          f"({len(every)} scenarios):\n\n| predictor | agreement | states |\n| --- | --- | --- |")
    for k, (a, n) in offline(mean, parts, every).items():
        print(f"| {k} | {a / max(n, 1):.4f} | {n} |")
    keep = [i for i, s in enumerate(every) if closed_loop.has_safe_states(s.grid, s.value, settings)]
    card = checkpoint.load_card(args.model)
    fs = FilterSettings(epsilon=float(card["epsilon"]), mode="blend", dt=settings.dt)
    per_world = -(-args.episodes // len(keep))
    rows = {v: {"results": [], "split": [0, 0]} for v in VARIANTS}
    for w, i in enumerate(keep):
        s = every[i]
        world = World(s.name, s.scenario.shapes, ValueTable(s.grid, s.value), s.scenario.dynamics_params())
        table, tables = ValueTable(s.grid, mean[i]), [ValueTable(s.grid, p[i]) for p in parts]
        eps = closed_loop.draw_episodes(world, per_world, settings, seed=args.seed * 100003 + w, first=w * per_world)
        for v, row in rows.items():
            row["results"].append(closed_loop.run_episodes(
                world, eps, make_filter(world, fs, table, tables, v, row["split"]), settings))
    print(f"\nClosed loop, blend mode, ε = {fs.epsilon:.3f} m, {len(keep)} worlds × {per_world} episodes:\n")
    print("| on a split | episodes | collisions | intervention rate | split (of acting decisions) | by world |\n"
          "| --- | --- | --- | --- | --- | --- |")
    for v, row in rows.items():
        r = closed_loop.summarize(row["results"])
        split = f"{row['split'][0]} / {row['split'][1]}" if row["split"][1] else "-"
        by_world = collisions_by_world(row["results"], [every[i] for i in keep])
        where = ", ".join(f"{k} ({n})" for k, n in by_world.items()) or "-"
        print(f"| {v} | {r['episodes']} | {r['collisions']} | {r['intervention_rate']:.3f} | {split} | {where} |")


if __name__ == "__main__":
    main()
