"""``hjrno bench tracker``: how well the laser people tracker (core/scan_tracker.py) knows IR-SIM's pedestrians.

The people benchmark's episodes, maps and pedestrians, run lockstep with its Nav2-like follower unfiltered and
IR-SIM's LiDAR at 10 Hz.  After each scan the returns off the static map go to the tracker, with the settings the
node gives it for the robot's agent tables, and its confirmed agents are compared with the pedestrians in view
(within ``RANGE`` m and with a return on them).  Per map: the share of those the tracker vouches for (the rest keep
the motion margin; also of those within ``NEAR`` m, where the filter acts), the velocity error against the truth
(p50, p95, max; the share over the tables' deviation δ, and of those the share in a manoeuvre: the true velocity
changed by over MANOEUVRE m/s in the last 0.4 s; beside it, a perfect tracker's share, its velocity one scan old),
the position error, and the share of agents whose disk misses part of the person.
"""

from __future__ import annotations

import dataclasses
import json
import platform
import time
from pathlib import Path

import numpy as np

from hjrno_ros.core.atomic import atomic_write
from hjrno_ros.core.point_obstacles import STATIC_MATCH
from hjrno_ros.core.scan_tracker import ScanTracker, TrackerSettings
from hjrno_ros.core.tables import records_table
from hjrno_ros.studies import navigation as nav

RANGE = 5.0  # m: pedestrians this near the robot count
NEAR = 1.5  # m: and those this near, where the filter acts, apart
SEEN = 0.3  # m: a pedestrian with a return this near its centre is in view
MATCH = 0.5  # m: an agent this near a pedestrian is its track
MANOEUVRE = 0.2  # m/s: a change of the true velocity over the last 0.4 s above this is a manoeuvre


@dataclasses.dataclass
class Tally:
    """What the comparisons found so far."""

    in_view: int = 0
    near: int = 0  # in view within NEAR
    near_vouched: int = 0
    errors: list[float] = dataclasses.field(default_factory=list)  # m/s, per vouched-for person in view
    manoeuvres: list[bool] = dataclasses.field(default_factory=list)
    perfect: list[float] = dataclasses.field(default_factory=list)  # m/s: a perfect tracker's, one scan old
    offsets: list[float] = dataclasses.field(default_factory=list)  # m
    outside: int = 0


def observer(world, tracker: ScanTracker, clearance, tally: Tally) -> nav.Filter:
    """A pass-through filter that feeds each ``SCAN_EVERY``-th step's scan to ``tracker`` and tallies its agents
    against ``world``'s pedestrians."""
    from hjrno_ros.tools.nav_bench import STEP
    from hjrno_ros.tools.people_bench import SCAN_EVERY

    history, steps, back = [], [0], int(round(0.4 / (SCAN_EVERY * STEP)))

    def observe(state: np.ndarray, t: float, nominal: np.ndarray) -> tuple[np.ndarray, bool]:
        steps[0] += 1
        if steps[0] % SCAN_EVERY:
            return nominal, False
        points, here = world.scan_points(), np.array(world.pose[:2])
        off_map = points[clearance(points) > STATIC_MATCH]
        tracker.update(off_map, here, world.time, world.time)
        agents, truth = tracker.agents(), world.people_velocities
        history.append(truth)
        before = history[max(len(history) - 1 - back, 0)]
        for j, (p, v, r) in enumerate(zip(world.people_positions, truth, world.people_radii, strict=True)):
            seen = len(off_map) and np.linalg.norm(off_map - p, axis=-1).min() < SEEN
            if np.linalg.norm(p - here) > RANGE or not seen:
                continue
            tally.in_view += 1
            gaps = np.linalg.norm(agents.positions - p, axis=-1) if len(agents) else np.array([np.inf])
            i = int(np.argmin(gaps))
            near = np.linalg.norm(p - here) <= NEAR
            tally.near += near
            if gaps[i] < MATCH:
                tally.near_vouched += near
                tally.errors.append(float(np.linalg.norm(agents.velocities[i] - v)))
                tally.manoeuvres.append(float(np.linalg.norm(v - before[j])) > MANOEUVRE)
                tally.perfect.append(float(np.linalg.norm(v - history[max(len(history) - 2, 0)][j])))
                tally.offsets.append(float(gaps[i]))
                tally.outside += bool(gaps[i] + r > agents.radii[i])
        return nominal, False

    return observe


