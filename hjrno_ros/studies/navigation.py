"""Navigation in IR-SIM: maps, robots, drivers, safety filters and the lockstep episode runner (no ROS).

- **Maps** (:class:`NavMap`): a held-out floor plan (:mod:`hjrno_ros.truth.floor_plans` at seeds the training never
  used, the whole 20 m plan rasterised at 5 cm) or a map_server map such as Nav2's depot.
- **Robots** (:data:`ROBOTS`): a TurtleBot3-class and a Jackal-class differential drive.
- **Drivers**: the Nav2-like follower (:mod:`hjrno_ros.studies.path_follower`: A* on the map inflated by the
  footprint, Regulated Pure Pursuit, and Nav2's progress checker with its BackUp recovery and a new plan), a
  careless goal-seeker blind to walls, and interruptions: every ``interrupt_every`` s a spin in place at ω_max (1 s)
  or, for a robot that reverses, backing up at v_min (1 s).
- **Filters**, in process: none, the collision_monitor-style stop zone (:mod:`hjrno_ros.core.stop_zone`), and the
  least-restrictive filter (:mod:`hjrno_ros.core.least_restrictive`) on windowed value tables from the HJ solver
  (the ground truth) or the learned model.  brt_node over DDS runs in :mod:`hjrno_ros.ros.harness`.

An episode visits its goals in turn for ``duration`` s of simulated time; IR-SIM moves the robot (its kinematics and
acceleration limits) and decides collisions (its own check); an episode ends at a collision.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hjrno_ros.core import geometry
from hjrno_ros.core.dynamics import DiffDriveParams
from hjrno_ros.core.grids import GridSpec, wrap_angle
from hjrno_ros.core.least_restrictive import certificate, filter_least_restrictive
from hjrno_ros.core.safety_filter import FilterSettings, clip_to_limits
from hjrno_ros.core.stop_zone import StopZoneSettings, stop_zone_filter
from hjrno_ros.studies.path_follower import FollowerSettings, Grid2D, RegulatedPurePursuit, plan

RESOLUTION = 0.05  # m: floor plans rasterised like a map_server map
GOAL_CLEARANCE = 0.3  # m beyond the footprint: starts and goals keep this from obstacles
MIN_GOAL_DISTANCE, MAX_GOAL_DISTANCE = 3.0, 6.0  # m between consecutive goals (straight line)
STOPPED_SPEED, STOPPED_TURN = 0.02, 0.05  # m/s, rad/s: below both, the robot counts as stopped
PLANNER_MARGIN = 0.1  # m beyond the footprint the planner's paths keep (as a costmap's inscribed radius would): a
# path closer to walls than the safety filter's own margin (the map's cell diagonal, the braking distance) is one no
# filter lets the robot follow
PROGRESS_RADIUS, PROGRESS_TIME = 0.5, 10.0  # m, s: Nav2's progress checker defaults
BACKUP_DISTANCE, BACKUP_SPEED = 0.3, 0.15  # m, m/s: Nav2's BackUp recovery (behavior tree defaults)
REPLAN_PERIOD = 1.0  # s: Nav2's navigate_w_replanning_and_recovery tree replans at 1 Hz


@dataclasses.dataclass(frozen=True)
class Robot:
    """A differential-drive base: footprint and limits (SI)."""

    name: str
    radius: float
    v_max: float
    v_min: float
    omega_max: float
    a_max: float
    alpha_max: float  # rad/s²: the simulated base's angular acceleration limit (the model has none)

    def params(self) -> DiffDriveParams:
        """The filter's model of the robot (tracking error 0.1 per unit speed, as the bundled card)."""
        return DiffDriveParams(a_max=self.a_max, omega_max=self.omega_max, v_min=self.v_min, v_max=self.v_max)


ROBOTS = {
    "turtlebot3": Robot("turtlebot3", 0.105, 0.22, -0.22, 2.84, 1.0, 3.2),
    "jackal": Robot("jackal", 0.25, 1.0, -1.0, 2.0, 1.0, 4.0),
}


