"""``hjrno bench depot``: brt_node on Nav2's depot map, careless drivers over DDS in real time.

The map is ``../shared/maps/depot.{pgm,yaml}`` beside the checkout (Nav2's nav2_bringup depot map,
Apache-2.0), loaded as map_server does (:mod:`hjrno_ros.core.map_file`).  brt_node runs in its own
process (the bundled model and its calibrated ε unless told otherwise) and serves every episode;
:mod:`hjrno_ros.ros.harness.episode_driver` resets a simulated point robot between episodes.  Starts are drawn
in the free space at least ``CLEARANCE`` from obstacles (the largest connected part of it), at rest,
and the drivers take turns: ``straight`` (v_max, headed for an obstacle cell within 5 m), ``edge``
(v_max, pointed at the nearest map edge: an attempt to drive off the map), ``goal`` (the demo's
goal-seeking twist to goals ≥ 3 m apart whose straight path crosses an obstacle where one can be
found) and ``goal_off_map`` (the same, to a goal 2 m beyond the nearest edge).

Counted per episode: a collision (the robot's position inside an occupied or unknown cell, i.e. an
exact clearance ≤ 0 for a point robot), a map exit (its position beyond the map's edge), the minimum
exact clearance to the obstacle cells and the map's edge, distance, interventions and command latency.
Writes ``depot.md`` and ``depot.json``; returns 1 when any episode collided or left the map.
"""

from __future__ import annotations

import json
import math
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

from hjrno_ros.core.atomic import atomic_write
from hjrno_ros.core.geometry import occupancy_signed_distance, occupancy_to_mask
from hjrno_ros.core.map_file import MapFile, load_map
from hjrno_ros.core.tables import markdown_table

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_MAP = ROOT.parent / "shared" / "maps" / "depot.yaml"
DRIVERS = ("straight", "edge", "goal", "goal_off_map")  # hjrno_ros.ros.harness.episode_driver.DRIVERS (rclpy-free here)
CLEARANCE = 0.5  # m: starts and goals at least this far from obstacles and the map's edge
MIN_GOAL_DISTANCE = 3.0  # m
GOALS = 4  # goals per goal episode, visited in turn
BEYOND_EDGE = 2.0  # m: goal_off_map's goal lies this far beyond the nearest edge
AIM_RANGE = 5.0  # m: straight episodes head for an obstacle cell this close (else a random heading)
OBSTACLE_THRESHOLD = 50  # brt_node's occupied_threshold default; the depot map holds only 0, 100


class DepotWorld:
    """The map's obstacle cells (occupied or unknown), their signed distance and exact clearances."""

    def __init__(self, m: MapFile) -> None:
        self.map = m
        self.resolution, self.origin = m.resolution, np.asarray(m.origin, float)
        self.obstacle = occupancy_to_mask(m.occupancy, OBSTACLE_THRESHOLD, True)
        self.sd = occupancy_signed_distance(m.occupancy, m.resolution, OBSTACLE_THRESHOLD, True)  # edge included
        self.extent = self.origin + np.asarray(m.occupancy.shape) * m.resolution
        free = self.sd >= CLEARANCE
        labels, n = ndimage.label(free)
        if n == 0:
            raise ValueError(f"{m.image}: no free space {CLEARANCE:g} m from obstacles")
        sizes = ndimage.sum_labels(free, labels, np.arange(1, n + 1))
        self.free_cells = np.argwhere(labels == 1 + int(np.argmax(sizes)))  # the largest connected part
        self.obstacle_cells = np.argwhere(self.obstacle)

    def centre(self, cells: np.ndarray) -> np.ndarray:
        return self.origin + (np.asarray(cells) + 0.5) * self.resolution

    def edge_distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance to the map's edge (> 0 inside the map)."""
        p = np.asarray(points, float)
        return np.minimum(p - self.origin, self.extent - p).min(-1)

    def clearance(self, points: np.ndarray, reach: float = 1.0) -> np.ndarray:
        """Exact distance (m) of points (n, 2) to the nearest obstacle cell (as a square) or the map's edge;
        ≤ 0 inside an obstacle cell or beyond the edge.  Beyond ``reach`` the raster's signed distance."""
        p = np.asarray(points, float).reshape(-1, 2)
        h = self.resolution
        out = self.edge_distance(p)
        r = int(math.ceil(reach / h)) + 1
        n = np.asarray(self.obstacle.shape)
        for k, q in enumerate(p):
            if out[k] <= 0:
                continue
            ij = np.floor((q - self.origin) / h).astype(int)
            lo, hi = np.clip(ij - r, 0, n), np.clip(ij + r + 1, 0, n)
            cells = np.argwhere(self.obstacle[lo[0]:hi[0], lo[1]:hi[1]]) + lo
            if len(cells) == 0:
                out[k] = min(out[k], max(reach, float(self.sd[tuple(np.clip(ij, 0, n - 1))])))
                continue
            gap = np.maximum(np.abs(q - self.centre(cells)) - h / 2, 0.0)
            out[k] = min(out[k], float(np.hypot(gap[:, 0], gap[:, 1]).min()))
        return out

    def crosses_obstacle(self, a: np.ndarray, b: np.ndarray) -> bool:
        seg = a + np.linspace(0.0, 1.0, max(int(np.linalg.norm(b - a) / (self.resolution / 2)), 2))[:, None] * (b - a)
        ij = np.floor((seg - self.origin) / self.resolution).astype(int)
        inside = np.all((ij >= 0) & (ij < self.obstacle.shape), axis=1)
        return bool((~inside).any() or self.obstacle[ij[inside, 0], ij[inside, 1]].any())


