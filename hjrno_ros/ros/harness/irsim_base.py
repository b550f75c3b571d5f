"""A robot in IR-SIM behind ROS 2 topics, in real time: the navigation benchmark's and the demo's base.

:class:`IrSimBase` latches the map (reliable + transient local), publishes odometry in the map frame from IR-SIM's
pose and velocity every ``step_time``, runs a driver (:class:`~hjrno_ros.studies.navigation.GoalDriver`) that sends
the nominal TwistStamped on ``cmd_vel_smoothed``, and steps IR-SIM in real time with the *filtered* command from
``cmd_vel``; a filtered command older than ``cmd_timeout`` counts as zero (a base's watchdog).  ``direct``: no
filter in the loop, the base executes the nominal.  IR-SIM decides collisions.  Filtered commands are matched to
the nominal they answer by stamp: a change counts as an intervention, a zero command answering nothing (the node's
own timer) as a fail-closed stop; the node's status counts all its fail-closed stops.
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
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import LaserScan

from hjrno_ros.ros.brt_node.messages import occupancy_message, odometry_message
from hjrno_ros.ros.harness.commands import StampedCommands, unsafe_grid
from hjrno_ros.ros.harness.spin import base_topics, drive_base
from hjrno_ros.studies.navigation import STOPPED_SPEED, STOPPED_TURN, EpisodeResult, GoalDriver, NavMap


@dataclasses.dataclass
class BaseLog:
    trace: list = dataclasses.field(default_factory=list)  # (t, x, y, v, θ, changed) per step
    grids: list = dataclasses.field(default_factory=list)  # (t, origin, resolution, unsafe mask [ix, iy])
    latency_s: list = dataclasses.field(default_factory=list)
    commands: int = 0
    changed: int = 0
    stopped: int = 0
    stops_before: int = 0  # the node's fail-closed stop count when the episode began
    collided_at: float | None = None
    status: dict = dataclasses.field(default_factory=dict)


class IrSimBase(Node):
    def __init__(self, world, nav_map: NavMap, driver: GoalDriver, step_time: float = 0.05, direct: bool = False,
                 cmd_timeout: float = 0.25, context=None, name: str = "irsim_base", scan_every: int = 0) -> None:
        """``scan_every`` > 0: publish IR-SIM's LiDAR scan on ``scan`` every that many steps (the world needs its
        LiDAR)."""
        super().__init__(name, context=context)
        self.world, self.driver, self.step_time, self.direct = world, driver, step_time, direct
        self.cmd_timeout = cmd_timeout
        self.log = BaseLog()
        self.running = False
        self.t0 = time.monotonic()
        self._filtered, self._filtered_at = np.zeros(2), -math.inf
        self._changed = False
        self.map_pub, self.odom_pub, self.cmd_pub = base_topics(self, self._on_cmd, self._on_grid)
        self.commands = StampedCommands(self, self.cmd_pub, keep=100)
        grid = occupancy_message(nav_map.occupancy(), nav_map.resolution, nav_map.origin)
        grid.header.stamp = self.get_clock().now().to_msg()
        self.map_pub.publish(grid)
        self.scan_every, self._ticks = scan_every, 0
        self.scan_pub = self.create_publisher(LaserScan, "scan", qos_profile_sensor_data) if scan_every else None
        self.create_timer(step_time, self._tick)

    def now(self) -> float:
        return time.monotonic() - self.t0

    def begin(self) -> None:
        """Start the episode's clock and motion (brt_node filters); its stops count from here."""
        self.log.stops_before = self.log.status.get("counts", {}).get("stops", 0)
        self.running, self.t0 = True, time.monotonic()

    def _tick(self) -> None:
        """Every step_time: the nominal command out, IR-SIM one step with the latest filtered one, odometry out."""
        x, y, theta = self.world.pose
        v, omega = self.world.velocity
        if self.running and self.log.collided_at is None and not self.driver.finished:
            t = self.now()
            self._send(np.asarray(self.driver(np.array([x, y, theta]), t), float))
            fresh = time.monotonic() - self._filtered_at <= self.cmd_timeout
            twist = self._filtered if fresh else np.zeros(2)
            self.log.trace.append((t, x, y, v, theta, self._changed))
            self.log.stopped += abs(v) < STOPPED_SPEED and abs(omega) < STOPPED_TURN and not self.driver.finished
            self.world.step(float(twist[0]), float(twist[1]))
            if self.world.collided:
                self.log.collided_at = t
            x, y, theta = self.world.pose
            v, omega = self.world.velocity
        stamp = self.get_clock().now().to_msg()
        self.odom_pub.publish(odometry_message(x, y, theta, v, "map", stamp))
        self._ticks += 1
        if self.scan_pub is not None and self._ticks % self.scan_every == 0:
            self.scan_pub.publish(scan_message(self.world.scan(), stamp))

    def _send(self, nominal: np.ndarray) -> None:
        self.log.commands += 1
        if self.direct:
            self._filtered, self._filtered_at, self._changed = nominal, time.monotonic(), False
            return
        self.commands.send(nominal)

    def _on_cmd(self, msg: TwistStamped) -> None:
        self._filtered, latency, changed = self.commands.answer(msg)
        self._filtered_at = time.monotonic()
        if latency is None:  # the node's fail-closed timer: a stop that answers no command
            return
        self.log.latency_s.append(latency)
        self._changed = changed
        self.log.changed += self.running and self._changed

    def _on_grid(self, msg: OccupancyGrid) -> None:
        self.log.grids.append(unsafe_grid(msg, self.now()))

    def result(self) -> EpisodeResult:
        """The episode as the lockstep runner reports it."""
        log, driver = self.log, self.driver
        stops = log.status.get("counts", {}).get("stops", log.stops_before) - log.stops_before
        return EpisodeResult(log.collided_at is not None, log.collided_at, list(driver.reached),
                             len(driver.episode.goals), len(log.trace), log.stopped, log.changed,
                             0 if self.direct else stops, np.array(log.trace).reshape(-1, 6))


def scan_message(scan: tuple[np.ndarray, float, float, float], stamp) -> LaserScan:
    """IR-SIM's LiDAR scan as a LaserScan in the robot's frame; a beam that hit nothing (range_max) reads inf."""
    ranges, angle_min, increment, range_max = scan
    msg = LaserScan()
    msg.header.frame_id, msg.header.stamp = "laser", stamp
    msg.angle_min, msg.angle_increment = angle_min, increment
    msg.angle_max = angle_min + increment * (len(ranges) - 1)
    msg.range_min, msg.range_max = 0.0, range_max
    msg.ranges = np.where(ranges >= range_max - 1e-9, np.inf, ranges).tolist()
    return msg


def drive(domain: int, make_base: Callable[..., IrSimBase], seconds: float, ready: Callable[[BaseLog], bool],
          timeout: float = 120.0) -> IrSimBase:
    """Create the base on ``domain`` (``make_base(context=...)``), spin until ``ready(log)`` (the filter is up),
    then drive for ``seconds`` of real time or until a collision or the last goal."""
    return drive_base(domain, lambda context: make_base(context=context), seconds, ready,
                      lambda base: base.log.collided_at is not None or base.driver.finished, timeout)