@dataclasses.dataclass(frozen=True)
class NavMap:
    """Obstacle cells ``[ix, iy]`` (occupied or unknown) of a map, with their signed distance."""

    name: str
    obstacles: np.ndarray
    origin: tuple[float, float]
    resolution: float

    @property
    def sd(self) -> np.ndarray:
        return _signed_distance(self.obstacles, self.resolution)

    def clearance(self, sd: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
        """Points ``(..., 2)`` → their distance to the nearest obstacle cell (beyond the map: an obstacle)."""
        return lambda points: geometry.sample_raster(sd, self.origin, self.resolution, points,
                                                     outside=-self.resolution)

    def occupancy(self) -> np.ndarray:
        """int8 ``[ix, iy]``: 100 occupied, 0 free (what brt_node is sent)."""
        return np.where(self.obstacles, 100, 0).astype(np.int8)


def _signed_distance(obstacles: np.ndarray, resolution: float) -> np.ndarray:
    return geometry.signed_distance_from_mask(obstacles, resolution)


def walled(obstacles: np.ndarray) -> np.ndarray:
    """The cells with the map's outermost ring occupied: IR-SIM lets a robot leave its grid without a collision,
    brt_node treats the space beyond a map as an obstacle; the ring makes both see a wall there."""
    out = obstacles.copy()
    out[[0, -1], :] = out[:, [0, -1]] = True
    return out


def floor_plan_map(seed: int) -> NavMap:
    """A whole generated floor plan (the ``plans`` family at ``seed``) as a 5 cm map."""
    from hjrno_ros.truth.floor_plans import PLAN_HALF
    from hjrno_ros.truth.scenarios import make_scenario

    scenario = make_scenario("plans", seed)
    robot = np.asarray(scenario.params["robot_in_plan"])  # the shapes are centred on it: shift them back
    n = int(round(2 * PLAN_HALF / RESOLUTION))
    origin = (-PLAN_HALF, -PLAN_HALF)
    centres = origin[0] + (np.arange(n) + 0.5) * RESOLUTION
    xy = np.stack(np.meshgrid(centres, centres, indexing="ij"), -1) - robot
    obstacles = geometry.union_inside(scenario.shapes, xy)
    return NavMap(f"plan{seed}", walled(obstacles), origin, RESOLUTION)


def map_file_map(yaml_path: str | Path, occupied_threshold: int = 50) -> NavMap:
    """A map_server map (YAML + image); unknown cells count as obstacles."""
    from hjrno_ros.core.map_file import load_map

    m = load_map(yaml_path)
    obstacles = geometry.occupancy_to_mask(m.occupancy, occupied_threshold, True)
    return NavMap(Path(yaml_path).stem, walled(obstacles), tuple(m.origin), m.resolution)


@dataclasses.dataclass(frozen=True)
class Episode:
    start: tuple[float, float, float]
    goals: tuple[tuple[float, float], ...]


def draw_episodes(nav_map: NavMap, robot: Robot, n: int, goals: int, seed: int) -> list[Episode]:
    """``n`` episodes: a start at rest and ``goals`` goals, each MIN_GOAL_DISTANCE..MAX_GOAL_DISTANCE from the last
    (straight line), all in the map's largest free region (so the planner reaches them)."""
    rng = np.random.default_rng(seed)
    grid = Grid2D(nav_map.obstacles, nav_map.origin, nav_map.resolution)
    clear = grid.clearance
    from scipy import ndimage

    roomy = clear >= robot.radius + GOAL_CLEARANCE
    labels, count = ndimage.label(clear > robot.radius)
    if count == 0 or not roomy.any():
        raise ValueError(f"{nav_map.name}: no room for the {robot.name}")
    biggest = np.argmax(ndimage.sum_labels(roomy, labels, np.arange(1, count + 1))) + 1
    cells = np.argwhere(roomy & (labels == biggest))
    out = []
    while len(out) < n:
        points = [grid.centre(cells[rng.integers(len(cells))])]
        for _ in range(200 * goals):
            if len(points) > goals:
                break
            p = grid.centre(cells[rng.integers(len(cells))])
            if MIN_GOAL_DISTANCE <= np.linalg.norm(p - points[-1]) <= MAX_GOAL_DISTANCE:
                points.append(p)
        if len(points) > goals:
            heading = float(rng.uniform(-math.pi, math.pi))
            out.append(Episode((*map(float, points[0]), heading), tuple(tuple(map(float, p)) for p in points[1:])))
    return out


# --------------------------------------------------------------------------------------------- drivers
Driver = Callable[[np.ndarray, float], tuple[float, float]]  # (pose (x, y, θ), simulated s) -> twist


class GoalDriver:
    """Visits an episode's goals in turn with a steering law (follower or careless), with interruptions."""

    def __init__(self, kind: str, nav_map: NavMap, robot: Robot, episode: Episode, interrupt_every: float = 0.0,
                 sd: np.ndarray | None = None, inflation_weight: float = 3.0,
                 planner_map: NavMap | None = None, sensed: Callable[[], np.ndarray] | None = None) -> None:
        """``inflation_weight``: the planner's extra cost near obstacles, in the shape of Nav2's inflation layer (0:
        A* on the map inflated by the footprint only, shortest paths that hug every corner, which pure pursuit then
        cuts: a follower that collides on its own, and deadlocks at corners under any filter).  ``planner_map``: the
        map the planner knows at first (a static map without an obstacle that is there); after a recovery it plans
        on ``nav_map``, as Nav2's global costmap holds what its sensors have seen by then.  ``sensed``: the x-y points
        ``(k, 2)`` the robot's sensors see now (a LiDAR's returns); a follower given them replans every REPLAN_PERIOD
        s on its map with them marked, as Nav2's planner does on a global costmap with an obstacle layer (people in
        its way included), and keeps its path when no plan reaches the goal."""
        if kind not in ("follower", "careless"):
            raise ValueError(f"unknown driver {kind!r}")
        self.kind, self.robot, self.episode, self.interrupt_every = kind, robot, episode, interrupt_every
        self.inflation_weight = inflation_weight
        self._true_map = nav_map
        known = planner_map or nav_map
        self.grid = Grid2D(known.obstacles, known.origin, known.resolution)
        self.clearance = nav_map.clearance(nav_map.sd if sd is None else sd)
        self.goal = 0
        self.reached: list[float] = []  # simulated s at which each goal was reached
        self.recoveries = 0
        self._clear = self.grid.clearance if kind == "follower" else None
        self.paths = self._plan_all() if kind == "follower" else []
        self.follower: RegulatedPurePursuit | None = None
        self._anchor: tuple[np.ndarray, float] | None = None  # the progress checker's last position and time
        self._backing_until = -math.inf
        self.sensed, self._replanned = sensed, -math.inf

    def _plan(self, a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
        return plan(self.grid, a, b, self.robot.radius + PLANNER_MARGIN, weight=self.inflation_weight,
                    clear=self._clear)

    def _plan_all(self) -> list[np.ndarray | None]:
        """The planner's path to each goal from the start or the previous goal, planned before the episode."""
        points = [np.asarray(self.episode.start[:2])] + [np.asarray(g) for g in self.episode.goals]
        return [self._plan(a, b) for a, b in zip(points[:-1], points[1:], strict=True)]

    def _recovering(self, pose: np.ndarray, t: float) -> bool:
        """Nav2's progress checker and BackUp recovery: no 0.5 m of progress in 10 s (its defaults) backs the robot up
        0.3 m at 0.15 m/s and plans again from where it stands."""
        if t < self._backing_until:
            return True
        if self._anchor is None or np.linalg.norm(pose[:2] - self._anchor[0]) >= PROGRESS_RADIUS:
            self._anchor = (pose[:2].copy(), t)
        elif t - self._anchor[1] > PROGRESS_TIME and self.robot.v_min < 0:
            self.recoveries += 1
            self._backing_until = t + BACKUP_DISTANCE / BACKUP_SPEED
            self._anchor = None
            if self.grid.obstacles is not self._true_map.obstacles:  # the costmap has seen the map as it is
                m = self._true_map
                self.grid = Grid2D(m.obstacles, m.origin, m.resolution)
                self._clear = self.grid.clearance
            self.paths[self.goal] = self._plan(pose[:2], np.asarray(self.episode.goals[self.goal]))
            self.follower = None
            return True
        return False

    def _replan(self, pose: np.ndarray, t: float) -> None:
        """With ``sensed``: every REPLAN_PERIOD s, the path to the goal planned again on the map with the sensed points'
        cells marked occupied (the last plan is kept when none reaches the goal)."""
        if self.sensed is None or t - self._replanned < REPLAN_PERIOD:
            return
        self._replanned = t
        marked = self.grid.obstacles.copy()
        ij = np.floor((np.asarray(self.sensed(), float).reshape(-1, 2) - self.grid.origin) / self.grid.resolution)
        ij = ij[np.all((ij >= 0) & (ij < marked.shape), axis=1)].astype(int)
        marked[ij[:, 0], ij[:, 1]] = True
        grid = Grid2D(marked, self.grid.origin, self.grid.resolution)
        path = plan(grid, pose[:2], np.asarray(self.episode.goals[self.goal]), self.robot.radius + PLANNER_MARGIN,
                    weight=self.inflation_weight)
        if path is not None:
            self.paths[self.goal], self.follower = path, None

    @property
    def finished(self) -> bool:
        return self.goal >= len(self.episode.goals)

    def _follower(self) -> RegulatedPurePursuit | None:
        path = self.paths[self.goal]
        if self.follower is None and path is not None:
            self.follower = RegulatedPurePursuit(path, self.robot.v_max, self.robot.omega_max, self.clearance)
        return self.follower

    def __call__(self, pose: np.ndarray, t: float) -> tuple[float, float]:
        if self.finished:
            return 0.0, 0.0
        goal = np.asarray(self.episode.goals[self.goal])
        if np.linalg.norm(goal - pose[:2]) <= FollowerSettings.goal_tolerance:
            self.reached.append(t)
            self.goal += 1
            self.follower = None
            return self(pose, t)
        if self.interrupt_every and t % self.interrupt_every >= self.interrupt_every - 1.0:
            k = int(t // self.interrupt_every)
            if k % 2 == 1 and self.robot.v_min < 0:
                return self.robot.v_min, 0.0
            return 0.0, self.robot.omega_max * (1 if k % 4 < 2 else -1)
        if self.kind == "careless":
            error = float(wrap_angle(math.atan2(goal[1] - pose[1], goal[0] - pose[0]) - pose[2]))
            linear = self.robot.v_max * max(math.cos(error), 0.0)
            return linear, float(np.clip(2.0 * error, -self.robot.omega_max, self.robot.omega_max))
        if self._recovering(pose, t):
            return -min(BACKUP_SPEED, -self.robot.v_min), 0.0
        self._replan(pose, t)
        follower = self._follower()
        return (0.0, 0.0) if follower is None else follower.command(pose)


# --------------------------------------------------------------------------------------------- filters
Filter = Callable[[np.ndarray, float, np.ndarray], tuple[np.ndarray, bool]]  # (state (4,), t, nominal) -> out, changed


def no_filter(state: np.ndarray, t: float, nominal: np.ndarray) -> tuple[np.ndarray, bool]:
    return nominal, False


def stop_zone(nav_map: NavMap, robot: Robot, sd: np.ndarray | None = None) -> Filter:
    """collision_monitor's stop polygon (0.3 m beyond the footprint) and approach model (2 s)."""
    clearance = nav_map.clearance(nav_map.sd if sd is None else sd)

    def body(points: np.ndarray) -> np.ndarray:
        return clearance(points) - robot.radius

    def filt(state: np.ndarray, t: float, nominal: np.ndarray) -> tuple[np.ndarray, bool]:
        out, changed = stop_zone_filter(StopZoneSettings(), body, state[None], nominal[None])
        return out[0], bool(changed[0])

    return filt


def inflation(robot: Robot, model_grid: GridSpec | None, scale: float, map_resolution: float) -> float:
    """m: the footprint and half the cell diagonal of the coarser of the model's grid (at the robot's size) and the
    map (as brt_node's inflation_radius -1); without a model grid, of the map alone (the braking bound's)."""
    h = max(model_grid.spacings[0] * scale if model_grid is not None else 0.0, map_resolution)
    return robot.radius + h / math.sqrt(2)


class WindowedValues:
    """Value tables on windows around the robot, made by ``make(center)`` when the robot is a quarter window from the
    last centre (as brt_node recentres), and the least-restrictive filter on them."""

    def __init__(self, robot: Robot, window: float, make: Callable[[tuple[float, float]], object],
                 clearance: Callable[[np.ndarray], np.ndarray], epsilon: float, settings: FilterSettings) -> None:
        self.params, self.window, self.make = robot.params(), window, make
        self.clearance, self.epsilon, self.settings = clearance, epsilon, settings
        self.center: tuple[float, float] | None = None
        self.table = None
        self.tables = 0

    def __call__(self, state: np.ndarray, t: float, nominal: np.ndarray) -> tuple[np.ndarray, bool]:
        if self.center is None or math.hypot(state[0] - self.center[0], state[1] - self.center[1]) > self.window / 4:
            self.center = (float(state[0]), float(state[1]))
            self.table = self.make(self.center)
            self.tables += 1
        cert = certificate(self.params, self.clearance, self.table, self.epsilon)
        s = state.copy()
        s[2] = np.clip(s[2], self.params.v_min, self.params.v_max)
        out, changed, _ = filter_least_restrictive(self.params, self.settings, cert, s[None], nominal[None])
        return out[0], bool(changed[0])


# --------------------------------------------------------------------------------------------- the runner
@dataclasses.dataclass
class EpisodeResult:
    collided: bool
    collision_time: float | None
    reached: list[float]  # simulated s of each goal reached
    goals: int
    steps: int
    stopped: int  # steps with |v| < STOPPED_SPEED and |ω| < STOPPED_TURN while goals remained
    changed: int  # steps whose command the filter changed (beyond clipping to the limits)
    fail_closed: int  # steps the filter stopped the robot for a fault (brt_node only)
    trace: np.ndarray  # (steps, 6): t, x, y, v, θ, changed

    def as_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d.pop("trace")
        return d


def run_episode(world, driver: GoalDriver, filt: Filter, robot: Robot, duration: float,
                step_time: float) -> EpisodeResult:
    """Lockstep: each step the driver's nominal twist goes through ``filt`` (clipped to the robot's limits first, as
    the filters do) and IR-SIM applies the result for one ``step_time``."""
    params = robot.params()
    trace, stopped, changed = [], 0, 0
    collided_at = None
    steps = int(round(duration / step_time))
    for k in range(steps):
        t = k * step_time
        x, y, theta = world.pose
        v, omega = world.velocity
        state = np.array([x, y, v, theta])
        nominal = np.asarray(driver(np.array([x, y, theta]), t), float)
        nominal = clip_to_limits(params, state[None], nominal[None], step_time)[0]
        out, was_changed = filt(state, t, nominal)
        changed += was_changed
        stopped += not driver.finished and abs(v) < STOPPED_SPEED and abs(omega) < STOPPED_TURN
        trace.append((t, x, y, v, theta, was_changed))
        world.step(float(out[0]), float(out[1]))
        if world.collided:
            collided_at = t + step_time
            break
        if driver.finished:
            break
    return EpisodeResult(collided_at is not None, collided_at, list(driver.reached), len(driver.episode.goals),
                         len(trace), stopped, changed, 0, np.array(trace))


# --------------------------------------------------------------------------------------------- value windows
MODEL_GRID = GridSpec((-5.0, -5.0, 0.0, -math.pi), (5.0, 5.0, 1.0, math.pi), (32, 32, 9, 16), (3,))  # the card's


def solver_windows(robot: Robot, nav_map: NavMap, sd: np.ndarray, settings: FilterSettings,
                   grid: GridSpec = MODEL_GRID) -> WindowedValues:
    """The ground-truth filter: the least-restrictive filter on converged HJ solves of windows around the robot (the
    robot's forward model in its own units, reversing by symmetry, as the bundled card), cached on a lattice of an
    eighth of the window so that episodes and filters share solves; ε = 0."""
    from hjrno_ros.core.similarity import Scaling
    from hjrno_ros.core.value_table import value_table
    from hjrno_ros.truth.solver import solve
    from hjrno_ros.truth.systems import robot_system

    params = robot.params()
    scaling = Scaling.of(params)
    model = dataclasses.replace(scaling.params_to_model(params), v_min=0.0)
    s = scaling.length
    clear = nav_map.clearance(sd)
    grow = inflation(robot, grid, s, nav_map.resolution)
    window = (grid.hi[0] - grid.lo[0]) * s
    cache: dict[tuple[int, int], object] = {}

    def make(center: tuple[float, float]) -> object:
        key = tuple(int(round(c / (window / 8))) for c in center)
        if key not in cache:
            c = np.asarray(key) * window / 8
            xy = np.stack(np.meshgrid(grid.axis(0), grid.axis(1), indexing="ij"), -1) * s + c
            target = np.broadcast_to(((clear(xy) - grow) / s)[:, :, None, None], grid.shape).astype(np.float32)
            values, _ = solve(robot_system(model), grid, np.ascontiguousarray(target), tolerance=5e-3,
                              max_horizon=12.0, criterion="band")
            shifted = GridSpec((grid.lo[0] + c[0] / s, grid.lo[1] + c[1] / s, *grid.lo[2:]),
                               (grid.hi[0] + c[0] / s, grid.hi[1] + c[1] / s, *grid.hi[2:]), grid.shape, grid.periodic)
            cache[key] = value_table(scaling.grid_to_robot(shifted), np.asarray(values) * s)
        return cache[key]

    bound = inflation(robot, None, s, nav_map.resolution)
    return WindowedValues(robot, window, make, lambda points: clear(points) - bound, 0.0, settings)


def learned_windows(stem: str | Path, robot: Robot, nav_map: NavMap, sd: np.ndarray,
                    settings: FilterSettings) -> WindowedValues:
    """The learned filter in process: the model at ``stem`` served at the robot's size (as brt_node does), its
    calibrated ε scaled to the robot."""
    from hjrno_ros.core.scaled_values import ScaledValueFunction, covered_scaling, filter_params
    from hjrno_ros.learning.value_function import LearnedValueFunction

    vf = LearnedValueFunction(stem, device="cpu")
    params = robot.params()
    scaling = covered_scaling(vf.params, params, vf.card.inputs.get("param_ranges"))
    scaled = ScaledValueFunction(vf, scaling, filter_params(vf.params, params))
    clear = nav_map.clearance(sd)
    grow = inflation(robot, vf.grid, scaling.length, nav_map.resolution)

    def v0(points: np.ndarray) -> np.ndarray:
        return clear(points) - grow

    def make(center: tuple[float, float]) -> object:
        return scaled.local_table(v0(scaled.window_points(center)).astype(np.float32), center, 0.0, 0.0)

    bound = inflation(robot, None, scaling.length, nav_map.resolution)
    return WindowedValues(robot, scaled.window[0], make, lambda points: clear(points) - bound,
                          vf.card.margin() * scaling.length, settings)
