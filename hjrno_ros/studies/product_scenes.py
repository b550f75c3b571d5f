"""The product models' behaviour scenes: a robot that can stop and reverse, near walls.

One 8 m × 6 m map holds every scene: a wall 1 m ahead of a robot at rest, a 1.6 m wide dead-end corridor,
a wall behind a reversing robot (moving, and at rest), a robot beside a wall asked to spin, a robot inside a
wall.  The differential drive (:data:`DIFF_DRIVE_SCENES`) has its own: it turns in place where the car cannot,
escapes backwards or by turning from rest inside the margin, and accelerates from rest to full speed in the open.
Each scene is a start state (x, y, v, θ), a constant nominal command and a duration; :func:`judge` says
what must hold.
The scenes run offline against a table (:func:`simulate`) and over DDS with brt_node
(:mod:`hjrno_ros.ros.harness.scene_driver`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from hjrno_ros.core import geometry, least_restrictive, safety_filter
from hjrno_ros.core.dynamics import CarParams, DiffDriveParams, RobotParams
from hjrno_ros.core.tables import markdown_table
from hjrno_ros.core.value_table import ValueTable
from hjrno_ros.studies.closed_loop import base_step

RESOLUTION = 0.05  # m
ORIGIN = (0.0, 0.0)
SIZE = (160, 120)  # cells: 8 m x 6 m
WALLS = (  # x0, x1, y0, y1 in m
    (6.0, 6.2, 0.0, 6.0),  # the right wall
    (0.8, 4.6, 3.4, 3.6),  # the corridor's lower wall
    (0.8, 4.6, 5.2, 5.4),  # its upper wall: 1.6 m between them
    (4.4, 4.6, 3.4, 5.4),  # its dead end
    (0.0, 0.2, 0.0, 3.0),  # the wall behind the reversing robot
)


@dataclasses.dataclass(frozen=True)
class Scene:
    name: str
    start: tuple[float, float, float, float]  # x, y, v, θ
    nominal: tuple[float, float]  # linear m/s, angular rad/s
    seconds: float
    expect: str


SCENES = (
    Scene("rest_stop", (5.0, 1.5, 0.0, 0.0), (0.0, 0.0), 3.0, "at rest 1 m from a wall, nominal stop: stays at rest"),
    Scene("rest_forward", (5.0, 1.5, 0.0, 0.0), (0.3, 0.0), 8.0, "nominal 0.3 m/s at the wall 1 m ahead: stops before"),
    Scene("dead_end", (1.2, 4.4, 0.3, 0.0), (0.3, 0.0), 14.0,
          "1.6 m dead-end corridor at 0.3 m/s: no collision, |v| never above the nominal's"),
    Scene("reverse", (1.2, 1.5, -0.3, 0.0), (-0.3, 0.0), 7.0, "reversing at 0.3 m/s toward a wall behind: braked"),
    Scene("rest_reverse", (0.4, 2.0, 0.0, 0.0), (-0.3, 0.0), 3.0,
          "at rest 0.2 m before a wall behind, nominal reverse: creeps back, slowing, at rest short of the wall"),
    Scene("spin", (5.5, 1.0, 0.0, 0.0), (0.0, 1.0), 3.0, "spin in place 0.5 m from a wall: no motion added"),
    Scene("inside_wall", (6.1, 2.0, 0.0, 0.0), (0.3, 0.5), 2.0, "inside a wall: never more speed than the nominal"),
)
DIFF_DRIVE_SCENES = (
    *(s for s in SCENES if s.name not in ("spin", "rest_reverse")),
    Scene("rest_reverse", (0.3, 2.0, 0.0, 0.0), (-0.3, 0.0), 3.0,
          "at rest 0.1 m before a wall behind, nominal reverse: creeps back, slowing, at rest short of the wall"),
    Scene("spin_in_place", (5.5, 1.0, 0.0, 0.0), (0.0, 1.0), 3.0,
          "spin in place 0.5 m from a wall: it turns (> 2 rad), no x-y motion"),
    Scene("escape_back", (5.9, 1.5, 0.0, 0.0), (-0.3, 0.0), 4.0,
          "at rest 0.1 m from the wall ahead (inside the margin), nominal reverse: backs out of the margin"),
    Scene("escape_turn", (5.9, 2.0, 0.0, 0.0), (0.0, 1.0), 3.0,
          "at rest 0.1 m from the wall ahead (inside the margin), nominal spin: turns in place"),
    Scene("accelerate", (1.0, 1.0, 0.0, 0.5), (1.0, 0.0), 1.6,
          "from rest in the open, nominal v_max: reaches 0.9 v_max, never changed"),
)


def scene_map() -> np.ndarray:
    """The scenes' occupancy raster ``[ix, iy]`` (0 free, 100 occupied)."""
    occ = np.zeros(SIZE, np.int8)
    for x0, x1, y0, y1 in WALLS:
        occ[int(round(x0 / RESOLUTION)):int(round(x1 / RESOLUTION)),
            int(round(y0 / RESOLUTION)):int(round(y1 / RESOLUTION))] = 100
    return occ


