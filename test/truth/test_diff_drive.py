"""The differential-drive model (docs/design.md, "Robot models") validated by checks that can fail: exact similarity
against direct solves, a round robot at rest is safe at every heading, slower is never less safe, safe starts never
collide under the optimal control (forwards, reversing and turning in place), indoor scenes converge."""

import dataclasses

import numpy as np
import pytest
from conftest import assert_slower_never_less_safe, safe_starts

from hjrno_ros.core.dynamics import DIFF_DRIVE_MODEL, DiffDriveParams, optimal_control, robot_f, turn_gain
from hjrno_ros.core.geometry import Disk
from hjrno_ros.core.grids import car_grid
from hjrno_ros.core.similarity import Coverage, Dimensionless, Scaling, robot_to_robot
from hjrno_ros.core.value_table import ReversingTable, ValueTable
from hjrno_ros.studies import simulation
from hjrno_ros.truth import problems
from hjrno_ros.truth.scenarios import make_scenario
from hjrno_ros.truth.solver import interior_mask, solve
from hjrno_ros.truth.systems import DiffDrive, robot_system

COARSE = (32, 32, 9, 16)
REVERSING = DiffDriveParams(v_min=-0.6)  # 9 speed nodes -0.6, -0.4, ..., 1.0: v = 0 is a node


def _solved(name: str, params: DiffDriveParams, shape=COARSE, inflate: bool = False):
    problem = problems.make_problem(name, shape, params)
    target = problem.target - (problem.grid.half_cell_diagonal if inflate else 0.0)
    value, report = solve(problem.dynamics, problem.grid, target, **problem.solve_options)
    return problem, target, value, report


@pytest.fixture(scope="module", params=["disk", "indoor"])
def forward(request):
    return _solved(request.param, DiffDriveParams())


@pytest.fixture(scope="module")
def reversing_indoor():
    return _solved("indoor", REVERSING, inflate=True)


def test_formulas_turn_at_rest_and_name_the_model():
    p = DiffDriveParams(omega_max=2.0)
    state = np.array([[0.0, 0.0, 0.0, 0.3], [0.0, 0.0, -0.5, 0.3]])
    f = robot_f(p, state, np.array([[0.0, 2.0], [0.0, -2.0]]), np.zeros((2, 2)))
    assert f[0, 3] == 2.0 and f[1, 3] == -2.0  # θ̇ = ω, at rest too; a car's θ̇ = v·κ would be 0 at rest
    assert np.all(turn_gain(p, state[:, 2]) == 1.0)
    u = optimal_control(p, state, np.array([[0, 0, -1.0, 0.5], [0, 0, -1.0, 0.5]]))
    assert np.all(u[:, 1] == 2.0)  # the turn's sign does not flip when reversing (unlike the car's curvature)
    assert p.as_dict()["model"] == DIFF_DRIVE_MODEL and DiffDriveParams.from_dict(p.as_dict()) == p
    assert isinstance(robot_system(p), DiffDrive)
    with pytest.raises(ValueError, match="omega_max"):
        DiffDriveParams(omega_max=0.0)


def test_similarity_maps_one_robot_onto_another():
    """Length v_max/ω_max, time 1/ω_max: the reference robot (ω = v_max = 1, a = 0.5) on a 10 m window with a 1 m disk
    against ω = 4 rad/s, v_max = 0.5 m/s, a = 1 m/s² (the same a/(v·ω) = 0.5, s = 0.125 m, τ = 0.25 s) on a
    1.25 m window with a 0.125 m disk, both solved directly: V_B/s equals V_A to grid accuracy.  Twice the braking on
    the same sizes moves V visibly: the check can fail."""
    a = DiffDriveParams(a_max=0.5)
    b = DiffDriveParams(a_max=1.0, omega_max=4.0, v_max=0.5)
    assert Dimensionless.of(a).close_to(Dimensionless.of(b))
    scale = robot_to_robot(a, b)
    assert scale.length == pytest.approx(0.125) and scale.time == pytest.approx(0.25)
    assert Scaling.of(b).params_to_model(b) == DiffDriveParams(a_max=0.5)

    def solve_for(robot: DiffDriveParams, s: Scaling) -> np.ndarray:
        grid = s.grid_to_robot(car_grid((24, 24, 7, 12), v_range=(0.0, 1.0)))
        target = Disk((0.0, 0.0), s.length).sdf(grid.states()[..., :2])
        value, report = solve(DiffDrive(robot), grid, target, chunk=s.duration_to_robot(1.0),
                              tolerance=s.rate_to_robot(1e-3), max_horizon=s.duration_to_robot(20.0))
        assert report.converged, report.summary()
        return value / s.length

    va, vb = solve_for(a, Scaling(1.0, 1.0)), solve_for(b, scale)
    assert np.abs(va - vb).max() < 1e-3 and np.array_equal(va <= 0, vb <= 0)
    stronger = solve_for(DiffDriveParams(a_max=1.0), Scaling(1.0, 1.0))
    assert np.abs(stronger - va).max() > 0.05


