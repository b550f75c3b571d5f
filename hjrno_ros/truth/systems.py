"""The ground robots (car, differential drive) and Air3D as ``hj_reachability`` dynamics: the shared formulas of
:mod:`hjrno_ros.core.dynamics` evaluated with ``jax.numpy``, and the grid conversion."""

from __future__ import annotations

import dataclasses
import math

import hj_reachability as hj
import jax.numpy as jnp
import numpy as np

from hjrno_ros.core.dynamics import (
    Air3DParams,
    CarParams,
    DiffDriveParams,
    RobotParams,
    _concrete,
    air3d_f,
    air3d_optimal_control,
    air3d_worst_disturbance,
    disturbance_bound,
    optimal_control,
    robot_f,
    turn_gain,
    worst_direction,
)
from hjrno_ros.core.grids import GridSpec


def hj_grid(grid: GridSpec) -> hj.Grid:
    """``grid`` as an ``hj_reachability`` grid (periodic axes exclude their end point)."""
    return hj.Grid.from_lattice_parameters_and_boundary_conditions(
        hj.sets.Box(np.array(grid.lo), np.array(grid.hi)), grid.shape, periodic_dims=grid.periodic
    )


# ---------------------------------------------------------------------------------------------
# hj_reachability wrappers.  Instances compare equal when their parameters do, so the solver's
# jit cache (dynamics is a static argument) is shared between equal parameter sets.


class _SharedFormulas(hj.ControlAndDisturbanceAffineDynamics):
    """hj dynamics whose f, optimal control and disturbance are the shared formulas of core.dynamics
    (a subclass names them as ``_f``, ``_control``, ``_disturbance`` or overrides the two methods)."""

    def __init__(self, params, control_space, disturbance_space):
        self.params = params
        super().__init__("max", "min", control_space, disturbance_space)

    def __call__(self, state, control, disturbance, time):
        return type(self)._f(self.params, state, control, disturbance, jnp)

    def optimal_control_and_disturbance(self, state, time, grad_value):
        p = self.params
        return type(self)._control(p, state, grad_value, jnp), type(self)._disturbance(p, state, grad_value, jnp)

    def __hash__(self) -> int:
        return hash((type(self), self.params)) if _concrete(dataclasses.astuple(self.params)) else id(self)

    def __eq__(self, other) -> bool:
        if not _concrete(dataclasses.astuple(self.params)):
            return self is other
        return type(self) is type(other) and self.params == other.params


class DynamicDubinsCar(_SharedFormulas):
    """A ground robot (the dynamic Dubins car, or with :class:`DiffDrive` the differential drive) as
    ``hj_reachability`` dynamics; control maximises, disturbance minimises.

    The disturbance bound δ·|v| + d₀ depends on the state, an hj disturbance space cannot: the
    disturbance variable here is e in the unit ball and the position disturbance is
    d = (δ·|v| + d₀)·e, so the disturbance Jacobian carries the bound.  Then hj's Lax-Friedrichs
    dissipation sees the right magnitude, and the Hamiltonian's disturbance term is
    −(δ·|v| + d₀)·‖∇ₓᵧV‖, the same worst case as :func:`~hjrno_ros.core.dynamics.worst_disturbance`.
    """

    state_names = ("x", "y", "v", "theta")

    def __init__(self, params: RobotParams = CarParams()):
        p = params
        super().__init__(
            p,
            hj.sets.Box(jnp.array([-p.a_max, -p.turn_max]), jnp.array([p.a_max, p.turn_max])),
            hj.sets.Ball(jnp.zeros(2), 1.0),
        )

    def __call__(self, state, control, disturbance, time):
        bound = disturbance_bound(self.params, state[..., 2], jnp)[..., None]
        return robot_f(self.params, state, control, bound * disturbance, jnp)

    def optimal_control_and_disturbance(self, state, time, grad_value):
        return optimal_control(self.params, state, grad_value, jnp), worst_direction(grad_value, jnp)

    def open_loop_dynamics(self, state, time):
        v, theta = state[2], state[3]
        return jnp.array([v * jnp.cos(theta), v * jnp.sin(theta), 0.0, 0.0])

    def control_jacobian(self, state, time):
        return jnp.array([[0.0, 0.0], [0.0, 0.0], [1.0, 0.0], [0.0, turn_gain(self.params, state[2], jnp)]])

    def disturbance_jacobian(self, state, time):
        b = disturbance_bound(self.params, state[2], jnp)
        return jnp.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0], [0.0, 0.0]]) * b


