"""Ground-truth value tables against a tracked moving agent (a person), for brt_node to read with numpy.

Model.  The agent is a disk of radius r_a moving with measured velocity u (speed s = |u|) and deviating from it by
at most δ_agent m/s in any direction.  In the **agent's frame** (origin at the agent, +x along u) the robot's state
(x, y, v, θ), θ = robot heading − the agent's heading of motion, is a differential drive (DiffDriveParams: v̇ = a,
|a| ≤ a_max, θ̇ = ω, |ω| ≤ ω_max, v ∈ [v_min, v_max]) with a constant drift −s on ẋ:

    ẋ = v cos θ − s + d₁,   ẏ = v sin θ + d₂,   ‖d‖ ≤ δ_track·|v| + d₀,   d₀ = d₀_robot + δ_agent + Δs/2

(:class:`~hjrno_ros.truth.systems.AgentRelative`).  One level per tabulated speed s_k = k·Δs; the node looks up
the nearest level, and the Δs/2 in d₀ covers the difference between the measured velocity and that level's, so
the nearest level is sound for measured speeds up to s_max + Δs/2 (the card's ``agent_speed_covered_max``).

Avoid set: contact while moving.  l(x) = max(|p| − R, cap·(1 − |v|/v_tol)), R = robot radius + agent radius,
v_tol = 0.02 m/s (both terms in metres): l ≤ 0 iff the disks touch while |v| ≥ v_tol.  A robot at rest is never
in the avoid set (a person walking into a stopped robot is not the robot's doing), so braking always keeps it safe
and V∞ converges.  The rest term is ``cap``, the most the node reads: once the robot has stopped, nothing after
counts, so V of a moving state is the least gap (less the disturbance's worst) on its best way to rest or around
the agent, a distance, even where the agent could later reach the stopped robot.  (A rest term of v_tol·T made
every moving state of a robot that cannot outrun the agent read v_tol·T: 4 mm for the TurtleBot3, no distance.)
The rest node v = 0 is a one-node ridge in v, which hj's Lax-Friedrichs dissipation would lower; the solve
therefore locks the acceleration below v_tol (the robot at exactly rest stays at rest, see AgentRelative), and the
node never reads the v = 0 node (core/tracked_agents.py reads the nearest moving nodes).

V∞ per level comes from :func:`hjrno_ros.truth.solver.solve` (band criterion) and is clipped above at ``cap``
(the node uses min(V, cap)).  Files: ``<stem>.safetensors`` (tensor ``values``, levels × nx × ny × nv × nθ, float16
rounded towards −∞ unless float32 is asked for) and the card ``<stem>.json``, both written atomically; the card's
``values_sha256`` is the SHA-256 of the tensor file.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from hjrno_ros.core.atomic import atomic_write
from hjrno_ros.core.dynamics import DiffDriveParams
from hjrno_ros.core.grids import GridSpec

V_TOL = 0.02  # m/s: below this speed the robot counts as at rest (never in the avoid set)
AGENT_RADIUS = 0.2  # m: IR-SIM's pedestrians
DEFAULT_SPEEDS = "0,0.25,0.5,0.75,1,1.25,1.5"  # m/s
DEFAULT_DEVIATION = 0.3  # m/s
DEFAULT_CAP = 1.0  # m
DEFAULT_MARGIN = 0.4  # m added to the box half-width, and kept between the unsafe set and the extrapolated edge
EDGE_CELLS = 2  # x-y cells at the box edge that hj extrapolates


def stop_time(robot: DiffDriveParams) -> float:
    """T = max(|v_min|, v_max)/a_max, s: the longest stop, which turns the speed term of l into metres."""
    return max(abs(robot.v_min), robot.v_max) / robot.a_max


def default_cell(robot: DiffDriveParams) -> float:
    """m: the x-y cell for a robot: 0.2 where it brakes over 0.5 m or more from its top speed (a Jackal), else 0.1
    (a TurtleBot3 stops within 3 cm: its table needs the finer cell near contact)."""
    return 0.2 if max(abs(robot.v_min), robot.v_max) ** 2 / (2 * robot.a_max) >= 0.5 else 0.1


def level_spacing(speeds: Sequence[float]) -> float:
    """Δs of evenly spaced agent speed levels 0, Δs, 2Δs, … (0 for the single level 0), or a ValueError."""
    s = np.asarray(speeds, float)
    if s.ndim != 1 or s.size == 0 or s[0] != 0 or not np.all(np.isfinite(s)):
        raise ValueError(f"agent speeds must be finite levels starting at 0, got {list(speeds)}")
    if s.size == 1:
        return 0.0
    step = np.diff(s)
    if step[0] <= 0 or not np.allclose(step, step[0], rtol=1e-6, atol=1e-9):
        raise ValueError(f"agent speeds must be evenly spaced and increasing, got {list(speeds)}")
    return float(step[0])


def solved_deviation(deviation: float, speeds: Sequence[float]) -> float:
    """δ_agent + Δs/2, m/s: the agent's deviation the tables are solved with (the nearest level is sound)."""
    if not (math.isfinite(deviation) and deviation >= 0):
        raise ValueError(f"deviation must be finite and >= 0, got {deviation}")
    return deviation + level_spacing(speeds) / 2


