"""The shared formulas: numpy and hj_reachability agree, optimal controls are optimal, limits hold."""

import hj_reachability as hj
import jax.numpy as jnp
import numpy as np
import pytest

from hjrno_ros.core import dynamics as dyn
from hjrno_ros.truth import systems

RNG = np.random.default_rng(7)


def car_states(n, v_range=(0, 1)):
    return np.column_stack([RNG.uniform(-5, 5, n), RNG.uniform(-5, 5, n), RNG.uniform(*v_range, n),
                            RNG.uniform(-3, 3, n)])


# the paper's car, the product robot, and a product robot that reverses
MODELS = {"paper": dyn.CarParams(a_max=0.7, kappa_max=1.3, d_max=0.2),
          "product": dyn.CarParams.product(a_max=0.8, kappa_max=1.5, tracking_error=0.3),
          "reversing": dyn.CarParams.product(v_min=-0.6, d0=0.05)}


@pytest.mark.parametrize("name", MODELS)
def test_car_numpy_matches_hj_dynamics(name):
    """hj's disturbance is e in the unit ball, scaled by δ·|v| + d₀ in its Jacobian: d = (δ·|v| + d₀)·e."""
    p = MODELS[name]
    system = systems.DynamicDubinsCar(p)
    for s in car_states(20, (p.v_min, p.v_max)):
        u, e = RNG.uniform(-1, 1, 2), RNG.uniform(-0.7, 0.7, 2)
        s[2] = RNG.choice([-0.5, 0.5]) if p.v_min < 0 else 0.5  # away from the speed limits, where f is affine
        d = dyn.disturbance_bound(p, s[2]) * e
        np.testing.assert_allclose(dyn.robot_f(p, s, u, d), np.asarray(system(jnp.array(s), u, e, 0.0)), rtol=1e-5)
        affine = system.open_loop_dynamics(s, 0.0) + system.control_jacobian(s, 0.0) @ u
        affine = affine + system.disturbance_jacobian(s, 0.0) @ e
        np.testing.assert_allclose(dyn.robot_f(p, s, u, d), np.asarray(affine), rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("name", MODELS)
def test_car_optimal_control_maximises_and_disturbance_minimises(name):
    p = MODELS[name]
    states, grads = car_states(200, (p.v_min, p.v_max)), RNG.normal(size=(200, 4))
    u_star, d_star = dyn.optimal_control(p, states, grads), dyn.worst_disturbance(p, states, grads)
    bound = dyn.disturbance_bound(p, states[:, 2])[:, None]
    assert np.allclose(np.linalg.norm(d_star, axis=-1, keepdims=True), bound)
    h_star = np.sum(grads * dyn.robot_f(p, states, u_star, d_star), -1)
    for _ in range(50):
        u = np.column_stack([RNG.uniform(-p.a_max, p.a_max, 200), RNG.uniform(-p.kappa_max, p.kappa_max, 200)])
        angle = RNG.uniform(0, 2 * np.pi, 200)
        d = bound * np.sqrt(RNG.uniform(size=(200, 1))) * np.column_stack([np.cos(angle), np.sin(angle)])
        assert np.all(np.sum(grads * dyn.robot_f(p, states, u, d_star), -1) <= h_star + 1e-9)
        assert np.all(np.sum(grads * dyn.robot_f(p, states, u_star, d), -1) >= h_star - 1e-9)


@pytest.mark.parametrize("name", MODELS)
def test_car_hj_optimal_matches_numpy(name):
    p = MODELS[name]
    system = systems.DynamicDubinsCar(p)
    for s, g in zip(car_states(10, (p.v_min, p.v_max)), RNG.normal(size=(10, 4)), strict=True):
        u, e = system.optimal_control_and_disturbance(jnp.array(s), 0.0, jnp.array(g))
        np.testing.assert_allclose(np.asarray(u), dyn.optimal_control(p, s, g), rtol=1e-6)
        np.testing.assert_allclose(dyn.disturbance_bound(p, s[2]) * np.asarray(e),
                                   dyn.worst_disturbance(p, s, g), rtol=1e-5, atol=1e-7)
        h = np.asarray(system.hamiltonian(jnp.array(s), 0.0, 0.0, jnp.array(g)))
        expect = (g[0] * s[2] * np.cos(s[3]) + g[1] * s[2] * np.sin(s[3]) + p.a_max * abs(g[2])
                  + p.kappa_max * abs(s[2] * g[3]) - dyn.disturbance_bound(p, s[2]) * np.hypot(g[0], g[1]))
        np.testing.assert_allclose(h, expect, rtol=1e-5, atol=1e-6)


def test_reversing_turns_the_other_way():
    """θ̇ = v·u₂: backwards, the curvature that raises V has the opposite sign."""
    p = MODELS["reversing"]
    grad = np.array([0.0, 0.0, 0.0, 1.0])  # V grows with θ
    forward, backward = np.array([0.0, 0.0, 0.5, 0.0]), np.array([0.0, 0.0, -0.5, 0.0])
    for state in (forward, backward):
        u = dyn.optimal_control(p, state, grad)
        assert dyn.robot_f(p, state, u, np.zeros(2))[3] == pytest.approx(p.kappa_max * 0.5)  # θ̇ > 0 either way
    assert dyn.optimal_control(p, backward, grad)[1] == -p.kappa_max


def test_a_stopped_product_robot_stays_stopped():
    p = dyn.CarParams.product()
    rest = np.array([[1.0, 2.0, 0.0, 0.3]])
    grads = RNG.normal(size=(1, 4))
    assert np.all(dyn.worst_disturbance(p, rest, grads) == 0)
    f = dyn.robot_f(p, rest, np.array([[0.0, p.kappa_max]]), dyn.worst_disturbance(p, rest, grads))
    assert np.all(f == 0)


@pytest.mark.parametrize("v_min", [0.2, -0.6])
def test_speed_stays_within_limits(v_min):
    p = dyn.CarParams(v_min=v_min, v_max=1.0)
    at_top = np.array([[0.0, 0.0, 1.0, 0.0]])
    at_bottom = np.array([[0.0, 0.0, v_min, 0.0]])
    accelerate, brake = np.array([[1.0, 0.0]]), np.array([[-1.0, 0.0]])
    zero = np.zeros((1, 2))
    assert dyn.robot_f(p, at_top, accelerate, zero)[0, 2] == 0.0
    assert dyn.robot_f(p, at_top, brake, zero)[0, 2] == -1.0
    assert dyn.robot_f(p, at_bottom, brake, zero)[0, 2] == 0.0
    # The optimal control never asks to leave the range, whatever the gradient says.
    wants_faster = np.array([[0.0, 0.0, 1.0, 0.0]])
    assert dyn.optimal_control(p, at_top, wants_faster)[0, 0] == 0.0
    assert dyn.optimal_control(p, at_bottom, -wants_faster)[0, 0] == 0.0


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
    ({"v_min": 1.0, "v_max": 1.0}, "v_min < v_max"),
    ({"v_min": -2.0, "v_max": 0.0}, "v_max must be > 0"),
    ({"a_max": -1.0}, "a_max must be > 0"),
    ({"kappa_max": 0.0}, "kappa_max must be > 0"),
    ({"d0": -0.1}, "d0 must be >= 0"),
    ({"d_max": -0.1}, "d0 must be >= 0"),
    ({"tracking_error": -0.1}, r"tracking_error \(δ\) must be >= 0"),
    ({"a_max": float("nan")}, "finite"),
    ({"tracking_error": float("inf")}, "finite"),
    ({"d_max": 0.1, "d0": 0.1}, "not both"),
    ({"d_max": 0.1, "tracking_error": 0.1}, "speed-independent"),
])
def test_nonsensical_car_parameters_are_rejected(kwargs, message):
    """One ValueError line per problem, naming the parameter."""
    with pytest.raises(ValueError, match=message) as err:
        dyn.CarParams(**kwargs)
    assert "\n" not in str(err.value)


