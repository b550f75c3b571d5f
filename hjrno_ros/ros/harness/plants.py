"""What a :class:`~hjrno_ros.ros.harness.sim_base.SimBase` moves: the kinematic robot of the depot check and the
product scenes, a pose held still (the node bench, the fuzzer, the DDS tests); IR-SIM's robot is in
:mod:`hjrno_ros.ros.harness.irsim_base`."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from hjrno_ros.core.dynamics import RobotParams
from hjrno_ros.studies.closed_loop import base_step


class KinematicPlant:
    """The card's robot (car or differential drive) integrated with :func:`~hjrno_ros.studies.closed_loop.base_step`:
    the speed command reached within ``control_period`` s under a_max, and a random disturbance ‖d‖ ≤ δ·|v| + d₀.
    ``event(xy)`` says when the episode ends ("collision", "exit") or None."""

    def __init__(self, params: RobotParams, start: np.ndarray, event: Callable[[np.ndarray], str | None] | None = None,
                 control_period: float = 0.05, seed: int = 0) -> None:
        self.params, self.control_period = params, control_period
        self.event = event or (lambda xy: None)
        self.rng = np.random.default_rng(seed)
        self.x = np.zeros((1, 4))
        self.omega = 0.0
        self.place(start)

    def place(self, state: np.ndarray) -> None:
        """Put the robot at ``state`` (x, y, v, θ)."""
        self.x = np.asarray(state, float).reshape(1, 4).copy()
        self.omega = 0.0

    def pose(self) -> tuple[float, float, float]:
        return float(self.x[0, 0]), float(self.x[0, 1]), float(self.x[0, 3])

    def velocity(self) -> tuple[float, float]:
        return float(self.x[0, 2]), self.omega

    def step(self, twist: np.ndarray, dt: float) -> str | None:
        self.x = base_step(self.params, self.x, np.asarray(twist, float)[None], self.control_period, dt, self.rng)
        self.omega = float(twist[1])
        return self.event(self.x[0, :2])


class HeldPlant:
    """A robot held at a pose with a reported speed, moved only by its user (``at`` = (x, y, θ), one tuple so that
    another thread replaces it whole; ``v``); steps change nothing."""

    def __init__(self, x: float = 0.0, y: float = 0.0, theta: float = 0.0, v: float = 0.0) -> None:
        self.at, self.v = (x, y, theta), v

    def pose(self) -> tuple[float, float, float]:
        return self.at

    def velocity(self) -> tuple[float, float]:
        return self.v, 0.0

    def step(self, twist: np.ndarray, dt: float) -> str | None:
        return None