def measure(map_name: str, episodes: int, robot_name: str = "jackal", seconds: float = 60.0,
            agent_table: str | None = None) -> dict:
    """One map's row (module docstring)."""
    from hjrno_ros.core.tracked_agents import read_agent_table
    from hjrno_ros.studies.irsim_world import DiffDriveBase, IrSimWorld
    from hjrno_ros.tools.nav_bench import INTERRUPT, ROOT, STEP, nav_map_named
    from hjrno_ros.tools.people_bench import people_for

    table = read_agent_table(agent_table or ROOT / "models" / f"agents_{robot_name}")
    settings = TrackerSettings.for_table(table, 0.2)
    nav_map, robot = nav_map_named(map_name), nav.ROBOTS[robot_name]
    clearance = nav_map.clearance(nav_map.sd)
    base = DiffDriveBase(robot.radius, robot.v_max, robot.v_min, robot.omega_max, robot.a_max, robot.alpha_max)
    tally = Tally()
    for k, e in enumerate(nav.draw_episodes(nav_map, robot, episodes, 3, 0)):
        world = IrSimWorld(nav_map.obstacles, nav_map.origin, nav_map.resolution, base, e.start, STEP, lidar=True,
                           people=people_for(nav_map, robot, e, k), people_walk_on=True)
        driver = nav.GoalDriver("follower", nav_map, robot, e, INTERRUPT, nav_map.sd)
        try:
            nav.run_episode(world, driver, observer(world, ScanTracker(settings), clearance, tally), robot, seconds,
                            STEP)
        finally:
            world.close()
    err, man = np.array(tally.errors), np.array(tally.manoeuvres, bool)
    over = err > table.deviation
    return {"map": map_name, "episodes": episodes, "people_in_view": tally.in_view,
            "vouched_share": round(len(err) / max(tally.in_view, 1), 3),
            "vouched_share_near": round(float(tally.near_vouched / max(tally.near, 1)), 3),
            "velocity_error_p50": round(float(np.percentile(err, 50)), 3),
            "velocity_error_p95": round(float(np.percentile(err, 95)), 3),
            "velocity_error_max": round(float(err.max()), 3), "deviation": table.deviation,
            "over_deviation_share": round(float(over.mean()), 4),
            "over_deviation_in_manoeuvre": round(float(man[over].mean()), 3) if over.any() else None,
            "perfect_over_deviation_share": round(float((np.array(tally.perfect) > table.deviation).mean()), 4),
            "position_error_p95": round(float(np.percentile(tally.offsets, 95)), 3),
            "disk_misses_person_share": round(tally.outside / max(len(err), 1), 4)}


def run(out: Path, episodes: int = 4, maps: tuple[str, ...] = ("plan1000001", "depot"), progress=print,
        seconds: float = 60.0) -> int:
    """Measure each map (``seconds`` per episode) and write ``out``/tracker.{md,json}."""
    started, rows = time.perf_counter(), []
    for name in maps:
        rows.append(measure(name, episodes, seconds=seconds))
        progress(f"{name}: {rows[-1]}")
    note = (f"`hjrno bench tracker` on {platform.machine()}, Python {platform.python_version()}, "
            f"{time.strftime('%Y-%m-%d')}: the people benchmark's pedestrians and episodes, jackal, the follower "
            "unfiltered, lockstep, LiDAR at 10 Hz; people in view within 5 m. vouched: the tracker's confirmed agents "
            "among them (the others keep the motion margin); near: within 1.5 m. Velocity error against IR-SIM's; "
            "over_deviation: over the agent tables' δ, of which in a manoeuvre (true velocity changed by > 0.2 m/s "
            "in 0.4 s); perfect_over_deviation: a perfect tracker's at 10 Hz, its velocity one scan old. "
            "disk_misses_person: the agent's disk does not contain the whole person.")
    out.mkdir(parents=True, exist_ok=True)
    atomic_write(out / "tracker.json", lambda p: Path(p).write_text(json.dumps(
        {"note": note, "wall_s": round(time.perf_counter() - started), "rows": rows}, indent=1) + "\n"))
    atomic_write(out / "tracker.md", lambda p: Path(p).write_text(
        "\n".join(["# People tracker", "", note, "", *records_table(rows, blank_none=True)]) + "\n"))
    progress(f"wrote {out / 'tracker.md'}")
    return 0
