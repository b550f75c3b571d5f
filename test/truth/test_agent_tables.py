"""Value tables against a moving agent (hjrno_ros.truth.agent_tables): real solves on a tiny grid, checked by
properties that can fail: rest is safe, V ≤ l and ≤ cap, head-on from close is unsafe and moving away is not, a
faster agent never helps head-on, the unsafe set must stay inside the box, and the bundle round-trips by hash."""

import dataclasses
import json

import numpy as np
import pytest
from safetensors.numpy import load_file

from hjrno_ros.core.dynamics import DiffDriveParams
from hjrno_ros.core.grids import GridSpec
from hjrno_ros.truth import agent_tables as at
from hjrno_ros.truth.systems import AgentRelative, AgentRelativeParams

ROBOT = DiffDriveParams(a_max=1.0, omega_max=2.0, v_min=-1.0, v_max=1.0)  # Jackal-like, T = 1 s
R, SPEEDS, DEVIATION, CAP = 0.45, (0.0, 0.5), 0.1, 0.5
GRID = at.agent_grid(ROBOT, 3.0, 0.3, v_nodes=5, theta_nodes=8)  # 21 x 21 x 5 x 8, v = -1, -0.5, 0, 0.5, 1
V_IDX = {v: i for i, v in enumerate(GRID.axis(2))}


@pytest.fixture(scope="module")
def solved():
    values, report = at.solve_agent_table(ROBOT, R, SPEEDS, DEVIATION, GRID, CAP, edge_margin=0.3)
    return values, report


def _node(x: float, y: float) -> tuple[int, int]:
    return int(np.argmin(np.abs(GRID.axis(0) - x))), int(np.argmin(np.abs(GRID.axis(1) - y)))


def test_relative_dynamics_drift_lock_and_rebuild():
    p = at.level_params(ROBOT, 0.5, at.solved_deviation(DEVIATION, SPEEDS))
    assert p.d0 == pytest.approx(0.35) and p.agent_speed == 0.5 and p.rest_speed == at.V_TOL
    dyn = AgentRelative(p)
    rest, moving = np.array([1.0, 0.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.5, np.pi])
    push, still = np.array([1.0, 0.5]), np.zeros(2)
    assert np.allclose(dyn(rest, push, still, 0.0), [-0.5, 0.0, 0.0, 0.5])  # drift −s; at rest no acceleration
    assert np.allclose(dyn(moving, push, still, 0.0), [-1.0, 0.0, 1.0, 0.5], atol=1e-6)
    assert np.allclose(dyn.open_loop_dynamics(moving, 0.0), [-1.0, 0.0, 0.0, 0.0], atol=1e-6)
    assert float(dyn.control_jacobian(rest, 0.0)[2, 0]) == 0.0 and float(dyn.control_jacobian(moving, 0.0)[2, 0]) == 1
    faster = AgentRelative(dataclasses.replace(p, agent_speed=1.0))
    assert dyn != faster and hash(dyn) != hash(faster)  # the solver's jit cache tells speeds apart
    rebuilt = type(p)(*dataclasses.astuple(p))  # what solver._step does with traced values
    assert AgentRelative(rebuilt) == dyn
    with pytest.raises(ValueError, match="agent_speed"):
        AgentRelativeParams(agent_speed=-0.1)


def test_speed_levels_and_grid_are_checked():
    assert at.level_spacing((0, 0.25, 0.5)) == 0.25 and at.solved_deviation(0.3, (0, 0.25)) == pytest.approx(0.425)
    for bad in ((0.25, 0.5), (0, 0.25, 0.75), (0, -0.5)):
        with pytest.raises(ValueError):
            at.level_spacing(bad)
    assert 0.0 in GRID.axis(2) and GRID.shape == (21, 21, 5, 8) and GRID.periodic == (3,)
    with pytest.raises(ValueError, match="none at v = 0; --v-nodes 3 or 5 or 7 or 9 would"):
        at.agent_grid(ROBOT, 3.0, 0.3, v_nodes=4)
    slower_back = dataclasses.replace(ROBOT, v_min=-0.25, v_max=0.5)  # reverses at half its top speed
    assert 0.0 in at.agent_grid(slower_back, 3.0, 0.3, v_nodes=7).axis(2)
    with pytest.raises(ValueError, match="--v-nodes 4 or 7 or 10 or 13 would"):
        at.agent_grid(slower_back, 3.0, 0.3, v_nodes=11)


def test_tables_are_converged_capped_below_the_target_and_safe_at_rest(solved):
    values, report = solved
    assert values.shape == (len(SPEEDS), *GRID.shape) and values.dtype == np.float32
    assert all(lv["converged"] for lv in report["levels"]), report["levels"]
    assert values.max() <= CAP
    assert np.all(values <= np.minimum(at.agent_target(GRID, R, CAP), CAP)[None] + 1e-6)
    rest = values[:, :, :, V_IDX[0.0]]
    assert rest.min() >= CAP - 0.02  # a robot at rest is never blamed: the rest term is the cap
    assert all(0 < lv["moving_unsafe_share"] < 0.5 for lv in report["levels"])


