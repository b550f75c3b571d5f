"""The value table's own lookup against scipy's interpolator, and the gradient made only when asked for."""

import numpy as np
from scipy import interpolate

from hjrno_ros.core.grids import GridSpec
from hjrno_ros.core.value_table import ReversingTable, ValueTable, multilinear

GRID = GridSpec((-2.0, -1.0, 0.0, -np.pi), (2.0, 3.0, 1.0, np.pi), (9, 7, 5, 8), (3,))


def scipys(values: np.ndarray, states: np.ndarray) -> np.ndarray:
    """scipy's interpolation of ``values`` (GRID's shape, then channels) at ``states``, headings wrapped by a closing
    slice, the other axes clamped to the box."""
    axes = [*GRID.axes()[:3], np.append(GRID.axes()[3], np.pi)]
    closed = np.concatenate([values, values[:, :, :, :1]], 3)
    s = np.clip(states, GRID.lo, GRID.hi)
    s[:, 3] = -np.pi + np.mod(states[:, 3] + np.pi, 2 * np.pi)
    return interpolate.RegularGridInterpolator(axes, closed)(s)


def test_values_and_gradients_equal_scipys_inside_beyond_the_box_and_across_the_heading_wrap():
    rng = np.random.default_rng(0)
    values = rng.normal(size=GRID.shape)
    table = ValueTable(GRID, values)
    states = rng.uniform([-3.0, -2.0, -0.5, -9.0], [3.0, 4.0, 1.5, 9.0], (500, 4))
    np.testing.assert_allclose(table.value(states), scipys(values, states), atol=1e-12)
    np.testing.assert_allclose(table.value(states), table.value_and_gradient(states)[0], atol=1e-12)
    wrapped = np.concatenate([values[..., -1:], values, values[..., :1]], 3)
    partials = [np.gradient(values, h, axis=i) for i, h in enumerate(GRID.spacings[:3])]
    partials.append(np.gradient(wrapped, GRID.spacings[3], axis=3)[..., 1:-1])  # central across the wrap
    np.testing.assert_allclose(table.gradient(states), scipys(np.stack(partials, -1), states), atol=1e-12)
    assert table.value(states[0]).shape == table.value_and_gradient(states[0])[0].shape == (1,)
    assert table.value(states.reshape(5, 100, 4)).shape == (5, 100)


def test_a_non_finite_state_reads_nan_and_the_others_are_unaffected():
    table = ValueTable(GRID, np.ones(GRID.shape))
    states = np.array([[0.0, 0.0, 0.5, 0.0], [np.nan, 0.0, 0.5, 0.0], [0.0, 0.0, 0.5, np.inf]])
    out = table.value(states)
    assert out[0] == 1.0 and np.isnan(out[1:]).all()


def test_the_gradient_interpolator_is_made_on_first_use_and_reversing_states_read_the_mirror():
    rng = np.random.default_rng(1)
    forward = ValueTable(GRID, rng.normal(size=GRID.shape))  # speeds from 0: a forward table
    assert forward._vg is None  # the constructor no longer pays for ∇V
    table = ReversingTable(forward)
    back = np.array([[0.3, 0.7, -0.4, 1.0]])
    mirrored = np.array([[0.3, 0.7, 0.4, 1.0 + np.pi]])
    np.testing.assert_allclose(table.value(back), forward.value(mirrored), atol=1e-12)
    assert forward._vg is None
    table.prepare_gradient()
    assert forward._vg is not None
    np.testing.assert_allclose(table.value_and_gradient(back)[0], table.value(back), atol=1e-12)


def test_a_leading_level_axis_is_indexed_not_interpolated():
    values = np.stack([np.zeros(GRID.shape), np.full(GRID.shape, 2.0)])
    coords = (np.zeros(3), np.zeros(3), np.full(3, 0.5), np.zeros(3))
    np.testing.assert_allclose(multilinear(values, GRID, coords, (np.array([0, 1, 1]),)), [0.0, 2.0, 2.0])
