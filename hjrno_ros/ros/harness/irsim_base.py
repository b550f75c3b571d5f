"""IR-SIM's robot as a :class:`~hjrno_ros.ros.harness.sim_base.SimBase` plant: the navigation benchmark's, the people
benchmark's and the demo's base, in real time.

:func:`irsim_base` makes the base: IR-SIM's pose and velocity as odometry every ``step_time``, a
:class:`~hjrno_ros.studies.navigation.GoalDriver` sending the nominal TwistStamped in the same step, IR-SIM stepped
with the latest filtered command; IR-SIM decides collisions.  ``scan_every`` > 0 publishes IR-SIM's LiDAR scan;
``agents_every`` > 0 the pedestrians as tracked agents (a perfect tracker: IR-SIM's positions and velocities).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from sensor_msgs.msg import LaserScan

from hjrno_ros.ros.harness.sim_base import BaseLog, Rates, SimBase, agents_message
from hjrno_ros.ros.harness.spin import drive_base
from hjrno_ros.studies.navigation import EpisodeResult, GoalDriver, NavMap


class IrSimPlant:
    """An :class:`~hjrno_ros.studies.irsim_world.IrSimWorld`'s robot; a step lasts the world's ``step_time``."""

    def __init__(self, world: Any) -> None:
        self.world = world

    def pose(self) -> tuple[float, float, float]:
        return tuple(float(c) for c in self.world.pose)

    def velocity(self) -> tuple[float, float]:
        return tuple(float(c) for c in self.world.velocity)

    def step(self, twist: np.ndarray, dt: float) -> str | None:
        self.world.step(float(twist[0]), float(twist[1]))
        return "collision" if self.world.collided else None


class PoseDriver:
    """A GoalDriver (called with the pose (x, y, θ)) as a SimBase driver (called with the state (x, y, v, θ))."""

    def __init__(self, goal: GoalDriver) -> None:
        self.goal = goal

    def __call__(self, state: np.ndarray, t: float) -> np.ndarray:
        return self.goal(state[[0, 1, 3]], t)

    @property
    def finished(self) -> bool:
        return self.goal.finished


def irsim_base(world: Any, nav_map: NavMap, driver: GoalDriver, step_time: float = 0.05, direct: bool = False,
               cmd_timeout: float = 0.25, context: Any = None, name: str = "irsim_base",
               scan_every: int = 0, agents_every: int = 0, agents_topic: str = "tracked_agents") -> SimBase:
    """The base for ``world`` driven by ``driver``, its map latched; ``scan_every`` > 0: IR-SIM's LiDAR scan on
    ``scan`` every that many steps (the world needs its LiDAR); ``agents_every`` > 0: the pedestrians' true
    positions, velocities and radii on ``agents_topic`` every that many steps (:func:`agents_message`)."""
    scan = (lambda stamp: scan_message(world.scan(), stamp)) if scan_every else None
    agents = (lambda stamp: agents_message(world.people_positions, world.people_velocities, world.people_radii,
                                           stamp)) if agents_every else None
    base = SimBase(context, IrSimPlant(world), PoseDriver(driver), name=name,
                   rates=Rates(step_time, step_time, cmd_timeout), direct=direct, scan=scan, scan_every=scan_every,
                   keep=100, agents=agents, agents_every=agents_every, agents_topic=agents_topic)
    base.publish_map(nav_map.occupancy(), nav_map.resolution, nav_map.origin)
    return base


def episode_result(base: SimBase) -> EpisodeResult:
    """The episode as the lockstep runner reports it."""
    log, driver = base.log, base.driver.goal
    stops = log.status.get("counts", {}).get("stops", log.stops_before) - log.stops_before
    return EpisodeResult(log.outcome is not None, log.ended_at, list(driver.reached), len(driver.episode.goals),
                         len(log.trace), log.stopped, log.changed, 0 if base.direct else stops,
                         np.array(log.trace).reshape(-1, 6))


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


def drive(domain: int, make_base: Callable[..., SimBase], seconds: float, ready: Callable[[BaseLog], bool],
          timeout: float = 120.0) -> SimBase:
    """Create the base on ``domain`` (``make_base(context=...)``), spin until ``ready(log)`` (the filter is up),
    then drive for ``seconds`` of real time or until a collision or the last goal."""
    return drive_base(domain, lambda context: make_base(context=context), seconds, ready, lambda base: base.ended,
                      timeout)
