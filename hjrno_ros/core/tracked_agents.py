"""Tracked agents (people, carts) and the robot's relative value against each (numpy only).

A tracked agent is a disk with a measured position and velocity in the map frame.  Against one agent the robot's
safety is a relative problem (docs/design.md, "Tracked agents"): in the agent's frame (origin at the agent, +x along
its velocity) the robot's state (x, y, v, θ) moves with the robot's own dynamics plus the agent's drift −s along x,
the agent deviating from its velocity by at most δ.  The avoid set is *contact while moving*; a robot at rest is
outside it.  The table of that value function, solved per robot over agent speed levels by
:mod:`hjrno_ros.truth.agent_tables` and read here, gives W_agent; the filter's certificate is the minimum of the
static certificate and every agent's (:func:`with_agents`).

Agents move during the filter's look-ahead: the certificate of the state reached after t seconds is judged against
the agents predicted t seconds on (:meth:`AgentCertificate.at`, read by the filter through
:func:`~hjrno_ros.core.least_restrictive.at_time`); the agents' data is predicted to the robot state's time and δ·|age|
added to its radius (W falls by at most that: it is 1-Lipschitz in the relative position).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from pathlib import Path

import numpy as np

from hjrno_ros.core.dynamics import DiffDriveParams
from hjrno_ros.core.grids import GridSpec
from hjrno_ros.core.least_restrictive import Certificate
from hjrno_ros.core.value_table import multilinear


@dataclasses.dataclass(frozen=True)
class Agents:
    """Tracked agents in the map frame: positions and velocities ``(k, 2)`` (m, m/s), radii ``(k,)`` (m), as of
    ``received`` (monotonic s)."""

    positions: np.ndarray
    velocities: np.ndarray
    radii: np.ndarray
    received: float = 0.0

    def __post_init__(self) -> None:
        k = len(self.positions)
        if self.positions.shape != (k, 2) or self.velocities.shape != (k, 2) or self.radii.shape != (k,):
            raise ValueError(f"agents need positions (k, 2), velocities (k, 2), radii (k,), got "
                             f"{self.positions.shape}, {self.velocities.shape}, {self.radii.shape}")

    def __len__(self) -> int:
        return len(self.positions)

    def predicted(self, seconds: float) -> np.ndarray:
        """Positions ``seconds`` on at the measured velocities."""
        return self.positions + self.velocities * seconds


def relative_states(states: np.ndarray, positions: np.ndarray, velocities: np.ndarray) -> np.ndarray:
    """Robot states ``(..., 4)`` (x, y, v, θ in the map frame) in each of k agents' frames, ``(k, ..., 4)``: origin at
    the agent's position ``(k, 2)``, +x along its velocity ``(k, 2)`` (along the map's x for an agent at rest)."""
    positions, velocities = np.asarray(positions, float), np.asarray(velocities, float)
    shape = (-1,) + (1,) * (np.ndim(states) - 1)
    heading = np.arctan2(velocities[:, 1], velocities[:, 0]).reshape(shape)  # atan2(0, 0) = 0: the map's x
    c, s = np.cos(heading), np.sin(heading)
    dx = states[..., 0] - positions[:, 0].reshape(shape)
    dy = states[..., 1] - positions[:, 1].reshape(shape)
    theta = (states[..., 3] - heading + np.pi) % (2 * np.pi) - np.pi
    v = np.broadcast_to(states[..., 2], dx.shape)
    return np.stack([c * dx + s * dy, -s * dx + c * dy, v, theta], -1)


@dataclasses.dataclass(frozen=True)
class AgentTable:
    """The relative value tables of one robot over agent speed levels (m/s, evenly spaced from 0), solved for
    contact at ``radius`` (m: the robot's and an agent's radius together), values capped at ``cap`` (m)."""

    grid: GridSpec  # (x, y, v, θ) in the agent's frame, θ periodic
    speeds: tuple[float, ...]
    values: np.ndarray  # (levels, *grid.shape), m
    radius: float
    cap: float
    deviation: float  # m/s: how far an agent may deviate from its measured velocity (as solved)
    rest: tuple[float, float]  # (v_tol m/s, the least W at |v| <= v_tol, m): at rest the robot is never to blame
    robot: dict

    @property
    def margin(self) -> float:
        """Taken off the interpolated value: half an x-y cell's diagonal (V is 1-Lipschitz in position)."""
        return self.grid.half_cell_diagonal

    def levels(self, speeds: np.ndarray) -> np.ndarray:
        """The tabulated speed nearest each of ``speeds`` (the tables were solved with half the spacing added to δ);
        −1 beyond the last level by more than half a spacing."""
        step = self.speeds[1] - self.speeds[0] if len(self.speeds) > 1 else math.inf
        k = np.rint(np.asarray(speeds, float) / step).astype(int) if math.isfinite(step) else np.zeros(
            np.shape(speeds), int)
        return np.where(k < len(self.speeds), k, -1)

    def value(self, relative: np.ndarray, speeds: np.ndarray, radii: np.ndarray) -> np.ndarray:
        """W at relative states ``(k, ..., 4)`` against k agents of ``speeds`` ``(k,)``, contact at ``radii``
        ``(k,)`` (robot's and agent's): the table less its interpolation margin and the radius beyond the solved
        one (V shifts by at most that), at most ``cap``; −inf against an agent faster than the tables (nothing
        vouches for the robot).  Beyond the table's box its edge values hold (V grows with distance).  The rest
        node is never read: a moving state reads the moving nodes (speeds below the first node take its value, V
        falling with speed), and at rest W is the larger of the first nodes either way and the rest value, so that
        neither stopping nor the first step of a start jumps."""
        level = self.levels(speeds)
        shape = (-1,) + (1,) * (relative.ndim - 2)
        v, step = relative[..., 2], self.grid.spacings[2]
        v_tol, at_rest = self.rest
        rest = np.abs(v) <= v_tol
        reverse = self.grid.lo[2] < 0
        first = np.where(v > v_tol, np.maximum(v, step), np.where(v < -v_tol, np.minimum(v, -step), step))
        lvl = np.broadcast_to(np.maximum(level, 0).reshape(shape), v.shape)
        w = self._lookup(lvl, relative, first)
        if reverse and rest.any():  # at rest: also the first node backwards
            back = self._lookup(lvl[rest], relative[rest], np.full(int(rest.sum()), -step))
            w[rest] = np.maximum(w[rest], back)
        w = np.where(rest, np.maximum(w, at_rest), w)
        w = np.minimum(w - np.maximum(np.asarray(radii, float) - self.radius, 0.0).reshape(shape), self.cap)
        return np.where((level >= 0).reshape(shape), w, -np.inf)

    def _lookup(self, level: np.ndarray, relative: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Multilinear interpolation of the levels' tables at (x, y, ``v``, θ) of ``relative``, positions and speeds
        clamped to the box, θ wrapped; less the margin."""
        coords = (relative[..., 0], relative[..., 1], v, relative[..., 3])
        return multilinear(self.values, self.grid, coords, (level,)) - self.margin


def robot_options(robot: DiffDriveParams, radius: float) -> str:
    """The ``hjrno agents`` options that solve the tables for a robot of these limits and footprint
    radius ``radius`` m (RADIUS where it is not positive: the node's footprint_radius was left at 0)."""
    size = f"{radius:g}" if radius > 0 else "RADIUS"
    return (f"--v-min {robot.v_min:g} --v-max {robot.v_max:g} --a-max {robot.a_max:g} --omega-max "
            f"{robot.omega_max:g} --tracking-error {robot.tracking_error:g} --radius {size}")


def read_agent_table(stem: str | Path) -> AgentTable:
    """``<stem>.json`` and ``<stem>.safetensors`` (:mod:`hjrno_ros.truth.agent_tables`), checked against each other:
    a ValueError with one line when either is missing, corrupt or contradicts the other."""
    from safetensors import SafetensorError
    from safetensors.numpy import load_file

    stem = Path(stem)
    card_path, data_path = stem.with_name(stem.name + ".json"), stem.with_name(stem.name + ".safetensors")
    try:
        card = json.loads(card_path.read_text())
        raw = data_path.read_bytes()
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ValueError(f"agent table {stem}: {err}") from None
    if not isinstance(card, dict) or card.get("kind") != "agent_relative":
        raise ValueError(f"agent table {card_path}: not an agent_relative card")
    if hashlib.sha256(raw).hexdigest() != card.get("values_sha256"):
        raise ValueError(f"agent table {data_path}: SHA-256 differs from its card (another or a damaged file)")
    try:
        values = load_file(str(data_path))["values"].astype(np.float32)
        g = card["grid"]
        grid = GridSpec(g["lo"], g["hi"], g["shape"], g.get("periodic", (3,)))
        speeds = tuple(float(s) for s in card["agent_speeds"])
        cap, radius, deviation = float(card["cap"]), float(card["radius"]), float(card["deviation"])
        robot = dict(card["robot"])
        rest = (float(card["v_tol"]), float(card["rest_value"]))
    except (SafetensorError, KeyError, TypeError, ValueError) as err:
        raise ValueError(f"agent table {stem}: {type(err).__name__}: {err}") from None
    if values.shape != (len(speeds), *grid.shape) or not np.all(np.isfinite(values)):
        raise ValueError(f"agent table {stem}: values {values.shape} (finite: {np.isfinite(values).all()}) do not "
                         f"match {len(speeds)} speeds on grid {grid.shape}")
    if speeds[0] != 0 or (len(speeds) > 1 and not np.allclose(np.diff(speeds), speeds[1] - speeds[0])):
        raise ValueError(f"agent table {stem}: speeds must be evenly spaced from 0, got {speeds}")
    return AgentTable(grid, speeds, values, radius, cap, deviation, rest, robot)


class AgentCertificate:
    """W = min(the static certificate, every agent's W) at states reached ``elapsed`` s after now."""

    def __init__(self, static: Certificate, table: AgentTable, agents: Agents, footprint: float, age: float,
                 elapsed: float = 0.0):
        self.static, self.table, self.agents, self.footprint = static, table, agents, footprint
        self.age, self.elapsed = age, elapsed
        shift = getattr(static, "at", None)  # untracked returns that may approach make it time-varying too
        self.static_then = shift(elapsed) if shift is not None else static

    @property
    def floor(self) -> Certificate:
        """What the agents do not lower: the static certificate, which the filter holds to its rule while W is at
        or below 0 (core/least_restrictive.py)."""
        return self.static_then

    def at(self, seconds: float) -> AgentCertificate:
        """This certificate for states ``seconds`` after now (the agents moved on meanwhile)."""
        return AgentCertificate(self.static, self.table, self.agents, self.footprint, self.age, seconds)

    def agents_value(self, states: np.ndarray) -> np.ndarray:
        """The least W over the agents at ``states`` ``(..., 4)``."""
        states = np.asarray(states, float)
        a, t = self.agents, self.age + self.elapsed
        reach = self.table.deviation * abs(self.age)  # how far an agent may be off its prediction from old data
        rel = relative_states(states, a.predicted(t), a.velocities)
        w = self.table.value(rel, np.hypot(*a.velocities.T), a.radii + self.footprint + reach)
        return w.min(0)

    def __call__(self, states: np.ndarray) -> np.ndarray:
        return np.minimum(self.static_then(states), self.agents_value(states))


def with_agents(static: Certificate, table: AgentTable | None, agents: Agents | None, footprint: float,
                at: float) -> Certificate:
    """The static certificate, with the agents' W where a table and agents are given (the robot's radius
    ``footprint``, m); "now" is the monotonic time ``at`` (the robot state's), to which the agents are predicted."""
    if table is None or agents is None or len(agents) == 0:
        return static
    return AgentCertificate(static, table, agents, footprint, at - agents.received)
