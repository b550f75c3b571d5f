"""``hjrno bench nav``: navigation in IR-SIM with and without safety filters, the README's headline table.

Maps: held-out floor plans (the ``plans`` family at seeds the training never used) and Nav2's depot map
(``../shared/maps/depot.yaml``).  Robots: TurtleBot3-class and Jackal-class differential drives
(:data:`hjrno_ros.studies.navigation.ROBOTS`).  Drivers: the Nav2-like ``follower`` (A* + Regulated Pure Pursuit)
and a ``careless`` goal-seeker blind to walls, both interrupted every ``INTERRUPT`` s by a spin in place or a
second of reversing.  Filters, each on the same episodes:

- ``none``, ``stop_zone`` (collision_monitor-style), ``ground_truth`` (the least-restrictive filter on converged HJ
  solves of windows around the robot) and ``learned`` (the same filter on the bundled model's windows, in process):
  lockstep with IR-SIM, one filter decision per 50 ms step;
- ``brt_node``: the node in its own process over DDS, IR-SIM stepped in real time (:mod:`hjrno_ros.ros.harness`).

Per row: collisions (IR-SIM's check), goals reached, goals against those the unfiltered follower reaches without
collision, time to goal against the unfiltered run (goals both reached), share of time stopped, interventions and
the fail-closed share.  Merges its rows into ``nav.json`` (a rerun of a case replaces its rows) and renders
``nav.md``.
"""

from __future__ import annotations

import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

from hjrno_ros.core.atomic import atomic_write
from hjrno_ros.core.safety_filter import FilterSettings
from hjrno_ros.core.tables import records_table
from hjrno_ros.studies import navigation as nav

ROOT = Path(__file__).resolve().parents[2]
DEPOT = ROOT.parent / "shared" / "maps" / "depot.yaml"
PLAN_SEEDS = (1_000_001, 1_000_002)  # held out: the plans datasets draw train seeds from 0, test from 1,000,000
FILTERS = ("none", "stop_zone", "ground_truth", "learned", "brt_node")
DRIVERS = ("follower", "careless")
INTERRUPT = 15.0  # s between spins / reversing
STEP = 0.05  # s
DURATION = {"turtlebot3": 90.0, "jackal": 40.0}  # s per episode: three goals at the robot's speed


def node_params(robot: nav.Robot) -> dict:
    """brt_node's parameters for ``robot`` in the harness (TwistStamped, as Nav2 Jazzy can be set)."""
    return {"robot_model": "diff_drive", "a_max": robot.a_max, "omega_max": robot.omega_max, "v_max": robot.v_max,
            "v_min": robot.v_min, "footprint_radius": robot.radius, "enable_stamped_cmd_vel": True,
            "stop_pub_timeout": 0.5}


def world_for(nav_map: nav.NavMap, robot: nav.Robot, episode: nav.Episode):
    from hjrno_ros.studies.irsim_world import DiffDriveBase, IrSimWorld

    base = DiffDriveBase(robot.radius, robot.v_max, robot.v_min, robot.omega_max, robot.a_max, robot.alpha_max)
    return IrSimWorld(nav_map.obstacles, nav_map.origin, nav_map.resolution, base, episode.start, STEP)


def lockstep_filter(name: str, nav_map: nav.NavMap, sd: np.ndarray, robot: nav.Robot, model: str | Path,
                    cache: dict) -> nav.Filter:
    """One in-process filter; the ground truth's solved windows are shared through ``cache``."""
    settings = FilterSettings(mode="least_restrictive", dt=STEP)
    if name == "none":
        return nav.no_filter
    if name == "stop_zone":
        return nav.stop_zone(nav_map, robot, sd)
    key = (name, nav_map.name, robot.name)
    if key not in cache:
        cache[key] = (nav.solver_windows(robot, nav_map, sd, settings) if name == "ground_truth"
                      else nav.learned_windows(model, robot, nav_map, sd, settings))
    windows = cache[key]
    windows.center = None  # a new episode: recentre (the solved windows stay cached)
    return windows


