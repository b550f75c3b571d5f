"""How far IR-SIM's pedestrians depart from their measured velocity: the deviation δ a tracked agent's value tables
must assume (docs/design.md, "Tracked agents").

For every pedestrian and step t of the people benchmark's episodes (the Jackal's follower, unfiltered, lockstep),
the position error of the constant-velocity prediction over s ≤ τ seconds, divided by s: the velocity deviation
that the prediction needs, ‖p(t + s) − p(t) − u(t)·s‖ / s.  Printed per horizon τ: max, 99th and 95th percentile.
Then the walkers' accelerations, ‖u(t + step) − u(t)‖ / step while they walk: the bound a model of a person with
bounded acceleration (the velocity as a state) would need to cover them.

    python -m hjrno_ros.tools.pedestrian_motion [--episodes 2]
"""

from __future__ import annotations

import argparse

import numpy as np

from hjrno_ros.studies import navigation as nav

HORIZONS = (0.5, 1.0, 1.5)  # s: about the Jackal-class base's time to stop (1 s), and either side


def prediction_deviation(positions: np.ndarray, velocities: np.ndarray, step: float, horizon: float) -> np.ndarray:
    """‖p(t + s) − p(t) − u(t)·s‖ / s for s = step, 2·step, … ≤ ``horizon``, over positions and velocities
    ``(T, k, 2)``: every window's needed velocity deviation, m/s, flat."""
    out = []
    for n in range(1, int(round(horizon / step)) + 1):
        error = positions[n:] - positions[:-n] - velocities[:-n] * (n * step)
        out.append(np.linalg.norm(error, axis=-1).ravel() / (n * step))
    return np.concatenate(out)


def accelerations(velocities: np.ndarray, step: float, moving: float = 0.02) -> np.ndarray:
    """‖u(t + step) − u(t)‖ / step, m/s², over velocities ``(T, k, 2)``, for the steps at which the walker moves
    (faster than ``moving`` m/s at either end), flat."""
    speed = np.linalg.norm(velocities, axis=-1)
    walking = (speed[1:] > moving) | (speed[:-1] > moving)
    return (np.linalg.norm(np.diff(velocities, axis=0), axis=-1) / step)[walking]


def tracks(episodes: int, robot_name: str = "jackal", map_seed: int = 1000001) -> list[tuple[np.ndarray, np.ndarray]]:
    """The pedestrians' positions and velocities ``(T, k, 2)`` per episode of the people benchmark."""
    from hjrno_ros.studies.irsim_world import DiffDriveBase, IrSimWorld
    from hjrno_ros.tools.nav_bench import DURATION, INTERRUPT
    from hjrno_ros.tools.people_bench import STEP, people_for

    robot, nav_map = nav.ROBOTS[robot_name], nav.floor_plan_map(map_seed)
    sd = nav_map.sd
    base = DiffDriveBase(robot.radius, robot.v_max, robot.v_min, robot.omega_max, robot.a_max, robot.alpha_max)
    out = []
    for k, e in enumerate(nav.draw_episodes(nav_map, robot, episodes, 3, 0)):
        world = IrSimWorld(nav_map.obstacles, nav_map.origin, nav_map.resolution, base, e.start, STEP, lidar=False,
                           people=people_for(nav_map, robot, e, k))
        positions, velocities = [], []

        def record(state, t, nominal, world=world, positions=positions, velocities=velocities):
            positions.append(world.people_positions.copy())
            velocities.append(world.people_velocities.copy())
            return nominal, False

        try:
            nav.run_episode(world, nav.GoalDriver("follower", nav_map, robot, e, INTERRUPT, sd), record, robot,
                            DURATION[robot_name], STEP)
        finally:
            world.close()
        out.append((np.array(positions), np.array(velocities)))
    return out


def main(argv: list[str] | None = None) -> int:
    from hjrno_ros.tools.people_bench import STEP

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--episodes", type=int, default=2)
    args = p.parse_args(argv)
    runs = tracks(args.episodes)
    print("| horizon s | max m/s | p99 m/s | p95 m/s |\n| --- | --- | --- | --- |")
    for horizon in HORIZONS:
        d = np.concatenate([prediction_deviation(pos, vel, STEP, horizon) for pos, vel in runs])
        print(f"| {horizon:g} | {d.max():.2f} | {np.percentile(d, 99):.2f} | {np.percentile(d, 95):.2f} |")
    a = np.concatenate([accelerations(vel, STEP) for _, vel in runs])
    print("\n| walking steps | max m/s² | p99.9 | p99 | p95 | share above 2 m/s² |\n" + "| --- " * 6 + "|")
    print(f"| {a.size} | {a.max():.1f} | {np.percentile(a, 99.9):.1f} | {np.percentile(a, 99):.1f} | "
          f"{np.percentile(a, 95):.1f} | {np.mean(a > 2):.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
