"""Live observation sources beside the map, in the manner of Nav2 collision_monitor's ``observation_sources``.

``observation_sources`` names them; each name has its own parameters (:data:`SOURCE_PARAMETERS`, read as
``<name>.type``, ``<name>.topic``, …).  Types:

* ``scan``: sensor_msgs/LaserScan.  The sensor's pose on the robot is a parameter (tf2 is not on PyPI).  Its
  returns are placed in the map frame with the robot's pose *at the scan's stamp* (odometry history).
* ``costmap``: a Nav2 costmap as OccupancyGrid (full updates) in the map frame, e.g. the rolling local costmap.
  Its cells at or above ``cost_threshold`` are obstacles; beyond its edge it says nothing ("not observed"): the
  map input covers the robot there, so a rolling window's edge is no wall.

Each source answers ``get(now)`` with its newest data or the reason it is unusable (none yet, older than its
``timeout``), like the node's other inputs; a stale ``required`` source fails the node closed with the source
named.  The value worker turns the fresh sources into :class:`~hjrno_ros.core.point_obstacles.PointObstacles`
(:func:`live_obstacles`).
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from nav_msgs.msg import OccupancyGrid
from sensor_msgs.msg import LaserScan

from hjrno_ros.core.point_obstacles import PointObstacles, Pose2, behind, scan_points, transform
from hjrno_ros.ros.brt_node.inputs import MapRejected, parse_map
from hjrno_ros.ros.brt_node.messages import finite
from hjrno_ros.ros.brt_node.parameters import Param

SOURCE_TYPES = ("scan", "costmap")
SOURCE_PARAMETERS: dict[str, Param] = {
    "type": Param("scan", "scan (sensor_msgs/LaserScan, sensor-data QoS) | costmap (a Nav2 costmap as OccupancyGrid "
                          "in the map frame, full updates, e.g. the rolling local costmap)", read_only=True),
    "topic": Param("", "the source's topic; '' = the source's name", read_only=True),
    "timeout": Param(0.5, "s: data older than this is stale (receipt time); 0 = never", 0.0, 1e6, read_only=True),
    "required": Param(True, "a stale or missing source fails the node closed; false: it is left out while stale",
                      read_only=True),
    "sensor_pose": Param([0.0, 0.0, 0.0], "scan: the sensor's x (m), y (m) and yaw (rad) on the robot (the "
                                          "odometry's child frame)", read_only=True),
    "cost_threshold": Param(99, "costmap: cost >= threshold is an obstacle (99: Nav2's inscribed cost)", 0, 100,
                            read_only=True),
}
STATIC_MATCH = 0.15  # m: scan returns this close to a static-map obstacle are that obstacle (localisation, cells)
RETURN_DEPTH = 0.2  # m: a scan return is the near edge of a disk this wide in radius behind it (a person's torso)


@dataclasses.dataclass(frozen=True)
class SourceConfig:
    """One observation source's parameters."""

    name: str
    type: str = "scan"
    topic: str = ""
    timeout: float = 0.5
    required: bool = True
    sensor_pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
    cost_threshold: int = 99

    @classmethod
    def build(cls, name: str, values: dict[str, Any]) -> SourceConfig | str:
        """The config of source ``name`` from its ``<key>: value`` parameters, or why they are unusable."""
        if not name or not all(c.isalnum() or c == "_" for c in name):
            return f"observation source names are letters, digits and '_', got {name!r}"
        v = {key: spec.default if values.get(key) is None else values[key] for key, spec in SOURCE_PARAMETERS.items()}
        if v["type"] not in SOURCE_TYPES:
            return f"{name}.type must be one of {list(SOURCE_TYPES)}, got {v['type']!r}"
        pose = list(v["sensor_pose"])
        if len(pose) != 3 or not all(isinstance(x, int | float) and math.isfinite(x) for x in pose):
            return f"{name}.sensor_pose must be three finite numbers [x, y, yaw], got {pose}"
        timeout = v["timeout"]
        if isinstance(timeout, bool) or not isinstance(timeout, int | float) or not 0 <= timeout < math.inf:
            return f"{name}.timeout must be a number >= 0, got {timeout!r}"
        if not 0 <= int(v["cost_threshold"]) <= 100:
            return f"{name}.cost_threshold must lie in [0, 100], got {v['cost_threshold']}"
        return cls(name, str(v["type"]), str(v["topic"] or name), float(timeout), bool(v["required"]),
                   tuple(float(x) for x in pose), int(v["cost_threshold"]))


@dataclasses.dataclass(frozen=True)
class Observation:
    """A source's newest data: obstacle points in the sensor frame (scan) or the map frame (costmap)."""

    points: np.ndarray  # (N, 2)
    frame_id: str
    stamp_ns: int
    received: float  # monotonic s
    version: int
    margin: float = 0.0  # m the points are grown by as they are (a costmap cell's half diagonal)