def clearance(points: np.ndarray) -> np.ndarray:
    """Signed distance (m) of x-y ``points`` to the walls and the map's edge."""
    sd = geometry.occupancy_signed_distance(scene_map(), RESOLUTION)
    return geometry.sample_raster(sd, ORIGIN, RESOLUTION, points, outside=-RESOLUTION)


def judge(scene: Scene, states: np.ndarray, outputs: np.ndarray) -> list[str]:
    """What went wrong in a run: ``states`` (k, 4) of the base, ``outputs`` (m, 2) the filtered commands."""
    problems = []
    start_clear = clearance(np.asarray(scene.start[:2])[None])[0] > 0
    if start_clear and (clearance(states[:, :2]) <= 0).any():
        problems.append(f"collision (minimum clearance {clearance(states[:, :2]).min():.3f} m)")
    speed = abs(scene.nominal[0])
    if len(outputs) and np.abs(outputs[:, 0]).max() > max(speed, abs(scene.start[2])) + 1e-9:
        problems.append(f"output speed {np.abs(outputs[:, 0]).max():.3f} above the nominal's {speed}")
    if scene.name in ("rest_stop", "spin"):
        moved = np.linalg.norm(states[:, :2] - states[0, :2], axis=-1).max()
        if moved > 1e-3 or np.abs(states[:, 2]).max() > 1e-6:
            problems.append(f"moved {moved:.4f} m from rest")
        if len(outputs) and np.abs(outputs[:, 0]).max() > 0:
            problems.append("a non-zero speed was commanded at rest")
    if scene.name in ("rest_forward", "reverse", "dead_end", "rest_reverse") and abs(states[-1, 2]) > 0.05:
        problems.append(f"still moving at {states[-1, 2]:.3f} m/s at the end")
    if scene.name in ("spin_in_place", "escape_turn"):
        moved = np.linalg.norm(states[:, :2] - states[0, :2], axis=-1).max()
        turned = np.abs(np.diff(np.unwrap(states[:, 3]))).sum()
        if moved > 1e-3 or turned < 2.0:
            problems.append(f"moved {moved:.4f} m, turned {turned:.2f} rad")
    if scene.name == "escape_back" and clearance(states[-1:, :2])[0] < clearance(states[:1, :2])[0] + 0.2:
        problems.append(f"backed out only to {clearance(states[-1:, :2])[0]:.3f} m from the wall")
    if scene.name == "accelerate":
        if states[:, 2].max() < 0.9 * scene.nominal[0]:
            problems.append(f"reached only {states[:, 2].max():.3f} m/s")
        if len(outputs) and np.abs(outputs - scene.nominal).max() > 1e-9:
            problems.append("a command in the open was changed")
    return problems


def decide(params: RobotParams, table, settings: safety_filter.FilterSettings, state: np.ndarray,
           nominal: tuple[float, float]) -> safety_filter.Decision:
    """The filter's decision at ``state`` on the scenes' map, as brt_node makes it (least_restrictive: the
    certificate's braking bound on the map grown by the table grid's h/√2)."""
    if settings.mode == "least_restrictive":
        grow = table.grid.half_cell_diagonal

        def inflated(points: np.ndarray) -> np.ndarray:
            return clearance(points) - grow

        cert = least_restrictive.certificate(params, inflated, table, settings.epsilon)
        return least_restrictive.decide(params, settings, cert, state, *nominal)
    values, grads = table.value_and_gradient(state)
    return safety_filter.filter_command(params, settings, state, float(values[0]), grads[0], *nominal)