def draw_episodes(world: DepotWorld, n: int, seed: int = 0) -> list[dict]:
    """``n`` episodes: {"driver", "start": (x, y, 0, θ), "goals": [(x, y), ...]}; drivers take turns."""
    rng = np.random.default_rng([seed, 43])
    cells = world.free_cells
    lo, hi = world.origin, world.extent
    episodes = []
    for i in range(n):
        driver = DRIVERS[i % len(DRIVERS)]
        xy = world.centre(cells[rng.integers(len(cells))])
        theta, goals = float(rng.uniform(-np.pi, np.pi)), []
        gaps = np.array([xy[0] - lo[0], hi[0] - xy[0], xy[1] - lo[1], hi[1] - xy[1]])  # west, east, south, north
        side = int(np.argmin(gaps))
        if driver == "straight":  # aimed at an obstacle cell within AIM_RANGE, where there is one
            near = world.obstacle_cells[np.linalg.norm(world.centre(world.obstacle_cells) - xy, axis=1) <= AIM_RANGE]
            if len(near):
                d = world.centre(near[rng.integers(len(near))]) - xy
                theta = float(np.arctan2(d[1], d[0]))
        elif driver == "edge":
            theta = (np.pi, 0.0, -np.pi / 2, np.pi / 2)[side]
        elif driver == "goal":
            prev = xy
            for _ in range(GOALS):
                pick = None
                for attempt in range(200):  # prefer goals behind an obstacle: a careless line would hit it
                    g = world.centre(cells[rng.integers(len(cells))])
                    if np.linalg.norm(g - prev) < MIN_GOAL_DISTANCE:
                        continue
                    pick = g
                    if world.crosses_obstacle(prev, g) or attempt > 150:
                        break
                goals.append(pick if pick is not None else world.centre(cells[rng.integers(len(cells))]))
                prev = goals[-1]
        elif driver == "goal_off_map":
            along = float(rng.uniform(-3.0, 3.0))
            g = xy.copy()
            axis = 0 if side < 2 else 1
            g[axis] = (lo[0] - BEYOND_EDGE, hi[0] + BEYOND_EDGE, lo[1] - BEYOND_EDGE, hi[1] + BEYOND_EDGE)[side]
            g[1 - axis] = np.clip(g[1 - axis] + along, lo[1 - axis], hi[1 - axis])
            goals.append(g)
        episodes.append({"driver": driver, "start": [float(xy[0]), float(xy[1]), 0.0, theta],
                         "goals": [[float(g[0]), float(g[1])] for g in goals]})
    return episodes