def box_half_width(robot: DiffDriveParams, radius: float, speeds: Sequence[float], deviation: float, cap: float,
                   margin: float = DEFAULT_MARGIN) -> float:
    """h = R + cap + (|v|max + s_max + δ)·T + margin, m: the closing distance of a stop, plus cap and a margin."""
    closing = max(abs(robot.v_min), robot.v_max) + max(speeds) + solved_deviation(deviation, speeds)
    return radius + cap + closing * stop_time(robot) + margin


def agent_grid(robot: DiffDriveParams, half_width: float, cell: float, v_nodes: int = 11,
               theta_nodes: int = 16) -> GridSpec:
    """(x, y, v, θ) over [−h, h]² (h rounded up to whole cells: a node at x = y = 0), v over [v_min, v_max] with a
    node at v = 0 (a reversing robot's ``v_nodes`` must put one there), θ periodic over [−π, π)."""
    if not (cell > 0 and half_width > 0):
        raise ValueError(f"need cell > 0 and half_width > 0, got {cell}, {half_width}")
    if robot.v_min != 0 and not (v_nodes >= 3 and _zero_on_node(robot, v_nodes)):
        fits = [n for n in range(3, 42) if _zero_on_node(robot, n)][:4]
        raise ValueError(f"{v_nodes} speed nodes over [{robot.v_min:g}, {robot.v_max:g}] m/s have none at v = 0"
                         + (f"; --v-nodes {' or '.join(map(str, fits))} would" if fits else ""))
    half = math.ceil(half_width / cell - 1e-9)
    h = half * cell
    grid = GridSpec((-h, -h, robot.v_min, -math.pi), (h, h, robot.v_max, math.pi),
                    (2 * half + 1, 2 * half + 1, v_nodes, theta_nodes), (3,))
    if grid.spacings[2] / 2 <= V_TOL:
        raise ValueError(f"speed spacing {grid.spacings[2]:.3f} m/s: only the node v = 0 may lie below v_tol = {V_TOL}")
    return grid


def _zero_on_node(robot: DiffDriveParams, v_nodes: int) -> bool:
    """Whether ``v_nodes`` evenly spaced speeds over [v_min, v_max] put one at v = 0."""
    k = -robot.v_min * (v_nodes - 1) / (robot.v_max - robot.v_min)
    return abs(k - round(k)) < 1e-6


def agent_target(grid: GridSpec, radius: float, cap: float) -> np.ndarray:
    """l = max(|p| − R, cap·(1 − |v|/v_tol)) on ``grid``, float32: ≤ 0 iff in contact while moving."""
    x, y, v = np.meshgrid(grid.axis(0), grid.axis(1), grid.axis(2), indexing="ij")
    l3 = np.maximum(np.hypot(x, y) - radius, cap * (1.0 - np.abs(v) / V_TOL))
    return np.ascontiguousarray(np.broadcast_to(l3[..., None], grid.shape), dtype=np.float32)


def level_params(robot: DiffDriveParams, speed: float, deviation_solved: float):
    """One level's AgentRelativeParams: the robot's d₀ plus the solved deviation, drift s, rest lock below v_tol."""
    from hjrno_ros.truth.systems import AgentRelativeParams

    fields = {f.name: getattr(robot, f.name) for f in dataclasses.fields(DiffDriveParams)}
    fields["d0"] = robot.d0 + deviation_solved
    return AgentRelativeParams(**fields, agent_speed=float(speed), rest_speed=V_TOL)


