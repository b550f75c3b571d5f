"""``hjrno bench people``: brt_node with a laser, and with tracked agents, among pedestrians in IR-SIM, over DDS.

Four pedestrians walk at 0.5–1.0 m/s with IR-SIM's social-force behaviour (they avoid each other, walls and the
robot, as people do, but not always in time): two along the robot's route against it (turning up to 1 m short
of its goals: :func:`turning_points`), two between random points of the map. The static map lacks them; the
robot's drivers (the Nav2-like follower and the careless driver of the navigation benchmark) are blind to them;
``--drivers replanning`` adds the follower that plans around its LiDAR's returns every second, as Nav2's does.
``brt_node`` gets the static map and IR-SIM's LiDAR as a ``scan`` observation source at 10 Hz
(``obstacle_speed_max`` its default, 1 m/s); ``brt_node+tracker``'s scan source also tracks people on its returns
(``track_people``: core/scan_tracker.py); ``brt_node+agents`` gets the pedestrians as tracked agents instead (a
perfect tracker: IR-SIM's positions and velocities, PointCloud2 at 10 Hz); both with the robot's relative value
tables (docs/design.md, "Tracked agents"). The baseline ``stop_zone`` is collision_monitor's stop polygon and approach
model, seeing the people exactly. Each case also runs without people, so that goals and time to goal compare with
the same episodes on an empty floor.

Reported per (driver, filter, people): collisions split by the robot's speed at contact (IR-SIM's own check; moving:
|v| > 0.02 m/s, else a person walked into a stopped robot), the least gap between the robot's and a person's disks
(over all steps, and over the steps the robot moved in), goals, time to goal against the same runs without people,
and the stopped and fail-closed shares.  A moving contact ends the episode.  A person walking into the robot at rest
does not by default (``after_rest_contact="continue"``): they walk on, as people who bump into a robot do, and the
robot goes on once they are off it; ``"end"`` ends the episode at any contact, as IR-SIM's stop mode does.
"""

from __future__ import annotations

import contextlib
import json
import math
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np

from hjrno_ros.core.atomic import atomic_write
from hjrno_ros.core.stop_zone import StopZoneSettings, stop_zone_filter
from hjrno_ros.core.tables import records_table
from hjrno_ros.studies import navigation as nav
from hjrno_ros.studies.irsim_world import REST_SPEED
from hjrno_ros.tools.nav_bench import INTERRUPT, STEP, node_params

MOVING = REST_SPEED  # m/s: the robot moved into the contact above this speed
SCAN_EVERY = 2  # steps of STEP s between LaserScans: 10 Hz
SEED_OFFSET = 7  # the random pedestrians' seed, after the episodes'
TURN_SHORT = 1.0  # m: the walkers on the robot's route turn this far short of its goals and start
WALKER_CLEARANCE = 0.4  # m: a turning point's least distance to a wall
DEFAULT_MAP = "plan1000001"  # a held-out floor plan; ``depot`` is Nav2's map
AGENTS_TOPIC = "tracked_agents"  # brt_node+agents: IR-SIM's pedestrians as a perfect tracker's PointCloud2
SCAN_TIMEOUT = 0.5  # s: the scan source's default timeout
AFTER_REST_CONTACT = ("continue", "end")  # a person walked into the robot at rest: the episode goes on, or ends


class PeopleRun(NamedTuple):
    """One episode and what the world saw of its contacts."""

    result: nav.EpisodeResult
    contact_speed: float | None  # m/s, the crash's (None: no crash)
    min_gap: float  # m between the robot's and a person's disks, every step
    min_gap_moving: float  # the same over the steps the robot moved in
    rest_contacts: int  # people who walked into the robot at rest and walked on


