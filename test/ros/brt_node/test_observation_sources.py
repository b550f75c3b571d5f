"""Observation sources beside the map: laser scans and rolling costmaps, each with its own timeout; obstacles off
the static map grown for their possible motion.  Geometry without DDS, then brt_node over real DDS."""

from __future__ import annotations

import math
import os
import threading
import time
import types
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from conftest import wait_for  # noqa: E402
from dds_driver import FAR, driver_and_node, occupancy  # noqa: E402
from rclpy.qos import qos_profile_sensor_data  # noqa: E402
from sensor_msgs.msg import LaserScan  # noqa: E402

from hjrno_ros.core.point_obstacles import PointObstacles, behind, scan_points, transform  # noqa: E402
from hjrno_ros.ros.brt_node.config import NodeConfig  # noqa: E402
from hjrno_ros.ros.brt_node.observation_sources import (  # noqa: E402
    RETURN_DEPTH,
    STATIC_MATCH,
    ObservationSource,
    SourceConfig,
    live_obstacles,
    parse_costmap,
    parse_scan,
)

DOMAIN = 51 + os.getpid() % 50
ROOT = Path(__file__).resolve().parents[3]
DIFF_DRIVE = {"model_path": str(ROOT / "models" / "default"), "robot_model": "diff_drive"}  # the product default


def scan_msg(ranges: list[float], stamp=None) -> LaserScan:
    msg = LaserScan()
    msg.header.frame_id = "laser"
    if stamp is not None:
        msg.header.stamp = stamp
    msg.angle_min, msg.angle_increment = -math.pi, 2 * math.pi / len(ranges)
    msg.angle_max = msg.angle_min + msg.angle_increment * (len(ranges) - 1)
    msg.range_min, msg.range_max = 0.05, 10.0
    msg.ranges = [float(r) for r in ranges]
    return msg


def person_ahead(distance: float, beams: int = 360, half_width: float = 0.2) -> list[float]:
    """Ranges of a scan that sees one object ``distance`` m straight ahead, about 2·half_width m wide."""
    angles = -math.pi + 2 * math.pi / beams * np.arange(beams)
    return [distance if abs(a) <= half_width / distance else math.inf for a in angles]


def test_scan_returns_become_points_in_the_map_frame():
    pts = scan_points(np.array([1.0, np.inf, np.nan, 0.01, 2.0]), -math.pi / 2, math.pi / 2, 0.05, 10.0)
    assert pts == pytest.approx(np.array([[0.0, -1.0], [0.0, -2.0]]), abs=1e-12)  # inf, NaN, under range: none
    moved = transform(transform(pts, (0.1, 0.0, 0.0)), (2.0, 3.0, math.pi / 2))  # sensor on the base, base in map
    assert moved == pytest.approx(np.array([[3.0, 3.1], [4.0, 3.1]]), abs=1e-12)
    obstacles = PointObstacles(moved, margin=0.25)
    assert obstacles.distance(np.array([[3.0, 4.1], [4.0, 3.1]])) == pytest.approx([0.75, -0.25])
    assert np.all(np.isinf(PointObstacles(np.zeros((0, 2))).distance(np.zeros((3, 2)))))


def test_the_distance_to_many_returns_is_the_exact_nearest_one():
    rng = np.random.default_rng(2)
    returns, nodes = rng.uniform(-5.0, 5.0, (1500, 2)), rng.uniform(-4.0, 4.0, (32, 32, 2))
    exact = np.linalg.norm(nodes[:, :, None, :] - returns, axis=-1).min(-1) - 0.1
    np.testing.assert_allclose(PointObstacles(returns, margin=0.1).distance(nodes), exact, atol=1e-12)


def test_malformed_sources_and_scans_are_refused_with_one_line():
    assert "type" in SourceConfig.build("scan", {"type": "sonar"})
    assert "sensor_pose" in SourceConfig.build("scan", {"sensor_pose": [0.0, math.nan, 0.0]})
    assert "names" in SourceConfig.build("front scan", {})
    cfg = SourceConfig.build("front", {"sensor_pose": [0, 0, 1], "timeout": 0.2})  # integers accepted
    assert cfg == SourceConfig("front", "scan", "front", 0.2, True, (0.0, 0.0, 1.0), 99)
    values = NodeConfig().as_dict()
    assert "twice" in NodeConfig.build({**values, "observation_sources": ["a", "a"]}, startup=True)
    built = NodeConfig.build({**values, "observation_sources": ["a"]}, startup=True, sources={"a": {"type": "scan"}})
    assert built.sources == (SourceConfig("a", topic="a"),)
    bad = scan_msg([1.0] * 8)
    bad.angle_increment = math.nan
    with pytest.raises(ValueError, match="not finite"):
        parse_scan(bad)
    source = ObservationSource(cfg)
    assert "not finite" in source.on_message(bad) and source.rejected == 1
    assert "no data from observation source 'front'" in source.get(time.monotonic())[1]


