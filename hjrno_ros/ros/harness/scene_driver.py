"""The product scenes (:mod:`hjrno_ros.studies.product_scenes`) over DDS: a
:class:`~hjrno_ros.ros.harness.sim_base.SimBase` with a :class:`~hjrno_ros.ros.harness.plants.KinematicPlant` on the
scenes' map, Twist commands, the scene's constant nominal at 20 Hz, the robot (car or differential drive) integrated
in real time at 50 Hz with the *filtered* command (stale for > 0.25 s: brake) and a random disturbance
‖d‖ ≤ δ·|v| + d₀."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from hjrno_ros.core.dynamics import RobotParams
from hjrno_ros.ros.harness.plants import KinematicPlant
from hjrno_ros.ros.harness.sim_base import BaseLog, SimBase
from hjrno_ros.studies import product_scenes


def scene_base(context: Any, params: RobotParams, seed: int = 0) -> SimBase:
    """The scenes' base, at rest at the origin with the scenes' map latched."""
    base = SimBase(context, KinematicPlant(params, np.zeros(4), seed=seed), None, name="scene_base", stamped=False,
                   keep_grids=False)
    base.publish_map(product_scenes.scene_map(), product_scenes.RESOLUTION, product_scenes.ORIGIN)
    return base


def place(base: SimBase, state: tuple[float, float, float, float]) -> None:
    """Put the robot at ``state`` and hold it there (no nominal command, no integration)."""
    base.running = False
    base.plant.place(np.asarray(state, float))


def run(base: SimBase, scene: product_scenes.Scene) -> tuple[np.ndarray, np.ndarray]:
    """Drive ``scene`` in real time from its start; (states (k, 4) before each physics step and at the end, filtered
    outputs (m, 2) received meanwhile)."""
    place(base, scene.start)
    base.log, base.driver = BaseLog(), lambda state, t: np.asarray(scene.nominal, float)
    base.filtered, base.filtered_at, base.nominal = np.zeros(2), -math.inf, None
    base.begin()
    time.sleep(scene.seconds)
    base.running = False
    states = [row[1:5] for row in base.log.trace] + [base.state()]
    return np.array(states, float), np.array(base.log.outputs, float).reshape(-1, 2)
