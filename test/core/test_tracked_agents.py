"""Tracked agents: the relative frame, the table lookup and the certificate that moves with the agents."""

import json
import math

import numpy as np
import pytest
from safetensors.numpy import save_file

from hjrno_ros.core import least_restrictive
from hjrno_ros.core.grids import GridSpec
from hjrno_ros.core.tracked_agents import (
    AgentCertificate,
    Agents,
    AgentTable,
    read_agent_table,
    relative_states,
    with_agents,
)

GRID = GridSpec((-3.0, -3.0, -1.0, -math.pi), (3.0, 3.0, 1.0, math.pi), (31, 31, 5, 8), (3,))
RADIUS, CAP = 0.45, 1.0


def distance_table(speeds=(0.0, 0.5, 1.0)) -> AgentTable:
    """Tables holding the distance to the contact disk, less 0.1 m per agent speed level (a value falls with the
    agent's speed)."""
    x, y = np.meshgrid(*GRID.axes()[:2], indexing="ij")
    d = np.hypot(x, y) - RADIUS
    values = np.stack([np.broadcast_to((d - 0.1 * k)[..., None, None], GRID.shape) for k in range(len(speeds))])
    return AgentTable(GRID, tuple(speeds), values, RADIUS, CAP, 0.3, (0.02, 0.02), {})


def one(table: AgentTable, relative, speed: float, radius: float) -> np.ndarray:
    """W against one agent at relative states ``(n, 4)``."""
    return table.value(np.asarray(relative, float)[None], np.array([speed]), np.array([radius]))[0]


def agents(positions, velocities, radius=0.2, received=0.0) -> Agents:
    k = len(positions)
    return Agents(np.array(positions, float).reshape(k, 2), np.array(velocities, float).reshape(k, 2),
                  np.full(k, radius), received)


def test_relative_states_put_the_agent_at_the_origin_moving_along_x():
    robot = np.array([[1.0, 3.0, 0.5, math.pi / 2], [0.0, -2.0, 0.0, 1.0]])
    rel = relative_states(robot, np.array([[1.0, 2.0], [0.0, 0.0]]), np.array([[0.0, 0.8], [0.0, 0.0]]))
    assert rel.shape == (2, 2, 4)
    np.testing.assert_allclose(rel[0, 0], [1.0, 0.0, 0.5, 0.0], atol=1e-12)  # walking along +y
    np.testing.assert_allclose(rel[1, 1], [0.0, -2.0, 0.0, 1.0], atol=1e-12)  # at rest: the map's axes


def test_table_value_takes_the_margin_the_cap_and_the_speed_level():
    table = distance_table()
    rel = np.array([[1.0, 0.0, 0.5, 0.0]])
    w0 = one(table, rel, 0.0, RADIUS)[0]
    assert w0 == pytest.approx(1.0 - RADIUS - table.margin, abs=1e-9)
    assert one(table, rel, 0.6, RADIUS)[0] == pytest.approx(w0 - 0.1, abs=1e-9)  # nearest level: 0.5 m/s
    assert one(table, rel, 0.0, RADIUS + 0.2)[0] == pytest.approx(w0 - 0.2, abs=1e-9)  # a larger agent
    assert one(table, rel, 0.0, RADIUS - 0.2)[0] == pytest.approx(w0, abs=1e-9)  # a smaller one: no credit
    assert one(table, [[2.9, 0.0, 0.5, 0.0]], 0.0, RADIUS)[0] == CAP  # capped
    assert one(table, [[7.0, 0.0, 0.5, 0.0]], 0.0, RADIUS)[0] == CAP  # beyond the box
    assert one(table, rel, 1.3, RADIUS)[0] == -math.inf  # faster than the tables: not vouched for
    inside = np.array([[0.1, 0.0, 0.0, 0.0], [0.1, 0.0, 0.3, 0.0]])  # in contact: at rest, and moving
    np.testing.assert_allclose(one(table, inside, 0.0, RADIUS), [0.02, 0.1 - RADIUS - table.margin])


