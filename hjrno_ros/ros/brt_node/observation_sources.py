"""Live observation sources beside the map, in the manner of Nav2 collision_monitor's ``observation_sources``.

``observation_sources`` names them; each name has its own parameters (:data:`SOURCE_PARAMETERS`, read as
``<name>.type``, ``<name>.topic``, …).  Types:

* ``scan``: sensor_msgs/LaserScan.  The sensor's pose on the robot is a parameter (tf2 is not on PyPI).  Its
  returns are placed in the map frame with the robot's pose *at the scan's stamp* (odometry history).
* ``costmap``: a Nav2 costmap as OccupancyGrid (full updates) in the map frame, e.g. the rolling local costmap.
  Its cells at or above ``cost_threshold`` are obstacles; beyond its edge it says nothing ("not observed"): the
  map input covers the robot there, so a rolling window's edge is no wall.
* ``agents``: tracked agents (people, carts) as sensor_msgs/PointCloud2 in the map frame, one point per agent with
  float32/float64 fields ``x``, ``y``, ``vx``, ``vy`` (m, m/s) and optionally ``radius`` (m; else ``agent_radius``),
  like a radar's tracked-object cloud (no people_msgs or radar_msgs on PyPI's ROS 2 wheels).  Each agent gets its
  own relative value (core/tracked_agents.py; :func:`fresh_agents`); scan returns and costmap cells at an agent are
  *tracked* and not grown by the motion margin, which the agent's value covers.  It adds no obstacle disks.

Each source answers ``get(now)`` with its newest data or the reason it is unusable (none yet, older than its
``timeout``), like the node's other inputs; a stale ``required`` source fails the node closed with the source
named.  The value worker turns the fresh sources into :class:`~hjrno_ros.core.point_obstacles.PointObstacles`
(:func:`live_obstacles`); the node and the worker read the fresh agents with :func:`fresh_agents`.
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
from sensor_msgs.msg import LaserScan, PointCloud2, PointField

from hjrno_ros.core.point_obstacles import STATIC_MATCH, PointObstacles, Pose2, behind, scan_points, transform
from hjrno_ros.core.scan_tracker import ScanTracker, TrackerSettings
from hjrno_ros.core.tracked_agents import Agents, AgentTable
from hjrno_ros.ros.brt_node.inputs import MapRejected, parse_map
from hjrno_ros.ros.brt_node.messages import finite
from hjrno_ros.ros.brt_node.parameters import Param

SOURCE_TYPES = ("scan", "costmap", "agents")
SOURCE_PARAMETERS: dict[str, Param] = {
    "type": Param("scan", "scan (sensor_msgs/LaserScan, sensor-data QoS) | costmap (a Nav2 costmap as OccupancyGrid "
                          "in the map frame, full updates, e.g. the rolling local costmap) | agents (tracked agents "
                          "as PointCloud2 in the map frame, fields x, y, vx, vy and optional radius, sensor-data "
                          "QoS; needs agent_table)", read_only=True),
    "topic": Param("", "the source's topic; '' = the source's name", read_only=True),
    "timeout": Param(0.5, "s: data older than this is stale (receipt time); 0 = never", 0.0, 1e6, read_only=True),
    "required": Param(True, "a stale or missing source fails the node closed; false: it is left out while stale",
                      read_only=True),
    "sensor_pose": Param([0.0, 0.0, 0.0], "scan: the sensor's x (m), y (m) and yaw (rad) on the robot (the "
                                          "odometry's child frame)", read_only=True),
    "cost_threshold": Param(99, "costmap: cost >= threshold is an obstacle (99: Nav2's inscribed cost)", 0, 100,
                            read_only=True),
    "agent_radius": Param(0.2, "agents: m, an agent's radius when the cloud has no radius field; scan with "
                               "track_people: a person's radius", 0.01, 5.0, read_only=True),
    "track_people": Param(False, "scan: follow the returns off the static map from scan to scan; confirmed tracks "
                                 "are tracked agents (needs agent_table), the rest keep the motion margin "
                                 "(core/scan_tracker.py)", read_only=True),
}
RETURN_DEPTH = 0.2  # m: a scan return is the near edge of a disk this wide in radius behind it (a person's torso)
AGENT_MATCH = 0.3  # m: a return or cell this far beyond a tracked agent's disk is that agent (tracking, timing)
AGENT_FIELDS = ("x", "y", "vx", "vy")  # an agents cloud's required fields; "radius" is optional
FLOAT_FORMATS = {PointField.FLOAT32: "f4", PointField.FLOAT64: "f8"}
MAX_AGENTS, MAX_AGENT_RADIUS, MAX_AGENT_SPEED = 1000, 5.0, 10.0  # more, larger or faster: a malformed cloud


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
    agent_radius: float = 0.2
    track_people: bool = False

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
        radius, spec = v["agent_radius"], SOURCE_PARAMETERS["agent_radius"]
        if isinstance(radius, bool) or not isinstance(radius, int | float) or not spec.lo <= radius <= spec.hi:
            return f"{name}.agent_radius must lie in [{spec.lo:g}, {spec.hi:g}] m, got {radius!r}"
        if v["track_people"] and v["type"] != "scan":
            return f"{name}.track_people is for scan sources, {name} is a {v['type']} source"
        return cls(name, str(v["type"]), str(v["topic"] or name), float(timeout), bool(v["required"]),
                   tuple(float(x) for x in pose), int(v["cost_threshold"]), float(radius), bool(v["track_people"]))


@dataclasses.dataclass(frozen=True)
class Observation:
    """A source's newest data: obstacle points in the sensor frame (scan) or the map frame (costmap); for an agents
    source the agents' positions as points and the agents themselves."""

    points: np.ndarray  # (N, 2)
    frame_id: str
    stamp_ns: int
    received: float  # monotonic s
    version: int
    margin: float = 0.0  # m the points are grown by as they are (a costmap cell's half diagonal)
    agents: Agents | None = None  # an agents source's data


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