def episode_row(i: int, episode: dict, log, world: DepotWorld) -> dict:
    """One episode's numbers from its log (see :class:`hjrno_ros.ros.harness.episode_driver.EpisodeLog`)."""
    states = np.array([s[1:5] for s in log.trace]) if log.trace else np.zeros((0, 4))
    clear = world.clearance(states[:, :2]) if len(states) else np.array([world.clearance(
        np.asarray(episode["start"][:2])[None])[0]])
    lat = np.asarray(log.latency_s) * 1e3
    return {
        "episode": i, "driver": episode["driver"], "start": [round(v, 3) for v in episode["start"]],
        "outcome": log.outcome or "ok", "collision": log.outcome == "collision", "exit": log.outcome == "exit",
        "driven_s": round(log.trace[-1][0], 2) if log.trace else 0.0,
        "distance_m": round(float(np.linalg.norm(np.diff(states[:, :2], axis=0), axis=-1).sum()), 2),
        "min_clearance_m": round(float(clear.min()), 3),
        "final_xy": [round(float(v), 3) for v in states[-1, :2]] if len(states) else None,
        "goals_reached": len(log.goals),
        "commands": log.commands, "interventions": log.changed,
        "latency_ms_p50": round(float(np.percentile(lat, 50)), 2) if lat.size else None,
        "latency_ms_p95": round(float(np.percentile(lat, 95)), 2) if lat.size else None,
        "ready_s": round(log.ready_s, 2),
        "start_value_m": None if log.start_value is None else round(log.start_value, 3),
    }


def summarize(rows: list[dict]) -> dict:
    """Totals over episodes: counts, clearance, distance, intervention rate, latency (from the rows)."""
    def block(rs: list[dict]) -> dict:
        commands = sum(r["commands"] for r in rs)
        p50 = [r["latency_ms_p50"] for r in rs if r["latency_ms_p50"] is not None]
        p95 = [r["latency_ms_p95"] for r in rs if r["latency_ms_p95"] is not None]
        return {
            "episodes": len(rs),
            "collisions": sum(r["collision"] for r in rs),
            "exits": sum(r["exit"] for r in rs),
            # starts the node's V already puts in the unsafe set (V <= 0), and the collisions among them
            "starts_v_le_0": sum(r["start_value_m"] is not None and r["start_value_m"] <= 0 for r in rs),
            "collisions_from_v_le_0": sum(r["collision"] and r["start_value_m"] is not None
                                          and r["start_value_m"] <= 0 for r in rs),
            "min_clearance_m": min(r["min_clearance_m"] for r in rs),
            "clearance_p05_m": round(float(np.percentile([r["min_clearance_m"] for r in rs], 5)), 3),
            "mean_distance_m": round(float(np.mean([r["distance_m"] for r in rs])), 2),
            "intervention_rate": round(sum(r["interventions"] for r in rs) / max(commands, 1), 3),
            "goals_reached": sum(r["goals_reached"] for r in rs),
            "latency_ms_p50_median": round(float(np.median(p50)), 2) if p50 else None,
            "latency_ms_p95_max": round(float(max(p95)), 2) if p95 else None,
        }

    totals = block(rows)
    per_driver = {d: block([r for r in rows if r["driver"] == d]) for d in DRIVERS
                  if any(r["driver"] == d for r in rows)}
    return {"totals": totals, "per_driver": per_driver}


def markdown(summary: dict, note: str) -> str:
    keys = ["episodes", "collisions", "exits", "starts_v_le_0", "collisions_from_v_le_0", "min_clearance_m",
            "clearance_p05_m", "mean_distance_m",
            "intervention_rate", "goals_reached", "latency_ms_p50_median", "latency_ms_p95_max"]
    rows = [*summary["per_driver"].items(), ("**all**", summary["totals"])]
    lines = ["# Depot map check", "", note, "",
             *markdown_table(["driver", *keys], ([name, *(row[k] for k in keys)] for name, row in rows))]
    return "\n".join(lines) + "\n"


