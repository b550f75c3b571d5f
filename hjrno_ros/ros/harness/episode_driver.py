"""Many closed-loop episodes against one running brt_node over DDS, on an occupancy map (``hjrno bench depot``).

The base is a :class:`~hjrno_ros.ros.harness.sim_base.SimBase` with a
:class:`~hjrno_ros.ros.harness.plants.KinematicPlant` (the card's robot integrated in real time with the *filtered*
command and a random disturbance ‖d‖ ≤ δ·|v| + d₀; odometry at 50 Hz, TwistStamped nominal commands at 20 Hz, a
filtered command older than 0.25 s counting as zero) on an occupancy raster: a point robot collides when it enters
an obstacle cell and leaves the map when it crosses the map's edge.  The careless driver is chosen per episode, and
the robot is reset between episodes, so one node process serves many episodes.

Drivers: ``straight`` and ``edge`` command v_max with zero turn rate (the episode's start heading; ``edge``
episodes start pointed at the map's edge); ``goal`` and ``goal_off_map`` drive the demo's goal-seeking
twist to the episode's goals in turn (``goal_off_map``: a goal beyond the map's edge).  An episode
ends after ``seconds`` of driving, or at the first collision or map exit.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import rclpy
from geometry_msgs.msg import TwistStamped
from rclpy.executors import SingleThreadedExecutor

from hjrno_ros.core.dynamics import RobotParams
from hjrno_ros.ros.harness.plants import KinematicPlant
from hjrno_ros.ros.harness.sim_base import BaseLog, SimBase
from hjrno_ros.studies import closed_loop
from hjrno_ros.studies.closed_loop import EpisodeSettings

DRIVERS = ("straight", "edge", "goal", "goal_off_map")
STRAIGHT_DRIVERS = ("straight", "edge")


@dataclasses.dataclass
class EpisodeLog(BaseLog):
    """The base's log plus the episode's goals and start."""

    goals: list = dataclasses.field(default_factory=list)  # (t, x, y) when the next goal was set
    ready_s: float = 0.0  # s from the reset until brt_node filtered at the new start
    start_value: float | None = None  # brt_node's V at the start (its status when it first filtered there)


class RasterEvent:
    """"exit" beyond the raster's edge, "collision" inside an obstacle cell (bool ``[ix, iy]``), else None."""

    def __init__(self, obstacle: np.ndarray, resolution: float, origin: tuple[float, float]) -> None:
        self.obstacle, self.resolution, self.origin = np.asarray(obstacle, bool), float(resolution), np.asarray(origin)

    def __call__(self, xy: np.ndarray) -> str | None:
        ij = np.floor((np.asarray(xy, float) - self.origin) / self.resolution).astype(int)
        if np.any(ij < 0) or np.any(ij >= self.obstacle.shape):
            return "exit"
        return "collision" if self.obstacle[ij[0], ij[1]] else None


class CarelessDriver:
    """One of DRIVERS, blind to obstacles: v_max straight on, or the goal-seeking twist to ``goals`` in turn."""

    def __init__(self, params: RobotParams, kind: str, goals: np.ndarray, log: EpisodeLog) -> None:
        if kind not in DRIVERS:
            raise ValueError(f"unknown driver {kind!r}; one of {', '.join(DRIVERS)}")
        self.params, self.kind, self.goals, self.log, self.index = params, kind, goals, log, 0

    def __call__(self, state: np.ndarray, t: float) -> np.ndarray:
        if self.kind in STRAIGHT_DRIVERS:
            return np.array([self.params.v_max, 0.0])
        if np.linalg.norm(state[:2] - self.goals[self.index]) <= EpisodeSettings.goal_tolerance:
            self.index = (self.index + 1) % len(self.goals)
            self.log.goals.append((t, *self.goals[self.index]))
        return closed_loop.nominal_twist(self.params, state[None], self.goals[self.index][None],
                                         np.array(["goal"]))[0]


