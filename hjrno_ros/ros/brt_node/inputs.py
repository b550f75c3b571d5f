"""The node's inputs, each with its own validity: a map and the robot's state.

Like Nav2 collision_monitor's sources, every input answers ``get(now)`` with its data or the reason
it is unusable at that time; the node's fail-closed check is a loop over them.  Callbacks only
validate and store (cheap: they run on the executor that also filters commands); the map's signed
distance is computed by the value worker (:meth:`MapInput.install`).
"""

from __future__ import annotations

import collections
import dataclasses
import math
import threading
import time
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import OccupancyGrid, Odometry

from hjrno_ros.core import geometry
from hjrno_ros.core.grids import wrap_angle
from hjrno_ros.ros.brt_node.messages import finite, occupancy_array, planar_yaw

MAP_YAW_TOLERANCE = 1e-3  # rad: only axis-aligned maps are supported
Pose2 = tuple[float, float, float]  # (x, y, yaw)
ODOM_MATCH_NS = 200_000_000  # a scan is placed with the odometry sample nearest its stamp, if within 0.2 s


class MapRejected(ValueError):
    """An OccupancyGrid that cannot be used; the reason is the message."""


@dataclasses.dataclass(frozen=True)
class MapData:
    occupancy: np.ndarray  # int8 [ix, iy]
    sd: np.ndarray | None  # signed distance at cell centres, m (None until the worker computes it)
    origin: tuple[float, float]  # lower-left corner of cell (0, 0), m
    resolution: float  # m
    frame_id: str
    stamp: Any  # builtin_interfaces/Time of the map message
    received: float  # monotonic s
    version: int
    occupied_threshold: int = -1
    unknown_is_obstacle: bool = False


def parse_map(msg: OccupancyGrid, version: int, received: float) -> MapData:
    """Validate an OccupancyGrid (cheap); MapRejected with a reason.  ``sd`` is left None."""
    info = msg.info
    w, h, res = int(info.width), int(info.height), float(info.resolution)
    if w <= 0 or h <= 0:
        raise MapRejected(f"map size {w}x{h} is empty")
    if len(msg.data) != w * h:
        raise MapRejected(f"map data has {len(msg.data)} cells, width*height = {w * h}")
    if not (math.isfinite(res) and res > 0):
        raise MapRejected(f"map resolution must be finite and > 0, got {res}")
    p, q = info.origin.position, info.origin.orientation
    if not finite(p.x, p.y):
        raise MapRejected("map origin position is not finite")
    yaw = planar_yaw(q, MAP_YAW_TOLERANCE)
    if yaw is None:
        raise MapRejected("map origin quaternion is zero, not finite, tilted or mirrored")
    if abs(yaw) > MAP_YAW_TOLERANCE:
        raise MapRejected(f"map origin is rotated (yaw {yaw:.4f} rad); only axis-aligned maps are supported")
    occ = occupancy_array(msg)
    lo, hi = int(occ.min()), int(occ.max())
    if lo < -1 or hi > 100:
        raise MapRejected(f"map values must lie in -1..100, got [{lo}, {hi}]")
    return MapData(occ, None, (float(p.x), float(p.y)), res, msg.header.frame_id, msg.header.stamp, received, version)


def with_signed_distance(m: MapData, occupied_threshold: int, unknown_is_obstacle: bool) -> MapData:
    """``m`` with its signed distance (tens of ms for a 400 × 400 map: the worker's job)."""
    try:
        sd = geometry.occupancy_signed_distance(m.occupancy, m.resolution, occupied_threshold, unknown_is_obstacle)
    except ValueError as err:
        raise MapRejected(f"signed distance failed: {err}") from None
    return dataclasses.replace(m, sd=sd.astype(np.float32), occupied_threshold=occupied_threshold,
                               unknown_is_obstacle=unknown_is_obstacle)


