"""The safety filter on its own (core/safety_filter.py, core/stop_zone.py): scalar and batch forms agree, the QP
mode is the smallest change keeping the barrier condition, NaN fails closed, the stop zone scales and stops."""

import sys

import numpy as np
import pytest

from hjrno_ros.core.dynamics import CarParams, optimal_control, robot_f, worst_disturbance
from hjrno_ros.core.geometry import Disk
from hjrno_ros.core.safety_filter import FilterSettings, filter_batch, filter_command, minimal_change
from hjrno_ros.core.stop_zone import StopZoneSettings, stop_zone_filter

HJRNO = [sys.executable, "-m", "hjrno_ros.cli"]
PARAMS = CarParams()




@pytest.mark.parametrize("mode", ["switch", "blend", "qp"])
def test_batch_filter_matches_the_scalar_filter(mode):
    rng = np.random.default_rng(0)
    n = 200
    states = np.column_stack([rng.normal(size=(n, 2)), rng.uniform(0, 1, n), rng.uniform(-np.pi, np.pi, n)])
    values, grads = rng.uniform(-0.2, 0.6, n), rng.normal(size=(n, 4))
    nominal = np.column_stack([rng.uniform(0, 1, n), rng.uniform(-1, 1, n)])
    settings = FilterSettings(epsilon=0.1, mode=mode)
    out, intervened = filter_batch(PARAMS, settings, states, values, grads, nominal)
    for i in range(n):
        d = filter_command(PARAMS, settings, states[i], values[i], grads[i], *nominal[i])
        assert (d.linear, d.angular, d.intervened) == pytest.approx((*out[i], intervened[i]))
    assert 0 < intervened.mean() < 1


def test_qp_mode_is_the_smallest_change_that_keeps_the_barrier_condition():
    rng = np.random.default_rng(4)
    n = 300
    states = np.column_stack([rng.normal(size=(n, 2)), rng.uniform(0, 1, n), rng.uniform(-np.pi, np.pi, n)])
    values, grads = rng.uniform(-0.2, 0.6, n), rng.normal(size=(n, 4))
    nominal = np.column_stack([rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)])  # (a, κ) within the limits
    settings = FilterSettings(epsilon=0.1, mode="qp", decay_rate=2.0)
    u, changed = minimal_change(PARAMS, settings, states, values, grads, nominal)

    def rate(controls, x=states, g=grads):  # dV/dt under the worst-case disturbance
        return (g * robot_f(PARAMS, x, controls, worst_disturbance(PARAMS, x, g))).sum(-1)

    need = -settings.decay_rate * (values - settings.epsilon)
    assert np.array_equal(changed, rate(nominal) < need) and 0.2 < changed.mean() < 0.8
    assert np.array_equal(u[~changed], nominal[~changed])
    feasible = rate(optimal_control(PARAMS, states, grads)) >= need
    assert np.all(rate(u)[feasible] >= need[feasible] - 1e-9) and 0 < (~feasible).sum()
    grid = np.stack(np.meshgrid(np.linspace(-1, 1, 81), np.linspace(-1, 1, 81)), -1).reshape(-1, 2)
    for i in np.flatnonzero(changed & feasible)[:40]:  # nothing on a fine grid of the box is closer
        x, g = (np.broadcast_to(a[i], (len(grid), 4)) for a in (states, grads))
        ok = rate(grid, x, g) >= need[i]
        assert np.linalg.norm(u[i] - nominal[i]) <= np.linalg.norm(grid[ok] - nominal[i], axis=-1).min() + 1e-9


def test_batch_filter_fails_closed_on_nan():
    states = np.array([[0.0, 0.0, 0.5, 0.0], [0.0, 0.0, 0.5, 0.0]])
    out, intervened = filter_batch(PARAMS, FilterSettings(), states, np.array([np.nan, 1.0]), np.zeros((2, 4)),
                                   np.array([[1.0, 0.0], [np.nan, 0.0]]))
    assert np.all(out == 0) and intervened.all()


def test_stop_zone_scales_stops_and_passes():
    disk = Disk((2.0, 0.0), 0.5)
    clearance = lambda p: disk.sdf(np.asarray(p)[..., :2])  # noqa: E731
    states = np.array([[0.0, 0.0, 1.0, 0.0],      # heading at the disk, contact after ~1.45 s
                       [0.0, 0.0, 1.0, np.pi],    # heading away
                       [1.3, 0.0, 0.0, np.pi / 2]])  # 0.2 m from the disk: inside the stop zone
    nominal = np.array([[1.0, 0.0], [1.0, 0.0], [0.5, 0.3]])
    out, intervened = stop_zone_filter(StopZoneSettings(), clearance, states, nominal)
    assert 0.6 < out[0, 0] < 0.8 and intervened[0]
    assert np.array_equal(out[1], nominal[1]) and not intervened[1]
    assert np.all(out[2] == 0) and intervened[2]
