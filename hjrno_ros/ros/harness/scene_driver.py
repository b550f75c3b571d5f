"""A simulated base for :mod:`hjrno_ros.studies.product_scenes` over DDS: it latches the scenes' map, publishes
odometry at 50 Hz, sends the scene's nominal command at 20 Hz, and integrates the robot (car or differential
drive) in real time with the *filtered* command it receives (stale for > 0.25 s: brake) and a random disturbance
‖d‖ ≤ δ·|v| + d₀."""

from __future__ import annotations

import threading
import time

import numpy as np
from geometry_msgs.msg import Twist
from nav_msgs.msg import OccupancyGrid, Odometry
from rclpy.node import Node

from hjrno_ros.core.dynamics import RobotParams
from hjrno_ros.ros.brt_node.messages import LATCHED, occupancy_message, odometry_message
from hjrno_ros.studies import product_scenes
from hjrno_ros.studies.closed_loop import base_step

DT = 0.02  # s: physics and odometry
CMD_PERIOD = 0.05  # s: nominal commands; also the base's dt from speed command to acceleration
STALE = 0.25  # s


class SceneBase(Node):
    def __init__(self, context, params: RobotParams, seed: int = 0) -> None:
        super().__init__("scene_base", context=context)
        self.params, self.rng = params, np.random.default_rng(seed)
        self._lock = threading.Lock()
        self.x = np.zeros((1, 4))
        self.nominal: tuple[float, float] | None = None
        self.filtered, self.filtered_at = np.zeros((1, 2)), -np.inf
        self.states: list[np.ndarray] = []
        self.outputs: list[tuple[float, float]] = []
        self.map_pub = self.create_publisher(OccupancyGrid, "map", LATCHED)
        self.odom_pub = self.create_publisher(Odometry, "odom", 10)
        self.cmd_pub = self.create_publisher(Twist, "cmd_vel_smoothed", 10)
        self.create_subscription(Twist, "cmd_vel", self._on_cmd, 10)
        msg = occupancy_message(product_scenes.scene_map(), product_scenes.RESOLUTION, product_scenes.ORIGIN)
        self.map_pub.publish(msg)
        self.create_timer(DT, self._step)
        self.create_timer(CMD_PERIOD, self._command)

    def _on_cmd(self, msg: Twist) -> None:
        with self._lock:
            self.filtered, self.filtered_at = np.array([[msg.linear.x, msg.angular.z]]), time.monotonic()
            if self.nominal is not None:
                self.outputs.append((msg.linear.x, msg.angular.z))

    def _command(self) -> None:
        if self.nominal is not None:
            twist = Twist()
            twist.linear.x, twist.angular.z = self.nominal
            self.cmd_pub.publish(twist)

    def _step(self) -> None:
        with self._lock:
            if self.nominal is not None:
                fresh = time.monotonic() - self.filtered_at <= STALE
                twist = self.filtered if fresh else np.zeros((1, 2))
                self.x = base_step(self.params, self.x, twist, CMD_PERIOD, DT, self.rng)
                self.states.append(self.x[0].copy())
            x, y, v, theta = self.x[0]
        self.odom_pub.publish(odometry_message(x, y, theta, v, "map", self.get_clock().now().to_msg()))

    def place(self, state: tuple[float, float, float, float]) -> None:
        """Put the robot at ``state`` and hold it there (no nominal command, no integration)."""
        with self._lock:
            self.nominal, self.x = None, np.array([state], float)

    def run(self, scene: product_scenes.Scene) -> tuple[np.ndarray, np.ndarray]:
        """Drive ``scene`` in real time from its start; (states (k, 4), filtered outputs (m, 2))."""
        with self._lock:
            self.x = np.array([scene.start], float)
            self.states, self.outputs = [self.x[0].copy()], []
            self.filtered, self.filtered_at = np.zeros((1, 2)), -np.inf
            self.nominal = scene.nominal
        time.sleep(scene.seconds)
        with self._lock:
            self.nominal = None
            return np.array(self.states), np.array(self.outputs).reshape(-1, 2)