class EpisodeBase(SimBase):
    """A SimBase on an occupancy raster whose driver and start change per episode (:meth:`reset`)."""

    def __init__(self, obstacle: np.ndarray, occupancy: np.ndarray, resolution: float, origin: tuple[float, float],
                 params: RobotParams, seed: int = 0, context: Any = None) -> None:
        """``obstacle``: bool ``[ix, iy]``, the cells a robot must not enter (occupied and unknown);
        ``occupancy``: the int8 raster published as the map."""
        plant = KinematicPlant(params, np.zeros(4), RasterEvent(obstacle, resolution, origin), seed=seed)
        super().__init__(context, plant, None, name="episode_base", keep_grids=False)
        self.params = params
        self._episode_ns = 0  # ROS time of the reset: older filtered commands are ignored
        self.publish_map(occupancy, resolution, origin)

    def reset(self, start: np.ndarray, driver: str, goals: np.ndarray | None = None) -> None:
        """Stop, put the robot at ``start`` (x, y, v, θ) with a fresh log, and set the episode's driver."""
        self.running = False
        self.plant.place(start)
        goals = np.asarray(goals if goals is not None and len(goals) else np.asarray(start)[None, :2], float)
        self.log = EpisodeLog()
        self.driver = CarelessDriver(self.params, driver, goals.reshape(-1, 2), self.log)
        self.filtered, self.filtered_at, self._changed, self.nominal = np.zeros(2), -math.inf, False, None
        self.commands.forget()
        self._episode_ns = self.get_clock().now().nanoseconds

    def on_filtered(self, msg: TwistStamped) -> None:
        stamp = msg.header.stamp
        if stamp.sec * 1_000_000_000 + stamp.nanosec < self._episode_ns:  # answers the previous episode
            return
        super().on_filtered(msg)


def filtering_at(status: dict, start: np.ndarray, tolerance: float = 0.05) -> bool:
    """Whether brt_node's status says it filters (not fail-closed) with the robot at ``start`` and a value
    window computed around it."""
    robot, grid = status.get("robot"), status.get("value_grid")
    if status.get("state") in (None, "fail_closed", "bypassed") or not robot or not grid:
        return False
    if math.hypot(robot["x"] - start[0], robot["y"] - start[1]) > tolerance:
        return False
    return math.hypot(grid["center"][0] - start[0], grid["center"][1] - start[1]) <= 1.0


def run_episodes(domain: int, robot_args: dict, episodes: list[dict], seconds: float,
                 check: Callable[[], None] = lambda: None, ready_timeout: float = 60.0,
                 done: Callable[[int, EpisodeLog], None] = lambda i, log: None) -> list[EpisodeLog]:
    """Create an EpisodeBase on ``domain`` (``robot_args``: its constructor's keywords) and run ``episodes``
    (each {"driver", "start": (x, y, v, θ), "goals": [(x, y), ...]}) one after the other against the running
    brt_node: reset, wait until the node filters at the start, drive for ``seconds`` or until a collision or
    exit.  ``check()`` raises if the node is gone; ``done(i, log)`` is called after each episode."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    robot = EpisodeBase(context=context, **robot_args)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(robot)
    logs = []
    try:
        for i, episode in enumerate(episodes):
            start = np.asarray(episode["start"], float)
            robot.reset(start, episode["driver"], np.asarray(episode.get("goals") or [], float))
            robot.log.status = {}
            t_reset = time.monotonic()
            while not filtering_at(robot.log.status, start):
                check()
                if time.monotonic() - t_reset > ready_timeout:
                    raise RuntimeError(f"episode {i}: brt_node did not filter at the start ({start[0]:.2f}, "
                                       f"{start[1]:.2f}) within {ready_timeout:g} s: "
                                       f"{robot.log.status.get('reason', 'no status received')}")
                executor.spin_once(timeout_sec=0.05)
            robot.log.ready_s = time.monotonic() - t_reset
            robot.log.start_value = robot.log.status.get("value")
            robot.begin()
            end = robot.t0 + seconds
            while time.monotonic() < end and robot.log.outcome is None:
                executor.spin_once(timeout_sec=0.01)
            robot.running = False
            logs.append(robot.log)
            done(i, robot.log)
        return logs
    finally:
        executor.shutdown(timeout_sec=2.0)
        robot.destroy_node()
        rclpy.shutdown(context=context)