def turning_points(a: tuple[float, float], b: tuple[float, float], clearance: Callable[[np.ndarray], np.ndarray],
                   short: float = TURN_SHORT) -> tuple[tuple[float, float], tuple[float, float]]:
    """A walker's turning points on the segment a–b, up to ``short`` m inside each end (at most a third of the
    segment; less where the point would lie within WALKER_CLEARANCE of a wall, the end itself at worst): a walker
    whose turning point is the robot's goal stands beside the robot as long as the robot is there (its social force
    pushes it off the robot, its goal pulls it back), and the robot waits for it: neither moves."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    length = float(np.linalg.norm(b - a))
    if length == 0:
        return tuple(map(float, a)), tuple(map(float, b))
    unit = (b - a) / length

    def inside(end: np.ndarray, direction: np.ndarray) -> tuple[float, float]:
        for d in np.linspace(min(short, length / 3), 0.0, 6):
            point = end + d * direction
            if d == 0 or float(clearance(point[None])[0]) >= WALKER_CLEARANCE:
                break
        return tuple(map(float, point))

    return inside(a, unit), inside(b, -unit)


def people_for(nav_map: nav.NavMap, robot: nav.Robot, episode: nav.Episode, seed: int) -> tuple:
    """Four pedestrians: two on the robot's route against it (turning short of its goals), two between random free
    points."""
    from hjrno_ros.studies.irsim_world import Person

    start, goals = episode.start[:2], episode.goals
    others = nav.draw_episodes(nav_map, robot, 2, 1, seed + SEED_OFFSET)
    clearance = nav_map.clearance(nav_map.sd)
    people = [Person(turning_points(goals[0], tuple(start), clearance), speed=0.8),
              Person(turning_points(goals[-1], goals[0], clearance), speed=1.0),
              *(Person((e.start[:2], e.goals[0]), speed=0.5 + 0.25 * k) for k, e in enumerate(others))]
    far = [p for p in people if np.hypot(*(np.asarray(p.waypoints[0]) - start)) >= 1.5]  # none on the robot
    return tuple(far)


FILTERS = ("none", "stop_zone", "brt_node", "brt_node+tracker", "brt_node+agents")
TABLES = ("brt_node+tracker", "brt_node+agents")  # the filters that read the agent tables
DRIVERS = ("follower", "careless", "replanning")  # replanning: the follower with the LiDAR in its planner's costmap
BLIND = ("follower", "careless")  # the default: drivers blind to people


def run(out: Path, episodes: int = 2, robot_name: str = "jackal", map_name: str = DEFAULT_MAP,
        seconds: float | None = None, model: str | None = None, obstacle_speed_max: float = 1.0,
        scan_timeout: float = SCAN_TIMEOUT, after_rest_contact: str = "continue",
        filters: tuple[str, ...] = FILTERS, agent_table: str | None = None, progress=print,
        drivers: tuple[str, ...] = BLIND) -> int:
    """The benchmark; returns 1 when brt_node drove into something.  Rows merge into ``out``/people.json by
    (driver, filter, obstacle_speed_max, agent_deviation, scan_timeout, after_rest_contact), one file per robot and
    map (:func:`results_stem`).  ``after_rest_contact``: ``continue`` (a person who walked into the robot at rest
    walks on and the episode goes on) or ``end``.  ``scan_timeout``: the scan source's timeout, s, which the motion
    margin covers.
    ``map_name``: ``depot`` or ``planSEED`` (``nav_bench.nav_map_named``).  ``seconds`` per episode: the
    navigation benchmark's for the robot.  ``agent_table``: the tracked agents' tables (default: the bundled
    ``agents_<robot>``).  ``drivers``: the drivers blind to people by default; ``replanning`` is the follower with
    the LiDAR's returns marked in its planner's map, planning again every second (Nav2's planner on a global
    costmap with an obstacle layer)."""
    from hjrno_ros.core.tracked_agents import read_agent_table
    from hjrno_ros.studies.irsim_world import DiffDriveBase, IrSimWorld
    from hjrno_ros.tools.nav_bench import DURATION, ROOT, nav_map_named

    unknown = set(filters) - set(FILTERS)
    if unknown:
        raise ValueError(f"people bench filters are {FILTERS}, got {sorted(unknown)}")
    if after_rest_contact not in AFTER_REST_CONTACT:
        raise ValueError(f"after_rest_contact is one of {AFTER_REST_CONTACT}, got {after_rest_contact!r}")
    if set(drivers) - set(DRIVERS):
        raise ValueError(f"people bench drivers are {DRIVERS}, got {sorted(set(drivers) - set(DRIVERS))}")
    model = model or str(ROOT / "models" / "default")
    seconds = seconds or DURATION[robot_name]
    agent_table = agent_table or str(ROOT / "models" / f"agents_{robot_name}")
    deviation = read_agent_table(agent_table).deviation if set(TABLES) & set(filters) else None
    robot = nav.ROBOTS[robot_name]
    nav_map = nav_map_named(map_name)
    sd = nav_map.sd
    eps = nav.draw_episodes(nav_map, robot, episodes, 3, 0)
    base = DiffDriveBase(robot.radius, robot.v_max, robot.v_min, robot.omega_max, robot.a_max, robot.alpha_max)

    def world(e: nav.Episode, seed: int, people: bool, lidar: bool) -> IrSimWorld:
        crowd = people_for(nav_map, robot, e, seed) if people else ()
        return IrSimWorld(nav_map.obstacles, nav_map.origin, nav_map.resolution, base, e.start, STEP, lidar=lidar,
                          people=crowd, people_walk_on=after_rest_contact == "continue")

    runs: dict[tuple[str, str, bool], list[PeopleRun]] = {}
    started = time.perf_counter()
    for name in filters:
        with _filter_runner(name, nav_map, robot, sd, model, obstacle_speed_max, seconds, agent_table,
                            scan_timeout) as drive_one:
            for driver_kind in drivers:
                replanning = driver_kind == "replanning"
                for people in (False, True):
                    t0, results = time.perf_counter(), []
                    for k, e in enumerate(eps):
                        w = world(e, k, people, lidar=name.startswith("brt_node") or replanning)
                        driver = nav.GoalDriver("follower" if replanning else driver_kind, nav_map, robot, e,
                                                INTERRUPT, sd, sensed=w.scan_points if replanning else None)
                        try:
                            results.append(PeopleRun(drive_one(w, driver, e), w.contact_speed, w.min_people_clearance,
                                                     w.min_people_clearance_moving, w.rest_contacts))
                        finally:
                            w.close()
                    runs[(driver_kind, name, people)] = results
                    progress(f"{driver_kind} {name} people={people}: "
                             f"{sum(r.result.collided for r in results)} crashes, "
                             f"{sum(r.rest_contacts for r in results)} people walked on "
                             f"({time.perf_counter() - t0:.0f} s)")
    rows = [{**summarize(driver_kind, name, runs[(driver_kind, name, True)], runs[(driver_kind, name, False)]),
             "obstacle_speed_max": obstacle_speed_max if name in ("brt_node", "brt_node+tracker") else None,
             "agent_deviation": deviation if name in TABLES else None,
             "scan_timeout": scan_timeout if name.startswith("brt_node") else None,
             "after_rest_contact": after_rest_contact}
            for driver_kind in drivers for name in filters]
    write(Path(out), rows, {"episodes_per_case": episodes, "robot": robot_name, "map": map_name, "seconds": seconds,
                            "model": _shown(model, ROOT), "wall_s": round(time.perf_counter() - started)})
    progress(f"wrote {Path(out) / results_stem(robot_name, map_name)}.md")
    return int(any(r["collisions_moving"] for r in rows if r["filter"].startswith("brt_node")))


@contextlib.contextmanager
def _filter_runner(name: str, nav_map: nav.NavMap, robot: nav.Robot, sd: np.ndarray, model: str,
                   obstacle_speed_max: float, seconds: float, agent_table: str, scan_timeout: float = SCAN_TIMEOUT):
    """Yields ``drive(world, driver, episode) -> EpisodeResult`` for filter ``name``: lockstep for none and the stop
    zone, brt_node over DDS (one node process for all its episodes) for the others."""
    if not name.startswith("brt_node"):
        def lockstep(w, driver, e):
            filt = nav.no_filter if name == "none" else people_stop_zone(w, nav_map, robot, sd)
            return nav.run_episode(w, driver, filt, robot, seconds, STEP)

        yield lockstep
        return
    from hjrno_ros.tools.node_process import brt_node_process, free_domain

    tracked = name == "brt_node+agents"
    params = {**node_params(robot), "observation_sources": "[scan, people]" if tracked else "[scan]",
              "obstacle_speed_max": obstacle_speed_max, "scan.timeout": scan_timeout}
    if tracked:
        params |= {"people.type": "agents", "people.topic": AGENTS_TOPIC, "agent_table": agent_table}
    if name == "brt_node+tracker":
        params |= {"scan.track_people": True, "agent_table": agent_table}
    domain = free_domain()
    with brt_node_process(domain, params, model) as (proc, tail):
        def over_dds(w, driver, e):
            if proc.poll() is not None:
                raise RuntimeError(f"brt_node exited: {tail()}")
            return _drive(w, nav_map, driver, e, domain, seconds, tail, SCAN_EVERY if tracked else 0)

        yield over_dds


def people_stop_zone(w, nav_map: nav.NavMap, robot: nav.Robot, sd: np.ndarray) -> nav.Filter:
    """collision_monitor's stop polygon and approach model (``nav.stop_zone``) with the people's true positions as
    obstacles beside the map: the baseline that sees everything and knows no dynamics."""
    clearance = nav_map.clearance(sd)

    def body(points: np.ndarray) -> np.ndarray:
        people, radii = w.people_positions, w.people_radii
        gaps = np.linalg.norm(points[..., None, :] - people, axis=-1) - radii if len(people) else None
        nearest = gaps.min(-1) if gaps is not None else np.inf
        return np.minimum(clearance(points), nearest) - robot.radius

    def filt(state: np.ndarray, t: float, nominal: np.ndarray) -> tuple[np.ndarray, bool]:
        out, changed = stop_zone_filter(StopZoneSettings(), body, state[None], nominal[None])
        return out[0], bool(changed[0])

    return filt


def _drive(w, nav_map, driver, episode, domain, seconds, tail, agents_every: int = 0) -> nav.EpisodeResult:
    from hjrno_ros.ros.harness.irsim_base import drive, episode_result, irsim_base  # rclpy only when it runs

    x0, y0 = episode.start[:2]

    def ready(log) -> bool:
        s, at = log.status, log.status.get("robot") or {}
        return (s.get("state") not in (None, "fail_closed") and abs(at.get("x", 1e9) - x0) < 1e-3
                and abs(at.get("y", 1e9) - y0) < 1e-3)

    try:
        base = drive(domain, lambda context: irsim_base(w, nav_map, driver, STEP, context=context,
                                                       scan_every=SCAN_EVERY, agents_every=agents_every,
                                                       agents_topic=AGENTS_TOPIC), seconds, ready)
    except RuntimeError as err:
        raise RuntimeError(f"{err} (node: {tail()})") from None
    return episode_result(base)


def summarize(driver: str, name: str, with_people: list[PeopleRun], without: list[PeopleRun]) -> dict:
    """One row: the runs among people against the same episodes without them."""
    moving = sum(r.result.collided and (r.contact_speed is None or r.contact_speed > MOVING) for r in with_people)
    ratios = []
    for run, ref in zip(with_people, without, strict=True):
        both = min(len(run.result.reached), len(ref.result.reached))
        if both:
            ratios.append((run.result.reached[both - 1], ref.result.reached[both - 1]))
    steps = sum(r.result.steps for r in with_people)
    moving_gaps = [r.min_gap_moving for r in with_people if math.isfinite(r.min_gap_moving)]
    return {
        "driver": driver, "filter": name, "episodes": len(with_people),
        "collisions_moving": moving,
        "collisions_stopped": sum(r.result.collided for r in with_people) - moving
        + sum(r.rest_contacts for r in with_people),
        "collisions_without_people": sum(r.result.collided for r in without),
        "min_gap_to_people_m": round(min(r.min_gap for r in with_people), 3),
        "min_gap_moving_m": round(min(moving_gaps), 3) if moving_gaps else None,
        "goals": sum(len(r.result.reached) for r in with_people),
        "goals_without_people": sum(len(r.result.reached) for r in without),
        "time_to_goal_vs_no_people": round(sum(a for a, _ in ratios) / sum(b for _, b in ratios), 3) if ratios
        else None,
        "stopped_share": round(sum(r.result.stopped for r in with_people) / max(steps, 1), 3),
        "fail_closed_share": round(sum(r.result.fail_closed for r in with_people) / max(steps, 1), 4),
    }


def _shown(path: str, root: Path) -> str:
    """``path`` relative to the repository ``root`` when inside it: results files name no machine's paths."""
    resolved = Path(path).resolve()
    return str(resolved.relative_to(root.resolve())) if resolved.is_relative_to(root.resolve()) else str(path)


