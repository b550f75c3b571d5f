"""The robot the node filters for: its limits from the parameters, of the model card's robot model.

The node then serves it by exact similarity (:mod:`hjrno_ros.core.scaled_values`; docs/design.md, "Similarity").
d₀ is not a parameter: the robot keeps the card's d₀/v_max.
"""

from __future__ import annotations

import dataclasses
import math

from hjrno_ros.core.dynamics import CAR_MODEL, RobotParams
from hjrno_ros.ros.brt_node.config import NodeConfig
from hjrno_ros.ros.brt_node.parameters import ROBOT_MODEL_NAMES


def robot_params(card_robot: RobotParams, cfg: NodeConfig) -> RobotParams:
    """The robot of the parameters, of the card's model (``robot_model`` must name it: a ValueError says so
    otherwise): ``a_max``, ``omega_max`` (diff_drive) or ``kappa_max`` (car), ``v_max``, ``tracking_error`` (-1: the
    card's) and ``v_min`` (NaN: the card's v_min/v_max times the robot's v_max); d₀ keeps the card's d₀/v_max."""
    wanted = ROBOT_MODEL_NAMES[cfg.robot_model]
    if card_robot.model != wanted:
        name = next(k for k, v in ROBOT_MODEL_NAMES.items() if v == card_robot.model)
        raise ValueError(f"robot_model is {cfg.robot_model!r} but the model card is a {name!r} model: set "
                         f"robot_model: {name} or load a {cfg.robot_model} card")
    turn = "kappa_max" if card_robot.model == CAR_MODEL else "omega_max"
    other = "omega_max" if turn == "kappa_max" else "kappa_max"
    if getattr(cfg, other) != -1.0:
        raise ValueError(f"{other} is for the other robot model; a {cfg.robot_model} robot takes {turn}")

    def given(name: str) -> float:
        return getattr(cfg, name) if getattr(cfg, name) != -1.0 else getattr(card_robot, name)

    v_max = given("v_max")
    v_min = cfg.v_min if math.isfinite(cfg.v_min) else card_robot.v_min / card_robot.v_max * v_max
    return dataclasses.replace(card_robot, a_max=given("a_max"), d0=card_robot.d0 / card_robot.v_max * v_max,
                               v_min=v_min, v_max=v_max, tracking_error=given("tracking_error"),
                               **{turn: given(turn)})
