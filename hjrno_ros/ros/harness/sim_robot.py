"""A simulated robot over real ROS 2 topics, for the depot check (:mod:`hjrno_ros.ros.harness.episode_driver`).

It latches the map (reliable + transient local), publishes odometry in the map frame at
``odom_rate``, sends a careless goal-seeking TwistStamped command stream at ``cmd_rate`` (it
ignores obstacles: brt_node must keep it safe), and integrates the card's robot (car or differential drive)
with the *filtered* command and a random disturbance ‖d‖ ≤ δ·|v| + d₀.  A filtered command older than
``cmd_timeout`` counts as zero (brake), as a real base would.  It records the trajectory,
interventions, command latency and value-grid snapshots.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable

import numpy as np
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import OccupancyGrid
from rclpy.node import Node

from hjrno_ros.core.dynamics import RobotParams
from hjrno_ros.core.geometry import union_sdf
from hjrno_ros.ros.brt_node.messages import occupancy_message, odometry_message
from hjrno_ros.ros.harness.commands import StampedCommands, unsafe_grid
from hjrno_ros.ros.harness.spin import base_topics, drive_base
from hjrno_ros.studies import closed_loop
from hjrno_ros.studies.closed_loop import EpisodeSettings


@dataclasses.dataclass
class Log:
    """What the demo reports: per physics step (t, x, y, v, θ, intervened) and the rest."""

    states: list = dataclasses.field(default_factory=list)
    latency_s: list = dataclasses.field(default_factory=list)
    grids: list = dataclasses.field(default_factory=list)  # (t, origin, resolution, unsafe mask [ix, iy])
    goals: list = dataclasses.field(default_factory=list)  # (t, x, y) when a goal was set
    commands: int = 0
    interventions: int = 0
    collided_at: float | None = None
    status: dict = dataclasses.field(default_factory=dict)


class SimRobot(Node):
    def __init__(self, shapes: list, params: RobotParams, occupancy: np.ndarray, resolution: float,
                 origin: tuple[float, float], start: np.ndarray, goals: np.ndarray, seed: int = 0, context=None,
                 direct: bool = False, odom_rate: float = 50.0, cmd_rate: float = 20.0, cmd_timeout: float = 0.25,
                 control_period: float = 0.05, footprint: float = 0.0) -> None:
        """``direct``: no filter in the loop, the robot executes its own nominal commands; ``footprint``: the
        robot's radius, m (it collides when its body touches an obstacle)."""
        super().__init__("sim_robot", context=context)
        self.shapes, self.params, self.direct, self.footprint = shapes, params, direct, footprint
        self.x = np.asarray(start, float).reshape(1, 4).copy()
        self.goals, self.goal_index = np.asarray(goals, float), 0
        self.rng = np.random.default_rng(seed)
        self.dt, self.control_period, self.cmd_timeout = 1.0 / odom_rate, control_period, cmd_timeout
        self.log = Log()
        self.running = False
        self.t0 = time.monotonic()
        self._filtered = np.zeros(2)
        self._filtered_at = -math.inf
        self._intervened = False
        self.map_pub, self.odom_pub, self.cmd_pub = base_topics(self, self._on_cmd, self._on_grid)
        self.commands = StampedCommands(self, self.cmd_pub)
        grid = occupancy_message(occupancy, resolution, origin)
        grid.header.stamp = self.get_clock().now().to_msg()
        self.map_pub.publish(grid)
        self.create_timer(self.dt, self._step)
        self.create_timer(1.0 / cmd_rate, self._command)

    def now(self) -> float:
        return time.monotonic() - self.t0

    def begin(self) -> None:
        """Start the episode's clock and motion (brt_node filters)."""
        self.running, self.t0 = True, time.monotonic()

    def _step(self) -> None:
        """Physics at odom_rate: integrate with the latest filtered command, publish odometry."""
        if self.running and not self._ended():
            twist = self._filtered if time.monotonic() - self._filtered_at <= self.cmd_timeout else np.zeros(2)
            self.x = closed_loop.base_step(self.params, self.x, twist[None], self.control_period, self.dt, self.rng)
            t = self.now()
            self.log.states.append((t, *self.x[0], self._intervened))
            outcome = self.event(self.x[0, :2])
            if outcome is not None:
                self._end(outcome, t)
            elif (self._seeks_goal()
                  and np.linalg.norm(self.x[0, :2] - self.goals[self.goal_index]) <= EpisodeSettings.goal_tolerance):
                self.goal_index = (self.goal_index + 1) % len(self.goals)
                self.log.goals.append((t, *self.goals[self.goal_index]))
        x, y, v, theta = self.x[0]
        self.odom_pub.publish(odometry_message(x, y, theta, v, "map", self.get_clock().now().to_msg()))

    def event(self, xy: np.ndarray) -> str | None:
        """"collision" when the body touches an obstacle, else None."""
        return "collision" if union_sdf(self.shapes, np.asarray(xy, float)[None])[0] <= self.footprint else None

    def _ended(self) -> bool:
        return self.log.collided_at is not None

    def _end(self, outcome: str, t: float) -> None:
        self.log.collided_at = t

    def _seeks_goal(self) -> bool:
        return True

    def _command(self) -> None:
        """The careless nominal command: straight for the current goal."""
        if not self.running or self.log.collided_at is not None:
            return
        nominal = closed_loop.nominal_twist(self.params, self.x, self.goals[self.goal_index][None],
                                            np.array(["goal"]))[0]
        self.log.commands += 1
        if self.direct:
            self._filtered, self._filtered_at = nominal, time.monotonic()
        else:
            self.commands.send(nominal)

    def _on_cmd(self, msg: TwistStamped) -> None:
        self._filtered, latency, changed = self.commands.answer(msg)
        self._filtered_at = time.monotonic()
        if latency is None:  # a fail-closed stop of the node's own timer
            self._intervened = True
            return
        self.log.latency_s.append(latency)
        self._intervened = changed
        self.log.interventions += self._intervened

    def _on_grid(self, msg: OccupancyGrid) -> None:
        self.log.grids.append(unsafe_grid(msg, self.now()))


def drive(domain: int, robot_args: dict, seconds: float, ready: Callable[[Log], bool],
          timeout: float = 120.0) -> Log:
    """Create a SimRobot on ``domain`` (``robot_args``: its constructor's keywords), spin until
    ``ready(log)`` (brt_node filtering), then drive for ``seconds`` or until a collision."""
    robot = drive_base(domain, lambda context: SimRobot(context=context, **robot_args), seconds, ready,
                       lambda r: r.log.collided_at is not None, timeout)
    return robot.log
