"""Navigation in IR-SIM (studies/navigation.py, studies/path_follower.py, tools/nav_bench.py): the Nav2-like
follower, the drivers and the benchmark's rows, in lockstep and with brt_node over DDS in real time."""

import json
import math

import numpy as np
import pytest

from hjrno_ros.studies import navigation as nav
from hjrno_ros.studies.path_follower import Grid2D, RegulatedPurePursuit, plan
from hjrno_ros.tools import nav_bench


@pytest.fixture(scope="module")
def plan_map():
    return nav.floor_plan_map(nav_bench.PLAN_SEEDS[0])


def test_a_held_out_plan_is_a_closed_map(plan_map):
    assert plan_map.obstacles.shape == (400, 400) and plan_map.resolution == nav.RESOLUTION
    assert plan_map.obstacles[0].all() and plan_map.obstacles[-1].all()  # the map's edge is solid
    assert 0.05 < plan_map.obstacles.mean() < 0.8


def test_the_planner_keeps_the_footprint_off_walls_and_the_follower_turns_in_place(plan_map):
    robot = nav.ROBOTS["jackal"]
    episode = nav.draw_episodes(plan_map, robot, 1, 2, seed=3)[0]
    grid = Grid2D(plan_map.obstacles, plan_map.origin, plan_map.resolution)
    path = plan(grid, np.array(episode.start[:2]), np.array(episode.goals[0]), robot.radius)
    assert path is not None and np.linalg.norm(path[-1] - episode.goals[0]) < 1e-9
    clearance = plan_map.clearance(plan_map.sd)
    assert clearance(path).min() > robot.radius - plan_map.resolution
    follower = RegulatedPurePursuit(path, robot.v_max, robot.omega_max, clearance)
    heading = math.atan2(*(path[min(12, len(path) - 1)] - path[0])[::-1])
    linear, angular = follower.command(np.array([*path[0], heading + math.pi]))  # facing away from the path
    assert linear == 0.0 and abs(angular) == pytest.approx(1.8)  # rotate to heading, as RPP does
    linear, angular = follower.command(np.array([*path[0], heading]))
    assert 0.0 < linear <= robot.v_max and abs(angular) <= robot.omega_max


def test_goal_driver_interrupts_with_spins_and_reversing(plan_map):
    robot = nav.ROBOTS["turtlebot3"]
    episode = nav.draw_episodes(plan_map, robot, 1, 2, seed=1)[0]
    driver = nav.GoalDriver("careless", plan_map, robot, episode, interrupt_every=5.0)
    pose = np.array(episode.start)
    assert driver(pose, 4.5) == (0.0, robot.omega_max)  # the first interruption: a spin
    assert driver(pose, 9.5) == (robot.v_min, 0.0)  # the second: backing up
    assert driver(pose, 2.0)[0] >= 0.0


def test_a_follower_that_senses_replans_around_what_it_sees_once_a_second(plan_map):
    robot = nav.ROBOTS["jackal"]
    episode = nav.draw_episodes(plan_map, robot, 1, 2, seed=3)[0]
    blind = nav.GoalDriver("follower", plan_map, robot, episode)
    path = blind.paths[0]
    middle = path[len(path) // 2]  # a person standing on the middle of the planned path: a ring of returns
    ring = middle + 0.2 * np.stack([np.cos(np.linspace(0, 2 * np.pi, 24)), np.sin(np.linspace(0, 2 * np.pi, 24))], -1)
    seen = []
    sensing = nav.GoalDriver("follower", plan_map, robot, episode, sensed=lambda: seen.append(1) or ring)
    start = np.array(episode.start)
    sensing(start, 0.0)
    replanned = sensing.paths[0]
    assert len(seen) == 1 and replanned is not path and np.linalg.norm(replanned[-1] - episode.goals[0]) < 1e-9
    gap = np.linalg.norm(replanned[:, None] - ring[None], axis=-1).min()
    assert gap > robot.radius  # the new path keeps the footprint off what was sensed; the old one ran through it
    assert np.linalg.norm(path[:, None] - ring[None], axis=-1).min() < robot.radius
    sensing(start, 0.5)
    assert len(seen) == 1  # not again within the second
    sensing(start, 1.0)
    assert len(seen) == 2
    assert blind.sensed is None and blind(start, 0.0) is not None  # without sensing: the plan made at the start


@pytest.mark.real_time
def test_nav_bench_rows_lockstep_and_over_dds(tmp_path):
    """One short careless episode per filter on a held-out plan with the Jackal: the benchmark's rows, the learned
    filter in process and brt_node over DDS never collide, and the node never fails closed."""
    rc = nav_bench.run(tmp_path, episodes=1, robots=("jackal",), maps=(f"plan{nav_bench.PLAN_SEEDS[0]}",),
                       drivers=("careless",), filters=("none", "stop_zone", "learned", "brt_node"), seconds=15.0,
                       progress=lambda m: None)
    report = json.loads((tmp_path / "nav.json").read_text())
    rows = {r["filter"]: r for r in report["rows"]}
    assert set(rows) == {"none", "stop_zone", "learned", "brt_node"} and rc == 0
    for name in ("learned", "brt_node"):
        assert rows[name]["collisions"] == 0 and rows[name]["episodes"] == 1
    assert rows["brt_node"]["loop"] == "DDS, real time" and rows["brt_node"]["fail_closed_share"] == 0
    assert "| brt_node |" in (tmp_path / "nav.md").read_text()


def test_prediction_deviation_is_zero_for_steady_walkers_and_the_jump_for_a_turn():
    from hjrno_ros.tools.pedestrian_motion import prediction_deviation

    t = np.arange(21) * 0.05
    steady = np.stack([t, 0 * t], -1)[:, None]  # (T, 1, 2): 1 m/s along x
    u = np.broadcast_to([1.0, 0.0], steady.shape)
    assert prediction_deviation(steady, u, 0.05, 0.5).max() == pytest.approx(0.0, abs=1e-12)
    back = np.where(t[:, None, None] <= 0.5, steady, 2 * steady[10] - steady)  # turns back at 0.5 s
    u_back = np.where(t[:, None, None] < 0.5, u, -u)
    d = prediction_deviation(back, u_back, 0.05, 0.5)
    assert 1.5 < d.max() <= 2.0  # a turn back: up to the whole 2 m/s change


def test_accelerations_count_walking_steps_only_and_see_a_turn_back_at_once():
    from hjrno_ros.tools.pedestrian_motion import accelerations

    u = np.zeros((6, 2, 2))
    u[1:3, 0] = [1.0, 0.0]  # walker 0 starts at once, walks a step, turns back at once
    u[3:, 0] = [-1.0, 0.0]  # walker 1 stands throughout: none of its steps count
    a = accelerations(u, 0.05)
    assert a.size == 5 and sorted(a.round(6)) == [0.0, 0.0, 0.0, 20.0, 40.0]