def test_a_rolling_costmaps_edge_is_not_an_obstacle():
    from dds_driver import map_msg

    occ = np.zeros((30, 30), np.int8)  # a 3 m rolling window at 0.1 m with one lethal cell
    occ[20, 10] = 100
    points, half_diagonal = parse_costmap(map_msg(occ), 99)
    assert points.shape == (1, 2) and half_diagonal == pytest.approx(0.1 / math.sqrt(2))
    assert points[0] == pytest.approx([-10.0 + 2.05, -10.0 + 1.05])  # the cell's centre; nothing at the edges


def test_returns_on_the_static_map_keep_no_motion_margin():
    source = ObservationSource(SourceConfig("scan", timeout=0.5))
    source.on_message(scan_msg([1.0, 3.0, math.inf, math.inf]))  # beams at -π (1 m behind) and -π/2 (3 m right)
    wall_behind = lambda pts: np.linalg.norm(pts - [-1.0, 0.0], axis=-1)  # noqa: E731 - a static obstacle there
    obstacles, versions, reason = live_obstacles([source], time.monotonic(), "map", lambda _: (0.0, 0.0, 0.0),
                                                 wall_behind, approach=1.0)
    assert reason == "" and versions == (1,)
    static, moving = obstacles  # disks of RETURN_DEPTH behind each return, the unmapped one approaching
    assert static.points == pytest.approx(np.array([[-1.0 - RETURN_DEPTH, 0.0]]), abs=1e-9)
    assert moving.points == pytest.approx(np.array([[0.0, -3.0 - RETURN_DEPTH]]), abs=1e-9)
    assert (static.margin, moving.margin) == (RETURN_DEPTH, RETURN_DEPTH)
    assert (static.approach, moving.approach) == (0.0, 1.0) and moving.received == source.current.received
    assert static.distance(np.array([-0.5, 0.0])) == pytest.approx(0.5)  # the return is the disk's edge
    assert static.distance(np.array([-1.25, 0.0])) < 0  # behind it: inside, a signed distance
    assert STATIC_MATCH < 0.8
    assert behind(np.array([[3.0, 4.0]]), 0.5) == pytest.approx(np.array([[3.3, 4.4]]))
    stale = ObservationSource(SourceConfig("scan", timeout=0.01))
    stale.on_message(scan_msg([1.0] * 4))
    time.sleep(0.05)
    assert "is 0.0" in live_obstacles([stale], time.monotonic(), "map", lambda _: (0, 0, 0), wall_behind)[2]
    optional = ObservationSource(SourceConfig("scan", timeout=0.01, required=False))
    assert live_obstacles([optional], time.monotonic(), "map", lambda _: (0, 0, 0), wall_behind)[:2] == \
        ([], (-1,))


class Periodic:
    """Publishes ``self.message()`` on ``topic`` at 10 Hz from a thread while ``on``, until stopped."""

    def __init__(self, driver, kind, topic: str, qos) -> None:
        self.driver, self.on = driver, True
        self.pub = driver.create_publisher(kind, topic, qos)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def message(self):
        raise NotImplementedError

    def _run(self) -> None:
        while not self._stop.wait(0.1):
            if self.on:
                self.pub.publish(self.message())

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)


class Scanner(Periodic):
    """The robot's laser: scans from ``ranges``."""

    def __init__(self, driver, ranges: list[float]) -> None:
        self.ranges = ranges
        super().__init__(driver, LaserScan, "scan", qos_profile_sensor_data)

    def message(self) -> LaserScan:
        return scan_msg(self.ranges, self.driver.get_clock().now().to_msg())


def forward(driver, linear: float) -> types.SimpleNamespace:
    out = driver.command(linear, 0.0)
    assert out is not None
    return types.SimpleNamespace(linear=out.linear.x, angular=out.angular.z)