def test_head_on_from_close_is_unsafe_moving_away_is_safe(solved):
    values, _ = solved
    i, j = _node(R + 0.15, 0.0)  # 0.15 m from contact, ahead of the agent
    toward, away = 0, 4  # θ = −π (towards −x, at the agent) and θ = 0
    for k in range(len(SPEEDS)):
        assert values[k, i, j, V_IDX[1.0], toward] < 0
        assert values[k, i, j, V_IDX[1.0], away] > 0


def test_a_faster_agent_never_helps_head_on(solved):
    values, _ = solved
    xs = [i for i, x in enumerate(GRID.axis(0)) if R < x < 2.4]
    _, j = _node(0.0, 0.0)
    head_on = values[:, xs, j][:, :, [V_IDX[0.5], V_IDX[1.0]], 0]  # ahead, moving at the agent
    assert np.all(head_on[1] <= head_on[0] + 1e-3)
    assert np.any(head_on[1] < head_on[0] - 0.05)  # and it matters


def test_an_unsafe_set_at_the_box_edge_is_an_error():
    small = at.agent_grid(ROBOT, 1.2, 0.3, v_nodes=5, theta_nodes=8)
    with pytest.raises(ValueError, match="grow the box"):
        at.solve_agent_table(ROBOT, R, (0.0,), DEVIATION, small, CAP, max_horizon=3.0)


def test_bundle_round_trips_and_a_truncated_file_fails_its_hash(solved, tmp_path):
    values, report = solved
    card = at.make_card(robot=ROBOT, robot_radius=0.25, agent_radius=0.2, speeds=SPEEDS, deviation=DEVIATION,
                        cap=CAP, grid=GRID, report=report, reproduce="hjrno agents --robot test")
    tensor, card_path = at.write_agent_table(tmp_path / "agents", values, card)
    back = json.loads(card_path.read_text())
    assert back["kind"] == "agent_relative" and back["agent_speeds"] == list(SPEEDS) and back["radius"] == R
    assert back["deviation_solved"] == pytest.approx(0.35) and back["dtype"] == "float32"
    assert GridSpec.from_dict(back["grid"]) == GRID and back["shape"] == list(values.shape)
    assert [lv["converged"] for lv in back["solver"]] == [True, True]
    assert np.array_equal(load_file(tensor)["values"], values)
    assert at.file_sha256(tensor) == back["values_sha256"]
    tensor.write_bytes(tensor.read_bytes()[:-100])
    assert at.file_sha256(tensor) != back["values_sha256"]


def test_a_robot_slower_than_the_agent_still_reads_a_distance():
    """The TurtleBot3's case: the agent could later reach the stopped robot, yet a moving state's value is the gap
    it keeps on its way to rest, not a few millimetres."""
    slow = DiffDriveParams(a_max=1.0, omega_max=2.0, v_min=-0.3, v_max=0.3)
    grid = at.agent_grid(slow, 2.4, 0.2, v_nodes=5, theta_nodes=8)
    values, _ = at.solve_agent_table(slow, R, (0.0,), 0.3, grid, CAP, edge_margin=0.2)
    i, j = int(np.argmin(np.abs(grid.axis(0) - 1.05))), int(np.argmin(np.abs(grid.axis(1))))
    away = values[0, i, j, list(grid.axis(2)).index(0.3), 4]  # 0.6 m from contact, moving away at 0.3 m/s
    assert 0.3 < away <= 0.6


def test_the_node_reads_a_solved_table(solved, tmp_path):
    """core.tracked_agents reads what the solver wrote: rest is safe, head-on from close is not."""
    from hjrno_ros.core.tracked_agents import read_agent_table

    values, report = solved
    card = at.make_card(robot=ROBOT, robot_radius=0.25, agent_radius=0.2, speeds=SPEEDS, deviation=DEVIATION,
                        cap=CAP, grid=GRID, report=report, reproduce="hjrno agents --robot test")
    at.write_agent_table(tmp_path / "agents", values, card)
    table = read_agent_table(tmp_path / "agents")
    states = np.array([[R + 0.45, 0.0, 0.0, np.pi], [R + 0.45, 0.0, 1.0, np.pi], [R + 0.45, 0.0, 1.0, 0.0]])
    rest, toward, away = table.value(states[None], np.array([0.5]), np.array([R]))[0]
    assert rest >= card["rest_value"] and toward < 0 < away


def test_float16_storage_rounds_down():
    v = np.array([0.1, 0.3333, -0.2, 0.02, 1.0], np.float32)
    h = at.to_float16_down(v)
    assert h.dtype == np.float16 and np.all(h.astype(np.float32) <= v) and np.max(v - h) < 1e-3