def results_stem(robot_name: str, map_name: str) -> str:
    """people, people_<robot>, people_<map> or people_<robot>_<map>: the Jackal and the default plan are implied."""
    return "_".join(["people", *([robot_name] if robot_name != "jackal" else []),
                     *([map_name] if map_name != DEFAULT_MAP else [])])


def write(out: Path, rows: list[dict], run: dict) -> None:
    """Merge ``rows`` into the robot's and map's people.json (:func:`results_stem`; a rerun replaces its own rows) and
    render the .md beside it."""
    out.mkdir(parents=True, exist_ok=True)
    stem = results_stem(run["robot"], run["map"])
    key = lambda r: (r["driver"], r["filter"], r["obstacle_speed_max"], r.get("agent_deviation"),  # noqa: E731
                     r["scan_timeout"], r["after_rest_contact"])
    path = out / f"{stem}.json"
    old = json.loads(path.read_text())["rows"] if path.is_file() else []
    for r in old:  # rows from before the options: the scan source's default timeout, episodes ended at any contact
        r.setdefault("scan_timeout", SCAN_TIMEOUT if r["filter"].startswith("brt_node") else None)
        r.setdefault("after_rest_contact", "end")
        r.setdefault("min_gap_moving_m", None)
    rows = [r for r in old if key(r) not in {key(n) for n in rows}] + rows
    order = lambda r: FILTERS.index(r["filter"]) if r["filter"] in FILTERS else len(FILTERS)  # noqa: E731
    rows.sort(key=lambda r: (AFTER_REST_CONTACT.index(r["after_rest_contact"]), DRIVERS.index(r["driver"]), order(r),
                             r["obstacle_speed_max"] or 0.0,
                             r.get("agent_deviation") or 0.0, -(r["scan_timeout"] or 0.0)))
    report = {"machine": f"{platform.machine()}, Python {platform.python_version()}", "date": time.strftime("%Y-%m-%d"),
              "step_s": STEP, **run, "rows": rows}
    note = (f"`hjrno bench people` on {report['machine']}, {report['date']}: {run['robot']} on {run['map']}, "
            f"{run['episodes_per_case']} episodes per case of {run['seconds']:g} s, 4 social-force pedestrians at "
            "0.5-1.0 m/s (2 on the robot's route against it, turning short of its goals), IR-SIM's LiDAR at 10 Hz as "
            "brt_node's scan source (obstacle_speed_max and scan_timeout per row: the motion margin of returns off "
            "the map covers that speed over the stop, the latency and the timeout); "
            "brt_node+tracker's scan source tracks people on its returns (track_people: confirmed tracks are "
            "tracked agents, the rest keep the margin); brt_node+agents also gets the "
            "pedestrians' true positions and velocities at 10 Hz as a tracked-agents source (relative value tables "
            "solved for agents deviating from their velocity by agent_deviation m/s; their returns keep no margin); "
            "stop_zone is collision_monitor's stop polygon and approach model with the "
            "people's true positions. none and stop_zone run lockstep, brt_node over DDS in real time. "
            "collisions_moving: "
            f"the robot moved (|v| > {MOVING} m/s) into the contact (it ends the episode); collisions_stopped: a "
            "person walked into the robot at rest (after_rest_contact continue: they walk on through it, the robot "
            "held while they overlap, and the episode goes on; end: the episode ends there). min_gap: between the "
            "robot's and a person's disks, every step; min_gap_moving: over the steps the robot moved in. time to "
            "goal: against the same episodes without people, over the goals both reached.")
    atomic_write(path, lambda p: Path(p).write_text(json.dumps(report, indent=1) + "\n"))
    atomic_write(out / f"{stem}.md", lambda p: Path(p).write_text(
        "\n".join(["# People benchmark", "", note, "", *records_table(rows, blank_none=True)]) + "\n"))