def _cells_to_edge(grid: GridSpec) -> np.ndarray:
    """(nx, ny): x-y cells from each node to the nearest box edge."""
    def along(n: int) -> np.ndarray:
        i = np.arange(n)
        return np.minimum(i, n - 1 - i)
    return np.minimum(along(grid.shape[0])[:, None], along(grid.shape[1])[None, :])


def level_summary(grid: GridSpec, value: np.ndarray, cap: float) -> dict:
    """What the CLI prints and the card keeps per level, over the states that move (|v| ≥ v_tol), extrapolated
    edge cells excluded: the unsafe share; min V on the ring just inside them and its share at ``cap``; how close
    the unsafe set and the set V < cap come to the box edge, m (0: V < cap reaches the ring)."""
    cells = _cells_to_edge(grid)
    moving = np.abs(grid.axis(2)) >= V_TOL
    inner = cells >= EDGE_CELLS
    ring = value[cells == EDGE_CELLS][:, moving]
    v_moving = value[:, :, moving]
    h = grid.spacings[0]

    def gap(mask: np.ndarray) -> float:
        hit = np.any(mask, axis=(2, 3)) & inner
        return float((cells[hit].min() - EDGE_CELLS) * h) if hit.any() else math.inf

    return {"moving_unsafe_share": float(np.mean(v_moving[inner] <= 0)),
            "edge_min_moving": float(ring.min()), "edge_share_at_cap": float(np.mean(ring >= cap)),
            "unsafe_gap_to_edge_m": gap(v_moving <= 0), "below_cap_gap_to_edge_m": gap(v_moving < cap)}


def solve_agent_table(robot: DiffDriveParams, radius: float, speeds: Sequence[float], deviation: float,
                      grid: GridSpec, cap: float = DEFAULT_CAP, *, accuracy: str = "high", tolerance: float = 1e-3,
                      max_horizon: float = 80.0, chunk: float = 1.0, edge_margin: float = DEFAULT_MARGIN,
                      progress: Callable[[int, dict], None] | None = None) -> tuple[np.ndarray, dict]:
    """V∞ clipped at ``cap`` per agent speed level, float32 (levels, nx, ny, nv, nθ), and a report.

    ``radius`` is the contact radius R (robot + agent).  A level that does not converge is reported, not hidden.
    A level whose unsafe set comes within ``edge_margin`` m of the extrapolated edge cells is a ValueError (grow
    the box); V < cap reaching the edge is only reported (``cap_reached_inside`` false).
    ``progress(level_index, level_report)`` is called after each level."""
    from hjrno_ros.truth.solver import solve
    from hjrno_ros.truth.systems import AgentRelative

    if not (cap > 0 and radius > 0):
        raise ValueError(f"need cap > 0 and radius > 0, got cap={cap} radius={radius}")
    dev = solved_deviation(deviation, speeds)
    target = agent_target(grid, radius, cap)
    tables, levels = [], []
    for k, s in enumerate(speeds):
        value, rep = solve(AgentRelative(level_params(robot, s, dev)), grid, target, accuracy=accuracy, chunk=chunk,
                           max_horizon=max_horizon, tolerance=tolerance, criterion="band")
        level = {"speed": float(s), "converged": rep.converged, "horizon_s": rep.horizon, "wall_s": rep.wall_time,
                 "max_delta_band": rep.max_delta_band, **level_summary(grid, value, cap)}
        level["cap_reached_inside"] = level["below_cap_gap_to_edge_m"] > edge_margin
        if level["unsafe_gap_to_edge_m"] <= edge_margin:
            raise ValueError(f"agent speed {s} m/s: the unsafe set comes within {level['unsafe_gap_to_edge_m']:.2f} m "
                             f"of the extrapolated box edge (need > {edge_margin} m): grow the box")
        tables.append(np.minimum(value, cap))
        levels.append(level)
        if progress is not None:
            progress(k, level)
    report = {"levels": levels, "deviation_solved": dev, "v_tol": V_TOL, "stop_time_s": stop_time(robot),
              "all_converged": all(lv["converged"] for lv in levels)}
    return np.stack(tables).astype(np.float32), report


