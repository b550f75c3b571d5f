"""The bundled default: a differential-drive FNO that predicts the whole (v, θ) table of a window in one pass,
conditioned on a_max/(v_max·ω_max), forward speeds only.  Its card carries the covered range, metrics and
calibration; over DDS it serves a TurtleBot3 that reverses and turns in place, on a map at the robot's scale."""

from __future__ import annotations

import math

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from dds_driver import DOMAIN, ROOT, map_msg, occupancy, settle  # noqa: E402
from dds_driver import driver_and_node as _driver_and_node  # noqa: E402

from hjrno_ros.core.dynamics import DiffDriveParams  # noqa: E402
from hjrno_ros.core.model_card import ModelCard  # noqa: E402
from hjrno_ros.core.similarity import DIFF_DRIVE_NUMBERS, Coverage  # noqa: E402
from hjrno_ros.learning import checkpoint  # noqa: E402

DEFAULT = ROOT / "models" / "default"
TURTLEBOT3 = {"omega_max": 2.84, "v_max": 0.22, "v_min": -0.22, "a_max": 1.0, "robot_model": "diff_drive"}
S = 0.22 / 2.84  # its length scale v_max/ω_max, m per model unit (the test map's 20 m become 1.55 m)

pytestmark = pytest.mark.real_time  # runs a node over DDS in real time (test/conftest.py)


def test_the_default_is_a_diff_drive_table_fno_with_its_coverage_metrics_and_calibration():
    card = ModelCard.load(DEFAULT)
    assert card.kind == "fno" and card.dynamics == DiffDriveParams()
    assert card.inputs["table"] == [9, 16] and card.config["out_channels"] == 144
    assert list(card.inputs["param_ranges"]) == ["log_a_max"] and card.inputs["channels"] == ["v0", "log_a_max"]
    expected = Coverage.of(card.dynamics, card.inputs["param_ranges"])
    assert card.data["coverage"] == {n: list(r) for n, r in zip(DIFF_DRIVE_NUMBERS, expected.ranges, strict=True)}
    assert card.data["coverage"]["a_max/(v_max*omega_max)"] == pytest.approx([0.4, 4.5])
    assert card.epsilon is not None and card.data["calibration"]["alpha"] == 0.001
    assert {"test_rel_l2", "test_iou", "test_false_safe", "table_ms"} <= set(card.metrics)
    assert checkpoint.paths(DEFAULT)[0].stat().st_size <= 10e6
    assert card.command and "hjrno train" in card.command and "--table" in card.command


def test_one_pass_gives_every_speed_and_heading_with_an_exact_rest_slice():
    from hjrno_ros.learning.value_function import LearnedValueFunction

    vf = LearnedValueFunction(DEFAULT, device="cpu")
    xy = vf.window_points((0.0, 0.0))
    v0 = (np.abs(xy[..., 0] - 2.0) - 0.3).astype(np.float32)  # a wall 2 units ahead
    table = vf.table(v0, DiffDriveParams(a_max=1.6))
    assert table.shape == (32, 32, 9, 16) and np.all(table <= v0[:, :, None, None])
    assert np.array_equal(table[:, :, 0], np.broadcast_to(v0[:, :, None], (32, 32, 16)))  # at rest V = l
    ahead, away = table[20, 16, -1, 8], table[20, 16, -1, 0]  # full speed at x ≈ 1.45, heading +x (the wall) / −x
    assert ahead < away - 0.1  # heading for the wall at speed is worse than heading away


def test_a_reversing_turtlebot3_turns_in_place_and_is_slowed_at_walls():
    """Over DDS: the bundled default serves the TurtleBot3 (covered: a/(v·ω) = 1.6, reversing) on a map 7.75 cm per
    model unit; far from the wall a command passes; at rest beside it a spin passes; driving or reversing into it
    at full speed is slowed."""
    small_map = map_msg(occupancy(), resolution=0.1 * S)
    small_map.info.origin.position.x, small_map.info.origin.position.y = -10.0 * S, -10.0 * S
    with _driver_and_node(DEFAULT, DOMAIN + 48, publish_map=False, **TURTLEBOT3) as (driver, node):
        driver.map_pub.publish(small_map)
        p = node.vf.params
        assert (p.omega_max, p.v_min, p.a_max) == (2.84, -0.22, 1.0) and node.settings.mode == "least_restrictive"
        card = ModelCard.load(DEFAULT)
        assert node.settings.epsilon == pytest.approx(S * card.margin())  # one period ahead: no sampling margin
        settle(driver, -4.0 * S, -4.0 * S, 0.1, 0.0, timeout=20.0)  # > 9 units from the wall
        out = driver.command(0.15, 0.2)
        assert out is not None and (out.linear.x, out.angular.z) == (0.15, 0.2)
        # the wall spans x in [5.0, 5.4] units: at rest 0.3 units before it, facing it, a spin passes as it is
        st = settle(driver, 4.7 * S, 0.0, 0.0, 0.0, timeout=20.0)
        assert driver.command(0.0, 0.0) is not None  # a base at rest executes rest: the last output was the far
        # command, which the filter would take the base to go on executing until the spin acts (a teleported robot)
        out = driver.command(0.0, 2.0)
        assert out is not None and (out.linear.x, out.angular.z) == (0.0, 2.0), st
        # at full speed, heading at it: slowed
        settle(driver, 4.7 * S, 0.0, 0.22, 0.0, timeout=20.0)
        out = driver.command(0.22, 0.0)
        assert out is not None and out.linear.x < 0.22 - 1e-6
        # backing into it: facing away, reversing at full speed
        st = settle(driver, 4.7 * S, 0.0, -0.22, math.pi, timeout=20.0)
        out = driver.command(-0.22, 0.0)
        assert out is not None and -0.22 + 1e-6 < out.linear.x <= 0.0, (st["robot"], st["certificate"], out)
        assert np.isfinite(out.angular.z)
