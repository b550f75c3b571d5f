"""``hjrno demo``: a Nav2-like path follower meets an obstacle its map does not have; brt_node keeps it safe.

The robot is a Jackal-class differential drive in IR-SIM (the third-party simulator decides collisions) on a
held-out floor plan.  Its driver plans with A* on the static floor plan and follows the path with Regulated Pure
Pursuit, with Nav2's progress checker and BackUp recovery (then it plans again, on the map as it is: Nav2's global
costmap has seen the obstacle by then).  A box (a cart, 0.6 m) stands on its first path; brt_node's map has it, as
a live costmap would.  The same episode runs twice: without a filter (lockstep with IR-SIM) and with brt_node in
its own process over DDS in real time (the bundled model and its calibrated ε unless told otherwise).  The summary
prints goals reached and collisions of both, interventions and command latency; ``summary.json``, ``demo.png`` and
an animated ``demo.gif`` show the filtered run over the map with the node's BRT slice (orange: where the filter
changed the command).  Exit 1 if the filtered robot collided.  ``--no-filter`` runs (and draws) only the unfiltered
robot, and exits 1 when it collides.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from hjrno_ros.studies import navigation as nav

PLAN_SEED = 1_000_003  # a held-out floor plan
EPISODE_SEED = 4
ROBOT = "jackal"
STEP = 0.05  # s
BOX = 0.6  # m: the obstacle's side
BOX_AT = (0.5, 0.4, 0.6, 0.3, 0.7)  # where on the first path it may stand (share of the path's points)


def demo_episode(seed: int = EPISODE_SEED) -> tuple[nav.NavMap, nav.NavMap, np.ndarray, nav.Robot, nav.Episode]:
    """(the map as it is, the planner's static map, the first's signed distance, robot, episode) of the demo: the box
    stands on the static map's first path, where a way around it remains."""
    static = nav.floor_plan_map(PLAN_SEED)
    robot = nav.ROBOTS[ROBOT]
    episode = nav.draw_episodes(static, robot, 1, 3, seed)[0]
    path = nav.GoalDriver("follower", static, robot, episode).paths[0]
    cells = np.argwhere(np.ones(static.obstacles.shape, bool))
    xy = np.asarray(static.origin) + (cells + 0.5) * static.resolution
    for at in BOX_AT if path is not None else ():
        inside = (np.abs(xy - path[int(at * (len(path) - 1))]) <= BOX / 2).all(1)
        obstacles = static.obstacles.copy()
        obstacles[tuple(cells[inside].T)] = True
        world = nav.NavMap(static.name + "+box", obstacles, static.origin, static.resolution)
        if all(p is not None for p in nav.GoalDriver("follower", world, robot, episode).paths):
            return world, static, world.sd, robot, episode
    raise ValueError(f"demo episode {seed}: no path, or the box blocks every way to a goal")


def driver(world: nav.NavMap, static: nav.NavMap, sd: np.ndarray, robot: nav.Robot,
           episode: nav.Episode) -> nav.GoalDriver:
    return nav.GoalDriver("follower", world, robot, episode, sd=sd, planner_map=static)


def unfiltered(seconds: float, seed: int = EPISODE_SEED) -> nav.EpisodeResult:
    """The episode without a filter, lockstep with IR-SIM."""
    from hjrno_ros.tools.nav_bench import world_for

    world_map, static, sd, robot, episode = demo_episode(seed)
    world = world_for(world_map, robot, episode)
    try:
        return nav.run_episode(world, driver(world_map, static, sd, robot, episode), nav.no_filter, robot, seconds,
                               STEP)
    finally:
        world.close()


def run(out: Path, seconds: float = 60.0, seed: int = EPISODE_SEED, model: str | None = None,
        use_filter: bool = True, gif: bool = True) -> int:
    """Run the demo; print and write the summary and figures; 1 on a collision of the robot shown, else 0."""
    from hjrno_ros.ros.brt_node.value_sources import resolve_model
    from hjrno_ros.ros.harness.irsim_base import drive, episode_result, irsim_base
    from hjrno_ros.studies.plotting import demo_animation
    from hjrno_ros.tools.nav_bench import node_params, world_for
    from hjrno_ros.tools.node_process import brt_node_process, free_domain

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    nav_map, static, sd, robot, episode = demo_episode(seed)
    without = unfiltered(seconds, seed)
    summary = {"map": f"floor plan {PLAN_SEED} (held out), 20 m x 20 m, a {BOX} m box the planner's map lacks",
               "robot": f"{ROBOT}: {robot}", "driver": "A* + Regulated Pure Pursuit + Nav2 BackUp recovery",
               "goals": len(episode.goals), "without_filter": _outcome(without)}
    log = None
    if use_filter:
        stem = resolve_model(model or "")
        domain = free_domain()
        world = world_for(nav_map, robot, episode)
        try:
            with brt_node_process(domain, node_params(robot), stem) as (proc, tail):
                def ready(base_log) -> bool:
                    if proc.poll() is not None:
                        raise RuntimeError(f"brt_node exited with code {proc.returncode}: {tail()}")
                    return base_log.status.get("state") in ("ok", "unsafe_idle")

                base = drive(domain, lambda context: irsim_base(world, nav_map, driver(nav_map, static, sd, robot,
                                                                                      episode), STEP,
                                                               context=context), seconds, ready)
        finally:
            world.close()
        result, log = episode_result(base), base.log
        lat = np.asarray(log.latency_s) * 1e3
        summary["with_brt_node"] = {**_outcome(result), "model": stem.name,
                                    "epsilon": log.status.get("epsilon"), "commands": log.commands,
                                    "latency_ms_p50": round(float(np.percentile(lat, 50)), 2) if lat.size else None,
                                    "latency_ms_p95": round(float(np.percentile(lat, 95)), 2) if lat.size else None,
                                    "value_grids": len(log.grids)}
    summary["wall_s"] = round(time.monotonic() - started, 1)
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    shown = result if use_filter else without
    trace = shown.trace
    states = [tuple(row) for row in trace]
    figure_log = type("FigureLog", (), {"states": states, "grids": log.grids if log else [],
                                        "collided_at": shown.collision_time})()
    figures = demo_animation(out, nav_map.occupancy(), nav_map.resolution, figure_log,
                             np.array(episode.goals), gif=gif, view=10.0, footprint=robot.radius)
    for name, row in summary.items():
        print(f"{name:<16} {row}")
    print("wrote " + ", ".join(str(p) for p in [out / "summary.json", *figures]))
    return 1 if shown.collided else 0


def _outcome(result: nav.EpisodeResult) -> dict:
    trace = result.trace
    driven = float(np.linalg.norm(np.diff(trace[:, 1:3], axis=0), axis=-1).sum()) if len(trace) > 1 else 0.0
    return {"collided": result.collided, "collision_time_s": result.collision_time,
            "goals_reached": len(result.reached), "goal_times_s": [round(t, 1) for t in result.reached],
            "distance_m": round(driven, 2), "interventions": result.changed, "steps": result.steps,
            "stopped_share": round(result.stopped / max(result.steps, 1), 3)}