def file_sha256(path: str | Path) -> str:
    """SHA-256 of a file's bytes, hex."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def to_float16_down(values: np.ndarray) -> np.ndarray:
    """``values`` as float16 rounded towards −∞: never above the float32 value, so the stored table stays sound."""
    v = np.asarray(values, np.float32)
    h = v.astype(np.float16)
    up = h.astype(np.float32) > v
    h[up] = np.nextafter(h[up], np.float16(-np.inf))
    return h


def table_paths(stem: str | Path) -> tuple[Path, Path]:
    """``<stem>.safetensors`` and ``<stem>.json``."""
    stem = Path(stem)
    return stem.with_name(stem.name + ".safetensors"), stem.with_name(stem.name + ".json")


def write_agent_table(stem: str | Path, values: np.ndarray, card: dict) -> tuple[Path, Path]:
    """``<stem>.safetensors`` (tensor ``values``) and ``<stem>.json`` (``card`` plus ``dtype``, ``shape`` and
    ``values_sha256``), each atomically; the tensor first, so a card never names bytes that are not there yet."""
    from safetensors.numpy import save_file

    tensor, card_path = table_paths(stem)
    atomic_write(tensor, lambda tmp: save_file({"values": np.ascontiguousarray(values)}, tmp))
    card = {**card, "dtype": str(values.dtype), "shape": list(values.shape), "values_sha256": file_sha256(tensor)}
    atomic_write(card_path, lambda tmp: Path(tmp).write_text(json.dumps(card, indent=1) + "\n"))
    return tensor, card_path


def make_card(*, robot: DiffDriveParams, robot_radius: float, agent_radius: float, speeds: Sequence[float],
              deviation: float, cap: float, grid: GridSpec, report: dict, reproduce: str,
              storage_error: float = 0.0) -> dict:
    """The JSON card: what a numpy-only reader needs to rebuild the grid (GridSpec.from_dict(card["grid"])) and
    pick a level (nearest of ``agent_speeds``; beyond ``agent_speed_covered_max`` no level is sound)."""
    return {
        "kind": "agent_relative",
        "frame": "agent: origin at the agent, +x along its velocity; theta = robot heading - agent heading of motion",
        "robot": {**{k: float(v) for k, v in dataclasses.asdict(robot).items()}, "radius": robot_radius},
        "agent_radius": agent_radius,
        "radius": robot_radius + agent_radius,
        "agent_speeds": [float(s) for s in speeds],
        "agent_speed_covered_max": float(max(speeds)) + level_spacing(speeds) / 2,
        "deviation": deviation,
        "deviation_solved": report["deviation_solved"],
        "v_tol": V_TOL,
        "stop_time_s": report["stop_time_s"],
        "rest_value": V_TOL * report["stop_time_s"],
        "cap": cap,
        "axes": ["level", "x", "y", "v", "theta"],
        "grid": grid.as_dict(),
        "storage_error_max": storage_error,
        "solver": [{k: (None if v == math.inf else v) for k, v in lv.items()} for lv in report["levels"]],
        "reproduce": reproduce,
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }


def format_table(report: dict) -> str:
    """The per-level summary the CLI prints."""
    head = (f"{'level':>5} {'speed':>6} {'converged':>9} {'horizon s':>9} {'wall s':>7} {'unsafe moving':>13} "
            f"{'edge min V':>10} {'edge at cap':>11} {'V<cap gap m':>11}")
    rows = [head]
    for k, lv in enumerate(report["levels"]):
        rows.append(f"{k:>5} {lv['speed']:>6.2f} {str(lv['converged']):>9} {lv['horizon_s']:>9.1f} "
                    f"{lv['wall_s']:>7.1f} {lv['moving_unsafe_share']:>13.3f} {lv['edge_min_moving']:>10.3f} "
                    f"{lv['edge_share_at_cap']:>11.2f} {lv['below_cap_gap_to_edge_m']:>11.2f}")
    return "\n".join(rows)


def parse_speeds(text: str) -> tuple[float, ...]:
    """'0,0.25,0.5' -> (0.0, 0.25, 0.5), checked evenly spaced from 0."""
    try:
        speeds = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"--speeds must look like 0,0.25,0.5, got {text!r}") from None
    level_spacing(speeds)
    return speeds


def add_arguments(p) -> None:
    """``hjrno agents``' solver arguments (an argparse parser); the robot's own come from the caller."""
    p.add_argument("--out", default=None, help="stem of the table (default: models/agents_ROBOT for a named robot)")
    p.add_argument("--cell", type=float, default=None, help="x-y cell, m (default: 0.2 for a robot that brakes over "
                   "0.5 m or more, else 0.1)")
    p.add_argument("--speeds", default=DEFAULT_SPEEDS, help=f"agent speed levels, m/s (default {DEFAULT_SPEEDS})")
    p.add_argument("--deviation", type=float, default=DEFAULT_DEVIATION, help="agent's deviation from its measured "
                   f"velocity, m/s (default {DEFAULT_DEVIATION})")
    p.add_argument("--agent-radius", type=float, default=AGENT_RADIUS, help=f"m (default {AGENT_RADIUS})")
    p.add_argument("--cap", type=float, default=DEFAULT_CAP, help=f"values clipped above it, m (default {DEFAULT_CAP})")
    p.add_argument("--margin", type=float, default=DEFAULT_MARGIN, help=f"box margin, m (default {DEFAULT_MARGIN})")
    p.add_argument("--v-nodes", type=int, default=11, help="speed nodes, odd (default 11)")
    p.add_argument("--theta-nodes", type=int, default=16, help="heading nodes (default 16)")
    p.add_argument("--dtype", default="float16", choices=["float16", "float32"], help="storage (default float16, "
                   "rounded towards -inf)")


def reproduce_command(args, robot: str, out: str, cell: float) -> str:
    """The exact ``hjrno agents`` command line that rebuilds this table (``robot``: its options)."""
    return (f"hjrno agents {robot} --out {out} --cell {cell:g} --speeds {args.speeds} --deviation "
            f"{args.deviation:g} --agent-radius {args.agent_radius:g} --cap {args.cap:g} --margin {args.margin:g} "
            f"--v-nodes {args.v_nodes} --theta-nodes {args.theta_nodes} --dtype {args.dtype}")


def main(args, robot: DiffDriveParams, robot_radius: float, name: str, options: str) -> int:
    """``hjrno agents``: solve, write and summarise the tables of ``robot`` (footprint radius ``robot_radius`` m;
    ``name`` in messages, ``options`` its command-line options in the card's command); exit 3 if a level did not
    converge."""
    speeds = parse_speeds(args.speeds)
    cell = args.cell if args.cell is not None else default_cell(robot)
    radius = robot_radius + args.agent_radius
    h = box_half_width(robot, radius, speeds, args.deviation, args.cap, args.margin)
    grid = agent_grid(robot, h, cell, args.v_nodes, args.theta_nodes)
    out = args.out
    print(f"agents {name}: R = {radius:.3f} m, T = {stop_time(robot):.2f} s, box ±{grid.hi[0]:.2f} m, grid "
          f"{'x'.join(map(str, grid.shape))} x {len(speeds)} levels, deviation solved "
          f"{solved_deviation(args.deviation, speeds):.3f} m/s", flush=True)

    def progress(k: int, lv: dict) -> None:
        print(f"  level {k} (s = {lv['speed']:.2f} m/s): converged {lv['converged']} at {lv['horizon_s']:.0f} s, "
              f"{lv['wall_s']:.0f} s wall", flush=True)

    start = time.perf_counter()
    values, report = solve_agent_table(robot, radius, speeds, args.deviation, grid, args.cap,
                                       edge_margin=args.margin, progress=progress)
    stored = to_float16_down(values) if args.dtype == "float16" else values
    error = float(np.max(values - stored.astype(np.float32)))
    card = make_card(robot=robot, robot_radius=robot_radius, agent_radius=args.agent_radius, speeds=speeds,
                     deviation=args.deviation, cap=args.cap, grid=grid, report=report,
                     reproduce=reproduce_command(args, options, out, cell), storage_error=error)
    tensor, card_path = write_agent_table(out, stored, card)
    print(format_table(report))
    short = [f"{lv['speed']:g}" for lv in report["levels"] if not lv["cap_reached_inside"]]
    if short:
        print(f"note: V < cap reaches within {args.margin} m of the box edge at agent speeds {', '.join(short)} m/s")
    print(f"wrote {tensor} ({tensor.stat().st_size / 1e6:.2f} MB, {stored.dtype}, storage error <= {error:.1e} m) "
          f"and {card_path}; {time.perf_counter() - start:.0f} s")
    return 0 if report["all_converged"] else 3