def run(out: Path, episodes: int = 200, seconds: float = 12.0, seed: int = 0, model: str | None = None,
        map_path: str | Path | None = None, quiet: bool = False) -> int:
    """Run the check; print and write depot.md / depot.json; 1 if any episode collided or left the map."""
    from hjrno_ros.core.model_card import ModelCard
    from hjrno_ros.ros.brt_node.value_sources import resolve_model
    from hjrno_ros.ros.harness.episode_driver import run_episodes  # rclpy only when the check runs
    from hjrno_ros.tools.node_process import brt_node_process, free_domain

    if episodes < 1 or not seconds > 0:
        raise ValueError(f"need episodes >= 1 and seconds > 0, got {episodes} and {seconds}")
    map_path = Path(map_path) if map_path else DEFAULT_MAP
    if not map_path.is_file():
        raise ValueError(f"{map_path}: map not found (the depot map lives in ../shared/maps beside the checkout)")
    world = DepotWorld(load_map(map_path))
    plan = draw_episodes(world, episodes, seed)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    stem = resolve_model(model or "")
    card = ModelCard.load(stem)
    node_params = {"enable_stamped_cmd_vel": True, "model_path": str(stem)}
    domain = free_domain()
    robot = {"obstacle": world.obstacle, "occupancy": world.map.occupancy, "resolution": world.resolution,
             "origin": tuple(world.origin), "params": card.dynamics, "seed": seed}
    rows: list[dict] = []
    status: dict = {}
    started = time.monotonic()

    def done(i: int, log) -> None:
        rows.append(episode_row(i, plan[i], log, world))
        status.update(log.status)
        r = rows[-1]
        if not quiet:
            print(f"episode {i + 1:>3}/{episodes} {r['driver']:<12} {r['outcome']:<9} clearance "
                  f"{r['min_clearance_m']:6.3f} m, {r['distance_m']:5.2f} m, {r['interventions']}/{r['commands']} "
                  f"interventions", flush=True)

    with brt_node_process(domain, node_params) as (proc, log_tail):
        def check() -> None:
            if proc.poll() is not None:
                raise RuntimeError(f"brt_node exited with code {proc.returncode}: {log_tail()}")

        try:
            run_episodes(domain, robot, plan, seconds, check, done=done)
        except RuntimeError as err:
            raise RuntimeError(f"depot check failed after {len(rows)} episode(s): {err} (node log: {log_tail()})"
                               ) from None
    wall = time.monotonic() - started
    summary = summarize(rows)
    machine = f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
    shown = os.path.relpath(map_path, ROOT) if map_path.is_relative_to(ROOT.parent) else map_path.name
    model_shown = os.path.relpath(stem, ROOT) if Path(stem).resolve().is_relative_to(ROOT) else Path(stem).name
    m = world.map
    note = (f"`hjrno bench depot --episodes {episodes} --seconds {seconds:g}` on {machine}, "
            f"{time.strftime('%Y-%m-%d')}, {wall / 60:.1f} min: map `{shown}` ({m.occupancy.shape[0]} x "
            f"{m.occupancy.shape[1]} cells at {m.resolution:g} m, loaded as map_server does), brt_node in its own "
            f"process ({model_shown}, epsilon {status.get('epsilon', '?')} m, {status.get('filter_mode', '?')}), "
            f"a simulated point robot (the model's car, random disturbance <= {card.dynamics.tracking_error:g}|v| + "
            f"{card.dynamics.d0:g} m/s) over Fast "
            f"DDS in real time, {seconds:g} s per episode, starts at rest >= {CLEARANCE:g} m from obstacles, seed "
            f"{seed}. Drivers in turn: straight (v_max, headed for an obstacle cell within {AIM_RANGE:g} m), edge "
            "(v_max toward the nearest map edge), "
            f"goal (the demo's goal-seeking twist, goals behind obstacles), goal_off_map (a goal {BEYOND_EDGE:g} m "
            "beyond the nearest edge). A collision: the robot's position in an occupied or unknown cell; an exit: "
            "beyond the map's edge; clearance: exact distance to the obstacle cells and the edge.")
    result = {"machine": machine, "note": note, "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
              "command": f"hjrno bench depot --episodes {episodes} --seconds {seconds:g}", "seed": seed,
              "wall_s": round(wall, 1), "map": {"file": shown, "cells": list(m.occupancy.shape),
                                                "resolution": m.resolution, "origin": list(m.origin)},
              "model": model_shown, "epsilon": status.get("epsilon"), **summary, "episodes": rows}
    text = markdown(summary, note)
    atomic_write(out / "depot.json", lambda p: Path(p).write_text(json.dumps(result, indent=1) + "\n"))
    atomic_write(out / "depot.md", lambda p: Path(p).write_text(text))
    t = summary["totals"]
    print(f"depot: {t['episodes']} episodes, {t['collisions']} collisions, {t['exits']} map exits, min clearance "
          f"{t['min_clearance_m']} m, intervention rate {t['intervention_rate']} ({wall:.0f} s)")
    print(f"wrote {out / 'depot.md'}, {out / 'depot.json'}", file=sys.stdout)
    return 1 if t["collisions"] or t["exits"] else 0