def run_dds(cases: list, robot: nav.Robot, model: str | Path, duration: float) -> list[nav.EpisodeResult]:
    """brt_node over DDS in real time: one node process for the robot serves every (map, episode, driver) case."""
    from hjrno_ros.ros.harness.irsim_base import drive, episode_result, irsim_base
    from hjrno_ros.tools.node_process import brt_node_process, free_domain

    domain, out = free_domain(), []
    with brt_node_process(domain, node_params(robot), model) as (proc, tail):
        for nav_map, sd, episode, driver_kind in cases:
            world = world_for(nav_map, robot, episode)
            driver = nav.GoalDriver(driver_kind, nav_map, robot, episode, INTERRUPT, sd)
            x0, y0 = episode.start[:2]

            def ready(log, x0=x0, y0=y0) -> bool:
                s = log.status
                at = s.get("robot") or {}
                return (s.get("state") not in (None, "fail_closed") and abs(at.get("x", 1e9) - x0) < 1e-3
                        and abs(at.get("y", 1e9) - y0) < 1e-3 and (s.get("value_grid") or {}).get("center") is not None
                        and np.hypot(s["value_grid"]["center"][0] - x0, s["value_grid"]["center"][1] - y0) < 1e-3)

            try:
                base = drive(domain, lambda context, w=world, d=driver, m=nav_map: irsim_base(w, m, d, STEP,
                                                                                           context=context),
                             duration, ready)
            except RuntimeError as err:
                raise RuntimeError(f"{err} (node: {tail()})") from None
            finally:
                world.close()
            if proc.poll() is not None:
                raise RuntimeError(f"brt_node exited: {tail()}")
            out.append(episode_result(base))
    return out


def summarize(results: list[nav.EpisodeResult], reference: list[nav.EpisodeResult]) -> dict:
    """One row: outcomes of ``results`` against the unfiltered ``reference`` runs of the same episodes."""
    goals = sum(len(r.reached) for r in results)
    clean = sum(len(r.reached) for r in reference if not r.collided)  # the unfiltered driver's goals, no collision
    ratios = []
    for r, ref in zip(results, reference, strict=True):
        both = min(len(r.reached), len(ref.reached))
        if both:
            ratios.append((r.reached[both - 1], ref.reached[both - 1]))
    steps = sum(r.steps for r in results)
    return {
        "episodes": len(results),
        "collisions": sum(r.collided for r in results),
        "goals": goals,
        "goals_possible": sum(r.goals for r in results),
        "goals_vs_clean_none": round(goals / clean, 3) if clean else None,
        "time_to_goal_ratio": round(sum(a for a, _ in ratios) / sum(b for _, b in ratios), 3) if ratios else None,
        "stopped_share": round(sum(r.stopped for r in results) / max(steps, 1), 3),
        "intervention_share": round(sum(r.changed for r in results) / max(steps, 1), 3),
        "fail_closed_share": round(sum(r.fail_closed for r in results) / max(steps, 1), 4),
    }


def nav_map_named(name: str) -> nav.NavMap:
    """``depot`` (Nav2's map, :data:`DEPOT`) or ``planSEED`` (a floor plan), or a ValueError naming both."""
    if name == "depot":
        return nav.map_file_map(DEPOT)
    if name.startswith("plan") and name[4:].isdigit():
        return nav.floor_plan_map(int(name[4:]))
    raise ValueError(f"maps are depot or planSEED (e.g. plan{PLAN_SEEDS[0]}), got {name!r}")