def parse_scan(msg: LaserScan) -> np.ndarray:
    """A LaserScan's returns as points (N, 2) in its own frame; ValueError with one line if it is malformed."""
    if not finite(msg.angle_min, msg.angle_increment, msg.range_min, msg.range_max):
        raise ValueError("scan angle_min, angle_increment, range_min or range_max is not finite")
    if msg.angle_increment == 0 or msg.range_min < 0 or msg.range_max <= msg.range_min:
        raise ValueError(f"scan has angle_increment {msg.angle_increment}, range [{msg.range_min}, {msg.range_max}]")
    if len(msg.ranges) == 0 or len(msg.ranges) > 100_000:
        raise ValueError(f"scan has {len(msg.ranges)} ranges")
    return scan_points(np.asarray(msg.ranges, float), msg.angle_min, msg.angle_increment, msg.range_min,
                       msg.range_max)


def parse_costmap(msg: OccupancyGrid, threshold: int) -> tuple[np.ndarray, float]:
    """A costmap's obstacle cells as points (N, 2) at their centres, and the cells' half diagonal (m)."""
    try:
        m = parse_map(msg, 0, 0.0)
    except MapRejected as err:
        raise ValueError(str(err)) from None
    ix, iy = np.nonzero(m.occupancy >= threshold)
    centres = np.stack([m.origin[0] + (ix + 0.5) * m.resolution, m.origin[1] + (iy + 0.5) * m.resolution], -1)
    return centres.astype(float), m.resolution / math.sqrt(2)


class ObservationSource:
    """One source: ``on_message`` validates and stores (executor), ``get`` answers data or a reason."""

    def __init__(self, config: SourceConfig) -> None:
        self.config = config
        self._lock = threading.Lock()
        self.current: Observation | None = None
        self.rejected = 0
        self.error = ""
        self._version = 0

    def on_message(self, msg: Any) -> str | None:
        """Take a message; the rejection reason, or None."""
        try:
            if self.config.type == "scan":
                points, margin = parse_scan(msg), 0.0
            else:
                points, margin = parse_costmap(msg, self.config.cost_threshold)
        except ValueError as err:
            self.rejected += 1
            self.error = f"{self.config.name}: {err}"
            return self.error
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        with self._lock:
            self._version += 1
            self.current = Observation(points, msg.header.frame_id, stamp, time.monotonic(), self._version, margin)
        return None

    def get(self, now: float) -> tuple[Observation | None, str]:
        c, name = self.current, self.config.name
        if c is None:
            extra = f" ({self.rejected} rejected, last: {self.error})" if self.error else ""
            return None, f"no data from observation source '{name}' on '{self.config.topic}'{extra}"
        age = now - c.received
        if self.config.timeout > 0 and age > self.config.timeout:
            return None, f"observation source '{name}' is {age:.2f} s old (timeout {self.config.timeout:g} s)"
        return c, ""


    def status(self, now: float) -> dict[str, Any]:
        c = self.current
        return {"type": self.config.type, "topic": self.config.topic,
                "age_s": round(now - c.received, 3) if c else None, "points": len(c.points) if c else 0,
                "rejected": self.rejected, "last_error": self.error}


def live_obstacles(sources: list[ObservationSource], now: float, map_frame: str,
                   pose_at: Callable[[int], Pose2 | None], static_distance: Callable[[np.ndarray], np.ndarray],
                   moving_margin: float) -> tuple[list[PointObstacles], tuple[int, ...], str]:
    """The fresh sources' obstacles in the map frame as disks, grown by ``moving_margin`` (m) where they are not the
    static map (what lies within STATIC_MATCH of a static obstacle is that obstacle, which the map already holds);
    the sources' data versions; and the reason a required source is unusable ("" if none)."""
    out, versions = [], []
    for source in sources:
        data, reason = source.get(now)
        if data is None:
            if source.config.required:
                return [], (), reason
            versions.append(-1)
            continue
        name = source.config.name
        if source.config.type == "scan":  # returns, and disks behind them, placed with the pose at the scan's time
            pose = pose_at(data.stamp_ns)
            if pose is None:
                return [], (), f"observation source '{name}': no robot pose at the scan's stamp"
            sensor = source.config.sensor_pose
            seen = transform(transform(data.points, sensor), pose)
            centres, radius = transform(transform(behind(data.points, RETURN_DEPTH), sensor), pose), RETURN_DEPTH
        elif data.frame_id != map_frame:
            return [], (), f"observation source '{name}' frame '{data.frame_id}' != map frame '{map_frame}' (no tf2)"
        else:  # costmap cells: disks of their half diagonal around their centres
            seen, centres, radius = data.points, data.points, data.margin
        static = static_distance(seen) <= STATIC_MATCH + data.margin if len(seen) else np.zeros(0, bool)
        out += [PointObstacles(centres[static], radius), PointObstacles(centres[~static], radius + moving_margin)]
        versions.append(data.version)
    return out, tuple(versions), ""
