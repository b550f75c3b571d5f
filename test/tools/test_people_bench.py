"""``hjrno bench people`` end to end, short: IR-SIM pedestrians, the stop-zone baseline in lockstep and brt_node
with tracked agents over real DDS; the rows it writes and the safety it claims."""

import json

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("irsim")

from hjrno_ros.tools import people_bench  # noqa: E402


@pytest.mark.real_time
def test_people_bench_rows_and_no_moving_contact_with_tracked_agents(tmp_path):
    rc = people_bench.run(tmp_path, episodes=1, seconds=12.0, filters=("stop_zone", "brt_node+agents"),
                          progress=lambda m: None)
    report = json.loads((tmp_path / "people.json").read_text())
    rows = {(r["driver"], r["filter"]): r for r in report["rows"]}
    assert set(rows) == {(d, f) for d in ("follower", "careless") for f in ("stop_zone", "brt_node+agents")}
    assert rc == 0
    for driver in ("follower", "careless"):
        tracked = rows[(driver, "brt_node+agents")]
        assert tracked["collisions_moving"] == 0 and tracked["episodes"] == 1
        assert tracked["fail_closed_share"] < 0.05  # ready before the episode starts: no stale source on the way
    assert rows[("follower", "brt_node+agents")]["goals_without_people"] >= 1  # the follower gets going
    assert "| brt_node+agents |" in (tmp_path / "people.md").read_text()
    assert rows[("follower", "brt_node+agents")]["scan_timeout"] == 0.5  # the node's scan source, at its default
    assert rows[("follower", "stop_zone")]["scan_timeout"] is None  # no node, no scan source
    assert {r["after_rest_contact"] for r in rows.values()} == {"continue"}  # people walk on by default
    assert report["model"] == "models/default"  # no machine's path in a results file
    assert people_bench.results_stem("turtlebot3", "depot") == "people_turtlebot3_depot"
    assert people_bench.results_stem("jackal", people_bench.DEFAULT_MAP) == "people"
    with pytest.raises(ValueError, match="filters"):
        people_bench.run(tmp_path, filters=("magic",))
    with pytest.raises(ValueError, match="depot or planSEED"):
        people_bench.run(tmp_path, map_name="atlantis")
    with pytest.raises(ValueError, match="drivers"):
        people_bench.run(tmp_path, drivers=("magic",))
    with pytest.raises(ValueError, match="after_rest_contact"):
        people_bench.run(tmp_path, after_rest_contact="pause")


def test_rows_count_people_who_walked_on_as_contacts_at_rest_and_crashes_by_speed():
    from hjrno_ros.studies import navigation as nav

    def episode(collided: bool, reached: list[float]) -> nav.EpisodeResult:
        return nav.EpisodeResult(collided, 5.0 if collided else None, reached, 3, 200, 40, 0, 0, np.zeros((0, 6)))

    Run = people_bench.PeopleRun
    with_people = [Run(episode(False, [10.0, 20.0]), None, -0.3, 0.4, 2),  # two walked into it at rest, walked on
                   Run(episode(True, [12.0]), 0.6, -0.01, -0.01, 0),  # drove into someone at 0.6 m/s
                   Run(episode(True, []), 0.0, -0.02, np.inf, 0)]  # bumped at rest, the episode ended (end)
    without = [Run(episode(False, [8.0, 16.0, 24.0]), None, np.inf, np.inf, 0)] * 3
    row = people_bench.summarize("follower", "brt_node", with_people, without)
    assert (row["collisions_moving"], row["collisions_stopped"]) == (1, 3)
    assert (row["min_gap_to_people_m"], row["min_gap_moving_m"]) == (-0.3, -0.01)
    assert (row["goals"], row["goals_without_people"]) == (3, 9)
    assert row["time_to_goal_vs_no_people"] == pytest.approx((20.0 + 12.0) / (16.0 + 8.0), abs=1e-3)


def test_walkers_on_the_route_turn_short_of_the_robots_goals_and_off_the_walls():
    from hjrno_ros.studies import navigation as nav

    open_floor = lambda points: np.full(len(points), 10.0)  # noqa: E731
    assert people_bench.turning_points((0.0, 0.0), (4.0, 0.0), open_floor) == ((1.0, 0.0), (3.0, 0.0))
    assert people_bench.turning_points((0.0, 0.0), (1.5, 0.0), open_floor) == ((0.5, 0.0), (1.0, 0.0))  # a third
    robot, plan = nav.ROBOTS["jackal"], nav.floor_plan_map(1000001)
    clearance = plan.clearance(plan.sd)
    for k, e in enumerate(nav.draw_episodes(plan, robot, 4, 3, 0)):
        walkers = people_bench.people_for(plan, robot, e, k)
        for person, ends in zip(walkers[:2], [(e.goals[0], e.start[:2]), (e.goals[-1], e.goals[0])], strict=True):
            for point, end in zip(person.waypoints, ends, strict=True):
                inward = np.linalg.norm(np.subtract(point, end))
                assert 0.0 < inward <= people_bench.TURN_SHORT + 1e-9, (k, point, end)  # off the goal, near it
                assert clearance(np.array([point]))[0] >= people_bench.WALKER_CLEARANCE