class MapInput:
    """The newest valid map.  ``on_message`` validates (executor); ``install`` adds the signed distance (worker)."""

    def __init__(self, topic: str) -> None:
        self.topic = topic
        self._lock = threading.Lock()
        self._version = 0
        self.incoming: MapData | None = None  # validated, signed distance not yet computed
        self.current: MapData | None = None  # with its signed distance
        self.error = ""  # the last rejection
        self.rejected = 0
        self.dirty = False  # threshold or unknown handling changed: recompute the signed distance
        self.signed_distance_ms: float | None = None  # the last install's signed-distance time
        self.recomputed_version = -1  # the version that re-installed the current map (no new message)

    def _next_version(self) -> int:
        with self._lock:
            self._version += 1
            return self._version

    def on_message(self, msg: OccupancyGrid) -> str | None:
        """Take a map; the rejection reason, or None."""
        try:
            m = parse_map(msg, self._next_version(), time.monotonic())
        except MapRejected as err:
            return self.reject(err)
        with self._lock:
            self.incoming = m
        return None

    def reject(self, err: Exception) -> str:
        with self._lock:
            self.rejected += 1
        self.error = str(err)
        return self.error

    def install(self, occupied_threshold: int, unknown_is_obstacle: bool) -> str | None:
        """Make the newest validated map (or, when ``dirty``, the current one again) current with its signed
        distance; the rejection reason, or None."""
        with self._lock:
            m, self.incoming = self.incoming, None
        if m is None and self.dirty and self.current is not None:
            m = dataclasses.replace(self.current, version=self._next_version())
            self.recomputed_version = m.version
        self.dirty = False
        if m is None:
            return None
        start = time.perf_counter()
        try:
            self.current = with_signed_distance(m, occupied_threshold, unknown_is_obstacle)
        except MapRejected as err:
            return self.reject(err)
        self.signed_distance_ms = 1e3 * (time.perf_counter() - start)
        return None

    def get(self, now: float, timeout: float) -> tuple[MapData | None, str]:
        m = self.current
        if m is None:
            if self.incoming is not None:
                return None, "map received, its signed distance is being computed"
            extra = f" ({self.rejected} rejected, last: {self.error})" if self.error else ""
            return None, f"no map received on '{self.topic}'{extra}"
        if timeout > 0 and now - m.received > timeout:
            return None, f"map is {now - m.received:.1f} s old (map_timeout {timeout:g} s)"
        return m, ""


@dataclasses.dataclass(frozen=True)
class OdomSample:
    x: float
    y: float
    yaw: float
    v: float  # m/s, twist.linear.x
    frame_id: str
    stamp_ns: int  # header stamp
    received: float  # monotonic s


@dataclasses.dataclass(frozen=True)
class PoseFix:
    """A map-frame pose and the odometry pose at (nearly) the same time, for dead reckoning."""

    pose: Pose2
    odom: Pose2 | None
    frame_id: str
    received: float


@dataclasses.dataclass(frozen=True)
class RobotState:
    x: float
    y: float
    v: float  # measured, not clipped
    theta: float
    frame_id: str
    stamp_ns: int
    received: float  # monotonic s of the odometry

    def vector(self, v_lo: float, v_hi: float) -> np.ndarray:
        return np.array([self.x, self.y, min(max(self.v, v_lo), v_hi), self.theta])


