"""Closed-loop episodes of the dynamic Dubins car with a safety filter in the loop (no ROS).

A *world* is one solved scenario: its exact obstacles (clearance l(x, y)), its ground-truth V∞
table and the car's limits.  In each episode a careless nominal controller (goal seeking or
straight-line driving) sends twists (linear m/s, angular rad/s) every ``dt``; a filter may
replace them; the robot turns the twist into controls (a, κ) as a real base would (speed set
point reached at most at a_max, curvature ω / v within κ_max) and integrates the car over ``dt``
(RK4) with a bounded disturbance: random in the ball ‖d‖ ≤ δ·|v| + d₀, or worst-case from the
ground-truth gradient.  All episodes of a world run as one batch; every filter sees the same
starts, goals and noise.  An episode ends on collision (l ≤ 0), goal reached, leaving the
window, or time out.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable

import numpy as np

from hjrno_ros.core.dynamics import CarParams, disturbance_bound, robot_f, worst_disturbance
from hjrno_ros.core.geometry import union_sdf
from hjrno_ros.core.grids import wrap_angle
from hjrno_ros.core.safety_filter import twist_to_control
from hjrno_ros.core.value_table import ValueTable
from hjrno_ros.studies.simulation import ball, rk4_step

CONTROLLERS = ("goal", "straight", "reverse", "spin")
DISTURBANCES = ("random", "worst")
# A filter maps (states (n, 4), nominal twists (n, 2)) to (commands (n, 2), intervened (n,)).
Filter = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclasses.dataclass(frozen=True)
class World:
    """One map: exact obstacles, the ground-truth value table on its window, the car's limits."""

    name: str
    shapes: tuple
    truth: ValueTable
    params: CarParams
    scale: float = 1.0  # m per unit of the shapes' coordinates (a world seen at another robot's size)
    grid_clearance: Callable[[np.ndarray], np.ndarray] | None = None  # l − r interpolated on the table's grid

    def clearance(self, points: np.ndarray) -> np.ndarray:
        """l(x, y) in metres for points ``(..., 2)`` (or states ``(..., 4)``)."""
        return self.scale * union_sdf(self.shapes, np.asarray(points)[..., :2] / self.scale)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        g = self.truth.grid
        return np.asarray(g.lo[:2]), np.asarray(g.hi[:2])


@dataclasses.dataclass(frozen=True)
class EpisodeSettings:
    duration: float = 20.0  # s
    dt: float = 0.05  # s: control period
    goal_tolerance: float = 0.3  # m
    start_margin: float = 0.05  # m: starts have V_gt ≥ this (inside the true safe set)
    edge_margin: float = 0.5  # m: starts and goals stay this far inside the window
    goal_clearance: float = 0.5  # m: goals have l ≥ this
    min_goal_distance: float = 3.0  # m
    careless: bool = False  # also reverse (when the robot can) and spin-in-place drivers, 1 episode in 10 each

    def scaled(self, length: float) -> EpisodeSettings:
        """The same episodes for a robot ``length`` times the size (times unchanged)."""
        return dataclasses.replace(self, **{f: getattr(self, f) * length for f in (
            "goal_tolerance", "start_margin", "edge_margin", "goal_clearance", "min_goal_distance")})


@dataclasses.dataclass
class Episodes:
    """The fixed part of a world's episodes: starts (n, 4), goals (n, 2), controller / disturbance
    kind per episode, and the random disturbance sequence (steps, n, 2) shared by every filter, in the
    unit disk: each step scales it by the car's bound at the state, δ·|v| + d₀."""

    starts: np.ndarray
    goals: np.ndarray
    controller: np.ndarray  # str (n,)
    disturbance: np.ndarray  # str (n,)
    noise: np.ndarray


def has_safe_states(grid, values: np.ndarray, settings: EpisodeSettings) -> bool:
    """Whether any grid node where :func:`draw_episodes` places starts has V ≥ ``start_margin``
    (a room too tight for the car under the disturbance has none: it cannot stay safe forever)."""
    axes = [np.asarray(grid.axis(i)) for i in range(2)]
    inner = [(a >= lo + settings.edge_margin) & (a <= hi - settings.edge_margin)
             for a, lo, hi in zip(axes, grid.lo[:2], grid.hi[:2], strict=True)]
    return bool((values[np.ix_(inner[0], inner[1])] >= settings.start_margin).any())


