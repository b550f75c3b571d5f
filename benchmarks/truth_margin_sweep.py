"""Sweep of the ground-truth filter's margin δ (README, closed loop): 35 held-out worlds × 8 episodes.

    .venv/bin/python benchmarks/truth_margin_sweep.py > benchmarks/results/closed_loop_history/truth_margin_sweep.txt
"""

from hjrno_ros.closed_loop import EpisodeSettings, World
from hjrno_ros.stop_zone import StopZoneSettings
from hjrno_ros.value_table import ValueTable

from hjrno_ros import closed_loop, filter_study, held_out


def main(folders=("data/single32", "data/two32"), per_world: int = 8) -> None:
    solved = held_out.load(list(folders), "fresh")
    settings = EpisodeSettings()
    worlds = [World(s.name, s.scenario.shapes, ValueTable(s.grid, s.value), s.scenario.dynamics_params())
              for s in solved]
    episodes = [closed_loop.draw_episodes(w, per_world, settings, seed=i, first=i * per_world)
                for i, w in enumerate(worlds)]
    for mode in ("switch", "blend"):
        for eps in (0.0, 0.05, 0.1, 0.15, 0.2, 0.3):
            choice = filter_study.FilterChoice("truth", "hj", filter_study.TRUTH, mode, eps)
            results, hit = [], []
            for w, ep in zip(worlds, episodes, strict=True):
                filt = filter_study.make_filter(choice, w, {filter_study.TRUTH: w.truth}, StopZoneSettings(),
                                                settings.dt)
                results.append(closed_loop.run_episodes(w, ep, filt, settings))
                if (results[-1]["outcome"] == "collision").any():
                    hit.append(w.name)
            row = closed_loop.summarize(results)
            print(mode, "eps", eps, "collisions", row["collisions"], "of", row["episodes"],
                  f"intervention {row['intervention_rate']:.4f}", hit, flush=True)


if __name__ == "__main__":
    main()