def cloud_fields(msg: PointCloud2, required: tuple[str, ...], optional: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """The named FLOAT32/FLOAT64 fields of a PointCloud2, one float array (width × height,) each, read from
    ``data`` by its point_step, row_step, offsets, datatypes and byte order (sensor_msgs_py is not on PyPI);
    ValueError with one line when a field is missing or not one float or the data's length does not match."""
    fields = {f.name: f for f in msg.fields}
    if missing := [name for name in required if name not in fields]:
        raise ValueError(f"cloud has no field {missing} (fields {sorted(fields)})")
    names = [name for name in (*required, *optional) if name in fields]
    formats = [FLOAT_FORMATS.get(fields[name].datatype) for name in names]
    for name, fmt in zip(names, formats, strict=True):
        f = fields[name]
        if fmt is None or f.count > 1 or f.offset + int(fmt[1]) > msg.point_step:
            raise ValueError(f"cloud field '{name}' has datatype {f.datatype} x {f.count} at offset {f.offset} of "
                             f"point_step {msg.point_step} (want one FLOAT32 (7) or FLOAT64 (8) inside the point)")
    width, height, step, row = msg.width, msg.height, msg.point_step, msg.row_step
    if row < width * step or len(msg.data) != row * height:
        raise ValueError(f"cloud data has {len(msg.data)} bytes, want row_step {row} x height {height} with "
                         f"row_step >= width {width} x point_step {step}")
    if width * height == 0:
        return {name: np.zeros(0) for name in names}
    order = ">" if msg.is_bigendian else "<"
    dtype = np.dtype({"names": names, "formats": [order + fmt for fmt in formats],
                      "offsets": [fields[name].offset for name in names], "itemsize": step})
    rows = np.frombuffer(msg.data, np.uint8).reshape(height, row)[:, :width * step]
    points = np.ascontiguousarray(rows).view(dtype).reshape(-1)
    return {name: points[name].astype(float) for name in names}


def parse_agents(msg: PointCloud2, radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A tracked-agents cloud's positions and velocities (k, 2) and radii (k,) (``radius`` without a radius
    field); ValueError with one line if it is malformed or implausible (NaN/Inf, a radius outside (0, 5] m, a
    speed over 10 m/s, over 1000 agents)."""
    if msg.width * msg.height > MAX_AGENTS:
        raise ValueError(f"agents cloud has {msg.width * msg.height} points (at most {MAX_AGENTS})")
    c = cloud_fields(msg, AGENT_FIELDS, ("radius",))
    positions, velocities = np.stack([c["x"], c["y"]], -1), np.stack([c["vx"], c["vy"]], -1)
    radii = c.get("radius", np.full(len(positions), float(radius)))
    if not (np.isfinite(positions).all() and np.isfinite(velocities).all() and np.isfinite(radii).all()):
        raise ValueError("agents cloud has NaN or Inf values")
    if np.any((radii <= 0) | (radii > MAX_AGENT_RADIUS)):
        raise ValueError(f"agents cloud has a radius of {radii.min():.3g} or {radii.max():.3g} m, outside "
                         f"(0, {MAX_AGENT_RADIUS:g}]")
    if len(velocities) and (speed := float(np.hypot(*velocities.T).max())) > MAX_AGENT_SPEED:
        raise ValueError(f"agents cloud has an agent at {speed:.3g} m/s (at most {MAX_AGENT_SPEED:g})")
    return positions, velocities, radii


class ObservationSource:
    """One source: ``on_message`` validates and stores (executor), ``get`` answers data or a reason."""

    def __init__(self, config: SourceConfig, agent_table: AgentTable | None = None) -> None:
        """``agent_table``: with ``track_people``, what the tracks are read with (:meth:`track`)."""
        self.config = config
        self._lock = threading.Lock()
        self.current: Observation | None = None
        self.rejected = 0
        self.error = ""
        self._version = 0
        self.tracker: ScanTracker | None = None  # track_people: with the agent tables' settings
        self.tracked: tuple[int, Agents, np.ndarray] | None = None  # (scan version, its agents, their returns)
        if config.track_people and agent_table is not None:
            self.track(agent_table)

    def track(self, table: AgentTable) -> None:
        """Follow people on this scan source's returns, as agents of the tables ``table`` (the value worker feeds the
        tracker: :func:`update_trackers`)."""
        self.tracker, self.tracked = ScanTracker(TrackerSettings.for_table(table, self.config.agent_radius)), None

    def on_message(self, msg: Any) -> str | None:
        """Take a message; the rejection reason, or None."""
        agents = None
        try:
            if self.config.type == "scan":
                points, margin = parse_scan(msg), 0.0
            elif self.config.type == "agents":
                (points, velocities, radii), margin = parse_agents(msg, self.config.agent_radius), 0.0
            else:
                points, margin = parse_costmap(msg, self.config.cost_threshold)
        except ValueError as err:
            self.rejected += 1
            self.error = f"{self.config.name}: {err}"
            return self.error
        stamp, received = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec, time.monotonic()
        if self.config.type == "agents":
            agents = Agents(points, velocities, radii, received)
        with self._lock:
            self._version += 1
            self.current = Observation(points, msg.header.frame_id, stamp, received, self._version, margin, agents)
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
        out = {"type": self.config.type, "topic": self.config.topic,
               "age_s": round(now - c.received, 3) if c else None, "points": len(c.points) if c else 0,
               "rejected": self.rejected, "last_error": self.error}
        if self.config.type == "agents":
            out["agents"] = out["points"]
        elif self.tracker is not None:
            out["agents"] = len(self.tracked[1]) if self.tracked else 0
            out["tracks"] = len(self.tracker.tracks)
        return out


def fresh_agents(sources: list[ObservationSource], now: float, map_frame: str, scans: bool = True,
                 held: tuple[Agents, ...] = ()) -> tuple[Agents | None, str]:
    """The fresh ``agents`` sources' agents and (``scans``) the fresh tracking scans' confirmed tracks merged (None
    without any), or why a source is unusable: a required one stale or missing, any in another frame than the
    map's (no tf2).  A stale optional source is left out.  ``held``: the tracks a value table was made with
    (``ValueData.tracks``), kept beside newer ones: the table left their returns without the margin, and a tracker
    that moved on since may no longer vouch for them."""
    parts = [*held]
    for source in sources:
        if source.tracker is not None:  # a scan's tracks, in the map frame; a stale scan is the scan's check's
            data, _ = source.get(now)
            newer = source.tracked is not None and not any(a is source.tracked[1] for a in held)
            if scans and data is not None and newer:
                parts.append(source.tracked[1])
            continue
        if source.config.type != "agents":
            continue
        data, reason = source.get(now)
        if data is not None and data.frame_id != map_frame:
            return None, (f"observation source '{source.config.name}' frame '{data.frame_id}' != map frame "
                          f"'{map_frame}' (no tf2)")
        if data is None and source.config.required:
            return None, reason
        if data is not None:
            parts.append(data.agents)
    return (merge_agents(parts) if parts else None), ""


def lost_agents(sources: list[ObservationSource], versions: tuple[int, ...], now: float) -> str:
    """Why a value table made from the sources' data ``versions`` cannot be used ("" if it can): it left an agents
    source's (or a scan's tracked) people without the motion margin, and that (optional) source has gone stale
    since."""
    for k, source in enumerate(sources):
        made_with = k < len(versions) and versions[k] >= 0
        agents = source.config.type == "agents" or source.tracker is not None
        if agents and made_with and source.get(now)[0] is None:
            return f"value table made with the agents of '{source.config.name}', which are now stale"
    return ""


def merge_agents(parts: list[Agents]) -> Agents:
    """One Agents of several, as of the oldest receipt: the newer ones' positions predicted back to it, so that
    predicting the whole to any time gives each agent where its own data puts it."""
    received = min(a.received for a in parts)
    return Agents(np.concatenate([a.predicted(received - a.received) for a in parts]).reshape(-1, 2),
                  np.concatenate([a.velocities for a in parts]).reshape(-1, 2),
                  np.concatenate([a.radii for a in parts]), received)


def tracked(points: np.ndarray, agents: Agents | None, now: float) -> np.ndarray:
    """Which ``points`` (N, 2) lie within an agent's radius plus AGENT_MATCH of its position predicted to ``now``."""
    out = np.zeros(len(points), bool)
    if agents is None or len(agents) == 0 or len(points) == 0:
        return out
    centres = agents.predicted(now - agents.received)  # a few agents: every pair
    gaps = np.linalg.norm(points[None, :, :] - centres[:, None, :], axis=-1)
    return (gaps <= (agents.radii + AGENT_MATCH)[:, None]).any(0)


