"""The load generator of ``hjrno bench node``: drives a running brt_node over DDS and records latencies."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import OccupancyGrid, Odometry
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import LaserScan
from std_msgs.msg import String
from std_srvs.srv import SetBool

from hjrno_ros.ros.brt_node.messages import LATCHED, occupancy_message, odometry_message
from hjrno_ros.ros.harness.commands import StampedCommands
from hjrno_ros.ros.harness.spin import spin_in_background

NODE_NAME = "brt_node"


class BenchDriver(Node):
    """Drives a running brt_node over DDS and records latencies (perf_counter, this process).

    Publishes a static robot's odometry at ``odom_rate`` and TwistStamped commands at ``cmd_rate``
    (each keyed by its stamp, which the node copies through); ``publish_map`` latches a map and
    remembers when.  Latencies: command → filtered command (matched by stamp) and map → value grid
    (matched by ``info.map_load_time`` = the map's stamp).
    """

    def __init__(self, context: Any, pose: tuple[float, float, float], speed: float, frame_id: str = "map",
                 odom_rate: float = 50.0, cmd_rate: float = 20.0, scan_rate: float = 0.0) -> None:
        super().__init__("brt_bench_driver", context=context)
        qos = LATCHED
        self.pose, self.speed, self.frame_id = pose, speed, frame_id
        self.map_pub = self.create_publisher(OccupancyGrid, "map", qos)
        self.odom_pub = self.create_publisher(Odometry, "odom", 10)
        self.cmd_pub = self.create_publisher(TwistStamped, "cmd_vel_smoothed", 10)
        self.commands = StampedCommands(self, self.cmd_pub)
        self.cmd_latency: list[float] = []  # s
        self.map_sent: dict[tuple[int, int], float] = {}
        self.map_latency: list[float] = []  # s
        self.status: dict = {}
        self.sending = False
        self.create_subscription(TwistStamped, "cmd_vel", self._on_out, 50)
        self.create_subscription(OccupancyGrid, "brt/value_grid", self._on_grid, qos)
        self.first_status: float | None = None  # monotonic s of the node's first status
        self.create_subscription(String, "brt/status", self._on_status, 10)
        self.create_timer(1.0 / odom_rate, self._odom)
        self.create_timer(1.0 / cmd_rate, self._cmd)
        if scan_rate > 0:
            self.scan_pub = self.create_publisher(LaserScan, "scan", qos_profile_sensor_data)
            self.scans = 0
            self.create_timer(1.0 / scan_rate, self._scan)

    def _scan(self) -> None:
        """A 720-beam scan: a ring of walls 4 m away and a person 2.5 m ahead who walks from side to side."""
        msg = LaserScan()
        msg.header.frame_id, msg.header.stamp = "laser", self.get_clock().now().to_msg()
        msg.angle_min, msg.angle_increment, msg.range_min, msg.range_max = -math.pi, math.pi / 360, 0.05, 12.0
        msg.angle_max = msg.angle_min + 719 * msg.angle_increment
        angles = msg.angle_min + msg.angle_increment * np.arange(720)
        ranges = np.full(720, 4.0)
        person = 0.6 * math.sin(0.8 * self.scans / 10.0)  # lateral offset, m
        bearing = math.atan2(person, 2.5)
        ranges[np.abs(angles - bearing) < 0.12] = math.hypot(2.5, person)
        msg.ranges = ranges.tolist()
        self.scans += 1
        self.scan_pub.publish(msg)

    def _on_status(self, msg: String) -> None:
        if self.first_status is None:
            self.first_status = time.monotonic()
        self.status = json.loads(msg.data)

    def publish_map(self, occupancy: np.ndarray, resolution: float, origin: tuple[float, float], sec: int) -> None:
        msg = occupancy_message(occupancy, resolution, origin, self.frame_id)
        msg.header.stamp.sec = sec
        self.map_sent[(sec, 0)] = time.perf_counter()
        self.map_pub.publish(msg)

    def _odom(self) -> None:
        self.odom_pub.publish(odometry_message(*self.pose, self.speed, self.frame_id,
                                               self.get_clock().now().to_msg()))

    def _cmd(self) -> None:
        if not self.sending:
            return
        self.commands.send(np.array([self.speed, 0.1]))

    def _on_out(self, msg: TwistStamped) -> None:
        _, latency, _ = self.commands.answer(msg)
        if latency is not None:
            self.cmd_latency.append(latency)

    def _on_grid(self, msg: OccupancyGrid) -> None:
        sent = self.map_sent.pop((msg.info.map_load_time.sec, msg.info.map_load_time.nanosec), None)
        if sent is not None:
            self.map_latency.append(time.perf_counter() - sent)


def bench_drive(domain_id: int, maps: list[np.ndarray], resolution: float, origin: tuple[float, float],
                pose: tuple[float, float, float], speed: float, seconds: float, bypass_seconds: float = 0.0,
                map_period: float = 1.0, ready_timeout: float = 120.0, on_ready: Callable[[], None] | None = None,
                on_done: Callable[[], None] | None = None, alive: Callable[[], bool] = lambda: True,
                scan_rate: float = 0.0) -> dict:
    """Run a BenchDriver against a brt_node on ``domain_id``.

    Waits until the node filters (status ok), calls ``on_ready``, sends commands for ``seconds`` while
    publishing the next of ``maps`` every ``map_period``, calls ``on_done``; then, if ``bypass_seconds``
    > 0, bypasses the filter (``~/enable`` false) and sends commands for that long again: the same
    process and DDS path without the filter, a baseline for the command latency.  Returns raw
    latencies (s), counts and the node's last status.
    """
    driver, stop = spin_in_background(domain_id, lambda c: BenchDriver(c, pose, speed, scan_rate=scan_rate))
    enable = driver.create_client(SetBool, f"/{NODE_NAME}/enable")
    try:
        driver.publish_map(maps[0], resolution, origin, 1)
        end = time.monotonic() + ready_timeout
        while driver.status.get("state") != "ok":
            if time.monotonic() > end or not alive():
                raise RuntimeError(f"brt_node did not become ready: {driver.status.get('reason', 'no status')}")
            time.sleep(0.05)
        driver.map_latency.clear()  # the first map also waited for odometry and start-up
        ready_at = time.monotonic()
        if on_ready is not None:
            on_ready()
        driver.sending = True
        start = time.monotonic()
        k = 1
        while time.monotonic() - start + map_period <= seconds and alive():
            time.sleep(map_period)
            k += 1
            driver.publish_map(maps[(k - 1) % len(maps)], resolution, origin, k)
        time.sleep(max(0.0, seconds - (time.monotonic() - start)))
        driver.sending = False
        if on_done is not None:
            on_done()
        time.sleep(0.5)  # let the last outputs arrive
        sent = len(driver.cmd_latency) + driver.commands.unanswered
        result = {"cmd_latency_s": list(driver.cmd_latency), "cmd_sent": sent,
                  "map_latency_s": list(driver.map_latency), "maps_sent": k - 1, "status": dict(driver.status),
                  "bypass_latency_s": [], "bypass_sent": 0, "first_status_at": driver.first_status,
                  "ready_at": ready_at}
        if bypass_seconds > 0 and alive():
            if not enable.wait_for_service(timeout_sec=5.0):
                raise RuntimeError("brt_node's ~/enable service is not available")
            future = enable.call_async(SetBool.Request(data=False))
            end = time.monotonic() + 5.0
            while not future.done() and time.monotonic() < end:
                time.sleep(0.01)
            driver.cmd_latency.clear()
            driver.commands.forget()
            driver.sending = True
            time.sleep(bypass_seconds)
            driver.sending = False
            time.sleep(0.5)
            result["bypass_latency_s"] = list(driver.cmd_latency)
            result["bypass_sent"] = len(driver.cmd_latency) + driver.commands.unanswered
        return result
    finally:
        stop()
