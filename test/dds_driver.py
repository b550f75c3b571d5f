"""brt_node over real DDS, the shared part of the tests: a driver node that publishes map, odometry and commands and
watches the outputs, the test map, and the node started beside it on a private ROS domain.

Both nodes share one rclpy context on a private ROS domain (from the pid) and one SingleThreadedExecutor on a
background thread.  The model is the bundled ``models/paper_cnn`` if present, else a tiny FNO trained here on the
``ci`` dataset (~20 s).  Test modules in any folder import it (``test/`` is on the path as the conftest's folder).
"""

from __future__ import annotations

import contextlib
import math
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from conftest import wait_for  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from geometry_msgs.msg import Twist  # noqa: E402
from nav_msgs.msg import OccupancyGrid, Odometry  # noqa: E402
from rcl_interfaces.msg import Parameter as ParameterMsg  # noqa: E402
from rcl_interfaces.msg import ParameterType, ParameterValue  # noqa: E402
from rcl_interfaces.srv import SetParameters  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from std_msgs.msg import Float32MultiArray  # noqa: E402

from hjrno_ros.learning import checkpoint  # noqa: E402
from hjrno_ros.ros.brt_node.node import BrtNode  # noqa: E402
from hjrno_ros.ros.harness.plants import HeldPlant  # noqa: E402
from hjrno_ros.ros.harness.sim_base import Rates, SimBase  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DOMAIN = 1 + os.getpid() % 50  # Linux: ids <= 101 avoid the ephemeral port range
RES, ORIGIN, SIZE = 0.1, (-10.0, -10.0), 200  # 20 m x 20 m map
WALL = (slice(150, 154), slice(70, 130))  # x in [5.0, 5.4], y in [-3, 3]
FAR = (-4.0, -4.0)  # > 9 m from every obstacle
NEAR_WALL = (4.4, 0.0)  # 0.6 m in front of the wall
MAP_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def occupancy() -> np.ndarray:
    occ = np.zeros((SIZE, SIZE), np.int8)  # [ix, iy]
    occ[WALL] = 100
    occ[18:21, 168:171] = 100  # small obstacle near (-8, 7)
    return occ


def map_msg(occ: np.ndarray, stamp_sec: int = 1, resolution: float = RES, data=None) -> OccupancyGrid:
    msg = OccupancyGrid()
    msg.header.frame_id = "map"
    msg.header.stamp.sec = stamp_sec
    msg.info.resolution = resolution
    msg.info.width, msg.info.height = occ.shape
    msg.info.origin.position.x, msg.info.origin.position.y = ORIGIN
    msg.info.origin.orientation.w = 1.0
    msg.data = occ.T.ravel().tolist() if data is None else data
    return msg


@pytest.fixture(scope="session")
def model_stem(tmp_path_factory) -> Path:
    bundled = ROOT / "models" / "paper_cnn"
    if checkpoint.paths(bundled)[1].is_file():
        return bundled
    tmp = tmp_path_factory.mktemp("brt_model")
    hjrno = [sys.executable, "-m", "hjrno_ros.cli"]
    subprocess.run([*hjrno, "generate", "--experiment", "ci", "--out", str(tmp / "ci"), "--quiet"], check=True,
                   capture_output=True)
    subprocess.run([*hjrno, "train", "--data", str(tmp / "ci"), "--model", "fno", "--epochs", "1",
                    "--slices-per-epoch", "64", "--model-config", '{"width": 8, "modes": 4, "n_layers": 2}',
                    "--out", str(tmp / "model"), "--quiet"], check=True, capture_output=True)
    return tmp / "model"


