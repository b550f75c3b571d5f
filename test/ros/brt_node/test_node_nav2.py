"""brt_node as a Nav2 node over real DDS: the lifecycle through its services, a costmap as the map,
command type mismatches found in the ROS graph."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from dds_driver import DOMAIN, FAR, RES, Driver, driver_and_node, map_msg, occupancy, settle, wait_for  # noqa: E402
from geometry_msgs.msg import Twist, TwistStamped  # noqa: E402
from lifecycle_msgs.msg import State, Transition  # noqa: E402
from lifecycle_msgs.srv import ChangeState, GetState  # noqa: E402
from rclpy.node import Node  # noqa: E402
from scipy import ndimage  # noqa: E402


def managed(model: str, domain: int, **params):
    """A driver and a brt_node with ``autostart`` false (a lifecycle manager's job), not configured."""
    return driver_and_node(model, domain, publish_map=False, start=False, autostart=False, **params)


def transition(driver: Driver, transition_id: int) -> bool:
    client = driver.create_client(ChangeState, "/brt_node/change_state")
    return driver.call(client, ChangeState.Request(transition=Transition(id=transition_id)), 30.0).success


def lifecycle_state(driver: Driver) -> int:
    client = driver.create_client(GetState, "/brt_node/get_state")
    return driver.call(client, GetState.Request()).current_state.id


def test_lifecycle_through_its_services(model_stem):
    """configure -> inactive: nothing published, commands unanswered; activate: filtering; deactivate: silent
    again; a new activation starts clean (counters, odometry, value); cleanup -> unconfigured; shutdown."""
    with managed(model_stem, DOMAIN + 40) as (driver, node):
        driver.map_pub.publish(map_msg(occupancy()))
        assert lifecycle_state(driver) == State.PRIMARY_STATE_UNCONFIGURED
        assert transition(driver, Transition.TRANSITION_CONFIGURE)
        assert lifecycle_state(driver) == State.PRIMARY_STATE_INACTIVE
        time.sleep(0.5)
        assert driver.status == {} and driver.command(0.5, 0.0, wait=1.0) is None  # inactive: silent
        assert transition(driver, Transition.TRANSITION_ACTIVATE)
        assert lifecycle_state(driver) == State.PRIMARY_STATE_ACTIVE
        settle(driver, *FAR, 0.5, 0.0, timeout=20.0)
        out = driver.command(0.7, -0.3)
        assert out is not None and (out.linear.x, out.angular.z) == (0.7, -0.3)
        assert wait_for(lambda: driver.status["counts"]["commands"] >= 1, 2.0)
        assert transition(driver, Transition.TRANSITION_DEACTIVATE)
        assert lifecycle_state(driver) == State.PRIMARY_STATE_INACTIVE and not node.values.running
        time.sleep(0.3)
        driver.status = {}
        assert driver.command(0.5, 0.0, wait=1.0) is None and driver.status == {}
        assert transition(driver, Transition.TRANSITION_ACTIVATE)
        assert wait_for(lambda: driver.status.get("counts", {}).get("commands") == 0, 5.0), driver.status  # clean
        settle(driver, *FAR, 0.5, 0.0, timeout=20.0)  # the map was kept: no new map needed
        assert transition(driver, Transition.TRANSITION_DEACTIVATE)
        assert transition(driver, Transition.TRANSITION_CLEANUP)
        assert lifecycle_state(driver) == State.PRIMARY_STATE_UNCONFIGURED and not hasattr(node, "vf")
        assert transition(driver, Transition.TRANSITION_UNCONFIGURED_SHUTDOWN)
        assert lifecycle_state(driver) == State.PRIMARY_STATE_FINALIZED


def test_invalid_lifecycle_requests_are_refused_and_the_node_keeps_filtering(model_stem):
    """Every transition that does not exist from the present state (activate or deactivate while unconfigured;
    configure or deactivate while inactive; activate, configure, cleanup or shutdown while active; an unknown id
    in each) is refused with success false: the state stays, the node keeps running and, when active, filtering
    (rclpy alone raises out of the executor and ends the node)."""
    with managed(model_stem, DOMAIN + 44) as (driver, node):
        driver.map_pub.publish(map_msg(occupancy()))
        for bad in (Transition.TRANSITION_ACTIVATE, Transition.TRANSITION_DEACTIVATE, 99):
            assert not transition(driver, bad)
            assert lifecycle_state(driver) == State.PRIMARY_STATE_UNCONFIGURED
        assert transition(driver, Transition.TRANSITION_CONFIGURE)
        for bad in (Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_DEACTIVATE, 99):
            assert not transition(driver, bad)
            assert lifecycle_state(driver) == State.PRIMARY_STATE_INACTIVE
        assert transition(driver, Transition.TRANSITION_ACTIVATE)
        settle(driver, *FAR, 0.5, 0.0, timeout=20.0)
        for bad in (Transition.TRANSITION_ACTIVATE, Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_CLEANUP,
                    Transition.TRANSITION_UNCONFIGURED_SHUTDOWN, 99):
            assert not transition(driver, bad)
            assert lifecycle_state(driver) == State.PRIMARY_STATE_ACTIVE
            out = driver.command(0.7, -0.3)
            assert out is not None and (out.linear.x, out.angular.z) == (0.7, -0.3)


def test_a_bad_configuration_fails_the_transition_with_one_reason(model_stem):
    with managed("/nonexistent", DOMAIN + 41) as (driver, node):
        assert not transition(driver, Transition.TRANSITION_CONFIGURE)
        assert lifecycle_state(driver) == State.PRIMARY_STATE_UNCONFIGURED
        assert "nonexistent" in node.startup_error and "\n" not in node.startup_error


def nav2_costmap(occ: np.ndarray, inscribed: float, res: float) -> np.ndarray:
    """A Nav2-style costmap as OccupancyGrid values: lethal 100 on obstacles, inscribed 99 within the inscribed
    radius, then an exponential decay 98..1 (inflation_layer, cost_scaling_factor 3) out to 1 m."""
    dist = ndimage.distance_transform_edt(occ < 50) * res
    decay = np.clip(np.rint(98 * np.exp(-3.0 * (dist - inscribed))), 0, 98)
    cost = np.where(dist <= 1.0, decay, 0).astype(np.int8)
    cost[dist <= inscribed + 1e-6] = 99
    cost[occ >= 50] = 100
    return cost


def test_a_nav2_costmap_is_not_inflated_twice(model_stem):
    """With map_kind costmap the inscribed cells are the obstacles: V 2 m from the wall matches the plain map
    with the inscribed radius added to the inflation, instead of counting Nav2's whole decay region (before:
    1.20 against 1.60 with occupied_threshold 50)."""
    inscribed, pose = 0.3, (3.0, 0.0, 0.5, math.pi)  # 2 m from the wall at x = 5.0, heading away from it
    values = {}
    for kind, params, grid in (("plain", {"inflation_radius": inscribed + 0.23}, occupancy()),
                               ("costmap", {"map_kind": "costmap", "inflation_radius": 0.23},
                                nav2_costmap(occupancy(), inscribed, RES)),
                               ("threshold 50", {"inflation_radius": 0.23}, nav2_costmap(occupancy(), inscribed, RES))):
        with managed(model_stem, DOMAIN + 42, **params) as (driver, node):
            driver.map_pub.publish(map_msg(grid))
            node.start()
            values[kind] = settle(driver, *pose, timeout=20.0)["value"]
    assert values["costmap"] == pytest.approx(values["plain"], abs=0.05), values
    assert values["threshold 50"] < values["costmap"] - 0.2, values  # the double inflation it replaces


def test_a_command_type_mismatch_is_found_in_the_graph(model_stem):
    """A TwistStamped publisher on the Twist topic the node reads: its commands never arrive; the node says so
    in status and diagnostics instead of "ok"."""
    with managed(model_stem, DOMAIN + 43) as (driver, node):
        driver.map_pub.publish(map_msg(occupancy()))
        node.start()
        settle(driver, *FAR, 0.5, 0.0, timeout=20.0)
        assert driver.status["cmd_type_mismatch"] == []
        other = rclpy.Context()  # Fast DDS refuses two types on one topic in one participant: another one
        rclpy.init(context=other, domain_id=DOMAIN + 43)
        teleop = Node("teleop_stamped", context=other)
        try:
            teleop.create_publisher(TwistStamped, "cmd_vel_smoothed", 10)
            assert wait_for(lambda: any("TwistStamped" in m for m in driver.status["cmd_type_mismatch"]), 10.0), \
                driver.status
            assert wait_for(lambda: driver.diagnostics is not None and driver.diagnostics.level >= b"\x01", 3.0)
        finally:
            teleop.destroy_node()
            rclpy.shutdown(context=other)
        assert wait_for(lambda: driver.status["cmd_type_mismatch"] == [], 10.0), driver.status
        assert driver.command(0.5, 0.0) is not None and isinstance(driver.out[0][1], Twist)