def run(out: Path, episodes: int = 3, robots: tuple[str, ...] = tuple(nav.ROBOTS), maps: tuple[str, ...] = (),
        drivers: tuple[str, ...] = DRIVERS, filters: tuple[str, ...] = FILTERS, model: str | None = None,
        seed: int = 0, seconds: float | None = None, progress=print) -> int:
    """The benchmark; returns 1 when a filtered row collided.  ``seconds``: every episode's length instead of
    :data:`DURATION`."""
    model = model or str(ROOT / "models" / "default")
    maps = maps or (*(f"plan{s}" for s in PLAN_SEEDS), "depot")
    loaded = {name: nav_map_named(name) for name in maps}
    sds = {name: m.sd for name, m in loaded.items()}
    rows, cache, started = [], {}, time.perf_counter()
    for robot_name in robots:
        robot, duration = nav.ROBOTS[robot_name], seconds or DURATION[robot_name]
        for map_name, nav_map in loaded.items():
            eps = nav.draw_episodes(nav_map, robot, episodes, 3, seed)
            for driver_kind in drivers:
                reference = None  # the unfiltered runs every row is compared with
                for name in ("none", *(f for f in filters if f != "none")):
                    t0 = time.perf_counter()
                    if name == "brt_node":
                        results = run_dds([(nav_map, sds[map_name], e, driver_kind) for e in eps], robot, model,
                                          duration)
                    else:
                        results = []
                        for e in eps:
                            world = world_for(nav_map, robot, e)
                            try:
                                filt = lockstep_filter(name, nav_map, sds[map_name], robot, model, cache)
                                driver = nav.GoalDriver(driver_kind, nav_map, robot, e, INTERRUPT, sds[map_name])
                                results.append(nav.run_episode(world, driver, filt, robot, duration, STEP))
                            finally:
                                world.close()
                    reference = reference or results
                    if name not in filters:
                        continue
                    row = {"robot": robot_name, "map": map_name, "driver": driver_kind, "filter": name,
                           "loop": "DDS, real time" if name == "brt_node" else "lockstep",
                           **summarize(results, reference)}
                    rows.append(row)
                    progress(f"{robot_name} {map_name} {driver_kind} {name}: {row['collisions']} collisions, "
                             f"{row['goals']}/{row['goals_possible']} goals, time x{row['time_to_goal_ratio']}, "
                             f"stopped {row['stopped_share']}, fail-closed {row['fail_closed_share']} "
                             f"({time.perf_counter() - t0:.0f} s)")
                    write(out, rows, {"episodes_per_case": episodes, "seed": seed, "model": model,
                                      "durations_s": {r: seconds or DURATION[r] for r in robots},
                                      "wall_s": round(time.perf_counter() - started)})
    progress(f"wrote {out / 'nav.md'}")
    return int(any(r["collisions"] for r in rows if r["filter"] != "none"))


KEY = ("robot", "map", "driver", "filter")


def write(out: Path, rows: list[dict], run: dict) -> None:
    """Merge ``rows`` into ``out``/nav.json (a row per robot, map, driver and filter: a rerun replaces its rows, the
    others stay, with the run that made them) and render nav.md."""
    out.mkdir(parents=True, exist_ok=True)
    path = out / "nav.json"
    old = json.loads(path.read_text())["rows"] if path.is_file() else []
    command = "hjrno bench nav " + " ".join(sys.argv[3:] if sys.argv[1:3] == ["bench", "nav"] else [])
    stamp = {"date": time.strftime("%Y-%m-%d"), "command": command.strip(), **run}
    new = {tuple(r[k] for k in KEY): {**r, "run": stamp} for r in rows}
    merged = [r for r in old if tuple(r[k] for k in KEY) not in new] + list(new.values())
    merged.sort(key=lambda r: (r["robot"], r["map"], r["driver"], FILTERS.index(r["filter"])))
    report = {"machine": f"{platform.machine()}, Python {platform.python_version()}", "step_s": STEP,
              "interrupt_every_s": INTERRUPT, "rows": merged}
    atomic_write(path, lambda p: Path(p).write_text(json.dumps(report, indent=1) + "\n"))
    atomic_write(out / "nav.md", lambda p: Path(p).write_text(markdown(report)))


def markdown(report: dict) -> str:
    cols = ["robot", "map", "driver", "filter", "loop", "episodes", "collisions", "goals", "goals_vs_clean_none",
            "time_to_goal_ratio", "stopped_share", "intervention_share", "fail_closed_share"]
    runs = sorted({(r["run"]["date"], r["run"]["command"], r["run"]["episodes_per_case"]) for r in report["rows"]})
    lines = ["# Navigation benchmark", "",
             f"{report['machine']}; IR-SIM steps of {report['step_s']} s, spins or reversing every "
             f"{report['interrupt_every_s']:g} s; 3 goals per episode.  Goals vs clean none: goals reached against "
             "those the unfiltered driver reaches in episodes without collision; time to goal: against the "
             "unfiltered run, over the goals both reached.  Shares are of 50 ms steps.  Runs: "
             + "; ".join(f"{d} `{c}` ({e} episodes per case)" for d, c, e in runs) + ".", "",
             *records_table(report["rows"], cols, blank_none=True)]
    return "\n".join(lines) + "\n"
