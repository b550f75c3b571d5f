"""brt_node over real DDS: a driver node publishes map/odom/commands and watches the outputs.

Both nodes share one rclpy context on a private ROS domain (from the pid) and one
SingleThreadedExecutor on a background thread.  The model is the bundled ``models/paper_cnn`` if
present, else a tiny FNO trained here on the ``ci`` dataset (~20 s): with that one V is only
checked through what holds for any model (V ≤ V0, the filter's mapping), and the braking /
turning comparison with a ground-truth solve runs with the bundled model only.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from conftest import copy_model, wait_for  # noqa: E402
from dds_driver import (  # noqa: E402
    DOMAIN,
    FAR,
    MAP_QOS,
    NEAR_WALL,
    ORIGIN,
    RES,
    ROOT,
    driver_and_node,
    driver_context,
    map_msg,
    occupancy,
    settle,
)
from diagnostic_msgs.msg import DiagnosticStatus  # noqa: E402
from geometry_msgs.msg import PoseWithCovarianceStamped, TwistStamped  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from std_msgs.msg import String  # noqa: E402
from std_srvs.srv import SetBool  # noqa: E402

from hjrno_ros.core import geometry  # noqa: E402
from hjrno_ros.core.safety_filter import FilterSettings  # noqa: E402
from hjrno_ros.learning import checkpoint  # noqa: E402
from hjrno_ros.ros.brt_node.config import NodeConfig  # noqa: E402
from hjrno_ros.ros.brt_node.node import BrtNode  # noqa: E402
from hjrno_ros.ros.brt_node.parameters import refined_filter_settings  # noqa: E402
from hjrno_ros.ros.brt_node.value_worker import INFERENCE_NICE  # noqa: E402


def test_transient_local_map_before_start_is_received(ros):
    driver, _ = ros
    assert wait_for(lambda: driver.status.get("map_stamp") == [1, 0], 10.0), driver.status
    st = settle(driver, *FAR, 0.5, 0.0)
    assert not st["reason"].startswith("no map")
    assert st["signed_distance_ms"] > 0 and st["map_to_table_ms"]["p50"] >= st["signed_distance_ms"]  # its own part


def test_far_from_obstacles_command_passes_unchanged(ros):
    driver, _ = ros
    settle(driver, *FAR, 0.5, 0.0)
    out = driver.command(0.7, -0.3)
    assert out is not None and out.linear.x == 0.7 and out.angular.z == -0.3
    assert driver.status["value"] > driver.status["epsilon"]
    assert driver.status["symmetry_average"] is False  # the test model's card does not ask for it
    grid, values = driver.grid, driver.values
    assert grid.header.frame_id == "map" and len(grid.data) == grid.info.width * grid.info.height
    dims = values.layout.dim
    assert [d.label for d in dims] == ["y", "x"] and dims[0].size == grid.info.height
    assert dims[1].size == grid.info.width and len(values.data) == dims[0].stride


def test_inference_thread_yields_the_cpu_to_the_command_path(ros):
    """The inference thread runs niced (Linux schedules threads by their own nice value), so a busy
    CPU serves the executor's command callbacks first."""
    _, node = ros
    worker, niced = node.values.native_id, min(19, os.getpriority(os.PRIO_PROCESS, 0) + INFERENCE_NICE)
    assert wait_for(lambda: os.getpriority(os.PRIO_PROCESS, worker) == niced, 5.0)


def test_parameter_updates_are_validated(ros):
    driver, node = ros
    assert wait_for(lambda: "epsilon" in driver.status, 10.0)
    eps = driver.status["epsilon"]
    assert node.get_parameter("epsilon").value == -1.0  # the start-up sentinel may stay while others change
    assert driver.status["filter_mode"] == "least_restrictive"  # the default
    assert driver.set_param("filter_mode", "switch") == (True, "")
    assert wait_for(lambda: driver.status["filter_mode"] == "switch", 2.0)
    assert driver.set_param("filter_mode", "qp")[0] and driver.set_param("decay_rate", 8.0)[0]
    assert wait_for(lambda: (node.settings.mode, node.settings.decay_rate) == ("qp", 8.0), 2.0)
    assert driver.set_param("filter_mode", "blend")[0] and driver.set_param("decay_rate", 4.0)[0]
    assert wait_for(lambda: node.settings.mode == "blend" and node.settings.epsilon > eps, 2.0)  # + sampling margin
    assert driver.set_param("filter_mode", "least_restrictive")[0]
    for name, value, words in (("epsilon", -1.0, "epsilon"), ("filter_mode", "magic", "filter_mode"),
                               ("control_period", 0.0, "control_period"), ("decay_rate", -1.0, "decay_rate")):
        ok, reason = driver.set_param(name, value)
        assert not ok and words in reason, (name, reason)
    ok, _ = driver.set_param("epsilon", 0.2)
    assert ok and wait_for(lambda: driver.status["epsilon"] == 0.2, 2.0)
    assert node.settings.epsilon == 0.2
    assert driver.set_param("epsilon", eps)[0]


