"""What the node reads values from (numpy only): the interface of a learned operator
(:class:`~hjrno_ros.core.operator_values.OperatorValues`, its network run by onnxruntime or torch), of the same
seen at another robot's size (:class:`~hjrno_ros.core.scaled_values.ScaledValueFunction`) and of a solver card,
which has no operator (``ros.brt_node.value_sources.SolverGrid``: its tables come from the node's background
solver only)."""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from hjrno_ros.core.dynamics import RobotParams
from hjrno_ros.core.grids import GridSpec


class ValueSource(Protocol):
    """A value function over a robot-centred window, in the robot's SI units."""

    grid: GridSpec  # the card's (x, y, v, θ) grid, x-y relative to the window's centre
    params: RobotParams  # the robot it serves
    window: tuple[float, float]  # m
    shape: tuple[int, int]  # x-y nodes of V0
    whole_table: bool  # each table holds every speed and heading of the window
    predicts: bool  # False: no operator (a solver card): the node waits for the solver's table
    runtime: str  # what computes the values: "onnxruntime", "torch" or "solver"

    def window_points(self, center: tuple[float, float], shape: tuple[int, int] | None = None) -> np.ndarray:
        """The x-y nodes ``(nx, ny, 2)`` of the window centred at ``center``, where V0 is sampled."""
        ...

    def local_table(self, v0: np.ndarray, center: tuple[float, float], v: float, theta: float,
                    reach: tuple[float, float] = (0.0, 0.0)) -> Any:
        """The value table (``value``, ``value_and_gradient``, ``inside``) of the window for V0 ``v0``: every
        (v, θ), or a stencil around (v, θ) that spans ``reach`` (m/s, rad).  Only where ``predicts``."""
        ...
