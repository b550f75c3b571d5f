"""A person steps in front of a moving robot, over real DDS in real time: IR-SIM's Jackal-sized differential drive
drives straight for a goal 9 m away at up to 1 m/s (a careless driver, blind to people), a pedestrian (IR-SIM's
social-force walker, 1 m/s) crosses its path 3 m ahead, timed so that the driver alone runs into them at 1 m/s, and
brt_node (its own process, the bundled default, the
static map plus IR-SIM's LiDAR as a ``scan`` source at 10 Hz, ``obstacle_speed_max`` 1 m/s; ``tracking``: the
scan source follows people on its returns, as agents of the Jackal's relative value tables; ``agents``: also the
walker as a tracked agent, its true position and velocity at 10 Hz)
filters the commands. The robot never moves into the person (IR-SIM's own collision check), and it still gets on
with its way."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("irsim")

from dds_driver import ROOT  # noqa: E402

from hjrno_ros.studies import navigation as nav  # noqa: E402

MOVING = 0.02  # m/s: a contact at a speed above this is the robot's doing
STEP, SCAN_EVERY = 0.05, 2  # s, and steps between scans: 10 Hz


def room() -> nav.NavMap:
    """12 m × 8 m at 0.05 m, walled, empty inside: the static map knows nothing of the person."""
    obstacles = np.zeros((240, 160), bool)
    obstacles[:2], obstacles[-2:], obstacles[:, :2], obstacles[:, -2:] = True, True, True, True
    return nav.NavMap("room", obstacles, (0.0, 0.0), 0.05)


@pytest.mark.parametrize("people", ["none", "tracking", "agents"],
                         ids=["scan", "scan_tracking_people", "scan_and_tracked_agents"])
def test_a_person_stepping_in_front_is_not_hit_and_the_robot_goes_on(people):
    from hjrno_ros.ros.harness.irsim_base import drive, episode_result, irsim_base
    from hjrno_ros.studies.irsim_world import DiffDriveBase, IrSimWorld, Person
    from hjrno_ros.tools.nav_bench import node_params
    from hjrno_ros.tools.node_process import brt_node_process, free_domain

    nav_map, robot = room(), nav.ROBOTS["jackal"]
    episode = nav.Episode((1.5, 4.0, 0.0), ((10.5, 4.0),))
    person = Person(((4.5, 0.6), (4.5, 7.4)), speed=1.0)  # across the robot's line at x = 4.5 m, to and fro
    base_model = DiffDriveBase(robot.radius, robot.v_max, robot.v_min, robot.omega_max, robot.a_max, robot.alpha_max)

    def world_and_driver(lidar: bool) -> tuple[IrSimWorld, nav.GoalDriver]:
        return (IrSimWorld(nav_map.obstacles, nav_map.origin, nav_map.resolution, base_model, episode.start, STEP,
                           lidar=lidar, people=(person,)),
                nav.GoalDriver("careless", nav_map, robot, episode, 0.0, nav_map.sd))

    world, driver = world_and_driver(lidar=False)
    try:  # the same episode without the filter (lockstep): the driver runs into the person
        alone = nav.run_episode(world, driver, nav.no_filter, robot, 20.0, STEP)
        assert alone.collided and world.contact_speed > MOVING, (alone.collision_time, world.contact_speed)
    finally:
        world.close()
    world, driver = world_and_driver(lidar=True)
    domain = free_domain()
    params = {**node_params(robot), "observation_sources": "[scan]", "obstacle_speed_max": 1.0}
    tracked = people == "agents"
    if tracked:
        params |= {"observation_sources": "[scan, people]", "people.type": "agents", "people.topic": "tracked_agents",
                   "agent_table": "agents_jackal"}
    if people == "tracking":
        params |= {"scan.track_people": True, "agent_table": "agents_jackal"}

    def ready(log) -> bool:
        at = log.status.get("robot") or {}
        return (log.status.get("state") not in (None, "fail_closed") and abs(at.get("x", 1e9) - 1.5) < 1e-3
                and "scan" in log.status.get("observation_sources", {}))

    try:
        with brt_node_process(domain, params, ROOT / "models" / "default") as (proc, tail):
            base = drive(domain, lambda context: irsim_base(world, nav_map, driver, STEP, context=context,
                                                            scan_every=SCAN_EVERY,
                                                            agents_every=SCAN_EVERY if tracked else 0),
                         20.0, ready, timeout=90.0)
            assert proc.poll() is None, tail()
        result = episode_result(base)
        moved_into = result.collided and (world.contact_speed is None or world.contact_speed > MOVING)
        assert not moved_into, (world.contact_speed, result.collision_time, base.log.status)
        trace = result.trace  # (t, x, y, v, θ, changed)
        passed = trace[:, 1] > person.waypoints[0][0] + 1.0
        assert passed.any(), (trace[-1], world.people_positions)  # not frozen: beyond the person's line
        assert base.log.changed > 0  # the filter acted: the careless driver alone drives through the crossing
        assert world.min_people_clearance > 0.0 or not result.collided
    finally:
        world.close()