def test_inflation_radius_grows_obstacles_live(ros):
    """Any model's V ≤ V0 (clamped), so with obstacles grown by r every published V ≤ sd − r, and cells
    closer than r to the wall become lethal; a negative radius other than -1 (auto) is refused."""
    driver, node = ros
    settle(driver, 3.5, 0.0, 0.5, 0.0)  # 1.5 m from the wall (NEAR_WALL is the next test's: a new window there)
    h = max(node.vf.grid.spacings[:2])  # the default -1: h/√2 of the model grid (square cells)
    assert node.get_parameter("inflation_radius").value == -1.0
    assert driver.status["value_grid"]["inflation_radius"] == pytest.approx(h / math.sqrt(2))
    sd = geometry.occupancy_signed_distance(occupancy(), RES)
    r = 0.5
    assert driver.set_param("inflation_radius", r) == (True, "")
    try:
        assert wait_for(lambda: driver.status["value_grid"]["inflation_radius"] == r, 10.0)
        for _ in range(2):  # messages published after the new table was in place
            driver.grid = driver.values = None
            assert wait_for(lambda: driver.grid is not None and driver.values is not None, 5.0)
        grid, values = driver.grid, np.asarray(driver.values.data, float)
        h, (ox, oy) = grid.info.resolution, (grid.info.origin.position.x, grid.info.origin.position.y)
        ix, iy = np.meshgrid(np.arange(grid.info.width), np.arange(grid.info.height), indexing="xy")
        centres = np.stack([ox + (ix.ravel() + 0.5) * h, oy + (iy.ravel() + 0.5) * h], -1)  # x fastest
        v0 = geometry.sample_raster(sd, ORIGIN, RES, centres, outside=-RES)
        assert np.all(values <= v0 - r + 1e-4), (values - (v0 - r)).max()
        ring = (v0 > 0) & (v0 < r)  # free cells within r of an obstacle
        assert ring.any() and np.all(np.asarray(grid.data)[ring] == 100)
        ok, reason = driver.set_param("inflation_radius", -0.1)
        assert not ok and "inflation_radius" in reason
    finally:
        assert driver.set_param("inflation_radius", -1.0)[0]