def draw_episodes(world: World, n: int, settings: EpisodeSettings, seed: int, first: int = 0) -> Episodes:
    """``n`` episodes with starts in the true safe set; episode ``first + i`` alternates controller
    (even: goal, odd: straight; with ``settings.careless`` episodes 8 and 9 of every 10 reverse, if the robot
    can, and spin in place) and disturbance (pairs: random, worst)."""
    rng = np.random.default_rng(seed)
    lo, hi = world.bounds[0] + settings.edge_margin, world.bounds[1] - settings.edge_margin
    p = world.params
    starts, goals = [], []
    for _ in range(200):
        m = 64 * n
        cand = np.column_stack([rng.uniform(lo, hi, (m, 2)), rng.uniform(p.v_min, p.v_max, m),
                                rng.uniform(-np.pi, np.pi, m)])
        starts.extend(cand[world.truth.value(cand) >= settings.start_margin])
        goal = rng.uniform(lo, hi, (m, 2))
        goals.extend(goal[world.clearance(goal) >= settings.goal_clearance])
        if len(starts) >= n and len(goals) >= 4 * n:
            break
    if len(starts) < n or len(goals) < 4 * n:
        raise ValueError(f"{world.name}: cannot place {n} starts in the safe set / goals in free space")
    starts, goals = np.array(starts[:n]), np.array(goals)
    far = np.linalg.norm(goals[None] - starts[:, None, :2], axis=-1) >= settings.min_goal_distance
    pick = np.where(far.any(1), far.argmax(1), np.arange(n))  # the first far-enough goal
    index = first + np.arange(n)
    steps = int(round(settings.duration / settings.dt))
    controller = np.array(CONTROLLERS)[index % 2]
    if settings.careless:
        controller[index % 10 == 8] = "reverse" if p.v_min < 0 else "straight"
        controller[index % 10 == 9] = "spin"
    return Episodes(starts, goals[pick], controller, np.array(DISTURBANCES)[(index // 2) % 2],
                    ball(rng, (steps, n), 1.0))


def nominal_twist(params: CarParams, states: np.ndarray, goals: np.ndarray, controller: np.ndarray) -> np.ndarray:
    """Careless twists ``(n, 2)``: drive to the goal (turn towards it, slow down near it), straight at full speed,
    straight in reverse at full speed, or spin in place at κ_max·v_max."""
    delta = goals - states[:, :2]
    error = wrap_angle(np.arctan2(delta[:, 1], delta[:, 0]) - states[:, 3])
    dist = np.linalg.norm(delta, axis=-1)
    linear = params.v_max * np.clip(dist, 0.0, 1.0) * np.clip(np.cos(error), 0.3, 1.0)
    angular = np.clip(2.0 * error, -2.0, 2.0) * np.maximum(states[:, 2], 0.1)
    linear = np.select([controller == "straight", controller == "reverse", controller == "spin"],
                       [params.v_max, params.v_min, 0.0], linear)
    angular = np.where(controller == "spin", params.turn_rate_max,
                       np.where(controller == "goal", angular, 0.0))
    return np.column_stack([linear, angular])


def rk4(params: CarParams, x: np.ndarray, u: np.ndarray, d: np.ndarray, dt: float) -> np.ndarray:
    """One RK4 step of the car, θ wrapped."""
    x = rk4_step(lambda s, u_, d_: robot_f(params, s, u_, d_), x, u, d, dt)
    x[:, 3] = wrap_angle(x[:, 3])
    return x


def base_step(params: CarParams, x: np.ndarray, twist: np.ndarray, control_period: float, dt: float,
              rng: np.random.Generator) -> np.ndarray:
    """A simulated base over ``dt``: it turns ``twist`` (n, 2) into controls as a base does
    (:func:`twist_to_control` over ``control_period``) and moves under a random disturbance uniform in the
    car's disk ‖d‖ ≤ δ·|v| + d₀ (the demo's, the depot check's and the product scenes' robot)."""
    u = twist_to_control(params, x, twist, control_period)
    d = disturbance_bound(params, x[:, 2])[:, None] * ball(rng, (len(x),), 1.0)
    return rk4(params, x, u, d, dt)


def run_episodes(world: World, episodes: Episodes, filt: Filter | None, settings: EpisodeSettings,
                 trace: bool = False) -> dict:
    """Run all episodes of one world under one filter; per-episode metrics as arrays of length n
    (with ``trace``, also the states ``(steps + 1, n, 4)``, NaN after an episode ended)."""
    p, dt = world.params, settings.dt
    x = episodes.starts.astype(float).copy()
    n = len(x)
    lo, hi = world.bounds
    alive = np.ones(n, bool)
    outcome = np.full(n, "timeout", dtype=object)
    steps, interventions, raised = np.zeros(n, int), np.zeros(n, int), np.zeros(n, int)
    travelled, min_clear = np.zeros(n), world.clearance(x)
    jerk_sq, angacc_sq = np.zeros(n), np.zeros(n)
    last_a, last_w = np.full(n, np.nan), np.full(n, np.nan)
    filter_s, decisions = 0.0, 0
    worst = episodes.disturbance == "worst"
    path = np.full((len(episodes.noise) + 1, n, 4), np.nan) if trace else None
    if trace:
        path[0] = x
    for k in range(len(episodes.noise)):
        idx = np.flatnonzero(alive)
        if idx.size == 0:
            break
        xa = x[idx]
        twist = nominal_twist(p, xa, episodes.goals[idx], episodes.controller[idx])
        if filt is not None:
            start = time.perf_counter()
            nominal = twist
            twist, intervened = filt(xa, twist)
            filter_s += time.perf_counter() - start
            decisions += idx.size
            interventions[idx] += intervened
            raised[idx] += np.abs(twist[:, 0]) > np.abs(nominal[:, 0]) + 1e-9
        u = twist_to_control(p, xa, twist, dt)
        d = disturbance_bound(p, xa[:, 2])[:, None] * episodes.noise[k, idx]  # ‖d‖ ≤ δ·|v| + d₀
        if worst[idx].any():
            w = worst[idx]
            d[w] = worst_disturbance(p, xa[w], world.truth.gradient(xa[w]))
        xn = rk4(p, xa, u, d, dt)
        travelled[idx] += np.linalg.norm(xn[:, :2] - xa[:, :2], axis=-1)
        for acc, last, value in ((jerk_sq, last_a, u[:, 0]), (angacc_sq, last_w, twist[:, 1])):
            acc[idx] += np.nan_to_num((value - last[idx]) / dt) ** 2
            last[idx] = value
        x[idx] = xn
        if trace:
            path[k + 1, idx] = xn
        steps[idx] += 1
        clear = world.clearance(xn)
        min_clear[idx] = np.minimum(min_clear[idx], clear)
        ended = [(clear <= 0, "collision"),
                 ((episodes.controller[idx] == "goal")
                  & (np.linalg.norm(xn[:, :2] - episodes.goals[idx], axis=-1) <= settings.goal_tolerance), "goal"),
                 (((xn[:, :2] < lo) | (xn[:, :2] > hi)).any(-1), "exited")]
        for mask, name in ended:
            done = idx[mask & alive[idx]]
            outcome[done] = name
            alive[done] = False
    result = {"outcome": outcome, "steps": steps, "interventions": interventions, "raised_speed": raised,
              "travelled": travelled,
            "min_clearance": min_clear, "jerk_rms": np.sqrt(jerk_sq / np.maximum(steps - 1, 1)),
            "angacc_rms": np.sqrt(angacc_sq / np.maximum(steps - 1, 1)),
            "filter_us": np.full(n, 1e6 * filter_s / max(decisions, 1)),
            "controller": episodes.controller, "disturbance": episodes.disturbance}
    if trace:
        result["trace"] = (path, outcome.copy(), episodes.goals)
    return result


def summarize(results: list[dict]) -> dict:
    """One table row from the per-world results of one filter."""
    cat = {k: np.concatenate([r[k] for r in results]) for k in results[0] if k != "trace"}
    goal = cat["controller"] == "goal"
    steps = cat["steps"].sum()
    collided = cat["outcome"] == "collision"
    return {
        "episodes": int(len(collided)),
        "collisions": int(collided.sum()),
        "collision_rate": float(collided.mean()),
        "collisions_worst_d": int((collided & (cat["disturbance"] == "worst")).sum()),
        "intervention_rate": float(cat["interventions"].sum() / max(steps, 1)),
        "raised_speed": int(cat["raised_speed"].sum()),
        "goals_reached": float((cat["outcome"][goal] == "goal").mean()) if goal.any() else float("nan"),
        "distance_m": float(cat["travelled"].mean()),
        "min_clearance_m": float(cat["min_clearance"].min()),
        "mean_min_clearance_m": float(cat["min_clearance"].mean()),
        "jerk_rms": float(np.mean(cat["jerk_rms"])),
        "angacc_rms": float(np.mean(cat["angacc_rms"])),
        "filter_us": float(np.average(cat["filter_us"], weights=cat["steps"])) if steps else 0.0,
    }