def test_a_scan_source_stops_the_robot_before_what_only_the_laser_sees(model_stem):
    """At FAR the map is empty for 9 m: only the laser sees the person 0.6 m ahead of the robot at 1 m/s, inside
    its stopping distance (0.5 m at 1 m/s²) plus the inflation.  An empty scan passes the command; the person's
    scan brakes it; a silent laser fails the node closed, naming the source."""
    with driver_and_node(model_stem, DOMAIN, observation_sources=["scan"], obstacle_speed_max=0.0,
                         **DIFF_DRIVE, **{"scan.sensor_pose": [0.1, 0.0, 0.0]}) as (driver, _node):
        scanner = Scanner(driver, [math.inf] * 360)
        try:
            driver.pose, driver.v = (*FAR, 0.0), 1.0
            assert wait_for(lambda: driver.status.get("state") == "ok", 30.0), driver.status
            assert driver.status["observation_sources"]["scan"]["points"] == 0
            assert forward(driver, 1.0).linear == pytest.approx(1.0)  # nothing seen: unchanged
            scanner.ranges = person_ahead(1.9)  # 2 m ahead: far beyond the stopping distance, no motion margin
            assert wait_for(lambda: driver.status.get("observation_sources", {}).get("scan", {}).get("points", 0) > 0,
                            5.0)
            assert forward(driver, 1.0).linear == pytest.approx(1.0)  # least restrictive: unchanged
            scanner.ranges = person_ahead(0.5)  # 0.6 m from the robot's centre
            assert wait_for(lambda: driver.status.get("observation_sources", {}).get("scan", {}).get("points", 0) > 0
                            and driver.status.get("value") is not None and driver.status["value"] < 0.3, 10.0), \
                driver.status
            out = forward(driver, 1.0)
            assert out.linear < 1.0, out  # towards the person: braking
            scanner.on = False
            assert wait_for(lambda: driver.status.get("state") == "fail_closed", 5.0), driver.status
            assert "observation source 'scan'" in driver.status["reason"]
            assert forward(driver, 1.0).linear == 0.0
            scanner.ranges, scanner.on = [math.inf] * 360, True
            assert wait_for(lambda: driver.status.get("state") == "ok", 10.0), driver.status
        finally:
            scanner.stop()


def test_people_off_the_map_are_kept_at_the_motion_margin(model_stem):
    """The same person 2 m ahead: with obstacle_speed_max 1 m/s (margin 1 × (1 s to stop + 0.05 + 0.5) = 1.55 m)
    the command towards them is changed; the static map's wall 9 m away is not grown.  The stop's share of the
    margin follows the robot's speed (the braking bound): at rest, 1.3 m from the person, the robot may start
    towards them slowly (the top speed's margin alone held it still)."""
    with driver_and_node(model_stem, DOMAIN + 1, observation_sources=["scan"], obstacle_speed_max=1.0,
                         **DIFF_DRIVE) as (driver, node):
        scanner = Scanner(driver, person_ahead(2.0))
        try:
            driver.pose, driver.v = (*FAR, 0.0), 0.5
            assert wait_for(lambda: driver.status.get("observation_sources", {}).get("scan", {}).get("points", 0) > 0
                            and driver.status.get("state") in ("ok", "unsafe_idle", "intervening"), 30.0), \
                driver.status
            assert node.values.moving_margin() == pytest.approx(1.55)
            assert wait_for(lambda: forward(driver, 1.0).linear < 1.0, 5.0)
            assert occupancy()[150, 100] == 100  # the wall the margin leaves alone
            nearer = person_ahead(1.3)
            scanner.ranges, driver.v = nearer, 0.0
            assert wait_for(lambda: driver.status.get("observation_sources", {}).get("scan", {}).get("points")
                            == int(np.isfinite(nearer).sum()), 10.0)  # the nearer person's scan is the node's
            time.sleep(1.0)  # and the value table made from it
            assert all(forward(driver, 0.2).linear > 0.0 for _ in range(5))
            driver.v = 0.5
            assert wait_for(lambda: forward(driver, 0.5).linear < 0.5, 5.0)  # 0.5 m/s needs 0.55 + 0.5 + 0.125 m more
        finally:
            scanner.stop()


