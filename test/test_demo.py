"""The README's main command: brt_node (own process) + a simulated robot over real DDS."""

import json
import subprocess
import sys

import numpy as np

from hjrno_ros.core.geometry import union_sdf
from hjrno_ros.tools import demo

HJRNO = [sys.executable, "-m", "hjrno_ros.cli"]


def test_demo_world_goals_hide_behind_obstacles():
    shapes, occupancy, start, goals = demo.demo_world(0)
    assert occupancy.shape == (480, 480) and set(np.unique(occupancy)) == {0, 100}
    assert union_sdf(shapes, start[None, :2])[0] >= 1.0 and np.all(union_sdf(shapes, goals) >= 1.0)
    legs = np.vstack([start[:2], goals])
    for a, b in zip(legs[:-1], legs[1:], strict=True):  # a careless straight line would hit something
        assert union_sdf(shapes, a + np.linspace(0, 1, 50)[:, None] * (b - a)).min() <= 0


def test_demo_keeps_the_robot_safe_and_reports(tmp_path):
    run = subprocess.run([*HJRNO, "demo", "--seconds", "8", "--out", str(tmp_path)], capture_output=True,
                         text=True, timeout=600)
    assert run.returncode == 0, run.stdout + run.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["collided"] is False and summary["min_clearance_m"] > 0
    assert summary["commands"] > 100 and summary["distance_m"] > 2.0
    assert summary["latency_ms_p50"] is not None and summary["value_grids"] > 0
    assert summary["filter"].startswith("brt_node (default")
    for name in ("demo.png", "demo.gif"):
        assert (tmp_path / name).stat().st_size > 10_000


def test_demo_without_filter_collides_and_exits_nonzero(tmp_path):
    run = subprocess.run([*HJRNO, "demo", "--no-filter", "--seconds", "12", "--no-gif", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 1, run.stdout + run.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["collided"] is True and summary["filter"] == "none" and summary["min_clearance_m"] <= 0
