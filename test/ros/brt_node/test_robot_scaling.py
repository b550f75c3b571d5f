"""The node takes the robot (here a car card, the paper's): any robot of the card's model with its dimensionless
numbers is served by exact similarity; others are refused with the covered range."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from dds_driver import DOMAIN, FAR, NEAR_WALL, driver_and_node, map_msg, occupancy, settle  # noqa: E402

from hjrno_ros.core.dynamics import CarParams  # noqa: E402
from hjrno_ros.core.model_card import ModelCard  # noqa: E402
from hjrno_ros.core.safety_filter import sampling_margin  # noqa: E402
from hjrno_ros.core.scaled_values import ScaledValueFunction, covered_scaling  # noqa: E402
from hjrno_ros.core.similarity import Dimensionless  # noqa: E402
from hjrno_ros.ros.brt_node import parameters  # noqa: E402
from hjrno_ros.ros.brt_node.config import NodeConfig  # noqa: E402
from hjrno_ros.ros.brt_node.robot import robot_params  # noqa: E402

S = 0.25  # the small robot's length scale against the card's car: κ_max 4 /m, v_max 0.5 m/s, a_max 1 m/s²
SMALL = {"kappa_max": 4.0, "v_max": 0.5, "a_max": 1.0}


def cfg(**robot) -> NodeConfig:
    return NodeConfig(**{"robot_model": "car", **robot})


def test_robot_parameters_map_onto_the_card_or_are_refused(model_stem):
    card = ModelCard.load(model_stem)
    assert robot_params(card.dynamics, cfg()) == card.dynamics  # the defaults: the card's own car
    small = robot_params(card.dynamics, cfg(**SMALL))
    assert small == CarParams(a_max=1.0, kappa_max=4.0, d0=0.05, v_min=0.0, v_max=0.5)  # keeps d0/v_max
    scaling = covered_scaling(card.dynamics, small)
    assert scaling.length == pytest.approx(S) and scaling.speed == pytest.approx(0.5)
    turtlebot = robot_params(card.dynamics, cfg(kappa_max=2.84 / 0.22, v_max=0.22, a_max=2.5))
    with pytest.raises(ValueError, match=r"outside what the model card covers \(dynamic_dubins_car: "
                                         r"a_max/\(kappa_max\*v_max\^2\) 1,"):
        covered_scaling(card.dynamics, turtlebot)
    with pytest.raises(ValueError, match="set robot_model: car"):
        robot_params(card.dynamics, cfg(robot_model="diff_drive"))
    with pytest.raises(ValueError, match="omega_max is for the other robot model"):
        robot_params(card.dynamics, cfg(omega_max=2.0))
    assert "a_max" in NodeConfig.build({**cfg().as_dict(), "a_max": 0.0}, startup=True)
    assert isinstance(NodeConfig.build(cfg(v_min=math.nan).as_dict(), startup=True), NodeConfig)


def test_a_scaled_table_is_the_card_table_at_the_robot_size(model_stem):
    """The small robot's table at (s·x, s·y, (s/τ)·v, θ) is s times the card's at (x, y, v, θ), and its gradient
    follows the chain rule (∂x the same, ∂v times τ, ∂θ times s)."""
    from hjrno_ros.learning.value_function import LearnedValueFunction

    vf = LearnedValueFunction(model_stem, device="cpu")
    card = ModelCard.load(model_stem)
    small = robot_params(card.dynamics, cfg(**SMALL))
    scaled = ScaledValueFunction(vf, covered_scaling(card.dynamics, small), small)
    center = (1.0, -2.0)
    xy = vf.window_points(center)
    v0 = (np.abs(xy[..., 0] - 4.0) - 0.3).astype(np.float32)  # a wall 3 m ahead of the centre
    big_table = vf.local_table(v0, center, 0.6, 0.2)
    small_table = scaled.local_table(S * v0, (S * center[0], S * center[1]), 0.6 * 0.5, 0.2)
    assert np.allclose(scaled.window_points((S * center[0], S * center[1])), S * xy)
    state = np.array([center[0] + 1.3, center[1] - 0.4, 0.6, 0.2])
    small_state = state * [S, S, 0.5, 1.0]
    v_big, g_big = big_table.value_and_gradient(state)
    v_small, g_small = small_table.value_and_gradient(small_state)
    assert v_small[0] == pytest.approx(S * v_big[0], rel=1e-5, abs=1e-6)
    tau = S / 0.5
    assert np.allclose(g_small[0], g_big[0] * [1.0, 1.0, tau, S], rtol=1e-4, atol=1e-6)


def test_the_node_filters_a_smaller_robot_on_a_smaller_map(model_stem, ros):
    """Over DDS: the same map at a quarter of the size and the small robot give a quarter of the card robot's V
    at the corresponding states (the module's node serves the card's robot)."""
    driver, _ = ros
    reference = {name: settle(driver, *pose)["value"] for name, pose in
                 (("far", (*FAR, 0.5, 0.0)), ("near", (*NEAR_WALL, 1.0, 0.3)))}
    small_map = map_msg(occupancy(), resolution=0.1 * S)
    small_map.info.origin.position.x, small_map.info.origin.position.y = -10.0 * S, -10.0 * S
    with driver_and_node(model_stem, DOMAIN + 46, publish_map=False, **SMALL) as (small, node):
        small.map_pub.publish(small_map)
        margin = ModelCard.load(model_stem).margin()
        assert node.vf.params.kappa_max == 4.0 and node.settings.epsilon == pytest.approx(S * margin)  # one period
        # ahead (least_restrictive): no sampling margin; the modes that judge the present state add it
        blend = parameters.filter_settings(node.card, dataclasses.replace(node.config, filter_mode="blend"), node.scale,
                                           node.vf.params)
        assert blend.epsilon == pytest.approx(S * margin + sampling_margin(node.vf.params, node.settings.dt))
        for name, (x, y, v, theta) in (("far", (*FAR, 0.5, 0.0)), ("near", (*NEAR_WALL, 1.0, 0.3))):
            value = settle(small, S * x, S * y, 0.5 * v, theta, timeout=20.0)["value"]
            assert value == pytest.approx(S * reference[name], rel=2e-3, abs=2e-3), (name, value, reference)


def test_a_conditioned_product_card_covers_a_range_of_robots():
    from hjrno_ros.core.similarity import Coverage

    card = CarParams.product()
    coverage = Coverage.of(card, {"log_a_max": [math.log(0.5), math.log(4.0)]})
    turtlebot = CarParams(a_max=2.0, kappa_max=2.84 / 0.22, v_min=-0.22, v_max=0.22, tracking_error=0.05, d0=0.0)
    jackal = CarParams(a_max=3.0, kappa_max=2.0, v_min=-1.0, v_max=1.0, tracking_error=0.1, d0=0.0)
    assert coverage.covers(Dimensionless.of(turtlebot)) and coverage.covers(Dimensionless.of(jackal))
    scaling = covered_scaling(card, turtlebot, {"log_a_max": [math.log(0.5), math.log(4.0)]})
    assert scaling.length == pytest.approx(0.22 / 2.84) and scaling.speed == pytest.approx(0.22)
    for bad in (dict(a_max=10.0), dict(tracking_error=0.2), dict(v_min=-2.0)):
        with pytest.raises(ValueError, match=r"covers \(dynamic_dubins_car: a_max/\(kappa_max\*v_max\^2\) 0\.5\.\.4, "
                                             r"v_min/v_max -1\.\.0, tracking_error 0\.\.0\.1, d0/v_max 0\)"):
            covered_scaling(card, dataclasses.replace(jackal, **bad), {"log_a_max": [math.log(0.5), math.log(4.0)]})
    # without the conditioning channel only the card's own a_max/(κ v²) is covered
    with pytest.raises(ValueError, match=r"a_max/\(kappa_max\*v_max\^2\) 1,"):
        covered_scaling(card, jackal)


def test_a_forward_card_answers_reversing_states_by_symmetry(model_stem):
    """V(x, y, −v, θ) = V(x, y, v, θ + π): the table at a reversing state is the forward table turned round."""
    from hjrno_ros.learning.value_function import LearnedValueFunction

    vf = LearnedValueFunction(model_stem, device="cpu")
    xy = vf.window_points((0.0, 0.0))
    v0 = (np.abs(xy[..., 0] - 2.0) - 0.3).astype(np.float32)
    back = vf.local_table(v0, (0.0, 0.0), -0.6, 0.3)
    ahead = vf.local_table(v0, (0.0, 0.0), 0.6, 0.3 + math.pi)
    assert back.grid.lo[2] < 0 and back.grid.hi[2] < 0
    assert np.allclose(back.grid.lo[2:], (-ahead.grid.hi[2], 0.3 - vf.grid.spacings[3] / 2))
    assert np.array_equal(back.values, ahead.values[:, :, ::-1])
