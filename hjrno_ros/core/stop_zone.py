"""A Nav2-collision-monitor-style baseline filter: a stop zone plus an approach model (no ROS).

Like Nav2's ``collision_monitor``: ``stop`` zeroes the command while an obstacle is within
``stop_distance`` of the robot; ``approach`` forward-simulates the nominal twist (constant linear and
angular velocity, unicycle kinematics) for ``time_before_collision`` seconds in steps of
``simulation_time_step`` and, on predicted contact after t_c seconds, scales the whole twist by
t_c / time_before_collision.  It knows the obstacles exactly but nothing about the robot's
acceleration limits or disturbances: that is what the closed-loop table compares.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np


@dataclasses.dataclass(frozen=True)
class StopZoneSettings:
    stop_distance: float = 0.3  # m: obstacle this close to the robot → zero command (Nav2 "stop" polygon)
    time_before_collision: float = 2.0  # s: Nav2 "approach" default
    simulation_time_step: float = 0.1  # s: Nav2 default
    footprint_margin: float = 0.05  # m: predicted clearance below this counts as contact


def predicted_contact_time(settings: StopZoneSettings, clearance: Callable[[np.ndarray], np.ndarray],
                           states: np.ndarray, nominal: np.ndarray) -> np.ndarray:
    """First time (s) at which the constant nominal twist brings each robot into contact; inf if none."""
    steps = int(round(settings.time_before_collision / settings.simulation_time_step))
    t = settings.simulation_time_step * np.arange(1, steps + 1)  # (K,)
    x, y, th = states[:, 0:1], states[:, 1:2], states[:, 3:4]
    lin, ang = nominal[:, 0:1], nominal[:, 1:2]
    turning = np.abs(ang) > 1e-6
    safe_ang = np.where(turning, ang, 1.0)
    arc_x = np.where(turning, lin / safe_ang * (np.sin(th + ang * t) - np.sin(th)), lin * t * np.cos(th))
    arc_y = np.where(turning, -lin / safe_ang * (np.cos(th + ang * t) - np.cos(th)), lin * t * np.sin(th))
    points = np.stack([x + arc_x, y + arc_y], -1)  # (n, K, 2)
    hit = clearance(points) <= settings.footprint_margin
    first = np.where(hit.any(1), hit.argmax(1), -1)
    return np.where(first >= 0, t[np.maximum(first, 0)], np.inf)


def stop_zone_filter(settings: StopZoneSettings, clearance: Callable[[np.ndarray], np.ndarray],
                     states: np.ndarray, nominal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Commands ``(n, 2)`` and intervened ``(n,)`` for robots at ``states`` with nominal twists ``(n, 2)``."""
    t_c = predicted_contact_time(settings, clearance, states, nominal)
    scale = np.minimum(1.0, t_c / settings.time_before_collision)
    scale[clearance(states[:, :2]) <= settings.stop_distance] = 0.0
    return nominal * scale[:, None], scale < 1.0