def test_named_models_and_their_dicts():
    paper, product = dyn.CarParams.paper(), dyn.CarParams.product()
    assert paper == dyn.CarParams() and paper.preset == "paper" and product.preset == "product"
    assert (product.tracking_error, product.d0, product.v_min) == (0.1, 0.0, 0.0)
    assert dyn.CarParams.product(v_min=-0.5).preset is None and dyn.car_preset("product") == product
    assert paper.d_max == 0.1 and dyn.CarParams(d_max=0.2) == dyn.CarParams(d0=0.2)
    with pytest.raises(ValueError, match="depends on speed"):
        product.d_max  # noqa: B018 - the paper's scalar bound does not exist for the product robot
    assert product.disturbance_max() == pytest.approx(0.1)
    for p in (paper, product, dyn.CarParams.product(v_min=-0.5, d0=0.02)):
        assert p.as_dict()["model"] == dyn.CAR_MODEL and dyn.CarParams.from_dict(p.as_dict()) == p
    legacy = {"a_max": 1.0, "kappa_max": 1.0, "d_max": 0.1, "v_min": 0.0, "v_max": 1.0}  # a card before the product
    assert dyn.CarParams.from_dict(legacy) == paper
    with pytest.raises(ValueError, match="unknown car dynamics model"):
        dyn.CarParams.from_dict({**product.as_dict(), "model": "unicycle"})
    with pytest.raises(ValueError, match="unknown car parameter"):
        dyn.CarParams.from_dict({**product.as_dict(), "omega_max": 2.0})
    with pytest.raises(ValueError, match="unknown robot model"):
        dyn.car_preset("tank")


def test_nonsensical_air3d_parameters_are_rejected():
    with pytest.raises(ValueError, match="turn rates"):
        dyn.Air3DParams(evader_max_turn_rate=0.0)
    with pytest.raises(ValueError, match="speeds"):
        dyn.Air3DParams(pursuer_speed=-1.0)


def test_without_a_reason_in_v_the_safe_control_brakes():
    """∂V/∂v = 0 (V flat in speed, e.g. V = l far from obstacles): every u1 is optimal; u1 brakes towards rest."""
    p = dyn.CarParams.product(v_min=-0.6)
    states = np.array([[0.0, 0.0, 0.5, 0.0], [0.0, 0.0, -0.4, 0.0], [0.0, 0.0, 0.0, 0.0]])
    flat = np.array([[0.3, -0.2, 0.0, 0.1]] * 3)
    assert dyn.optimal_control(p, states, flat)[:, 0].tolist() == [-p.a_max, p.a_max, 0.0]
