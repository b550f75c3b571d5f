"""The node's background refinement (``refine_horizon`` > 0): which map to refine, when, and which stage the
filter may read.  The solve itself runs in a nice-19 child process (:mod:`hjrno_ros.ros.brt_node.refinement_process`,
which imports JAX only in that child)."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from hjrno_ros.core.map_tiling import map_grid
from hjrno_ros.core.value_table import ValueTable
from hjrno_ros.ros.brt_node.inputs import MapData, RobotState
from hjrno_ros.ros.brt_node.refinement_process import BackgroundRefinement

MAX_STATES = 4_000_000  # (x, y, v, θ) nodes: ~170 × 170 x-y nodes of the default model (a 54 m square map)
REFINE_SETTLE = 2.0  # s a map must stand before its refinement starts (a map updated every second never does)


@dataclasses.dataclass(frozen=True)
class RefinedValue:
    """A stage of the background refinement, for the map version it was started for."""

    table: ValueTable  # over the map × the model's (v, θ) grid
    map_version: int
    horizon: float  # simulated s of solver so far
    settled: bool
    wall_s: float
    cpus: int  # cores the solver process could run on


class Refinement:
    """``from_target``: a solver card's refinement, which starts from the target l: its stages before the solve
    settles under-approximate the tube (V ≥ V∞), so only a settled table is used."""

    def __init__(self, model_grid: Any, model: str, horizon: float, stage: float, cpus: int,
                 from_target: bool = False) -> None:
        self.model_grid, self.model, self.horizon, self.stage = model_grid, model, horizon, stage
        self.from_target = from_target
        self.process = BackgroundRefinement(cpus)
        self.version: int | None = None  # map version the refinement runs (or ran) for
        self.error = ""
        self.refined: RefinedValue | None = None

    def stop(self) -> None:
        self.process.stop()

    def step(self, m: MapData, v0: Callable[[MapData, np.ndarray], np.ndarray],
             log: Callable[[str, str], None]) -> None:
        """Start refining a new map version; take a newly finished stage of the current one."""
        if self.version != m.version:
            if time.monotonic() - m.received < REFINE_SETTLE:
                return
            self.version, self.refined, self.error = m.version, None, ""
            self.process.stop()
            far = tuple(o + n * m.resolution for o, n in zip(m.origin, m.occupancy.shape, strict=True))
            grid = map_grid(self.model_grid, m.origin, far)
            if int(np.prod(grid.shape)) > MAX_STATES:
                self.error = (f"map too large to refine: {grid.shape} states > {MAX_STATES:.0e}; "
                              "the operator's windows only")
                log("warning", self.error)
                return
            xy = np.stack(np.meshgrid(grid.axis(0), grid.axis(1), indexing="ij"), -1)
            self.process.start(m.version, v0(m, xy), grid, self.model, self.horizon, self.stage)
            return
        stage = self.process.poll()
        if self.process.error and self.process.error != self.error:
            self.error = self.process.error
            log("error", self.error)
        if stage is not None and stage.key == m.version:
            self.refined = RefinedValue(ValueTable(stage.grid, stage.values), m.version, stage.horizon, stage.settled,
                                        stage.wall_s, stage.cpus)
            log("info", f"refined value for map {m.version}: {stage.horizon:g} simulated s "
                        f"({'settled' if stage.settled else 'not settled'}), {stage.wall_s:.1f} s wall on "
                        f"{stage.cpus} core(s)")

    def usable(self, m: MapData, state: RobotState) -> RefinedValue | None:
        """The refined table if it is the current map's and the robot is two x-y cells inside it."""
        r = self.refined
        if r is None or r.map_version != m.version or (self.from_target and not r.settled):
            return None
        g = r.table.grid
        margin = 2 * np.asarray(g.spacings[:2])
        lo, hi = np.asarray(g.lo[:2]) + margin, np.asarray(g.hi[:2]) - margin
        return r if bool(np.all((lo <= (state.x, state.y)) & ((state.x, state.y) <= hi))) else None

    def status(self, m: MapData | None) -> dict[str, Any]:
        r = self.refined
        current = r is not None and m is not None and r.map_version == m.version
        state = ("failed" if self.error else "running" if self.process.running else "done" if current else "waiting")
        return {"state": state, "error": self.error, "horizon_s": r.horizon if current else 0.0,
                "settled": bool(current and r.settled), "wall_s": r.wall_s if current else None,
                "cpus": r.cpus if current else None}
