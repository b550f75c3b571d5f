"""Exact similarity (docs/design.md, "Similarity"): the maps both ways, and two robots of different
sizes with equal dimensionless numbers, solved directly, agree after scaling."""

import math

import numpy as np
import pytest

from hjrno_ros.core.dynamics import CarParams
from hjrno_ros.core.geometry import Disk
from hjrno_ros.core.grids import car_grid
from hjrno_ros.core.similarity import Dimensionless, Scaling, robot_to_robot
from hjrno_ros.core.value_table import ValueTable
from hjrno_ros.truth.solver import solve
from hjrno_ros.truth.systems import DynamicDubinsCar

RNG = np.random.default_rng(3)
SMALL = CarParams.product(kappa_max=4.0, v_max=0.5)  # a = 1 m/s²: a/(κ v²) = 1, the reference robot's ratio
TURTLEBOT = CarParams.product(a_max=2.5, kappa_max=2.84 / 0.22, v_max=0.22)  # ω 2.84 rad/s at v 0.22 m/s


def test_model_units_of_a_robot():
    scale = Scaling.of(SMALL)
    assert (scale.length, scale.time, scale.speed) == (0.25, 0.5, 0.5)
    model = scale.params_to_model(SMALL)
    assert model.kappa_max == pytest.approx(1.0) and model.v_max == pytest.approx(1.0)
    assert model.a_max == pytest.approx(1.0) and model.tracking_error == 0.1 and model.d0 == 0.0
    assert Dimensionless.of(SMALL).close_to(Dimensionless.of(CarParams.product()))
    back = scale.params_to_robot(model)
    for name in ("a_max", "kappa_max", "d0", "v_min", "v_max", "tracking_error"):
        assert getattr(back, name) == pytest.approx(getattr(SMALL, name))
    tb = Scaling.of(TURTLEBOT)
    assert tb.length == pytest.approx(0.0775, abs=1e-4)  # a 10-unit model window is 0.77 m
    assert Dimensionless.of(TURTLEBOT).accel_ratio == pytest.approx(2.5 / (12.91 * 0.22 ** 2), rel=1e-3)
    lo, hi = tb.window_to_robot((-5.0, -5.0), (5.0, 5.0))
    assert hi[0] - lo[0] == pytest.approx(0.775, abs=1e-3)
    np.testing.assert_allclose(tb.window_to_model(lo, hi), ((-5.0, -5.0), (5.0, 5.0)))


def test_dimensionless_numbers_of_the_paper_and_a_reversing_robot():
    paper = Dimensionless.of(CarParams.paper(d0=0.05, v_max=0.5, kappa_max=4.0))
    assert (paper.accel_ratio, paper.speed_ratio, paper.tracking_error, paper.rest_disturbance) == (1.0, 0.0, 0.0, 0.1)
    reversing = Dimensionless.of(CarParams.product(v_min=-0.25, v_max=0.5, kappa_max=2.0, a_max=0.5))
    assert reversing.speed_ratio == -0.5 and reversing.accel_ratio == 1.0
    assert reversing.model_params() == CarParams.product(v_min=-0.5)