def compose(a: Pose2, b: Pose2) -> Pose2:
    """SE(2) composition a ∘ b."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2]


def inverse(a: Pose2) -> Pose2:
    c, s = math.cos(a[2]), math.sin(a[2])
    return -c * a[0] - s * a[1], s * a[0] - c * a[1], -a[2]


def _stamp_ns(header: Any) -> int:
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


class StateInput:
    """The robot's state in the map frame: odometry, optionally composed with a map-frame pose (AMCL).

    With ``pose_topic`` the pose is dead-reckoned with odometry between pose messages (map←odom
    correction from the odometry sample nearest the pose's stamp), so a sparse localisation source is
    fine; only odometry has to be fresh.  tf2 is not on PyPI: frames must match the map's.
    """

    def __init__(self, odom_topic: str, pose_topic: str) -> None:
        self.odom_topic, self.pose_topic = odom_topic, pose_topic
        self.odom: OdomSample | None = None
        self._history: collections.deque[OdomSample] = collections.deque(maxlen=250)
        self.fix: PoseFix | None = None

    def on_odom(self, msg: Odometry) -> bool:
        """Take an odometry message; False if it is unusable (NaN/Inf, a zero or non-planar quaternion)."""
        p, v = msg.pose.pose.position, msg.twist.twist.linear.x
        yaw = planar_yaw(msg.pose.pose.orientation)
        if not finite(p.x, p.y, v) or yaw is None:
            return False
        sample = OdomSample(float(p.x), float(p.y), yaw, float(v), msg.header.frame_id, _stamp_ns(msg.header),
                            time.monotonic())
        self.odom = sample
        self._history.append(sample)  # for a pose's or a scan's time
        if self.pose_topic:
            fix = self.fix
            if fix is not None and fix.odom is None:  # pose came first: anchor dead reckoning here
                self.fix = dataclasses.replace(fix, odom=(sample.x, sample.y, sample.yaw))
        return True

    def on_pose(self, msg: PoseWithCovarianceStamped) -> bool:
        """Take a map-frame pose; False if it is unusable."""
        p = msg.pose.pose.position
        yaw = planar_yaw(msg.pose.pose.orientation)
        if not finite(p.x, p.y) or yaw is None:
            return False
        stamp_ns = _stamp_ns(msg.header)
        history = list(self._history)
        odom = None
        if history:  # odometry pose at the pose's time: dead reckoning starts from there
            nearest = min(history, key=lambda s: abs(s.stamp_ns - stamp_ns))
            odom = (nearest.x, nearest.y, nearest.yaw)
        self.fix = PoseFix((float(p.x), float(p.y), yaw), odom, msg.header.frame_id, time.monotonic())
        return True

    def pose_at(self, stamp_ns: int, state: RobotState) -> Pose2 | None:
        """The map-frame pose at ``stamp_ns`` (a scan's stamp): ``state``'s pose moved back by the odometry's motion
        since then; None without an odometry sample within ODOM_MATCH_NS of that time."""
        history, now = list(self._history), self.odom
        if not history or now is None:
            return None
        then = min(history, key=lambda s: abs(s.stamp_ns - stamp_ns))
        if abs(then.stamp_ns - stamp_ns) > ODOM_MATCH_NS:
            return None
        back = compose(inverse((now.x, now.y, now.yaw)), (then.x, then.y, then.yaw))
        return compose((state.x, state.y, state.theta), back)

    def get(self, now: float, timeout: float, map_frame: str | None) -> tuple[RobotState | None, str]:
        odom = self.odom
        if odom is None:
            return None, f"no odometry received on '{self.odom_topic}'"
        age = now - odom.received
        if age > timeout:
            return None, f"odometry is {age:.2f} s old (odom_timeout {timeout:g} s)"
        if self.pose_topic:
            fix = self.fix
            if fix is None:
                return None, f"no pose received on '{self.pose_topic}'"
            if map_frame is not None and fix.frame_id != map_frame:
                return None, (f"pose frame '{fix.frame_id}' != map frame '{map_frame}' (no tf2 from PyPI: "
                              "the pose must be in the map frame)")
            pose = fix.pose  # ∘ the odometry motion since the pose's time
            if fix.odom is not None:
                pose = compose(fix.pose, compose(inverse(fix.odom), (odom.x, odom.y, odom.yaw)))
            frame = fix.frame_id
        else:
            if map_frame is not None and odom.frame_id != map_frame:
                return None, (f"odometry frame '{odom.frame_id}' != map frame '{map_frame}' (tf2 is not available "
                              "from PyPI: publish odometry in the map frame or set pose_topic)")
            pose, frame = (odom.x, odom.y, odom.yaw), odom.frame_id
        theta = float(wrap_angle(pose[2]))
        return RobotState(pose[0], pose[1], odom.v, theta, frame, odom.stamp_ns, odom.received), ""