def simulate(params: RobotParams, table, settings: safety_filter.FilterSettings, scene: Scene,
             seed: int = 0, dt: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """The scene offline: the base integrates the filtered command (RK4, ``dt``) with a random disturbance
    ‖d‖ ≤ δ·|v| + d₀; the filter runs every control period.  (states (k, 4), outputs (m, 2))."""
    rng = np.random.default_rng(seed)
    x = np.array([scene.start], float)
    states, outputs = [x[0].copy()], []
    twist = np.zeros((1, 2))
    every = max(1, int(round(settings.dt / dt)))
    for k in range(int(round(scene.seconds / dt))):
        if k % every == 0:
            s = x[0].copy()
            s[2] = np.clip(s[2], params.v_min, params.v_max)
            d = decide(params, table, settings, s, scene.nominal)
            twist = np.array([[d.linear, d.angular]])
            outputs.append(twist[0].copy())
        x = base_step(params, x, twist, settings.dt, dt, rng)
        states.append(x[0].copy())
    return np.array(states), np.array(outputs)


def solve_scene_table(params: RobotParams, cell: float = 0.2, speeds: int = 7, headings: int = 16,
                      horizon: float = 60.0) -> ValueTable:
    """The ground truth for the scenes' map: the solver from the target (obstacles grown by h/√2 of the grid, as
    the node does), until it settles or ``horizon`` simulated s."""
    from hjrno_ros.core.map_tiling import map_grid
    from hjrno_ros.core.model_card import ModelCard
    from hjrno_ros.truth.map_refinement import broadcast_target, refine
    from hjrno_ros.truth.systems import robot_system

    card = ModelCard.from_dict(ModelCard.solver(params, cell, speeds, headings))
    far = (ORIGIN[0] + SIZE[0] * RESOLUTION, ORIGIN[1] + SIZE[1] * RESOLUTION)
    grid = map_grid(card.grid, ORIGIN, far)
    xy = np.stack(np.meshgrid(grid.axis(0), grid.axis(1), indexing="ij"), -1)
    v0 = (clearance(xy) - grid.half_cell_diagonal).astype(np.float32)
    target = broadcast_target(v0, grid)
    *_, (_, values, _) = refine(robot_system(params), grid, target, target, horizon, horizon)
    return ValueTable(grid, values)


def run_all(params: RobotParams, scenes: tuple[Scene, ...], out: str | None = None, epsilon: float = 0.1) -> str:
    """Every scene in every filter mode against the solved table (``hjrno simulate --scenes product``): a
    markdown table (also appended to ``out``/scenes.md when given)."""
    from pathlib import Path

    table = solve_scene_table(params)
    rows = []
    for scene in scenes:
        for mode in safety_filter.MODES:
            states, outputs = simulate(params, table, safety_filter.FilterSettings(epsilon=epsilon, mode=mode), scene)
            problems = judge(scene, states, outputs)
            rows.append([scene.name, mode, "; ".join(problems) or "none", f"{clearance(states[:, :2]).min():.3f}",
                         f"{states[-1, 2]:.3f}", f"{np.abs(outputs[:, 0]).max() if len(outputs) else 0.0:.3f}"])
    lines = [f"# Product scenes ({params})", "",
             *markdown_table(["scene", "mode", "problems", "min clearance m", "final speed m/s",
                              "max output speed m/s"], rows)]
    text = "\n".join(lines) + "\n"
    if out is not None:
        Path(out).mkdir(parents=True, exist_ok=True)
        with open(Path(out) / "scenes.md", "a") as f:
            f.write(text + "\n")
    return text


ROBOTS = {"car": (CarParams.product(v_min=-0.5), SCENES),
          "diff_drive": (DiffDriveParams(v_min=-0.5), DIFF_DRIVE_SCENES)}


def main(out) -> int:
    """``hjrno simulate --scenes product``: every scene under every filter mode for a reversing product car and a
    reversing differential drive; prints scenes.md; 0 when every scene passed in the least-restrictive mode (the
    node's default) and every row was written."""
    if out is not None:
        from pathlib import Path

        (Path(out) / "scenes.md").unlink(missing_ok=True)
    failed = 0
    for params, scenes in ROBOTS.values():
        text = run_all(params, scenes, out)
        print(text)
        failed += sum(1 for line in text.splitlines() if "| least_restrictive |" in line and "| none |" not in line)
    return int(failed > 0)