def test_coverage_is_per_model():
    card = DiffDriveParams()
    coverage = Coverage.of(card, {"log_a_max": [np.log(0.4), np.log(4.5)]})
    turtlebot = DiffDriveParams(a_max=1.0, omega_max=2.84, v_max=0.22, v_min=-0.22)
    assert coverage.covers(Dimensionless.of(turtlebot))
    from hjrno_ros.core.dynamics import CarParams

    car = CarParams.product(kappa_max=2.84 / 0.22, v_max=0.22, a_max=1.0)
    assert not coverage.covers(Dimensionless.of(car))  # same numbers, other equations
    assert "diff_drive" in coverage.describe()


def test_forward_solves_converge_fast(forward):
    assert forward[3].converged and forward[3].horizon <= 6.0, forward[3].summary()


def test_round_robot_at_rest_is_safe_at_every_heading(forward, reversing_indoor):
    """V(x, y, 0, θ) = l for every θ outside obstacles: a round footprint turns in place safely.  Forwards v = 0 is
    the speed axis' edge (stated 1e-3 m); reversing, a ridge inside the axis the scheme rounds off conservatively
    (below l, stated 0.1 m)."""
    for (problem, target, value, _), tol in ((forward, 1e-3), (reversing_indoor, 0.1)):
        rest = int(np.argmin(np.abs(problem.grid.axis(2))))
        outside = (target[:, :, rest] > 0) & interior_mask(problem.grid, (0, 1))[:, :, rest]
        error = (target[:, :, rest] - value[:, :, rest])[outside]
        assert np.all(error >= -1e-5) and error.max() < tol, error.max()
        spread = np.ptp(value[:, :, rest], axis=-1)[outside[..., 0]]
        assert spread.max() < tol  # the same at every heading


def test_slower_is_never_less_safe(forward, reversing_indoor):
    assert_slower_never_less_safe(forward, reversing_indoor)


@pytest.mark.parametrize("disturbance", ["worst", "random"])
def test_safe_starts_never_collide(reversing_indoor, disturbance):
    """600 starts with V > 0.02 in the indoor scene, a third reversing and a sixth at rest (where the optimal control
    may turn in place), 10 s under the optimal control and the worst or a random disturbance: no contact."""
    problem, _, value, report = reversing_indoor
    assert report.converged
    params, table = problem.dynamics.params, ValueTable(problem.grid, value)
    rng = np.random.default_rng(23)
    safe = safe_starts(table, params.v_min, rng, at_rest=1 / 6)
    assert len(safe) == 600 and np.sum(safe[:, 2] < 0) >= 150 and np.sum(safe[:, 2] == 0) >= 60
    control, worst = simulation.optimal_feedback(params, table)
    noise = worst if disturbance == "worst" else simulation.random_disturbance(params, rng)
    out = simulation.simulate(simulation.robot_dynamics(params), control, noise, problem.clearance, safe, 10.0,
                              dt=0.02, wrap=simulation.wrap_car)
    assert not out.collided.any(), f"{out.collided.sum()} of {len(safe)} safe starts collided"


def test_forward_table_serves_a_reversing_robot(reversing_indoor):
    """A forward-only solve answers reversing states by symmetry, V(x, y, −v, θ) = V(x, y, v, θ + π), within the
    grid's error at the speed axis (d₀ = 0: V for v ≥ 0 does not depend on v_min)."""
    problem, target, value, _ = reversing_indoor
    grid = problem.grid
    rest = int(np.argmin(np.abs(grid.axis(2))))
    fwd_grid = car_grid(COARSE[:2] + (COARSE[2] - rest, COARSE[3]), v_range=(0.0, 1.0))
    fwd, _ = solve(DiffDrive(dataclasses.replace(REVERSING, v_min=0.0)), fwd_grid,
                   np.ascontiguousarray(target[:, :, rest:]), **problem.solve_options)
    mirrored = ReversingTable(ValueTable(fwd_grid, fwd))
    rng = np.random.default_rng(5)
    s = np.column_stack([rng.uniform(-4, 4, 2000), rng.uniform(-4, 4, 2000), rng.uniform(-0.6, -0.1, 2000),
                         rng.uniform(-np.pi, np.pi, 2000)])
    diff = mirrored.value(s) - ValueTable(grid, value).value(s)
    assert np.mean(np.abs(diff)) < 0.02 and np.abs(diff).max() < 0.3


def test_indoor_scenes_converge():
    """Rooms of the indoor family converge at the default grid (the paper's car mostly does not within 60 s)."""
    for seed in range(3):
        scenario = make_scenario("indoor", seed, robot="diff_drive")
        grid = scenario.grid(COARSE)
        _, report = solve(scenario.dynamics(), grid, scenario.target(grid), tolerance=3e-3, max_horizon=20.0,
                          criterion="band")
        assert report.converged and report.horizon <= 8.0, report.summary()