def ground_truth_control(node: BrtNode, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(u*, ∇V) at ``state`` from a converged solve on a 24x24x7x12 grid of the same window (~7 s)."""
    from hjrno_ros.core.dynamics import optimal_control
    from hjrno_ros.core.grids import car_grid
    from hjrno_ros.core.value_table import ValueTable
    from hjrno_ros.truth.solver import solve
    from hjrno_ros.truth.systems import DynamicDubinsCar

    vf = node.vf
    wx, wy = vf.window
    lo, hi = (state[0] - wx / 2, state[1] - wy / 2), (state[0] + wx / 2, state[1] + wy / 2)
    grid = car_grid((24, 24, 7, 12), lo, hi, (vf.params.v_min, vf.params.v_max))
    sd = geometry.occupancy_signed_distance(occupancy(), RES)
    l0 = geometry.sample_raster(sd, ORIGIN, RES, grid.states()[:, :, 0, 0, :2], outside=-RES)
    l0 -= node.values.inflation()  # the obstacles the node sees
    target = np.broadcast_to(l0[:, :, None, None], grid.shape).astype(np.float32)
    values, _ = solve(DynamicDubinsCar(vf.params), grid, target, accuracy="medium", max_horizon=20.0)
    grad = ValueTable(grid, values).gradient(state)[0]
    return optimal_control(vf.params, state, grad), grad


def test_driving_into_wall_is_overridden(ros):
    """1 m/s, 0.6 m before a wall, heading 0.3 rad off its normal: the filter takes over; in switch mode with the
    optimal control (bang-bang curvature), in the default mode with the closest admissible command, which also
    turns away and never adds speed.

    Ground truth here (a converged solve): V ≈ 0, ∂V/∂θ > 0 (turn left, away from the wall, at full
    curvature) and ∂V/∂v ≥ 0 (a stopped car drifts into the wall under the disturbance, so braking
    is not what the true value function asks for; at v_max the feasible u1 is 0).
    """
    driver, node = ros
    bundled = Path(node.model_stem) == ROOT / "models" / "paper_cnn"
    theta, v = 0.3, 1.0
    st = settle(driver, *NEAR_WALL, v, theta)
    eps = st["epsilon"]
    if not bundled:  # the tiny test model's V is not accurate; V <= V0 = 0.6 m makes 0.7 m a sure trigger
        assert driver.set_param("epsilon", 0.7)[0]
    try:
        out = driver.command(1.0, 0.0)
        assert out is not None and (out.linear.x, out.angular.z) != (1.0, 0.0)
        assert out.linear.x <= 1.0 and (out.angular.z > 0 or not bundled), out
        assert driver.set_param("filter_mode", "switch")[0]
        assert wait_for(lambda: driver.status["value"] is not None and driver.status["value"] <= 0.6 + 1e-6, 5.0)
        out = driver.command(1.0, 0.0)
        assert out is not None and (out.linear.x, out.angular.z) != (1.0, 0.0)
        assert wait_for(lambda: driver.status["state"] == "intervening", 2.0), driver.status
        p, dt = node.vf.params, node.settings.dt
        assert min(abs(out.linear.x - np.clip(v + k * p.a_max * dt, p.v_min, p.v_max)) for k in (-1, 0, 1)) < 1e-9
        assert abs(abs(out.angular.z) - v * p.kappa_max) < 1e-9  # bang-bang curvature, ω = v·u2
        grid = driver.grid  # inside the wall V <= V0 < 0: the palette says lethal
        cell = (int((5.2 - grid.info.origin.position.x) / grid.info.resolution),
                int((0.0 - grid.info.origin.position.y) / grid.info.resolution))
        assert grid.data[cell[1] * grid.info.width + cell[0]] == 100
        if bundled:
            u, grad = ground_truth_control(node, np.array([*NEAR_WALL, v, theta]))
            assert grad[3] > 1e-2 and out.angular.z > 0, (out, u, grad)  # turn away, like the ground truth
            if abs(grad[2]) > 2e-2:  # the speed gradient is decisive: same feasible acceleration sign
                assert np.sign(out.linear.x - v) == np.sign(u[0]), (out, u, grad)
    finally:
        assert driver.set_param("filter_mode", "least_restrictive")[0]
        assert driver.set_param("epsilon", eps)[0]


def test_stale_odometry_stops_within_one_control_period(ros):
    driver, node = ros
    settle(driver, *FAR, 0.5, 0.0)
    assert driver.command(0.5, 0.0) is not None
    driver.out.clear()
    driver.odom_on = False
    t_last = driver.last_odom
    assert wait_for(lambda: driver.out, 3.0)
    t_zero, zero = driver.out[0]
    assert zero.linear.x == 0.0 and zero.angular.z == 0.0
    control_period, odom_timeout = node.config.control_period, node.config.odom_timeout
    assert t_zero - t_last <= odom_timeout + control_period + 0.5, t_zero - t_last  # margin: loaded 2-core CI
    assert "odometry is" in driver.status["reason"] or wait_for(lambda: "odometry" in driver.status["reason"], 1.0)
    time.sleep(node.config.stop_pub_timeout + 0.3 - (time.monotonic() - t_last))
    driver.out.clear()
    time.sleep(0.4)
    assert not driver.out, "zeros must stop after stop_pub_timeout so teleop can take over"
    settle(driver, *FAR, 0.5, 0.0)


def test_nan_command_and_odometry_are_dropped_and_counted(ros):
    driver, _ = ros
    settle(driver, *FAR, 0.5, 0.0)
    before = driver.status["dropped"]
    assert driver.command(float("nan"), 0.0, wait=0.4) is None
    assert wait_for(lambda: driver.status["dropped"]["cmd"] == before["cmd"] + 1, 2.0)
    odom = Odometry()
    odom.header.frame_id = "map"
    odom.pose.pose.position.x, odom.pose.pose.orientation.w = float("inf"), 1.0
    driver.odom_pub.publish(odom)
    assert wait_for(lambda: driver.status["dropped"]["odom"] == before["odom"] + 1, 2.0)
    assert driver.status["state"] == "ok"  # the good odometry before and after it is still used


def test_odometry_in_another_frame_fails_closed(ros):
    driver, _ = ros
    settle(driver, *FAR, 0.5, 0.0)
    driver.frame = "odom"
    try:
        assert wait_for(lambda: "frame" in driver.status["reason"], 2.0), driver.status
        assert driver.status["state"] == "fail_closed" and "tf2" in driver.status["reason"]
        out = driver.command(0.5, 0.2)
        assert out is not None and out.linear.x == 0.0 and out.angular.z == 0.0
        assert wait_for(lambda: driver.diagnostics is not None and driver.diagnostics.level == DiagnosticStatus.ERROR
                        and "frame" in driver.diagnostics.message, 3.0), driver.diagnostics
    finally:
        driver.frame = "map"


def test_bad_maps_are_rejected_and_previous_map_kept(ros):
    driver, _ = ros
    settle(driver, *FAR, 0.5, 0.0)
    before = driver.status["dropped"]["map"]
    occ = occupancy()
    driver.map_pub.publish(map_msg(occ, stamp_sec=2, data=[0] * 10))
    assert wait_for(lambda: driver.status["dropped"]["map"] == before + 1, 3.0)
    assert "cells" in driver.status["last_map_error"]
    driver.map_pub.publish(map_msg(occ, stamp_sec=3, resolution=float("nan")))
    assert wait_for(lambda: driver.status["dropped"]["map"] == before + 2, 3.0)
    assert "resolution" in driver.status["last_map_error"]
    assert driver.status["map_stamp"] == [1, 0] and driver.status["state"] == "ok"
    out = driver.command(0.4, 0.1)
    assert out is not None and out.linear.x == 0.4 and out.angular.z == 0.1
    driver.map_pub.publish(map_msg(occ))  # leave the good map latched


def test_signed_distance_runs_in_the_inference_thread_not_the_executor(ros, monkeypatch):
    """The map callback only validates: a 400 x 400 signed distance (~15 ms) in the executor thread
    would hold up every command behind it."""
    driver, _ = ros
    settle(driver, *FAR, 0.5, 0.0)
    threads: list[str] = []
    original = geometry.occupancy_signed_distance

    def recording(*args, **kwargs):
        threads.append(threading.current_thread().name)
        return original(*args, **kwargs)

    monkeypatch.setattr(geometry, "occupancy_signed_distance", recording)
    driver.map_pub.publish(map_msg(occupancy(), stamp_sec=4))
    assert wait_for(lambda: driver.status["map_stamp"] == [4, 0], 3.0)
    assert threads and set(threads) == {"brt_value_worker"}
    monkeypatch.undo()
    driver.map_pub.publish(map_msg(occupancy()))  # leave the stamp-1 map latched
    assert wait_for(lambda: driver.status["map_stamp"] == [1, 0], 3.0)


def test_bypass_passes_commands_and_reenable_filters(ros):
    driver, node = ros
    bundled = Path(node.model_stem) == ROOT / "models" / "paper_cnn"
    st = settle(driver, *NEAR_WALL, 1.0, 0.3)
    eps = st["epsilon"]
    if not bundled:
        assert driver.set_param("epsilon", 0.7)[0]
    try:
        assert driver.call(driver.enable, SetBool.Request(data=False)).success
        assert wait_for(lambda: driver.status["state"] == "bypassed", 2.0)
        out = driver.command(1.0, 0.0)
        assert out is not None and out.linear.x == 1.0 and out.angular.z == 0.0
        assert driver.call(driver.enable, SetBool.Request(data=True)).success
        assert wait_for(lambda: driver.status["state"] != "bypassed", 2.0)
        out = driver.command(1.0, 0.0)
        assert out is not None and (out.linear.x, out.angular.z) != (1.0, 0.0)
    finally:
        driver.call(driver.enable, SetBool.Request(data=True))
        driver.set_param("epsilon", eps)


def test_pose_topic_and_stamped_commands(ros, model_stem):
    """pose_topic set: map-frame pose ∘ (odometry motion since the pose's stamp), odometry in its own frame;
    enable_stamped_cmd_vel: TwistStamped in and out, header copied through."""
    driver, _ = ros
    overrides = {"model_path": str(model_stem), "robot_model": "car", "pose_topic": "amcl_pose",
                 "cmd_vel_in_topic": "pose_in",
                 "cmd_vel_out_topic": "pose_out", "status_topic": "brt_pose/status",
                 "value_grid_topic": "brt_pose/value_grid", "value_topic": "brt_pose/value",
                 "enable_stamped_cmd_vel": True}
    node = BrtNode(context=driver.context, cli_args=["--ros-args", "-r", "__node:=brt_pose_node"],
                   parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()])
    status: dict = {}
    driver.create_subscription(String, "brt_pose/status", lambda m: status.update(json.loads(m.data)), 10)
    pose_pub = driver.create_publisher(PoseWithCovarianceStamped, "amcl_pose", MAP_QOS)
    cmd_pub = driver.create_publisher(TwistStamped, "pose_in", 10)
    outputs: list[TwistStamped] = []
    driver.create_subscription(TwistStamped, "pose_out", outputs.append, 10)
    node.start()
    driver.executor.add_node(node)
    try:
        driver.pose, driver.v, driver.frame = (0.0, 0.0, 0.0), 0.5, "odom"
        assert wait_for(lambda: "no pose" in status.get("reason", ""), 10.0), status
        time.sleep(0.2)

        def publish_pose(frame: str) -> None:
            msg = PoseWithCovarianceStamped()
            msg.header.frame_id, msg.header.stamp = frame, driver.get_clock().now().to_msg()
            msg.pose.pose.position.x, msg.pose.pose.position.y = -4.0, -4.0
            msg.pose.pose.orientation.z = msg.pose.pose.orientation.w = math.sqrt(0.5)  # yaw π/2
            pose_pub.publish(msg)

        publish_pose("map")
        time.sleep(0.2)
        driver.pose = (1.0, 0.0, 0.0)  # 1 m forward in odom = +y in the map

        def at_expected() -> bool:
            robot = status.get("robot") or {}
            return (status.get("state") == "ok" and abs(robot.get("x", 9) + 4.0) < 1e-3
                    and abs(robot.get("y", 9) + 3.0) < 1e-3 and abs(robot.get("theta", 9) - math.pi / 2) < 1e-3)

        assert wait_for(at_expected, 5.0), status
        cmd = TwistStamped()
        cmd.header.frame_id, cmd.header.stamp = "base_link", driver.get_clock().now().to_msg()
        cmd.twist.linear.x, cmd.twist.angular.z = 0.3, 0.2
        cmd_pub.publish(cmd)
        assert wait_for(lambda: outputs, 2.0)
        assert outputs[0].header == cmd.header and outputs[0].twist == cmd.twist
        publish_pose("odom")
        assert wait_for(lambda: "pose frame 'odom'" in status.get("reason", ""), 3.0), status
    finally:
        driver.executor.remove_node(node)
        time.sleep(0.2)  # let callbacks in flight finish before the handles go
        node.destroy_node()
        driver.frame, driver.pose = "map", (*FAR, 0.0)


def test_missing_model_exits_nonzero_with_one_line():
    env = {**os.environ, "ROS_DOMAIN_ID": str(DOMAIN)}
    proc = subprocess.run([sys.executable, "-m", "hjrno_ros.ros.brt_node.main", "--ros-args", "-p",
                           "model_path:=/nonexistent"], capture_output=True, text=True, timeout=60, env=env)
    lines = [line for line in (proc.stdout + proc.stderr).splitlines() if line.strip()]
    assert proc.returncode == 1
    assert len(lines) == 1 and "/nonexistent" in lines[0] and "Traceback" not in lines[0], lines


def test_bundled_models_resolve_by_name():
    """model_path may name a bundled model ('' is ``default``): ``paper_cnn`` loads with each member in its two
    frames and the ε calibrated that way, ``v5`` is the same weights with one frame per member and its own ε; an
    unknown name is one clear error."""
    from hjrno_ros.ros.brt_node.value_sources import resolve_model

    assert resolve_model("") == ROOT / "models" / "default"
    stem = resolve_model("paper_cnn")
    assert stem == ROOT / "models" / "paper_cnn" and resolve_model(str(stem)) == stem
    model, card = checkpoint.load_model(stem)
    assert [m.elements for m in model.members] == [(0, 5), (1, 6), (3, 4)]
    assert card["calibration"]["member_frames"] == card["member_frames"] and card["epsilon"] > 0.1
    plain, plain_card = checkpoint.load_model(resolve_model("v5"))
    assert resolve_model("v5") == ROOT / "models" / "v5" and "member_frames" not in plain_card
    assert not any(hasattr(m, "elements") for m in plain.members) and plain_card["epsilon"] != card["epsilon"]
    pairs = zip(plain.state_dict().values(), model.state_dict().values(), strict=True)
    assert all(np.array_equal(a.numpy(), b.numpy()) for a, b in pairs)  # the same weights
    with pytest.raises(ValueError, match="no bundled model 'nope'"):
        resolve_model("nope")


def test_heading_across_pi_reads_the_stencil_not_its_clamped_edge():
    """A table made at θ = π − 0.05 holds headings π − 0.05 ± dθ/2 unwrapped; odometry then reports
    −π + 0.05 (the same heading turned 0.1 rad on): the lookup must use π + 0.05, inside the stencil,
    not −π + 0.05, which the table would clamp to its lower edge (a heading 0.3 rad off)."""
    from hjrno_ros.learning.value_function import LearnedValueFunction
    from hjrno_ros.ros.brt_node.inputs import RobotState
    from hjrno_ros.ros.brt_node.value_worker import table_state

    vf = LearnedValueFunction(ROOT / "models" / "paper_cnn", device="cpu")
    center, theta = (0.0, 0.0), math.pi - 0.05
    xy = vf.window_points(center)
    v0 = (np.abs(xy[..., 0] + 1.5) - 0.3).astype(np.float32)  # a wall 1.5 m behind the heading π
    table = vf.local_table(v0, center, 0.8, theta)
    state = RobotState(0.0, 0.0, 0.8, -math.pi + 0.05, "map", 0, 0.0)
    s = table_state(state, theta, vf.params.v_min, vf.params.v_max)
    assert s[3] == pytest.approx(math.pi + 0.05) and table.inside(s, axes=(3,))
    assert not table.inside(state.vector(vf.params.v_min, vf.params.v_max), axes=(3,))


def test_slice_stencil_holds_every_speed_and_heading_reached_before_the_next_table():
    """With a reach, a slice model's stencil is the card grid's nodes spanning v ± reach (within the speed range)
    and θ ± reach, and agrees with the plain 2 × 2 stencil where both hold the state."""
    from hjrno_ros.learning.value_function import LearnedValueFunction

    vf = LearnedValueFunction(ROOT / "models" / "paper_cnn", device="cpu")
    dv, dtheta = vf.grid.spacings[2], vf.grid.spacings[3]
    xy = vf.window_points((0.0, 0.0))
    v0 = (np.abs(xy[..., 0] - 2.0) - 0.3).astype(np.float32)
    for v, lo, hi in ((0.5, 0.25, 0.75), (0.95, 0.625, 1.0), (0.0, 0.0, 0.25)):
        table = vf.local_table(v0, (0.0, 0.0), v, 0.3, reach=(0.25, 0.25))
        g = table.grid
        assert (g.lo[2], g.hi[2]) == pytest.approx((lo, hi)) and (g.lo[3], g.hi[3]) == pytest.approx((0.0, 2 * dtheta))
        assert np.allclose(g.spacings[2:], (dv, dtheta))
    plain = vf.local_table(v0, (0.0, 0.0), 0.5 + dv / 2, 0.3)  # speeds 0.5, 0.625
    wide = vf.local_table(v0, (0.0, 0.0), 0.5, 0.3, reach=(0.25, 0.0))  # speeds 0.25 ... 0.75, the same headings
    state = np.array([0.4, 0.1, 0.5, plain.grid.lo[3]])  # a node of both tables
    assert wide.value(state) == pytest.approx(plain.value(state), abs=1e-4)


def test_config_yaml_lists_every_parameter_with_its_default():
    import yaml

    from hjrno_ros.ros.brt_node.parameters import PARAMETERS

    params = yaml.safe_load((ROOT / "config" / "brt_node.yaml").read_text())["brt_node"]["ros__parameters"]
    same = lambda a, b: a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))  # noqa: E731
    listed = {name: spec for name, spec in PARAMETERS.items() if spec.default != []}  # a params file has no []
    assert params.keys() == listed.keys()
    assert all(same(params[name], spec.default) for name, spec in listed.items()), params
    assert all(type(params[name]) is type(spec.default) for name, spec in listed.items())
    assert "# observation_sources:" in (ROOT / "config" / "brt_node.yaml").read_text()  # shown as an example


def test_refined_epsilon_comes_from_the_parameter_then_the_card_then_epsilon():
    """refine_epsilon >= 0 holds from the first stage; -1 takes the card's refine_epsilon from the stage it
    was calibrated at; without one in the card the refined table keeps epsilon's settings."""
    import dataclasses

    from hjrno_ros.core.model_card import ModelCard

    base = FilterSettings(epsilon=0.2, mode="blend")
    plain = dataclasses.replace(ModelCard.load(ROOT / "models" / "paper_cnn"), epsilon=0.2, refine_epsilon=None,
                                refine_horizon=None)
    card = dataclasses.replace(plain, refine_epsilon=0.12, refine_horizon=16.0)
    assert refined_filter_settings(card, base, NodeConfig(refine_epsilon=0.3)) == (FilterSettings(0.3, "blend"), 0.0)
    assert refined_filter_settings(card, base, NodeConfig(refine_epsilon=-1.0)) == (FilterSettings(0.12, "blend"), 16.0)
    assert refined_filter_settings(plain, base, NodeConfig(refine_epsilon=-1.0)) == (base, 0.0)


def test_refinement_takes_over_the_filter_for_its_map_only(model_stem, tmp_path):
    """refine_horizon > 0: the background solve over the whole 20 m map, warm-started from the operator,
    becomes the filter's table for that map version (it turns away from the wall, as the ground truth in
    test_driving_into_wall_is_overridden does), with the card's refine_epsilon from the stage it was
    calibrated at; a new map goes back to the operator at once and refines anew."""
    stem = copy_model(model_stem, tmp_path)
    checkpoint.update_card(stem, {"refine_epsilon": 0.7, "refine_calibration": {"horizon_s": 1.0}})
    with driver_and_node(stem, DOMAIN + 50, refine_horizon=1.0, refine_stage=1.0, refine_cpus=1) as (driver, node):
        theta, v = 0.3, 1.0
        st = settle(driver, *NEAR_WALL, v, theta)
        assert st["refinement"]["state"] in ("waiting", "running") and not st["refinement"]["error"], st
        assert wait_for(lambda: driver.status.get("value_source") == "refined", 240.0), driver.status
        assert wait_for(lambda: node.status()["refinement"]["state"] == "done", 30.0), node.status()  # child exits
        st, refined = node.status(), node.values.refinement.refined
        assert st["refinement"] == {"state": "done", "error": "", "horizon_s": 1.0, "settled": refined.settled,
                                    "wall_s": refined.wall_s, "cpus": 1}, st  # refine_cpus=1
        assert node.values.value.table is refined.table and refined.table.grid.shape[:2] == (63, 63)  # 20 m / h
        state = np.array([*NEAR_WALL, v, theta])
        assert st["value"] == pytest.approx(float(refined.table.value(state)[0]), abs=1e-6)
        assert (st["refine_epsilon"], st["refine_epsilon_from_s"]) == (0.7, 1.0)  # -1: the card's, from 1 s on
        assert driver.set_param("epsilon", 0.7)[0]  # V <= V0 = 0.6 m: a sure intervention
        out = driver.command(1.0, 0.0)
        assert out is not None and (out.linear.x, out.angular.z) != (1.0, 0.0)
        if model_stem == ROOT / "models" / "paper_cnn":
            assert refined.table.gradient(state)[0][3] > 1e-2 and out.angular.z > 0, out  # turn away
        driver.pose = (*NEAR_WALL, 3.0)  # facing away from the wall: 0 < V <= 0.6 m
        assert wait_for(lambda: abs((driver.status.get("value_grid") or {}).get("theta", 0) - 3.0) < 0.05, 5.0)
        assert driver.status["value_source"] == "refined" and 0 < driver.status["value"] < 0.6, driver.status
        for name, value in (("filter_mode", "switch"), ("epsilon", 0.0)):
            assert driver.set_param(name, value)[0], name
        out = driver.command(1.0, 0.0)  # V < the card's refine_epsilon 0.7: epsilon's 0 is not what acts
        assert out is not None and (out.linear.x, out.angular.z) != (1.0, 0.0), out
        node.refined_from = 2.0  # as if calibrated at 2 s: this 1 s table takes epsilon's 0, and V > 0 passes
        out = driver.command(1.0, 0.0)
        assert out is not None and (out.linear.x, out.angular.z) == (1.0, 0.0), out
        assert not driver.set_param("refine_epsilon", -0.5)[0]  # only -1 or >= 0
        assert driver.set_param("refine_epsilon", 0.0)[0] and node.status()["refine_epsilon_from_s"] == 0.0
        out = driver.command(1.0, 0.0)  # switch at refine_epsilon 0 and V > 0: passes
        assert out is not None and (out.linear.x, out.angular.z) == (1.0, 0.0), out
        assert driver.set_param("refine_epsilon", 0.7)[0] and node.status()["refine_epsilon"] == 0.7
        out = driver.command(1.0, 0.0)  # V < refine_epsilon: the refined table's epsilon acts, not epsilon's 0
        assert out is not None and (out.linear.x, out.angular.z) != (1.0, 0.0), out
        assert node.last_decision.intervened and node.status()["epsilon"] == 0.0
        driver.map_pub.publish(map_msg(occupancy(), stamp_sec=2))
        assert wait_for(lambda: (s := node.status())["map_stamp"] == [2, 0] and s["value_source"] == "operator",
                        5.0), node.status()
        refined = node.values.refinement.refined
        assert refined is None or refined.map_version != node.maps.current.version
        assert wait_for(lambda: node.status()["refinement"]["state"] == "running", 10.0), node.status()  # 2 s on


def test_node_process_runs_without_jax_takes_integer_floats_and_stops_cleanly(model_stem):
    """The node as its own process: neither JAX nor torch is loaded (their shared libraries are not mapped,
    onnxruntime's is: the card lists its export), ``-p inflation_radius:=0`` (an integer for a float parameter)
    is accepted, and SIGINT while the worker publishes exits 0 without a traceback or an error line, every time."""
    from hjrno_ros.tools.node_process import brt_node_process

    domain = DOMAIN + 25
    with driver_context(domain) as (driver, _):
        for run in range(3):
            driver.status = {}
            params = {"robot_model": "car", "value_timeout": 0.2, **({"inflation_radius": 0} if run == 0 else {})}
            with brt_node_process(domain, params, model_stem) as (proc, log_tail):
                assert wait_for(lambda: driver.status.get("state") == "ok" or proc.poll() is not None, 60.0), \
                    (driver.status, log_tail(10))
                assert proc.poll() is None, log_tail(10)
                if run == 0:
                    assert driver.status["value_grid"]["inflation_radius"] == 0.0
                    mapped = Path(f"/proc/{proc.pid}/maps").read_text()
                    assert "onnxruntime" in mapped and "libtorch" not in mapped and "jaxlib" not in mapped
                    assert driver.status["runtime"] == "onnxruntime"
                time.sleep(0.3 + 0.3 * run)  # the worker recomputes every value_timeout / 2 = 0.1 s
                proc.send_signal(2)
                proc.wait(timeout=15.0)
                log = log_tail(200)
            assert proc.returncode == 0, log
            assert "Traceback" not in log and "ERROR" not in log and "inference failed" not in log, log


def test_docs_parameter_tables_are_current():
    """docs/node.md's parameter tables, the node's and each observation source's, are generated from the node's
    declarations."""
    from hjrno_ros.ros.brt_node.observation_sources import SOURCE_PARAMETERS
    from hjrno_ros.ros.brt_node.parameters import markdown_table

    text = (ROOT / "docs" / "node.md").read_text()
    assert markdown_table() in text and markdown_table(SOURCE_PARAMETERS) in text


# ------------------------------------------------------------------ the node's contract over DDS


def test_driving_off_the_map_edge_is_filtered(ros):
    """The map's edge bounds the signed distance (space beyond it is unknown): heading out of the map at
    1 m/s, 0.5 m from its edge, the command is changed (before: passed unchanged with V = 3.77)."""
    driver, node = ros
    st = settle(driver, 9.5, 0.0, 1.0, 0.0)
    assert st["value"] < st["epsilon"], st
    out = driver.command(1.0, 0.0)
    assert out is not None and (out.linear.x, out.angular.z) != (1.0, 0.0)
    assert node.maps.current.sd[-1, 100] <= RES / 2 + 1e-6  # the edge cell: half a cell from the map's edge


def test_commands_beyond_the_limits_are_clipped(ros):
    """Far from obstacles: speeds beyond [v_min, v_max], huge turn rates and non-planar axes are clipped to
    the limits the filter assumes; a command within them still passes bit for bit."""
    driver, node = ros
    p = node.vf.params
    settle(driver, *FAR, 0.5, 0.0)
    clipped = driver.status["counts"]["clipped"]
    for nominal, expect in (((5.0, 0.0), (p.v_max, 0.0)), ((1e308, 0.0), (p.v_max, 0.0)),
                            ((-1.0, 0.0), (p.v_min, 0.0))):
        out = driver.command(*nominal)
        assert out is not None and (out.linear.x, out.angular.z) == expect, (nominal, out)
    assert driver.command(0.5, 0.0) is not None  # the base keeps 0.5 m/s until the next command acts
    out = driver.command(0.5, 100.0)
    bound = p.kappa_max * max(0.5, 0.5)
    assert out is not None and out.linear.x == 0.5 and out.angular.z == pytest.approx(bound)
    # a command changed only by clipping is not "ok": its own state, WARN on /diagnostics
    assert wait_for(lambda: driver.status.get("state") == "clipped", 2.0), driver.status
    assert wait_for(lambda: driver.diagnostics is not None and driver.diagnostics.level == DiagnosticStatus.WARN
                    and "clipped" in driver.diagnostics.message, 3.0), driver.diagnostics
    out = driver.command(0.5, 0.1, linear_y=1.0, angular_x=2.0)
    assert out is not None and (out.linear.y, out.angular.x, out.linear.x, out.angular.z) == (0.0, 0.0, 0.5, 0.1)
    assert wait_for(lambda: driver.status["counts"]["clipped"] >= clipped + 5, 2.0), driver.status["counts"]
    out = driver.command(0.7, -0.3)
    assert out is not None and (out.linear.x, out.angular.z) == (0.7, -0.3)


def test_non_normalised_odometry_quaternion_is_read_right(ros):
    """q = 10·(0, 0, sin 0.05, cos 0.05) is a heading of 0.1 rad, toward the wall 1 m ahead at 1 m/s: the
    filter acts (before: read as 1.52 rad, V = 0.71, passed)."""
    driver, _ = ros
    driver.q_scale = 10.0
    try:
        st = settle(driver, 4.0, 0.0, 1.0, 0.1)
        assert st["robot"]["theta"] == pytest.approx(0.1, abs=1e-6), st["robot"]
        out = driver.command(1.0, 0.0)
        assert out is not None and (out.linear.x, out.angular.z) != (1.0, 0.0)
    finally:
        driver.q_scale = 1.0


def test_status_reports_the_present_state(ros):
    """V <= epsilon without a recent command is "unsafe_idle" (WARN), not "ok"; far away it is "ok"."""
    driver, node = ros
    settle(driver, *NEAR_WALL, 1.0, 0.0)
    assert wait_for(lambda: time.monotonic() - (node._last_cmd or (-math.inf,))[0] > node.config.stop_pub_timeout
                    and driver.status["state"] == "unsafe_idle", 10.0), driver.status
    assert wait_for(lambda: driver.diagnostics is not None and driver.diagnostics.level == DiagnosticStatus.WARN, 3.0)
    settle(driver, *FAR, 0.5, 0.0)
    assert wait_for(lambda: driver.status["state"] == "ok", 3.0), driver.status


def test_epsilon_below_the_calibrated_margin_is_flagged(ros):
    driver, node = ros
    if node.card.epsilon is None:
        pytest.skip("the test model has no calibrated epsilon")  # the bundled model (in the repository) has one
    settle(driver, *FAR, 0.5, 0.0)
    assert driver.status["epsilon_below_calibrated"] is False
    eps = driver.status["epsilon"]
    assert driver.set_param("epsilon", 0.5 * node.card.epsilon)[0]
    try:
        assert wait_for(lambda: driver.status["epsilon_below_calibrated"] is True, 2.0), driver.status
        assert wait_for(lambda: driver.diagnostics is not None and driver.diagnostics.level == DiagnosticStatus.WARN
                        and any(kv.key == "epsilon_below_calibrated" and kv.value == "True"
                                for kv in driver.diagnostics.values), 3.0)
    finally:
        driver.set_param("epsilon", eps)


def test_an_unconfigured_node_exits_on_sigint(model_stem):
    """With autostart false nothing wakes the executor until a lifecycle manager calls; SIGINT still ends the
    node within a second, with exit 0 and no traceback."""
    from hjrno_ros.tools.node_process import brt_node_process

    with brt_node_process(DOMAIN + 31, {"autostart": False, "robot_model": "car"}, model_stem) as (proc, log_tail):
        maps = Path(f"/proc/{proc.pid}/maps")
        assert wait_for(lambda: proc.poll() is not None or "rclpy" in maps.read_text(), 30.0)
        time.sleep(4.0)  # past the imports: spinning, unconfigured
        assert proc.poll() is None, log_tail(20)
        start = time.monotonic()
        proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout=15.0)
        assert code == 0 and time.monotonic() - start < 2.0 and "Traceback" not in log_tail(50), log_tail(20)


def test_interrupt_at_any_moment_of_start_up_exits_cleanly(model_stem):
    """SIGINT while rclpy, torch or the model load: exit 0, at most one line, never a traceback.  Each run waits
    until the process has entered the node's code (numpy's extension is mapped: the handlers are installed
    before it is imported), then interrupts it after a delay; an interrupt during the interpreter's own start-up
    (site, .pth files) is Python's, not the node's."""
    env = {**os.environ, "ROS_DOMAIN_ID": str(DOMAIN + 30), "PYTHONUNBUFFERED": "1"}
    for delay in (0.0, 0.3, 0.8, 1.5, 2.5):
        proc = subprocess.Popen([sys.executable, "-m", "hjrno_ros.ros.brt_node.main", "--ros-args", "-p",
                                 f"model_path:={model_stem}", "-p", "robot_model:=car"], env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        maps = Path(f"/proc/{proc.pid}/maps")
        assert wait_for(lambda p=proc, m=maps: p.poll() is not None or "_multiarray_umath" in m.read_text(), 30.0)
        time.sleep(delay)
        proc.send_signal(2)
        out, _ = proc.communicate(timeout=30.0)
        lines = [ln for ln in out.splitlines() if ln.strip() and "[INFO]" not in ln]
        assert proc.returncode == 0 and "Traceback" not in out and len(lines) <= 1, (delay, out)