def test_states_grids_values_and_gradients_map_both_ways():
    scale = Scaling(0.25, 0.5)
    states = np.column_stack([RNG.uniform(-5, 5, 50), RNG.uniform(-5, 5, 50), RNG.uniform(-1, 1, 50),
                              RNG.uniform(-3, 3, 50)])
    np.testing.assert_allclose(scale.states_to_model(scale.states_to_robot(states)), states)
    grid = car_grid((9, 9, 5, 8))
    robot_grid = scale.grid_to_robot(grid)
    assert robot_grid.shape == grid.shape and robot_grid.periodic == grid.periodic
    np.testing.assert_allclose(robot_grid.states(), scale.states_to_robot(grid.states()))
    assert scale.grid_to_model(robot_grid) == grid
    # V(x) = s·V′(x/s, y/s, v·τ/s, θ) for a smooth V′: the chain rule is what gradient_to_robot does
    def model_value(z):
        return np.sin(z[..., 0]) * z[..., 1] + z[..., 2] ** 2 * np.cos(z[..., 3])

    def robot_value(x):
        return scale.value_to_robot(model_value(scale.states_to_model(x)))

    x, h = scale.states_to_robot(states), 1e-6
    numeric = np.stack([(robot_value(x + h * e) - robot_value(x - h * e)) / (2 * h) for e in np.eye(4)], -1)
    z = states
    model_grad = np.column_stack([np.cos(z[:, 0]) * z[:, 1], np.sin(z[:, 0]), 2 * z[:, 2] * np.cos(z[:, 3]),
                                  -z[:, 2] ** 2 * np.sin(z[:, 3])])
    np.testing.assert_allclose(scale.gradient_to_robot(model_grad), numeric, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(scale.gradient_to_model(scale.gradient_to_robot(model_grad)), model_grad)


def test_bad_scalings_are_rejected():
    with pytest.raises(ValueError, match="length and time > 0"):
        Scaling(0.0, 1.0)
    with pytest.raises(ValueError, match="not similar"):
        robot_to_robot(CarParams.product(), CarParams.product(a_max=2.0))
    with pytest.raises(ValueError, match="4 components"):
        Scaling(1.0, 1.0).states_to_model(np.zeros((2, 3)))


def _solve_scaled(robot: CarParams, scale: Scaling, shape, radius: float = 1.0, **options):
    """The reference disk problem (10-unit window, disk of ``radius`` units) for ``robot``, in its SI units.
    The solver's chunk and tolerance are scaled with it, so both solves step the same scaled times."""
    grid = scale.grid_to_robot(car_grid(shape, v_range=(robot.v_min / scale.speed, robot.v_max / scale.speed)))
    target = Disk((0.0, 0.0), radius * scale.length).sdf(grid.states()[..., :2])
    value, report = solve(DynamicDubinsCar(robot), grid, target, chunk=scale.duration_to_robot(1.0),
                          tolerance=scale.rate_to_robot(1e-3), max_horizon=scale.duration_to_robot(40.0), **options)
    assert report.converged
    return grid, value, report


@pytest.mark.parametrize("name, shape", [("product", (32, 32, 9, 16)), ("paper", (24, 24, 7, 12))])
def test_two_robots_with_equal_numbers_share_one_value_function(name, shape):
    """Reference robot (a = κ = v = 1) on a 10 m window with a 1 m disk against κ = 4 /m, v = 0.5 m/s,
    a = 1 m/s² on a 2.5 m window with a 0.25 m disk: V_B / s = V_A node by node.  Stated tolerance 1e-3
    (max |V_B/s − V_A|, model lengths; measured 1.1e-4 for the product model at 32²·9·16 and 3.4e-5 for the
    paper's at 24²·7·12: float32 and WENO's regularisation are not scale-free) and identical BRTs."""
    reference = CarParams.product() if name == "product" else CarParams.paper()
    small = (CarParams.product if name == "product" else CarParams.paper)(
        kappa_max=4.0, v_max=0.5, d0=reference.d0 * 0.5)
    scale = robot_to_robot(reference, small)
    assert (scale.length, scale.time) == (0.25, 0.5)
    grid_a, value_a, report_a = _solve_scaled(reference, Scaling(1.0, 1.0), shape)
    grid_b, value_b, report_b = _solve_scaled(small, scale, shape)
    assert report_a.horizon == pytest.approx(report_b.horizon / scale.time)
    error = np.abs(scale.value_to_model(value_b) - value_a).max()
    print(f"\n{name}: max |V_B/s - V_A| = {error:.1e} model lengths; horizons {report_a.horizon}, {report_b.horizon} s")
    assert error < 1e-3
    assert np.array_equal(value_a <= 0, value_b <= 0)
    # ∇V maps with the chain rule: the table's finite differences agree once scaled
    states = grid_a.states()[4:-4, 4:-4].reshape(-1, 4)[::7]
    grad_a = ValueTable(grid_a, value_a).gradient(states)
    grad_b = ValueTable(grid_b, value_b).gradient(scale.states_to_robot(states))
    np.testing.assert_allclose(scale.gradient_to_model(grad_b), grad_a, atol=2e-3)


def test_different_numbers_give_a_different_value_function():
    """The comparison above can fail: with twice the braking (a/(κ v²) = 2) the small robot is not similar."""
    strong = CarParams.product(kappa_max=4.0, v_max=0.5, a_max=2.0)
    scale = Scaling(0.25, 0.5)  # the same lengths and times as above, but the numbers differ
    grid_a, value_a, _ = _solve_scaled(CarParams.product(), Scaling(1.0, 1.0), (24, 24, 7, 12))
    _, value_b, _ = _solve_scaled(strong, scale, (24, 24, 7, 12))
    assert np.abs(scale.value_to_model(value_b) - value_a).max() > 0.05
    assert not math.isclose(Dimensionless.of(strong).accel_ratio, 1.0)
