"""brt_node on a real map over DDS: Nav2's depot map, careless drivers, the simulated base in real time.

``hjrno bench depot`` (hjrno_ros.tools.depot_check) at CI size: 12 episodes of 6 s against one brt_node
process (bundled model), the four drivers in turn (straight at an obstacle, straight at the map's edge,
goal-seeking, goal-seeking to a goal beyond the map's edge), starts at rest ≥ 0.5 m from obstacles.
Targets: 0 collisions and 0 exits from the map.  The ≥ 200-episode run is committed in
benchmarks/results/depot.{md,json}.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")

from hjrno_ros.core.map_file import load_map  # noqa: E402
from hjrno_ros.tools import depot_check  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
DEPOT = ROOT.parent / "shared" / "maps" / "depot.yaml"  # CI has ../shared beside the clone
EPISODES, SECONDS = 12, 6.0

pytestmark = [pytest.mark.skipif(not DEPOT.is_file(), reason="../shared/maps/depot.yaml not beside the checkout"),
              pytest.mark.real_time]  # the depot over DDS in real time (test/conftest.py)


def test_episode_plan_starts_in_free_space_and_aims_at_trouble():
    world = depot_check.DepotWorld(load_map(DEPOT))
    plan = depot_check.draw_episodes(world, 40, seed=0)
    assert [e["driver"] for e in plan[:4]] == list(depot_check.DRIVERS)
    starts = np.array([e["start"] for e in plan])
    assert np.all(world.clearance(starts[:, :2]) >= depot_check.CLEARANCE - 1e-9) and np.all(starts[:, 2] == 0)
    for e in plan:
        xy, theta = np.array(e["start"][:2]), e["start"][3]
        ray = xy + np.linspace(0, 40, 4000)[:, None] * [np.cos(theta), np.sin(theta)]
        if e["driver"] in ("straight", "edge"):  # a straight line from the start ends in an obstacle or off the map
            assert world.crosses_obstacle(xy, ray[-1])
        if e["driver"] == "edge":
            assert abs(theta) in (0.0, np.pi, np.pi / 2)
        if e["driver"] == "goal":
            assert len(e["goals"]) == depot_check.GOALS
            assert np.all(world.clearance(np.array(e["goals"])) >= depot_check.CLEARANCE - 1e-9)
        if e["driver"] == "goal_off_map":
            assert world.edge_distance(np.array(e["goals"]))[0] == pytest.approx(-depot_check.BEYOND_EDGE)
    # exact clearance: zero inside an obstacle cell, negative beyond the edge, a cell's half-width next to one
    cell = world.obstacle_cells[len(world.obstacle_cells) // 2]
    assert world.clearance(world.centre(cell)[None])[0] == 0.0
    assert world.clearance(np.array([[-0.3, 5.0]]))[0] == pytest.approx(-0.3)


def test_depot_episodes_over_dds_do_not_collide_or_leave_the_map(tmp_path):
    run = subprocess.run([sys.executable, "-m", "hjrno_ros.cli", "bench", "depot", "--episodes", str(EPISODES),
                          "--seconds", str(SECONDS), "--out", str(tmp_path)], capture_output=True, text=True,
                         timeout=420, cwd=ROOT)
    result_file = tmp_path / "depot.json"
    assert result_file.is_file(), run.stdout[-3000:] + run.stderr[-3000:]
    result = json.loads(result_file.read_text())
    totals, rows = result["totals"], result["episodes"]
    assert totals["episodes"] == len(rows) == EPISODES
    assert {r["driver"] for r in rows} == set(depot_check.DRIVERS)
    assert all(r["commands"] > 0 for r in rows)  # every episode drove against the node
    assert (tmp_path / "depot.md").read_text().startswith("# Depot map check")
    report = (f"{totals['collisions']} collisions, {totals['exits']} exits in {EPISODES} episodes; per driver: "
              + json.dumps({d: (b["collisions"], b["exits"]) for d, b in result["per_driver"].items()})
              + "; collided: " + json.dumps([{k: r[k] for k in ("episode", "driver", "start", "start_value_m")}
                                             for r in rows if r["collision"]]))
    print(report)
    assert totals["exits"] == 0, report
    assert totals["collisions"] == 0, report
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
