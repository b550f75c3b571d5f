"""Many closed-loop episodes against one running brt_node over DDS, on an occupancy map (``hjrno bench depot``).

:class:`EpisodeRobot` is the demo's :class:`~hjrno_ros.ros.harness.sim_robot.SimRobot` (latched map, odometry in
the map frame at ``odom_rate``, TwistStamped nominal commands at ``cmd_rate``, the dynamic Dubins car
integrated in real time with the *filtered* command and a random disturbance ‖d‖ ≤ δ·|v| + d₀, a filtered
command older than ``cmd_timeout`` counting as zero) with three changes: the world is an occupancy
raster (a point robot collides when it enters an obstacle cell, and leaves the map when it crosses the
map's edge), the careless driver is chosen per episode, and the robot is reset between episodes, so one
node process serves many episodes.

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
from nav_msgs.msg import OccupancyGrid
from rclpy.executors import SingleThreadedExecutor

from hjrno_ros.core.dynamics import RobotParams
from hjrno_ros.ros.harness.sim_robot import Log, SimRobot
from hjrno_ros.studies import closed_loop

DRIVERS = ("straight", "edge", "goal", "goal_off_map")
STRAIGHT_DRIVERS = ("straight", "edge")


@dataclasses.dataclass
class EpisodeLog(Log):
    """The demo's log plus the episode's outcome: "collision", "exit" or None (the time ran out)."""

    outcome: str | None = None
    ready_s: float = 0.0  # s from the reset until brt_node filtered at the new start
    start_value: float | None = None  # brt_node's V at the start (its status when it first filtered there)


class EpisodeRobot(SimRobot):
    """A SimRobot on an occupancy raster whose driver and start change per episode (:meth:`reset`)."""

    def __init__(self, obstacle: np.ndarray, occupancy: np.ndarray, resolution: float, origin: tuple[float, float],
                 params: RobotParams, seed: int = 0, context: Any = None, **kwargs: Any) -> None:
        """``obstacle``: bool ``[ix, iy]``, the cells a robot must not enter (occupied and unknown);
        ``occupancy``: the int8 raster published as the map."""
        self.obstacle = np.asarray(obstacle, bool)
        self.driver = "straight"
        self._episode_ns = 0  # ROS time of the reset: older filtered commands are ignored
        super().__init__([], params, occupancy, resolution, origin, np.zeros(4), np.zeros((1, 2)), seed=seed,
                         context=context, **kwargs)
        self.resolution, self.origin = float(resolution), np.asarray(origin, float)
        self.log = EpisodeLog()

    def reset(self, start: np.ndarray, driver: str, goals: np.ndarray | None = None) -> None:
        """Stop, put the robot at ``start`` (x, y, v, θ) with a fresh log, and set the episode's driver."""
        if driver not in DRIVERS:
            raise ValueError(f"unknown driver {driver!r}; one of {', '.join(DRIVERS)}")
        self.running = False
        self.x = np.asarray(start, float).reshape(1, 4).copy()
        self.driver = driver
        self.goals = np.asarray(goals if goals is not None and len(goals) else self.x[:, :2], float).reshape(-1, 2)
        self.goal_index = 0
        self.log = EpisodeLog()
        self._filtered, self._filtered_at, self._intervened = np.zeros(2), -math.inf, False
        self.commands.forget()
        self._episode_ns = self.get_clock().now().nanoseconds

    def event(self, xy: np.ndarray) -> str | None:
        """"exit" beyond the map's edge, "collision" inside an obstacle cell, else None."""
        ij = np.floor((np.asarray(xy, float) - self.origin) / self.resolution).astype(int)
        if np.any(ij < 0) or np.any(ij >= self.obstacle.shape):
            return "exit"
        return "collision" if self.obstacle[ij[0], ij[1]] else None

    def _ended(self) -> bool:
        return self.log.outcome is not None

    def _end(self, outcome: str, t: float) -> None:
        self.log.outcome, self.log.collided_at = outcome, t

    def _seeks_goal(self) -> bool:
        return self.driver not in STRAIGHT_DRIVERS

    def _command(self) -> None:
        """The episode's careless nominal command."""
        if not self.running or self.log.outcome is not None:
            return
        if self.driver in STRAIGHT_DRIVERS:
            nominal = np.array([self.params.v_max, 0.0])
        else:
            nominal = closed_loop.nominal_twist(self.params, self.x, self.goals[self.goal_index][None],
                                                np.array(["goal"]))[0]
        self.log.commands += 1
        self.commands.send(nominal)

    def _on_cmd(self, msg: TwistStamped) -> None:
        stamp = msg.header.stamp
        if stamp.sec * 1_000_000_000 + stamp.nanosec < self._episode_ns:  # answers the previous episode
            return
        super()._on_cmd(msg)

    def _on_grid(self, msg: OccupancyGrid) -> None:
        """The value grids are not kept (the demo's figures need them, the episodes do not)."""


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
    """Create an EpisodeRobot on ``domain`` (``robot_args``: its constructor's keywords) and run ``episodes``
    (each {"driver", "start": (x, y, v, θ), "goals": [(x, y), ...]}) one after the other against the running
    brt_node: reset, wait until the node filters at the start, drive for ``seconds`` or until a collision or
    exit.  ``check()`` raises if the node is gone; ``done(i, log)`` is called after each episode."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    robot = EpisodeRobot(context=context, **robot_args)
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
            robot.t0 = time.monotonic()
            robot.running = True
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