class DiffDrive(DynamicDubinsCar):
    """The differential drive: the same equations with θ̇ = u₂, |u₂| ≤ ω_max (it turns in place)."""

    def __init__(self, params: DiffDriveParams = DiffDriveParams()):
        super().__init__(params)


@dataclasses.dataclass(frozen=True)
class AgentRelativeParams(DiffDriveParams):
    """A differential drive seen from an agent that moves at ``agent_speed`` along +x of its own frame: the
    DiffDriveParams fields (d₀ carries the agent's deviation from that velocity) plus s and the rest lock.
    Positional construction ``AgentRelativeParams(*values)`` in field order is what the solver's traced rebuild
    uses, so every field is a float."""

    agent_speed: float = 0.0  # s, m/s: the agent's speed (the constant drift −s on ẋ)
    rest_speed: float = 0.0  # m/s: below this |v| the robot holds its speed (v̇ = 0); 0: never

    def __post_init__(self) -> None:
        super().__post_init__()
        s, r = self.agent_speed, self.rest_speed
        if _concrete((s, r)) and not (math.isfinite(s) and s >= 0 and math.isfinite(r) and r >= 0):
            raise ValueError(f"agent_speed and rest_speed must be finite and >= 0, got {s}, {r}")


class AgentRelative(DiffDrive):
    """The differential drive in the frame of an agent moving at s along +x: ẋ = v cos θ − s + d₁,
    ẏ = v sin θ + d₂ (‖d‖ ≤ δ·|v| + d₀), v̇ = u₁, θ̇ = u₂.  The drift enters both f and the open-loop part
    (hj's Lax-Friedrichs dissipation reads the latter); hash and equality include s through the params.

    Rest lock: below ``rest_speed`` the robot has no acceleration (v̇ = 0, so no v-dissipation either).  A target
    whose rest term is a one-node ridge in v (safe at rest, unsafe moving) is smoothed away at that node by hj's
    Lax-Friedrichs dissipation, which makes rest states near the agent unsafe; the lock keeps
    the rest node at the exact value of staying at rest.  It only takes a control away from the maximising
    robot, so the table stays conservative (it forgoes starting from exactly v = 0 to flee)."""

    def __init__(self, params: AgentRelativeParams = AgentRelativeParams()):
        super().__init__(params)

    def _drift(self):
        return jnp.array([1.0, 0.0, 0.0, 0.0]) * self.params.agent_speed

    def _moving(self, v):
        """1 where the robot may accelerate, 0 at rest (|v| < rest_speed)."""
        return jnp.where(jnp.abs(v) < self.params.rest_speed, 0.0, 1.0)

    def __call__(self, state, control, disturbance, time):
        gain = self._moving(state[..., 2])
        control = control * jnp.stack([gain, jnp.ones_like(gain)], axis=-1)
        return super().__call__(state, control, disturbance, time) - self._drift()

    def open_loop_dynamics(self, state, time):
        return super().open_loop_dynamics(state, time) - self._drift()

    def control_jacobian(self, state, time):
        return super().control_jacobian(state, time).at[2, 0].multiply(self._moving(state[2]))


def robot_system(params: RobotParams) -> DynamicDubinsCar:
    """The ``hj_reachability`` dynamics of a ground robot's parameters."""
    return DiffDrive(params) if isinstance(params, DiffDriveParams) else DynamicDubinsCar(params)


class Air3D(_SharedFormulas):
    """Air3D as ``hj_reachability`` dynamics; the evader (control) maximises, the pursuer minimises."""

    state_names = ("x", "y", "psi")
    _f = staticmethod(air3d_f)
    _control = staticmethod(air3d_optimal_control)
    _disturbance = staticmethod(air3d_worst_disturbance)

    def __init__(self, params: Air3DParams = Air3DParams()):
        p = params
        super().__init__(
            p,
            hj.sets.Box(jnp.array([-p.evader_max_turn_rate]), jnp.array([p.evader_max_turn_rate])),
            hj.sets.Box(jnp.array([-p.pursuer_max_turn_rate]), jnp.array([p.pursuer_max_turn_rate])),
        )

    def open_loop_dynamics(self, state, time):
        p = self.params
        vp = p.pursuer_speed
        return jnp.array([-p.evader_speed + vp * jnp.cos(state[2]), vp * jnp.sin(state[2]), 0.0])

    def control_jacobian(self, state, time):
        return jnp.array([[state[1]], [-state[0]], [-1.0]])

    def disturbance_jacobian(self, state, time):
        return jnp.array([[0.0], [0.0], [1.0]])
