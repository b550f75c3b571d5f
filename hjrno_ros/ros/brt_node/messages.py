"""Message conversions at the ROS boundary: occupancy rasters, odometry, commands, value grids.

Rasters in the core are ``[ix, iy]``; ROS's OccupancyGrid is row-major with x fastest
(``data[iy * width + ix]``): converted here and nowhere else (docs/design.md, "Conventions").
"""

from __future__ import annotations

import array
import math
from typing import Any

import numpy as np
from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import OccupancyGrid, Odometry
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float32MultiArray, MultiArrayDimension

# map_server / AMCL: reliable, transient local, depth 1 (a volatile subscriber never gets the map)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


PLANAR_TILT = 0.2  # rad: the most roll/pitch a planar robot's pose may have (ramps, sensor noise)


def planar_yaw(q: Any, tilt: float = PLANAR_TILT) -> float | None:
    """Yaw (rad) of a geometry_msgs Quaternion after normalising it; None if it is non-finite, (nearly) zero,
    or tilted more than ``tilt`` from the plane (a mirrored pose is tilted by π)."""
    if not finite(q.x, q.y, q.z, q.w):
        return None
    norm2 = q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w
    if not 1e-12 <= norm2 < math.inf:
        return None
    x, y, z, w = (c / math.sqrt(norm2) for c in (q.x, q.y, q.z, q.w))
    if 1.0 - 2.0 * (x * x + y * y) < math.cos(tilt):  # the body z axis' z component: cos(tilt)
        return None
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def occupancy_array(msg: OccupancyGrid) -> np.ndarray:
    """OccupancyGrid data as an int8 array ``[ix, iy]``."""
    data = msg.data
    flat = np.frombuffer(data, np.int8) if isinstance(data, array.array) else np.asarray(data, np.int8)
    return flat.reshape(msg.info.height, msg.info.width).T


def occupancy_message(occupancy: np.ndarray, resolution: float, origin: tuple[float, float],
                      frame_id: str = "map") -> OccupancyGrid:
    """The inverse of :func:`occupancy_array`: an int8 raster ``[ix, iy]`` as an OccupancyGrid (no stamp)."""
    msg = OccupancyGrid()
    msg.header.frame_id = frame_id
    msg.info.resolution = float(resolution)  # rclpy does not type-check fields: an int would be garbage
    msg.info.width, msg.info.height = occupancy.shape
    msg.info.origin.position.x, msg.info.origin.position.y = float(origin[0]), float(origin[1])
    msg.info.origin.orientation.w = 1.0
    msg.data = array.array("b", np.ascontiguousarray(occupancy.T, np.int8).tobytes())
    return msg


def odometry_message(x: float, y: float, yaw: float, speed: float, frame_id: str, stamp: Any) -> Odometry:
    """Odometry of a planar robot: pose (x, y, yaw) in ``frame_id``, forward speed in twist.linear.x."""
    msg = Odometry()
    msg.header.frame_id = frame_id
    msg.child_frame_id = "base_link"
    msg.header.stamp = stamp
    msg.pose.pose.position.x, msg.pose.pose.position.y = float(x), float(y)
    q = msg.pose.pose.orientation
    q.z, q.w = math.sin(yaw / 2), math.cos(yaw / 2)
    msg.twist.twist.linear.x = float(speed)
    return msg


def command_message(linear: float, angular: float, stamped: bool, header: Any = None,
                    stamp: Any = None, frame_id: str = "") -> Twist | TwistStamped:
    """A planar command; stamped with ``header`` (the nominal's, copied through) or ``stamp``/``frame_id``."""
    twist = Twist()
    twist.linear.x, twist.angular.z = float(linear), float(angular)
    if not stamped:
        return twist
    out = TwistStamped()
    if header is not None:
        out.header = header
    else:
        out.header.stamp = stamp
        out.header.frame_id = frame_id
    out.twist = twist
    return out


def value_messages(values: np.ndarray, info: dict, stamp_ns: int, map_stamp: Any,
                   value_clip: float) -> tuple[OccupancyGrid, Float32MultiArray]:
    """V on the window nodes ``[ix, iy]`` as a costmap-palette OccupancyGrid (V <= 0 -> 100, V >= value_clip -> 0)
    and as metres in a Float32MultiArray (row-major, x fastest, dims ("y", "x"))."""
    nx, ny = values.shape
    grid = OccupancyGrid()
    grid.header.frame_id = info["frame_id"]
    grid.header.stamp.sec, grid.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    grid.info.map_load_time = map_stamp
    grid.info.resolution = float(info["resolution"])
    grid.info.width, grid.info.height = nx, ny
    grid.info.origin.position.x, grid.info.origin.position.y = info["origin"]
    grid.info.origin.orientation.w = 1.0
    cost = np.clip(np.rint(100.0 * (1.0 - values / value_clip)), 0, 100).astype(np.int8)
    grid.data = array.array("b", cost.T.tobytes())
    arr = Float32MultiArray()
    arr.layout.dim = [MultiArrayDimension(label="y", size=ny, stride=nx * ny),
                      MultiArrayDimension(label="x", size=nx, stride=nx)]
    arr.data = array.array("f", np.ascontiguousarray(values.T).tobytes())
    return grid, arr


def command_type_mismatch(node: Any, in_topic: str, out_topic: str, stamped: bool) -> list[str]:
    """Publishers of ``in_topic`` and subscribers of ``out_topic`` (other than ``node``) whose type is the other
    Twist flavour: DDS never connects them, so nothing they send arrives.  Read from the ROS graph."""
    want = "geometry_msgs/msg/" + ("TwistStamped" if stamped else "Twist")
    found = []
    for topic, endpoints in ((in_topic, node.get_publishers_info_by_topic),
                             (out_topic, node.get_subscriptions_info_by_topic)):
        name = node.resolve_topic_name(topic)
        kinds = {e.topic_type for e in endpoints(name) if e.node_name != node.get_name()}
        found += [f"{name}: {k} (this node uses {want}: enable_stamped_cmd_vel)" for k in sorted(kinds - {want})]
    return found