def scan_in_map(source: ObservationSource, data: Observation, pose_at: Callable[[int], Pose2 | None]
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | str:
    """A scan's returns and the centres of the disks behind them in the map frame, placed with the robot's pose at
    the scan's stamp, and the sensor's position then; or why they cannot be placed."""
    pose = pose_at(data.stamp_ns)
    if pose is None:
        return f"observation source '{source.config.name}': no robot pose at the scan's stamp"
    sensor = source.config.sensor_pose
    seen = transform(transform(data.points, sensor), pose)
    centres = transform(transform(behind(data.points, RETURN_DEPTH), sensor), pose)
    return seen, centres, transform(np.asarray(sensor[:2], float), pose)


def update_trackers(sources: list[ObservationSource], now: float, pose_at: Callable[[int], Pose2 | None],
                    static_distance: Callable[[np.ndarray], np.ndarray]) -> None:
    """Feed each tracking scan source's newest scan, once, to its tracker: the returns off the static map (farther
    than STATIC_MATCH from its obstacles), in the map frame.  A scan without a pose at its stamp is skipped (the
    value worker's :func:`live_obstacles` reports it); one the tracker refuses (stamped no later than the last)
    leaves no tracks, so its returns keep the margin."""
    for source in sources:
        data, _ = source.get(now)
        if source.tracker is None or data is None or (source.tracked and source.tracked[0] == data.version):
            continue
        placed = scan_in_map(source, data, pose_at)
        if isinstance(placed, str):
            continue
        seen, _, sensor = placed
        off_map = np.nonzero(static_distance(seen) > STATIC_MATCH)[0] if len(seen) else np.zeros(0, int)
        if not source.tracker.update(seen[off_map], sensor, data.stamp_ns * 1e-9, data.received):
            source.tracked = None  # a duplicate or reordered scan: its returns keep the margin
            continue
        theirs = np.zeros(len(seen), bool)
        theirs[off_map[source.tracker.confirmed_returns()]] = True
        source.tracked = (data.version, source.tracker.agents(), theirs)


def live_obstacles(sources: list[ObservationSource], now: float, map_frame: str,
                   pose_at: Callable[[int], Pose2 | None], static_distance: Callable[[np.ndarray], np.ndarray],
                   agents: Agents | None = None, approach: float = 0.0
                   ) -> tuple[list[PointObstacles], tuple[int, ...], str]:
    """The fresh sources' obstacles in the map frame as disks, marked as approaching at ``approach`` m/s since their
    data arrived (:class:`PointObstacles`; the users grow them) where they are neither the static map (what lies
    within STATIC_MATCH of a static obstacle is that obstacle, which the map already holds) nor a tracked agent in
    ``agents`` (the agents sources': :func:`fresh_agents` with ``scans`` False) nor a return of the scan's own
    confirmed tracks (:func:`update_trackers`): an agent's own value covers its motion.  Also the sources' data
    versions (an agents source's too, so that new agents make a new table) and the reason a required source is
    unusable ("" if none).  Agents sources add no disks."""
    out, versions = [], []
    for source in sources:
        data, reason = source.get(now)
        if data is None:
            if source.config.required:
                return [], (), reason
            versions.append(-1)
            continue
        name = source.config.name
        versions.append(data.version)
        if source.config.type == "agents":
            continue
        if source.config.type == "scan":  # returns, and disks behind them, placed with the pose at the scan's time
            placed = scan_in_map(source, data, pose_at)
            if isinstance(placed, str):
                return [], (), placed
            (seen, centres, _), radius = placed, RETURN_DEPTH
        elif data.frame_id != map_frame:
            return [], (), f"observation source '{name}' frame '{data.frame_id}' != map frame '{map_frame}' (no tf2)"
        else:  # costmap cells: disks of their half diagonal around their centres
            seen, centres, radius = data.points, data.points, data.margin
        static = static_distance(seen) <= STATIC_MATCH + data.margin if len(seen) else np.zeros(0, bool)
        kept = static | tracked(seen, agents, now)
        if source.tracked is not None and source.tracked[0] == data.version:  # its own confirmed tracks' returns
            kept |= source.tracked[2]
        out += [PointObstacles(centres[kept], radius),
                PointObstacles(centres[~kept], radius, approach, data.received)]
    return out, tuple(versions), ""
