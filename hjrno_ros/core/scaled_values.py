"""A learned value function seen at another robot's size: exact similarity applied to a card (numpy only).

A card covers the robots of its model (differential drive or car) whose dimensionless numbers —
a_max/(v_max·ω_top) with ω_top = ω_max or κ_max·v_max, v_min/v_max, δ and d₀/v_max — lie in its
:class:`~hjrno_ros.core.similarity.Coverage`: one trained model serves all of them at their own size
(docs/design.md, "Similarity").  With the scaling s (lengths) and τ (times) from the card's model units to the
robot, a window s times the card's is sampled, V0/s (and the robot's numbers, for a conditioned model) goes to the
operator and V = s·V′ is read on a grid of s·x′, (s/τ)·v′: the table's own interpolation then gives
∂V/∂(x, y) = ∂V′/∂(x′, y′), ∂V/∂v = τ·∂V′/∂v′ and ∂V/∂θ = s·∂V′/∂θ′.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from hjrno_ros.core.dynamics import RobotParams
from hjrno_ros.core.grids import GridSpec
from hjrno_ros.core.similarity import Coverage, Dimensionless, Scaling, number_names
from hjrno_ros.core.value_table import value_table


def covered_scaling(card_robot: RobotParams, robot: RobotParams, param_ranges: dict | None = None) -> Scaling:
    """The scaling from the card's robot to ``robot`` (x_robot = s·x_card, t_robot = τ·t_card); ValueError naming
    the covered range if the card's :class:`Coverage` does not hold the robot's dimensionless numbers."""
    have, coverage = Dimensionless.of(robot), Coverage.of(card_robot, param_ranges)
    if not coverage.covers(have):
        got = f"{have.model}: " + ", ".join(f"{n} {v:.4g}" for n, v in zip(number_names(have.model), have.numbers,
                                                                          strict=True))
        raise ValueError(f"the robot ({got}) is outside what the model card covers ({coverage.describe()}): choose "
                         "limits in that range or a model trained for the robot")
    card, bot = Scaling.of(card_robot), Scaling.of(robot)
    return Scaling(bot.length / card.length, bot.time / card.time)


def filter_params(card_robot: RobotParams, robot: RobotParams) -> RobotParams:
    """The robot as the filter models it: its limits with the card's tracking error (≥ the robot's, covered)."""
    return dataclasses.replace(robot, tracking_error=card_robot.tracking_error)


class ScaledValueFunction:
    """A learned value function of the card's robot, seen at a covered robot's size and numbers: the interface the
    node uses (grid, params, window, shape, whole_table, window_points, local_table) in the robot's SI units."""

    def __init__(self, vf: Any, scaling: Scaling, robot: RobotParams) -> None:
        self.vf, self.scaling, self.params = vf, scaling, robot
        self.card = getattr(vf, "card", None)
        self.model_params = scaling.params_to_model(robot)  # the robot in the card's units
        self.grid: GridSpec = scaling.grid_to_robot(vf.grid)
        self.window = tuple(w * scaling.length for w in vf.window)
        self.shape = vf.shape
        self.whole_table, self.predicts, self.runtime = bool(vf.whole_table), bool(vf.predicts), vf.runtime

    def window_points(self, center: tuple[float, float], shape: tuple[int, int] | None = None) -> np.ndarray:
        s = self.scaling.length
        return self.vf.window_points((center[0] / s, center[1] / s), shape) * s

    def local_table(self, v0: np.ndarray, center: tuple[float, float], v: float, theta: float,
                    reach: tuple[float, float] = (0.0, 0.0)) -> Any:
        """The table around the state (``reach``: m/s and rad the robot may move from v and θ before the next)."""
        s, speed = self.scaling.length, self.scaling.speed
        grid, values = self.vf.local_values(np.asarray(v0) / s, (center[0] / s, center[1] / s), v / speed, theta,
                                            self.model_params, (reach[0] / speed, reach[1]))
        return value_table(self.scaling.grid_to_robot(grid), values * s)
