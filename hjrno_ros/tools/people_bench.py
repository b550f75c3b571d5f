"""``hjrno bench people``: brt_node with a laser among pedestrians in IR-SIM, over DDS in real time.

Four pedestrians walk at 0.5–1.0 m/s with IR-SIM's social-force behaviour (they avoid each other, walls and the
robot, as people do, but not always in time): two along the robot's route against it (between its goals), two
between random points of the map. The static map lacks them; the robot's drivers (the Nav2-like follower and the
careless driver of the navigation benchmark) are blind to them. ``brt_node`` gets the static map and IR-SIM's LiDAR
as a ``scan`` observation source at 10 Hz (``obstacle_speed_max`` its default, 1 m/s). Each case also runs without
people, so that goals and time to goal compare with the same episodes on an empty floor.

Reported per (driver, filter, people): collisions split by the robot's speed at contact (IR-SIM's own check; moving:
|v| > 0.02 m/s, else a person walked into a stopped robot), the least gap between the robot's and a person's disks,
goals, time to goal against the same runs without people, and the stopped and fail-closed shares.
"""

from __future__ import annotations

import json
import platform
import time
from pathlib import Path

import numpy as np

from hjrno_ros.core.atomic import atomic_write
from hjrno_ros.core.tables import records_table
from hjrno_ros.studies import navigation as nav
from hjrno_ros.tools.nav_bench import DRIVERS, INTERRUPT, STEP, node_params

MOVING = 0.02  # m/s: the robot moved into the contact above this speed
SCAN_EVERY = 2  # steps of STEP s between LaserScans: 10 Hz
SEED_OFFSET = 7  # the random pedestrians' seed, after the episodes'


def people_for(nav_map: nav.NavMap, robot: nav.Robot, episode: nav.Episode, seed: int) -> tuple:
    """Four pedestrians: two on the robot's route against it, two between random free points."""
    from hjrno_ros.studies.irsim_world import Person

    start, goals = episode.start[:2], episode.goals
    others = nav.draw_episodes(nav_map, robot, 2, 1, seed + SEED_OFFSET)
    people = [Person((goals[0], tuple(start)), speed=0.8), Person((goals[-1], goals[0]), speed=1.0),
              *(Person((e.start[:2], e.goals[0]), speed=0.5 + 0.25 * k) for k, e in enumerate(others))]
    far = [p for p in people if np.hypot(*(np.asarray(p.waypoints[0]) - start)) >= 1.5]  # none on the robot
    return tuple(far)


def run(out: Path, episodes: int = 2, robot_name: str = "jackal", map_name: str = "plan1000001",
        seconds: float = 40.0, model: str | None = None, obstacle_speed_max: float = 1.0, progress=print) -> int:
    """The benchmark; returns 1 when brt_node drove into something.  Rows merge into ``out``/people.json by
    (driver, filter, obstacle_speed_max)."""
    from hjrno_ros.studies.irsim_world import DiffDriveBase, IrSimWorld
    from hjrno_ros.tools.nav_bench import ROOT
    from hjrno_ros.tools.node_process import brt_node_process, free_domain

    model = model or str(ROOT / "models" / "default")
    robot = nav.ROBOTS[robot_name]
    nav_map = nav.floor_plan_map(int(map_name[4:]))
    sd = nav_map.sd
    eps = nav.draw_episodes(nav_map, robot, episodes, 3, 0)
    base = DiffDriveBase(robot.radius, robot.v_max, robot.v_min, robot.omega_max, robot.a_max, robot.alpha_max)

    def world(e: nav.Episode, seed: int, people: bool, lidar: bool) -> IrSimWorld:
        crowd = people_for(nav_map, robot, e, seed) if people else ()
        return IrSimWorld(nav_map.obstacles, nav_map.origin, nav_map.resolution, base, e.start, STEP, lidar=lidar,
                          people=crowd)

    runs: dict[tuple[str, str, bool], list[tuple]] = {}
    domain, started = free_domain(), time.perf_counter()
    params = {**node_params(robot), "observation_sources": "[scan]", "obstacle_speed_max": obstacle_speed_max}
    with brt_node_process(domain, params, model) as (proc, tail):
        for driver_kind in DRIVERS:
            for people in (False, True):
                for name in ("none", "brt_node"):
                    t0, results = time.perf_counter(), []
                    for k, e in enumerate(eps):
                        w = world(e, k, people, lidar=name == "brt_node")
                        driver = nav.GoalDriver(driver_kind, nav_map, robot, e, INTERRUPT, sd)
                        try:
                            if name == "none":
                                r = nav.run_episode(w, driver, nav.no_filter, robot, seconds, STEP)
                            else:
                                r = _drive(w, nav_map, driver, e, domain, seconds, tail)
                            results.append((r, w.contact_speed, w.min_people_clearance))
                        finally:
                            w.close()
                        if proc.poll() is not None:
                            raise RuntimeError(f"brt_node exited: {tail()}")
                    runs[(driver_kind, name, people)] = results
                    progress(f"{driver_kind} {name} people={people}: "
                             f"{sum(r.collided for r, _, _ in results)} collisions "
                             f"({time.perf_counter() - t0:.0f} s)")
    rows = [{**summarize(driver_kind, name, runs[(driver_kind, name, True)], runs[(driver_kind, name, False)]),
             "obstacle_speed_max": obstacle_speed_max if name == "brt_node" else None}
            for driver_kind in DRIVERS for name in ("none", "brt_node")]
    write(Path(out), rows, {"episodes_per_case": episodes, "robot": robot_name, "map": map_name, "seconds": seconds,
                            "model": str(model), "wall_s": round(time.perf_counter() - started)})
    progress(f"wrote {Path(out) / 'people.md'}")
    return int(any(r["collisions_moving"] for r in rows if r["filter"] != "none"))


