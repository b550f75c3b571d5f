"""The node's ROS interfaces, made on configure and destroyed on cleanup: publishers, subscriptions (with the
QoS of docs/node.md), timers and the ``~/enable`` service, in callback groups that keep one writer of cmd_vel;
and the lifecycle service's refusal of transitions that do not exist."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseWithCovarianceStamped, Twist, TwistStamped
from nav_msgs.msg import OccupancyGrid, Odometry
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import LaserScan, PointCloud2
from std_msgs.msg import Float32MultiArray, String
from std_srvs.srv import SetBool

from hjrno_ros.ros.brt_node import status
from hjrno_ros.ros.brt_node.config import NodeConfig
from hjrno_ros.ros.brt_node.messages import LATCHED

SOURCE_SUBSCRIPTIONS = {  # an observation source's type: its message and QoS
    "scan": (LaserScan, qos_profile_sensor_data),
    "costmap": (OccupancyGrid, LATCHED),
    # best effort (depth 5) matches a tracker's reliable publisher and a radar driver's best-effort one alike
    "agents": (PointCloud2, qos_profile_sensor_data),
}


class Interfaces:
    """``callbacks``: map, odom, pose, cmd, control, status, diagnostics, enable; ``sources``: one callback per
    observation source's name (:data:`SOURCE_SUBSCRIPTIONS`: a LaserScan or tracked agents' PointCloud2 with
    sensor-data QoS, a costmap reliable + transient local)."""

    def __init__(self, node: Any, cfg: NodeConfig, callbacks: dict[str, Callable[..., Any]],
                 sources: dict[str, Callable[..., Any]] | None = None) -> None:
        self._node, self._made = node, []
        cmd_type = TwistStamped if cfg.enable_stamped_cmd_vel else Twist
        cmd_group = MutuallyExclusiveCallbackGroup()  # command in/out and the stop timer: one cmd_vel writer
        state_group, map_group, misc_group, source_group = (MutuallyExclusiveCallbackGroup() for _ in range(4))
        pub, sub, timer = node.create_publisher, node.create_subscription, node.create_timer
        self.cmd = self._keep(node.destroy_publisher, pub(cmd_type, cfg.cmd_vel_out_topic, 10))
        self.grid = self._keep(node.destroy_publisher, pub(OccupancyGrid, cfg.value_grid_topic, LATCHED))
        self.value = self._keep(node.destroy_publisher, pub(Float32MultiArray, cfg.value_topic, 1))
        self.status = self._keep(node.destroy_publisher, pub(String, cfg.status_topic, 10))
        self.diagnostics = self._keep(node.destroy_publisher, pub(DiagnosticArray, "/diagnostics", 10))
        subscriptions = [(OccupancyGrid, cfg.map_topic, "map", LATCHED, map_group),
                         (Odometry, cfg.odom_topic, "odom", qos_profile_sensor_data, state_group),
                         (cmd_type, cfg.cmd_vel_in_topic, "cmd", 10, cmd_group)]
        if cfg.pose_topic:
            subscriptions.append((PoseWithCovarianceStamped, cfg.pose_topic, "pose", LATCHED, state_group))
        for kind, topic, name, qos, group in subscriptions:
            self._keep(node.destroy_subscription, sub(kind, topic, callbacks[name], qos, callback_group=group))
        for source in cfg.sources:  # their own group: a scan's parsing never waits behind a map's
            kind, qos = SOURCE_SUBSCRIPTIONS[source.type]
            self._keep(node.destroy_subscription, sub(kind, source.topic, (sources or {})[source.name], qos,
                                                      callback_group=source_group))
        self.control_timer = self._keep(node.destroy_timer, timer(cfg.control_period, callbacks["control"],
                                                                  callback_group=cmd_group))
        for period, name in ((status.STATUS_PERIOD, "status"), (status.DIAGNOSTICS_PERIOD, "diagnostics")):
            self._keep(node.destroy_timer, timer(period, callbacks[name], callback_group=misc_group))
        self._keep(node.destroy_service, node.create_service(SetBool, "~/enable", callbacks["enable"],
                                                             callback_group=misc_group))

    def _keep(self, destroy: Callable[[Any], Any], entity: Any) -> Any:
        self._made.append((destroy, entity))
        return entity

    def destroy(self) -> None:
        for destroy, entity in reversed(self._made):
            destroy(entity)
        self._made.clear()


def refuse_invalid_transitions(node: Any) -> None:
    """Make the lifecycle node's change_state service answer a transition that does not exist from the present
    state (activate while active, an unknown id) with success false and a warning; rclpy raises out of the
    executor instead, which would end the node."""
    service = getattr(node, "_service_change_state", None)
    if service is None:
        return
    change_state = service.callback

    def callback(request: Any, response: Any) -> Any:
        try:
            return change_state(request, response)
        except _rclpy.RCLError as err:
            node.get_logger().warning(f"lifecycle transition {request.transition.id} "
                                      f"'{request.transition.label}' refused: {err}")
            response.success = False
            return response

    service.callback = callback
