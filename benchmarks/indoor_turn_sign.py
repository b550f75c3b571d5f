"""Why a learned filter collides in a room (README, closed loop): on each collided path, was the
filter already acting when V_gt first fell to 0, and did the learned ∂V/∂θ (which picks the turn
of the safe control) have the ground truth's sign over the 2 s before?  Same worlds and episodes as
``hjrno simulate --data data/indoor32c --allow-unconverged --seed SEED`` (switch mode, card's ε).

    .venv/bin/python benchmarks/indoor_turn_sign.py out/models/indoor64_fno_aug out/models/indoor64_fno_aug_d4 \\
        > benchmarks/results/closed_loop_history/indoor_turn_sign_seed2.txt
"""

import argparse

import numpy as np
from hjrno_ros.closed_loop import EpisodeSettings, World
from hjrno_ros.safety_filter import FilterSettings
from hjrno_ros.stop_zone import StopZoneSettings
from hjrno_ros.value_table import ValueTable

from hjrno_ros import checkpoint, closed_loop, filter_study, held_out

BEFORE = 40  # steps (2 s) before V_gt ≤ 0 over which the turn sign is compared


def collided_paths(world: World, table: ValueTable, epsilon: float, episodes, settings) -> list[np.ndarray]:
    choice = filter_study.FilterChoice("learned", "hj", "learned", "switch", epsilon)
    filt = filter_study.make_filter(choice, world, {"learned": table}, StopZoneSettings(), settings.dt,
                                    FilterSettings.decay_rate)
    result = closed_loop.run_episodes(world, episodes, filt, settings, trace=True)
    path, outcome, _ = result["trace"]
    return [p[~np.isnan(p[:, 0])] for p in np.moveaxis(path[:, outcome == "collision"], 1, 0)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="+", help="model stems; the others' signs are also read on the first's paths")
    parser.add_argument("--data", default="data/indoor32c")
    parser.add_argument("--seed", type=int, default=2)
    parser.add_argument("--episodes", type=int, default=500)
    args = parser.parse_args()
    solved = held_out.load([args.data], "fresh", unconverged=True)
    settings, per_world = EpisodeSettings(), -(-args.episodes // len(solved))
    predicted = {stem: held_out.predict(stem, solved) for stem in args.models}
    for stem in args.models:
        card = checkpoint.load_card(stem)
        print(f"== {stem} (eps {card['epsilon']:.3f} m, symmetry_average {card.get('symmetry_average', False)}), "
              f"seed {args.seed}, switch mode")
        for w, s in enumerate(solved):
            world = World(s.name, s.scenario.shapes, ValueTable(s.grid, s.value), s.scenario.dynamics_params())
            tables = {m: ValueTable(s.grid, p[w]) for m, p in predicted.items()}
            episodes = closed_loop.draw_episodes(world, per_world, settings, seed=args.seed * 100003 + w,
                                                 first=w * per_world)
            paths = collided_paths(world, tables[stem], float(card["epsilon"]), episodes, settings)
            print(f"{s.name}: {len(paths)} collisions" + (report(world, tables, stem, float(card["epsilon"]), paths)
                                                         if paths else ""), flush=True)


def report(world: World, tables: dict[str, ValueTable], stem: str, epsilon: float, paths: list[np.ndarray]) -> str:
    """Filter acting at the first V_gt ≤ 0, turn-sign agreement of every model before it, where it happened."""
    acting, agree, where = 0, {m: [] for m in tables}, []
    for path in paths:
        k = int(np.argmax(world.truth.value(path) <= 0))
        acting += bool(k and tables[stem].value(path[k - 1:k])[0] <= epsilon)
        before = path[max(k - BEFORE, 0):k]
        truth_sign = np.sign(world.truth.gradient(before)[:, 3])
        for m, t in tables.items():
            agree[m].append(np.mean(np.sign(t.gradient(before)[:, 3]) == truth_sign) if len(before) else np.nan)
        where.append(path[k])
    signs = ", ".join(f"{m.split('/')[-1]} {np.nanmean(a):.0%}" for m, a in agree.items())
    return (f", filter acting at the first V_gt <= 0: {acting}; dV/dtheta sign as the truth's over the "
            f"{BEFORE * EpisodeSettings().dt:.0f} s before: {signs}; first V_gt <= 0 at (x, y, v, theta) median "
            f"{np.round(np.median(where, axis=0), 2).tolist()}")


if __name__ == "__main__":
    main()
