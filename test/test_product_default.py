"""The bundled default (issue 42): a product-model FNO conditioned on a_max/(κ_max·v_max²), forward speeds only.
Its card carries the covered range, metrics and calibration; over DDS it serves a TurtleBot3-class base that
reverses, on a map at the robot's own scale."""

from __future__ import annotations

import math

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from test_brt_node import DOMAIN, ROOT, map_msg, occupancy, settle  # noqa: E402
from test_brt_node import driver_and_node as _driver_and_node  # noqa: E402

from hjrno_ros.core.dynamics import CarParams  # noqa: E402
from hjrno_ros.core.model_card import ModelCard  # noqa: E402
from hjrno_ros.core.safety_filter import sampling_margin  # noqa: E402
from hjrno_ros.core.similarity import NUMBERS, Coverage  # noqa: E402
from hjrno_ros.learning import checkpoint  # noqa: E402

DEFAULT = ROOT / "models" / "default"
TURTLEBOT3 = {"kappa_max": 2.84 / 0.22, "v_max": 0.22, "v_min": -0.22, "a_max": 2.0}
S = 0.22 / 2.84  # its length scale: 1/κ_max, m per model unit (the test map's 20 m become 1.55 m)


def test_the_default_is_a_product_fno_with_its_coverage_metrics_and_calibration():
    card = ModelCard.load(DEFAULT)
    assert card.kind == "fno" and card.dynamics == CarParams.product()
    assert list(card.inputs["param_ranges"]) == ["log_a_max"]
    expected = Coverage.of(card.dynamics, card.inputs["param_ranges"])
    assert card.data["coverage"] == {n: list(r) for n, r in zip(NUMBERS, expected.ranges, strict=True)}
    assert card.data["coverage"]["a_max/(kappa_max*v_max^2)"] == pytest.approx([0.5, 4.0])
    assert card.epsilon is not None and card.data["calibration"]["alpha"] == 0.001
    assert {"test_rel_l2", "test_iou", "test_false_safe"} <= set(card.metrics)
    assert checkpoint.paths(DEFAULT)[0].stat().st_size <= 10e6
    assert card.command and "hjrno train" in card.command


def test_a_reversing_turtlebot3_is_filtered_at_its_own_scale():
    """Over DDS: the bundled default serves the TurtleBot3 (covered: a_max/(κ v²) 3.2, reversing) on a map 7.75 cm
    per model unit; far from the wall a command passes, driving or reversing into the wall is slowed."""
    small_map = map_msg(occupancy(), resolution=0.1 * S)
    small_map.info.origin.position.x, small_map.info.origin.position.y = -10.0 * S, -10.0 * S
    with _driver_and_node(DEFAULT, DOMAIN + 48, publish_map=False, **TURTLEBOT3) as (driver, node):
        driver.map_pub.publish(small_map)
        p = node.vf.params
        assert (p.kappa_max, p.v_min, p.a_max) == (TURTLEBOT3["kappa_max"], -0.22, 2.0)
        card = ModelCard.load(DEFAULT)
        assert node.settings.epsilon == pytest.approx(S * card.margin() + sampling_margin(p, node.settings.dt))
        settle(driver, -4.0 * S, -4.0 * S, 0.1, 0.0, timeout=20.0)  # > 9 units from the wall
        out = driver.command(0.15, 0.2)
        assert out is not None and (out.linear.x, out.angular.z) == (0.15, 0.2)
        # the wall spans x in [5.0, 5.4] units: 0.3 units before it at full speed, heading at it
        st = settle(driver, 4.7 * S, 0.0, 0.22, 0.0, timeout=20.0)
        assert st["value"] <= st["epsilon"]
        out = driver.command(0.22, 0.0)
        assert out is not None and out.linear.x < 0.22 - 1e-6
        # backing into it: facing away, reversing at full speed
        st = settle(driver, 4.7 * S, 0.0, -0.22, math.pi, timeout=20.0)
        assert st["value"] <= st["epsilon"], st
        out = driver.command(-0.22, 0.0)
        assert out is not None and -0.22 + 1e-6 < out.linear.x <= 0.0
        assert np.isfinite(out.angular.z)
