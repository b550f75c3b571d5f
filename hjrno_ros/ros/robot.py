"""The robot the node filters for: its limits from the parameters, mapped onto the model card's car by exact
similarity (docs/design.md, "Similarity").

A card covers the robots whose dimensionless numbers — a_max/(κ_max·v_max²), v_min/v_max, δ and d₀/v_max —
lie in its :class:`Coverage`: one trained model serves all of them at their own size.  With the scaling s
(lengths) and τ (times) from the card's model units to the robot, the node samples a window s times the card's,
feeds V0/s (and the robot's numbers, for a conditioned model) to the operator and reads V = s·V′ on a grid of
s·x′, (s/τ)·v′: the table's own interpolation then gives ∂V/∂(x, y) = ∂V′/∂(x′, y′), ∂V/∂v = τ·∂V′/∂v′ and
∂V/∂θ = s·∂V′/∂θ′.  d₀ is not a parameter: the robot keeps the card's d₀/v_max.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from hjrno_ros.core.dynamics import CarParams
from hjrno_ros.core.grids import GridSpec
from hjrno_ros.core.similarity import NUMBERS, Coverage, Dimensionless, Scaling
from hjrno_ros.core.value_table import ValueTable


def robot_params(card_car: CarParams, cfg: dict[str, Any]) -> CarParams:
    """The robot of the parameters: ``a_max``, ``kappa_max``, ``v_max``, ``tracking_error`` (-1: the card's) and
    ``v_min`` (NaN: the card's v_min/v_max times the robot's v_max); d₀ keeps the card's d₀/v_max."""
    v_max = cfg["v_max"] if cfg["v_max"] != -1.0 else card_car.v_max
    v_min = cfg["v_min"] if math.isfinite(cfg["v_min"]) else card_car.v_min / card_car.v_max * v_max
    return CarParams(a_max=cfg["a_max"] if cfg["a_max"] != -1.0 else card_car.a_max,
                     kappa_max=cfg["kappa_max"] if cfg["kappa_max"] != -1.0 else card_car.kappa_max,
                     d0=card_car.d0 / card_car.v_max * v_max, v_min=v_min, v_max=v_max,
                     tracking_error=(cfg["tracking_error"] if cfg["tracking_error"] != -1.0
                                     else card_car.tracking_error))


def covered_scaling(card_car: CarParams, robot: CarParams, param_ranges: dict | None = None) -> Scaling:
    """The scaling from the card's car to ``robot`` (x_robot = s·x_card, t_robot = τ·t_card); ValueError naming
    the covered range if the card's :class:`Coverage` does not hold the robot's dimensionless numbers."""
    have, coverage = Dimensionless.of(robot), Coverage.of(card_car, param_ranges)
    if not coverage.covers(have):
        got = ", ".join(f"{n} {v:.4g}" for n, v in zip(NUMBERS, dataclasses.astuple(have), strict=True))
        raise ValueError(f"the robot ({got}) is outside what the model card covers ({coverage.describe()}): choose "
                         "limits in that range or a model trained for the robot")
    card, bot = Scaling.of(card_car), Scaling.of(robot)
    return Scaling(bot.length / card.length, bot.time / card.time)


def filter_params(card_car: CarParams, robot: CarParams) -> CarParams:
    """The robot as the filter models it: its limits with the card's tracking error (≥ the robot's, covered)."""
    return dataclasses.replace(robot, tracking_error=card_car.tracking_error)


class ScaledValueFunction:
    """A learned value function of the card's car, seen at a covered robot's size and numbers: the interface the
    node uses (grid, params, window, shape, window_points, local_table) in the robot's SI units."""

    def __init__(self, vf: Any, scaling: Scaling, robot: CarParams) -> None:
        self.vf, self.scaling, self.params = vf, scaling, robot
        self.card = getattr(vf, "card", None)
        self.model_params = scaling.params_to_model(robot)  # the robot in the card's units
        self.grid: GridSpec = scaling.grid_to_robot(vf.grid)
        self.window = tuple(w * scaling.length for w in vf.window)
        self.shape = vf.shape

    def window_points(self, center: tuple[float, float], shape: tuple[int, int] | None = None) -> np.ndarray:
        s = self.scaling.length
        return self.vf.window_points((center[0] / s, center[1] / s), shape) * s

    def local_table(self, v0: np.ndarray, center: tuple[float, float], v: float, theta: float) -> ValueTable:
        s, speed = self.scaling.length, self.scaling.speed
        table = self.vf.local_table(np.asarray(v0) / s, (center[0] / s, center[1] / s), v / speed, theta,
                                    self.model_params)
        return ValueTable(self.scaling.grid_to_robot(table.grid), table.values * s)
