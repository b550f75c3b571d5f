"""``hjrno demo``: brt_node keeps a careless simulated robot safe, live over ROS 2 topics.

brt_node runs in its own process (the bundled model and its calibrated ε unless told otherwise);
:class:`hjrno_ros.ros.sim_robot.SimRobot` runs here: it latches a 24 m × 24 m map of random smooth
obstacles, publishes odometry, and drives a goal-seeking command stream that ignores obstacles
(each goal lies beyond one) while integrating the dynamic Dubins car with the filtered command
and a random disturbance.  After ``seconds`` of driving it prints a summary (collisions,
interventions, command latency), writes ``summary.json``, ``demo.png`` and an animated
``demo.gif`` of the trajectory over the map with the node's BRT slice overlaid, and returns 1 if
the robot collided (0 otherwise).  ``--no-filter`` drives the same robot without brt_node.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from hjrno_ros.core.geometry import rasterize, union_sdf
from hjrno_ros.core.model_card import ModelCard
from hjrno_ros.truth.scenarios import random_smooth_shape

MAP_SIZE = 24.0  # m, square, centred on the origin
RESOLUTION = 0.05  # m
ARENA = 6.0  # m: obstacles, goals and the start lie in [-ARENA, ARENA]²: robot-centred 10 m windows stay in the map
FOOTPRINT = 0.25  # m: the robot's radius (a base 0.5 m across), drawn to the map's scale and given to brt_node


def demo_world(seed: int = 0, obstacles: int = 6) -> tuple[list, np.ndarray, np.ndarray, np.ndarray]:
    """(shapes, occupancy [ix, iy] in {0, 100}, start (x, y, v, θ), goals (k, 2)) of a random arena."""
    rng = np.random.default_rng([seed, 7])
    shapes, centers = [], []
    while len(shapes) < obstacles:
        c = rng.uniform(-ARENA + 1.5, ARENA - 1.5, 2)
        if all(np.linalg.norm(c - o) > 3.2 for o in centers):
            centers.append(c)
            shapes.append(random_smooth_shape(rng, tuple(c), (0.5, 1.1)))
    cells = int(round(MAP_SIZE / RESOLUTION))
    origin = (-MAP_SIZE / 2, -MAP_SIZE / 2)
    mask = np.zeros((cells, cells), bool)
    for s, c in zip(shapes, centers, strict=True):  # each blob lies within 1.1 m of its centre
        i0, j0 = (int((c[k] - 1.2 - origin[k]) / RESOLUTION) for k in (0, 1))
        n = int(2.4 / RESOLUTION) + 1
        corner = (origin[0] + i0 * RESOLUTION, origin[1] + j0 * RESOLUTION)
        mask[i0:i0 + n, j0:j0 + n] |= rasterize(s, corner, RESOLUTION, (n, n))
    goals = []
    while len(goals) < 8:  # each goal lies behind an obstacle as seen from the previous one
        g = rng.uniform(-ARENA + 0.5, ARENA - 0.5, 2)
        if union_sdf(shapes, g[None])[0] < 1.0 or (goals and np.linalg.norm(g - goals[-1]) < 5.0):
            continue
        if goals:
            seg = goals[-1] + np.linspace(0, 1, 50)[:, None] * (g - goals[-1])
            if union_sdf(shapes, seg).min() > 0:
                continue
        goals.append(g)
    start = np.array([*goals[0], 0.0, rng.uniform(-np.pi, np.pi)])
    return shapes, np.where(mask, 100, 0).astype(np.int8), start, np.array(goals[1:])


def run(out: Path, seconds: float = 40.0, seed: int = 0, model: str | None = None, use_filter: bool = True,
        gif: bool = True) -> int:
    """Run the demo; print and write the summary and figures; 1 on collision, else 0."""
    from hjrno_ros.ros.model_files import resolve_model
    from hjrno_ros.ros.sim_robot import drive
    from hjrno_ros.tools.node_process import brt_node_process, free_domain

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    stem = resolve_model(model or "")
    params = ModelCard.load(stem).dynamics
    shapes, occupancy, start, goals = demo_world(seed)
    domain = free_domain()
    robot = {"shapes": shapes, "params": params, "occupancy": occupancy, "resolution": RESOLUTION,
             "origin": (-MAP_SIZE / 2, -MAP_SIZE / 2), "start": start, "goals": goals, "seed": seed,
             "direct": not use_filter, "footprint": FOOTPRINT}
    started = time.monotonic()
    if use_filter:
        node_params = {"enable_stamped_cmd_vel": True, "model_path": str(stem), "footprint_radius": FOOTPRINT}
        with brt_node_process(domain, node_params) as (proc, log_tail):
            def ready(log) -> bool:
                if proc.poll() is not None:
                    raise RuntimeError(f"brt_node exited with code {proc.returncode}: {log_tail()}")
                return log.status.get("state") == "ok"

            log = drive(domain, robot, seconds, ready)
    else:
        log = drive(domain, robot, seconds, lambda _: True)
    summary = summarize(log, shapes, use_filter, stem, seed, time.monotonic() - started)
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    from hjrno_ros.studies.plotting import demo_animation

    figures = demo_animation(out, occupancy, RESOLUTION, log, goals, gif=gif, footprint=FOOTPRINT)
    print("\n".join(f"{k:<24} {v}" for k, v in summary.items()))
    print("wrote " + ", ".join(str(p) for p in [out / "summary.json", *figures]))
    return 1 if summary["collided"] else 0


def summarize(log, shapes: list, use_filter: bool, stem: Path, seed: int, wall_s: float) -> dict:
    states = np.array([s[1:5] for s in log.states]) if log.states else np.zeros((0, 4))
    lat = np.asarray(log.latency_s) * 1e3
    pct = (lambda q: round(float(np.percentile(lat, q)), 2) if lat.size else None)  # noqa: E731
    return {
        "filter": f"brt_node ({stem.name}, eps {log.status.get('epsilon', '?')})" if use_filter else "none",
        "seed": seed,
        "driven_s": round(log.states[-1][0], 1) if log.states else 0.0,
        "collided": log.collided_at is not None,
        "collision_time_s": None if log.collided_at is None else round(log.collided_at, 2),
        "goals_reached": len(log.goals),
        "distance_m": round(float(np.linalg.norm(np.diff(states[:, :2], axis=0), axis=-1).sum()), 2),
        "footprint_m": FOOTPRINT,
        "min_clearance_m": round(float(union_sdf(shapes, states[:, :2]).min()) - FOOTPRINT, 3) if len(states) else None,
        "commands": log.commands,
        "interventions": log.interventions,
        "intervention_rate": round(log.interventions / max(log.commands, 1), 3),
        "latency_ms_p50": pct(50),
        "latency_ms_p95": pct(95),
        "latency_ms_p99": pct(99),
        "value_grids": len(log.grids),
        "wall_s": round(wall_s, 1),
    }