class Driver(SimBase):
    """The harness's base holding the robot where a test puts it (``pose`` (x, y, θ), ``v``, ``frame``; odometry at
    20 Hz unless ``odom_on`` is false; quaternions scaled by ``q_scale``), sending Twist commands one at a time
    (:meth:`command`) and recording every output, the value grid and value messages and the node's diagnostics."""

    def __init__(self, context):
        self.held = HeldPlant(*FAR, 0.0, 0.5)
        super().__init__(context, self.held, None, name="brt_test_driver", rates=Rates(0.05, 0.05), stamped=False,
                         keep_grids=False)
        self.out: list[tuple[float, Twist]] = []
        self.grid: OccupancyGrid | None = None
        self.values: Float32MultiArray | None = None
        self.diagnostics: DiagnosticStatus | None = None
        self.create_subscription(Float32MultiArray, "brt/value", lambda m: setattr(self, "values", m), 1)
        self.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)
        self.params, self.enable = self.client("set_parameters"), self.client("enable")
        self.frame, self.odom_on = "map", True
        self.q_scale = 1.0  # odometry quaternions scaled by this (a non-normalised quaternion when != 1)
        self.last_odom = 0.0

    @property
    def pose(self) -> tuple[float, float, float]:
        return self.held.at

    @pose.setter
    def pose(self, pose: tuple[float, float, float]) -> None:
        self.held.at = tuple(pose)

    @property
    def v(self) -> float:
        return self.held.v

    @v.setter
    def v(self, v: float) -> None:
        self.held.v = v

    @property
    def status(self) -> dict:
        return self.log.status

    @status.setter
    def status(self, status: dict) -> None:
        self.log.status = status

    def on_filtered(self, msg: Twist) -> None:
        self.out.append((time.monotonic(), msg))
        super().on_filtered(msg)

    def on_grid(self, msg: OccupancyGrid) -> None:
        self.grid = msg

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith("brt_node:"):
                self.diagnostics = status

    def odometry(self) -> Odometry:
        msg = super().odometry()
        msg.header.frame_id = self.frame
        q = msg.pose.pose.orientation
        q.z, q.w = self.q_scale * q.z, self.q_scale * q.w
        return msg

    def publish_odometry(self) -> None:
        if self.odom_on:
            super().publish_odometry()
            self.last_odom = time.monotonic()

    def set_param(self, name: str, value) -> tuple[bool, str]:
        kind = {float: (ParameterType.PARAMETER_DOUBLE, "double_value"),
                str: (ParameterType.PARAMETER_STRING, "string_value"),
                int: (ParameterType.PARAMETER_INTEGER, "integer_value")}[type(value)]
        pv = ParameterValue(type=kind[0], **{kind[1]: value})
        result = self.call(self.params, SetParameters.Request(parameters=[ParameterMsg(name=name, value=pv)]))
        return result.results[0].successful, result.results[0].reason

    def command(self, linear: float, angular: float, wait: float = 2.0, **axes: float) -> Twist | None:
        """Publish one nominal command (``axes``: other fields, e.g. linear_y=1.0); the first output received
        after it (None: nothing came)."""
        self.out.clear()
        msg = Twist()
        msg.linear.x, msg.angular.z = linear, angular
        for name, value in axes.items():
            part, axis = name.split("_")
            setattr(getattr(msg, part), axis, value)
        self.cmd_pub.publish(msg)
        if not wait_for(lambda: self.out, wait):
            return None
        return self.out[0][1]


@contextlib.contextmanager
def driver_context(domain: int, publish_map: bool = True) -> Iterator[tuple[Driver, SingleThreadedExecutor]]:
    """A driver spinning on its own context and domain; the map is published (transient local) first."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    driver = Driver(context)
    executor = SingleThreadedExecutor(context=context)  # like main(): inference has its own thread
    executor.add_node(driver)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    if publish_map:
        driver.map_pub.publish(map_msg(occupancy()))
        time.sleep(0.2)
    try:
        yield driver, executor
    finally:
        executor.shutdown(timeout_sec=2.0)
        driver.destroy_node()
        rclpy.shutdown(context=context)
        spinner.join(timeout=2.0)


@contextlib.contextmanager
def driver_and_node(model_stem: Path, domain: int, publish_map: bool = True, start: bool = True,
                    **params) -> Iterator[tuple[Driver, BrtNode]]:
    """(driver, node) on their own context and domain; ``start``: configure and activate the node."""
    with driver_context(domain, publish_map) as (driver, executor):
        overrides = [Parameter(k, value=v) for k, v in {"model_path": str(model_stem), "robot_model": "car",
                                                         **params}.items()]
        node = BrtNode(context=driver.context, parameter_overrides=overrides)
        if start:
            node.start()
        executor.add_node(node)
        try:
            yield driver, node
        finally:
            executor.remove_node(node)
            node.destroy_node()


@pytest.fixture(scope="module")
def ros(model_stem):
    with driver_and_node(model_stem, DOMAIN) as pair:
        yield pair


def settle(driver: Driver, x: float, y: float, v: float, theta: float, timeout: float = 10.0) -> dict:
    """Move the robot and wait until the node has a value window around it and is not fail-closed."""
    driver.pose, driver.v, driver.frame, driver.odom_on = (x, y, theta), v, "map", True

    def ready() -> bool:
        st, grid, robot = driver.status, driver.status.get("value_grid"), driver.status.get("robot") or {}
        return (st.get("state") in ("ok", "intervening", "clipped", "unsafe_idle") and grid is not None
                and math.hypot(grid["center"][0] - x, grid["center"][1] - y) < 0.05
                and abs(robot.get("v", math.inf) - v) < 1e-3
                and abs(math.remainder(robot["theta"] - theta, math.tau)) < 1e-3)

    assert wait_for(ready, timeout), driver.status
    return driver.status
