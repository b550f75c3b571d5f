"""Fixed reference problems for ``hjrno solve``, the benchmarks and the validation tests.

Each is deterministic: dynamics, grid, target l and the solve settings that suit it.  The car
problems take the robot model (``params``; default the paper's car, :meth:`CarParams.paper`, which the
reproduction tables use; :meth:`CarParams.product` is the product car, :class:`DiffDriveParams` the
differential drive); the grid's speed axis is the model's [v_min, v_max].
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from hjrno_ros.core.dynamics import Air3DParams, CarParams, RobotParams
from hjrno_ros.core.geometry import Box, Disk, Shape, air3d_collision_sdf, union_sdf
from hjrno_ros.core.grids import GridSpec, air3d_grid, car_grid
from hjrno_ros.truth.scenarios import make_scenario
from hjrno_ros.truth.systems import Air3D, robot_system

DEFAULT_CAR_SHAPE = (40, 40, 12, 20)
DEFAULT_AIR3D_SHAPE = (51, 40, 50)
INDOOR_SEED = 3  # the ``indoor`` problem: this scene of the indoor family (two walls with doors, clutter)


@dataclasses.dataclass
class Problem:
    name: str
    description: str
    dynamics: object
    grid: GridSpec
    target: np.ndarray
    shapes: tuple[Shape, ...]  # obstacles in the x-y plane (Air3D: evader, pursuer in body frames)
    solve_options: dict

    def clearance(self, states: np.ndarray) -> np.ndarray:
        """Exact l(x) at car states (..., 4) from the shapes (not the grid)."""
        return union_sdf(self.shapes, np.asarray(states)[..., :2])


def _car_grid(shape: tuple[int, ...], params: RobotParams) -> GridSpec:
    return car_grid(shape, v_range=(params.v_min, params.v_max))


def disk(shape=DEFAULT_CAR_SHAPE, params: RobotParams = CarParams()) -> Problem:
    grid = _car_grid(shape, params)
    shapes = (Disk((0.0, 0.0), 1.0),)
    target = union_sdf(shapes, grid.states()[..., :2]).astype(np.float32)
    return Problem("disk", "dynamic Dubins car, disk obstacle r = 1 m at the centre of a 10 m x 10 m window",
                   robot_system(params), grid, target, shapes, {"criterion": "interior"})


def room(shape=DEFAULT_CAR_SHAPE, params: RobotParams = CarParams()) -> Problem:
    """Converged is judged near V = 0: inside the walls V keeps sinking towards the extrapolated edge."""
    grid = _car_grid(shape, params)
    t, h = 0.4, 5.0  # wall thickness and half the room size, m
    shapes = (
        Box((0.0, -h + t / 2), (h, t / 2)),
        Box((0.0, h - t / 2), (h, t / 2)),
        Box((-h + t / 2, 0.0), (t / 2, h)),
        Box((h - t / 2, 0.0), (t / 2, h)),
    )
    target = union_sdf(shapes, grid.states()[..., :2]).astype(np.float32)
    return Problem("room", "dynamic Dubins car in a closed 10 m x 10 m room with 0.4 m walls",
                   robot_system(params), grid, target, shapes, {"criterion": "band", "max_horizon": 60.0})


def indoor(shape=DEFAULT_CAR_SHAPE, params: RobotParams = CarParams()) -> Problem:
    """Scene ``INDOOR_SEED`` of the indoor family; judged on the band, as the indoor datasets are."""
    fields = {k: v for k, v in params.as_dict().items() if k != "model"}
    scenario = make_scenario("indoor", INDOOR_SEED, **fields)
    grid = scenario.grid(shape)
    return Problem("indoor", f"dynamic Dubins car in indoor scene {INDOOR_SEED}: outer walls, "
                   f"{scenario.params['n_walls']} interior wall(s) with doors, {scenario.params['n_clutter']} clutter "
                   "item(s), 10 m x 10 m", robot_system(params), grid, scenario.target(grid), scenario.shapes,
                   {"criterion": "band", "max_horizon": 60.0})


def air3d(shape=DEFAULT_AIR3D_SHAPE, params: Air3DParams = Air3DParams()) -> Problem:
    grid = air3d_grid(shape)
    shapes = (Disk((0.0, 0.0), 2.5), Disk((0.0, 0.0), 2.5))
    target = air3d_collision_sdf(shapes[0], shapes[1], grid)
    return Problem("air3d", "Air3D, two circular agents r = 2.5 m (collision at 5 m), speeds 5 m/s",
                   Air3D(params), grid, target, shapes, {"criterion": "band", "max_horizon": 10.0, "chunk": 0.5})


PROBLEMS: dict[str, Callable[..., Problem]] = {"disk": disk, "room": room, "indoor": indoor, "air3d": air3d}
CAR_PROBLEMS = ("disk", "room", "indoor")


def make_problem(name: str, shape: tuple[int, ...] | None = None, params: RobotParams | None = None) -> Problem:
    """Problem ``name`` on ``shape`` (default: its own); ``params``: a car problem's robot model."""
    if name not in PROBLEMS:
        raise ValueError(f"unknown problem {name!r}; choose from {', '.join(PROBLEMS)}")
    kwargs = {} if shape is None else {"shape": tuple(shape)}
    if params is not None:
        if name not in CAR_PROBLEMS:
            raise ValueError(f"problem {name!r} has no robot model to choose; car problems: {', '.join(CAR_PROBLEMS)}")
        kwargs["params"] = params
    return PROBLEMS[name](**kwargs)
