"""Closed loop (studies/closed_loop.py): the ground-truth filter keeps a careless driver out of a real solve's
obstacle."""

import sys

import numpy as np
import pytest

from hjrno_ros.core.dynamics import CarParams
from hjrno_ros.core.safety_filter import FilterSettings, filter_batch
from hjrno_ros.core.value_table import ValueTable
from hjrno_ros.studies import closed_loop
from hjrno_ros.studies.closed_loop import EpisodeSettings, World
from hjrno_ros.truth import problems
from hjrno_ros.truth.solver import solve

HJRNO = [sys.executable, "-m", "hjrno_ros.cli"]
PARAMS = CarParams()




@pytest.fixture(scope="module")
def disk_world():
    problem = problems.disk((32, 32, 9, 16))
    value, report = solve(problem.dynamics, problem.grid, problem.target)
    assert report.converged
    return World("disk", tuple(problem.shapes), ValueTable(problem.grid, value), problem.dynamics.params)


@pytest.mark.parametrize("mode", ["switch", "qp"])
def test_ground_truth_filter_prevents_the_collisions_of_the_careless_driver(disk_world, mode):
    settings = EpisodeSettings(duration=12.0)
    episodes = closed_loop.draw_episodes(disk_world, 40, settings, seed=3)
    assert np.all(disk_world.truth.value(episodes.starts) >= settings.start_margin)
    table = disk_world.truth
    hj = lambda s, nominal: filter_batch(PARAMS, FilterSettings(epsilon=0.1, mode=mode), s,  # noqa: E731
                                         table.value(s), table.gradient(s), nominal)
    free = closed_loop.run_episodes(disk_world, episodes, None, settings)
    safe = closed_loop.run_episodes(disk_world, episodes, hj, settings, trace=True)
    assert (free["outcome"] == "collision").sum() >= 3
    assert (safe["outcome"] == "collision").sum() == 0
    assert np.all(safe["min_clearance"] > 0)
    row = closed_loop.summarize([safe])
    assert 0 < row["intervention_rate"] < 0.5 and row["goals_reached"] > 0
    path = safe["trace"][0]
    assert path.shape == (241, 40, 4) and np.isnan(path[-1]).any() == (safe["steps"] < 240).any()
