"""The shared formulas: numpy and hj_reachability agree, optimal controls are optimal, limits hold."""

import hj_reachability as hj
import jax.numpy as jnp
import numpy as np
import pytest

from hjrno_ros.core import dynamics as dyn
from hjrno_ros.truth import systems

RNG = np.random.default_rng(7)


def car_states(n):
    return np.column_stack([RNG.uniform(-5, 5, n), RNG.uniform(-5, 5, n), RNG.uniform(0, 1, n), RNG.uniform(-3, 3, n)])


def test_car_numpy_matches_hj_dynamics():
    p = dyn.CarParams(a_max=0.7, kappa_max=1.3, d_max=0.2)
    system = systems.DynamicDubinsCar(p)
    for s in car_states(20):
        u, d = RNG.uniform(-1, 1, 2), RNG.uniform(-0.1, 0.1, 2)
        s[2] = 0.5  # away from the speed limits, where f is affine
        np.testing.assert_allclose(dyn.car_f(p, s, u, d), np.asarray(system(jnp.array(s), u, d, 0.0)), rtol=1e-5)
        affine = system.open_loop_dynamics(s, 0.0) + system.control_jacobian(s, 0.0) @ u
        affine = affine + system.disturbance_jacobian(s, 0.0) @ d
        np.testing.assert_allclose(dyn.car_f(p, s, u, d), np.asarray(affine), rtol=1e-5, atol=1e-7)


def test_car_optimal_control_maximises_and_disturbance_minimises():
    p = dyn.CarParams(a_max=0.8, kappa_max=1.5, d_max=0.3)
    states, grads = car_states(200), RNG.normal(size=(200, 4))
    u_star, d_star = dyn.car_optimal_control(p, states, grads), dyn.car_worst_disturbance(p, states, grads)
    h_star = np.sum(grads * dyn.car_f(p, states, u_star, d_star), -1)
    for _ in range(50):
        u = np.column_stack([RNG.uniform(-p.a_max, p.a_max, 200), RNG.uniform(-p.kappa_max, p.kappa_max, 200)])
        angle = RNG.uniform(0, 2 * np.pi, 200)
        d = p.d_max * np.sqrt(RNG.uniform(size=(200, 1))) * np.column_stack([np.cos(angle), np.sin(angle)])
        assert np.all(np.sum(grads * dyn.car_f(p, states, u, d_star), -1) <= h_star + 1e-9)
        assert np.all(np.sum(grads * dyn.car_f(p, states, u_star, d), -1) >= h_star - 1e-9)


def test_car_hj_optimal_matches_numpy():
    p = dyn.CarParams()
    system = systems.DynamicDubinsCar(p)
    for s, g in zip(car_states(10), RNG.normal(size=(10, 4)), strict=True):
        u, d = system.optimal_control_and_disturbance(jnp.array(s), 0.0, jnp.array(g))
        np.testing.assert_allclose(np.asarray(u), dyn.car_optimal_control(p, s, g), rtol=1e-6)
        np.testing.assert_allclose(np.asarray(d), dyn.car_worst_disturbance(p, s, g), rtol=1e-5, atol=1e-7)


def test_speed_stays_within_limits():
    p = dyn.CarParams(v_min=0.2, v_max=1.0)
    at_top = np.array([[0.0, 0.0, 1.0, 0.0]])
    at_bottom = np.array([[0.0, 0.0, 0.2, 0.0]])
    accelerate, brake = np.array([[1.0, 0.0]]), np.array([[-1.0, 0.0]])
    zero = np.zeros((1, 2))
    assert dyn.car_f(p, at_top, accelerate, zero)[0, 2] == 0.0
    assert dyn.car_f(p, at_top, brake, zero)[0, 2] == -1.0
    assert dyn.car_f(p, at_bottom, brake, zero)[0, 2] == 0.0
    # The optimal control never asks to leave the range, whatever the gradient says.
    wants_faster = np.array([[0.0, 0.0, 1.0, 0.0]])
    assert dyn.car_optimal_control(p, at_top, wants_faster)[0, 0] == 0.0
    assert dyn.car_optimal_control(p, at_bottom, -wants_faster)[0, 0] == 0.0


def test_air3d_matches_hj_builtin():
    p = dyn.Air3DParams(evader_speed=4.0, pursuer_speed=3.0, evader_max_turn_rate=1.2, pursuer_max_turn_rate=0.8)
    ours = systems.Air3D(p)
    ref = hj.systems.Air3d(4.0, 3.0, 1.2, 0.8)
    for _ in range(30):
        s = jnp.array(RNG.uniform(-5, 5, 3))
        g = jnp.array(RNG.normal(size=3))
        u, d = ours.optimal_control_and_disturbance(s, 0.0, g)
        ur, dr = ref.optimal_control_and_disturbance(s, 0.0, g)
        np.testing.assert_allclose(np.asarray(u), np.asarray(ur))
        np.testing.assert_allclose(np.asarray(d), np.asarray(dr))
        np.testing.assert_allclose(np.asarray(ours(s, u, d, 0.0)), np.asarray(ref(s, u, d, 0.0)), rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(dyn.air3d_f(p, np.asarray(s), np.asarray(u), np.asarray(d)),
                                   np.asarray(ref(s, u, d, 0.0)), rtol=1e-5, atol=1e-6)


def test_equal_parameters_share_the_jit_cache_key():
    assert systems.DynamicDubinsCar(dyn.CarParams()) == systems.DynamicDubinsCar(dyn.CarParams())
    assert hash(systems.DynamicDubinsCar()) == hash(systems.DynamicDubinsCar(dyn.CarParams()))
    assert systems.DynamicDubinsCar(dyn.CarParams(a_max=2.0)) != systems.DynamicDubinsCar()


@pytest.mark.parametrize("kwargs, message", [
    ({"v_min": 1.0, "v_max": 0.5}, "v_min < v_max"),
    ({"a_max": -1.0}, "a_max"),
    ({"kappa_max": 0.0}, "kappa_max"),
    ({"d_max": -0.1}, "d_max"),
    ({"a_max": float("nan")}, "finite"),
])
def test_nonsensical_car_parameters_are_rejected(kwargs, message):
    with pytest.raises(ValueError, match=message):
        dyn.CarParams(**kwargs)


def test_nonsensical_air3d_parameters_are_rejected():
    with pytest.raises(ValueError, match="turn rates"):
        dyn.Air3DParams(evader_max_turn_rate=0.0)
    with pytest.raises(ValueError, match="speeds"):
        dyn.Air3DParams(pursuer_speed=-1.0)