def test_the_certificate_is_the_least_of_static_and_agents_and_moves_with_them():
    table = distance_table()
    people = agents([[1.5, 0.0]], [[-1.0, 0.0]])  # walking at the robot along -x
    static = lambda s: np.full(s.shape[:-1], 5.0)  # noqa: E731 - an open floor
    cert = with_agents(static, table, people, footprint=0.25, at=0.0)
    robot = np.array([[0.0, 0.0, 0.5, 0.0]])  # moving
    now, later = cert(robot)[0], least_restrictive.at_time(cert, 1.0)(robot)[0]
    assert now < 5.0 and later == pytest.approx(now - 1.0, abs=1e-6)  # the person came 1 m closer
    assert with_agents(static, table, agents([], []), 0.25, 0.0) is static
    assert with_agents(static, None, people, 0.25, 0.0) is static
    old = AgentCertificate(static, table, people, 0.25, age=0.5)  # data 0.5 s old: predicted, less δ·age
    assert old(robot)[0] == pytest.approx(cert(robot)[0] - 0.5 - 0.3 * 0.5, abs=1e-6)


def test_the_filter_judges_a_command_against_where_the_agents_will_be():
    """A person 0.9 m ahead walking at the robot: driving on at 1 m/s is changed; from rest, backing away passes."""
    from hjrno_ros.core.dynamics import DiffDriveParams
    from hjrno_ros.core.safety_filter import FilterSettings

    params = DiffDriveParams(a_max=1.0, omega_max=2.0, v_min=-1.0, v_max=1.0)
    settings = FilterSettings(epsilon=0.0, mode="least_restrictive", dt=0.05)
    static = lambda s: np.full(s.shape[:-1], 5.0)  # noqa: E731
    cert = with_agents(static, distance_table(), agents([[0.9, 0.0]], [[-0.5, 0.0]]), 0.25, 0.0)
    toward = least_restrictive.decide(params, settings, cert, np.array([0.0, 0.0, 1.0, 0.0]), 1.0, 0.0)
    away = least_restrictive.decide(params, settings, cert, np.zeros(4), -0.5, 0.0)
    assert toward.intervened and toward.linear < 1.0
    assert not away.intervened and away.linear == -0.5


def write_table(stem, values, speeds=(0.0, 0.5), **changes):
    save_file({"values": values}, f"{stem}.safetensors")
    import hashlib

    card = {"kind": "agent_relative", "grid": {"lo": list(GRID.lo), "hi": list(GRID.hi), "shape": list(GRID.shape),
                                               "periodic": [3]},
            "agent_speeds": list(speeds), "cap": CAP, "radius": RADIUS, "deviation": 0.3,
            "values_sha256": hashlib.sha256(open(f"{stem}.safetensors", "rb").read()).hexdigest(),
            "v_tol": 0.02, "rest_value": 0.02, "robot": {"a_max": 1.0, "v_max": 1.0}, **changes}
    with open(f"{stem}.json", "w") as f:
        json.dump(card, f)


def test_read_agent_table_refuses_bad_files_with_one_line(tmp_path):
    stem = tmp_path / "agents"
    good = np.zeros((2, *GRID.shape), np.float32)
    write_table(stem, good)
    assert read_agent_table(stem).speeds == (0.0, 0.5)
    cases = {"another file": lambda: save_file({"values": good + 1}, f"{stem}.safetensors"),
             "NaN": lambda: write_table(stem, np.full_like(good, np.nan)),
             "shape": lambda: write_table(stem, good[:1]),
             "speeds": lambda: write_table(stem, good, speeds=(0.2, 0.5)),
             "kind": lambda: write_table(stem, good, kind="model"),
             "missing": lambda: (stem.with_suffix(".safetensors").unlink(), None)}
    for name, spoil in cases.items():
        write_table(stem, good)
        spoil()
        with pytest.raises(ValueError) as err:
            read_agent_table(stem)
        assert "\n" not in str(err.value) and str(stem.name) in str(err.value), name


def test_the_lookup_is_scipys_multilinear_interpolation():
    from hjrno_ros.core.value_table import ValueTable

    rng = np.random.default_rng(3)
    values = rng.normal(size=(2, *GRID.shape))
    table = AgentTable(GRID, (0.0, 0.5), values, RADIUS, CAP, 0.3, (0.02, 0.02), {})
    states = rng.uniform([-3.0, -3.0, -1.0, -7.0], [3.0, 3.0, 1.0, 7.0], (200, 4))  # headings beyond ±π wrap
    for k in range(2):
        ours = table._lookup(np.full(200, k), states, states[:, 2]) + table.margin
        scipy_values = ValueTable(GRID, values[k]).value_and_gradient(states)[0]  # scipy's interpolator
        np.testing.assert_allclose(ours, scipy_values, atol=1e-9)