def test_a_rolling_costmap_source_adds_its_cells_and_its_edge_is_no_wall(model_stem):
    """A 3 m × 3 m rolling costmap around the robot at FAR: empty, V at the robot stays above the 1.5 m to its
    edge (the map covers the robot there); with one lethal cell 1 m ahead, V falls below 1 m."""
    from dds_driver import map_msg
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    with driver_and_node(model_stem, DOMAIN + 2, observation_sources=["local"], obstacle_speed_max=0.0, **DIFF_DRIVE,
                         **{"local.type": "costmap", "local.topic": "local_costmap/costmap"}) as (driver, _node):
        pub = driver.create_publisher(type(map_msg(occupancy())), "local_costmap/costmap", latched)
        stop, occ = threading.Event(), np.zeros((30, 30), np.int8)

        def publish() -> None:  # a rolling costmap at 5 Hz, its origin 1.5 m left of and below the robot
            while not stop.wait(0.2):
                msg = map_msg(occ)
                msg.info.origin.position.x, msg.info.origin.position.y = FAR[0] - 1.5, FAR[1] - 1.5
                pub.publish(msg)

        thread = threading.Thread(target=publish, daemon=True)
        thread.start()
        try:
            driver.pose, driver.v = (*FAR, 0.0), 0.0
            assert wait_for(lambda: driver.status.get("state") == "ok"
                            and "local" in driver.status.get("observation_sources", {}), 30.0), driver.status
            assert driver.status["observation_sources"]["local"]["points"] == 0
            assert driver.status["value"] > 1.6, driver.status  # the window's edge at 1.5 m is not an obstacle
            occ[24, 15] = 100  # the cell whose centre is 0.95 m ahead of the robot
            assert wait_for(lambda: driver.status.get("observation_sources", {}).get("local", {}).get("points") == 1
                            and driver.status.get("value") is not None and driver.status["value"] < 1.0, 10.0), \
                driver.status
        finally:
            stop.set()
            thread.join(timeout=2.0)


class Tracker(Periodic):
    """A people tracker (PointCloud2, reliable): one person at ``position`` walking at ``velocity``."""

    def __init__(self, driver, position, velocity=(0.0, 0.0)) -> None:
        from rclpy.qos import QoSProfile
        from sensor_msgs.msg import PointCloud2

        self.position, self.velocity = position, velocity
        super().__init__(driver, PointCloud2, "tracked_agents", QoSProfile(depth=10))

    def message(self):
        from hjrno_ros.ros.harness.sim_base import agents_message

        return agents_message(np.array([self.position]), np.array([self.velocity]), np.array([0.2]),
                              self.driver.get_clock().now().to_msg())


def test_a_tracked_person_gets_their_relative_value_instead_of_the_margin(model_stem):
    """The person 2 m ahead (1.55 m from contact) as the previous test, now also tracked: standing, the command
    towards them passes (no motion margin: their relative value vouches for the robot); walking at the robot at
    1 m/s, it is changed; a silent tracker fails the node closed, naming the source."""
    person = (FAR[0] + 2.0 + RETURN_DEPTH, FAR[1])
    with driver_and_node(model_stem, DOMAIN + 3, observation_sources=["scan", "people"], obstacle_speed_max=1.0,
                         agent_table="agents_jackal", a_max=1.0, omega_max=2.0, v_max=1.0, v_min=-1.0,
                         **DIFF_DRIVE, **{"people.type": "agents", "people.topic": "tracked_agents"}) as (driver, _):
        scanner, tracker = Scanner(driver, person_ahead(2.0)), Tracker(driver, person)
        try:
            driver.pose, driver.v = (*FAR, 0.0), 0.5
            assert wait_for(lambda: driver.status.get("observation_sources", {}).get("people", {}).get("agents") == 1
                            and driver.status.get("state") in ("ok", "unsafe_idle", "intervening"), 30.0), \
                driver.status
            assert wait_for(lambda: forward(driver, 1.0).linear == pytest.approx(1.0), 5.0), driver.status
            tracker.velocity = (-1.0, 0.0)  # walking at the robot
            assert wait_for(lambda: forward(driver, 1.0).linear < 1.0, 5.0), driver.status
            tracker.on = False
            assert wait_for(lambda: driver.status.get("state") == "fail_closed", 5.0), driver.status
            assert "'people'" in driver.status["reason"]
            assert forward(driver, 1.0).linear == 0.0
        finally:
            scanner.stop()
            tracker.stop()