def _drive(w, nav_map, driver, episode, domain, seconds, tail) -> nav.EpisodeResult:
    from hjrno_ros.ros.harness.irsim_base import drive, episode_result, irsim_base  # rclpy only when it runs

    x0, y0 = episode.start[:2]

    def ready(log) -> bool:
        s, at = log.status, log.status.get("robot") or {}
        return (s.get("state") not in (None, "fail_closed") and abs(at.get("x", 1e9) - x0) < 1e-3
                and abs(at.get("y", 1e9) - y0) < 1e-3)

    try:
        base = drive(domain, lambda context: irsim_base(w, nav_map, driver, STEP, context=context,
                                                       scan_every=SCAN_EVERY), seconds, ready)
    except RuntimeError as err:
        raise RuntimeError(f"{err} (node: {tail()})") from None
    return episode_result(base)


def summarize(driver: str, name: str, with_people: list[tuple], without: list[tuple]) -> dict:
    """One row: the runs among people against the same episodes without them."""
    moving = sum(r.collided and (v is None or v > MOVING) for r, v, _ in with_people)
    ratios = []
    for (r, _, _), (ref, _, _) in zip(with_people, without, strict=True):
        both = min(len(r.reached), len(ref.reached))
        if both:
            ratios.append((r.reached[both - 1], ref.reached[both - 1]))
    steps = sum(r.steps for r, _, _ in with_people)
    return {
        "driver": driver, "filter": name, "episodes": len(with_people),
        "collisions_moving": moving,
        "collisions_stopped": sum(r.collided for r, _, _ in with_people) - moving,
        "collisions_without_people": sum(r.collided for r, _, _ in without),
        "min_gap_to_people_m": round(min(g for _, _, g in with_people), 3),
        "goals": sum(len(r.reached) for r, _, _ in with_people),
        "goals_without_people": sum(len(r.reached) for r, _, _ in without),
        "time_to_goal_vs_no_people": round(sum(a for a, _ in ratios) / sum(b for _, b in ratios), 3) if ratios
        else None,
        "stopped_share": round(sum(r.stopped for r, _, _ in with_people) / max(steps, 1), 3),
        "fail_closed_share": round(sum(r.fail_closed for r, _, _ in with_people) / max(steps, 1), 4),
    }


def write(out: Path, rows: list[dict], run: dict) -> None:
    """Merge ``rows`` into people.json (a rerun replaces its own rows) and render people.md."""
    out.mkdir(parents=True, exist_ok=True)
    key = lambda r: (r["driver"], r["filter"], r["obstacle_speed_max"])  # noqa: E731
    path = out / "people.json"
    old = json.loads(path.read_text())["rows"] if path.is_file() else []
    rows = [r for r in old if key(r) not in {key(n) for n in rows}] + rows
    rows.sort(key=lambda r: (DRIVERS.index(r["driver"]), r["filter"] != "none", r["obstacle_speed_max"] or 0.0))
    report = {"machine": f"{platform.machine()}, Python {platform.python_version()}", "date": time.strftime("%Y-%m-%d"),
              "step_s": STEP, **run, "rows": rows}
    note = (f"`hjrno bench people` on {report['machine']}, {report['date']}: {run['robot']} on {run['map']}, "
            f"{run['episodes_per_case']} episodes per case of {run['seconds']:g} s, 4 social-force pedestrians at "
            "0.5-1.0 m/s (2 on the robot's route against it), IR-SIM's LiDAR at 10 Hz as brt_node's scan source "
            "(obstacle_speed_max per row); none runs lockstep, brt_node over DDS in real time. collisions_moving: "
            f"the robot moved (|v| > {MOVING} m/s) into the contact; collisions_stopped: a person walked into the "
            "robot at rest. min_gap: between the robot's and a person's disks. time to goal: against the same "
            "episodes without people, over the goals both reached.")
    atomic_write(out / "people.json", lambda p: Path(p).write_text(json.dumps(report, indent=1) + "\n"))
    atomic_write(out / "people.md", lambda p: Path(p).write_text(
        "\n".join(["# People benchmark", "", note, "", *records_table(rows, blank_none=True)]) + "\n"))
