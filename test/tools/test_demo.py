"""The README's main command: a Nav2-like follower in IR-SIM meets a box its map lacks, without a filter and with
brt_node over DDS."""

import json
import subprocess
import sys

import pytest

HJRNO = [sys.executable, "-m", "hjrno_ros.cli"]

pytestmark = pytest.mark.real_time  # runs a node over DDS in real time (test/conftest.py)


def test_demo_keeps_the_robot_safe_and_reports(tmp_path):
    run = subprocess.run([*HJRNO, "demo", "--seconds", "35", "--out", str(tmp_path)], capture_output=True,
                         text=True, timeout=600)
    assert run.returncode == 0, run.stdout + run.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    filtered, bare = summary["with_brt_node"], summary["without_filter"]
    assert filtered["collided"] is False and bare["collided"] is True
    assert filtered["goals_reached"] >= 1 and filtered["distance_m"] > 8.0  # it goes on, round the box
    assert filtered["latency_ms_p50"] is not None and filtered["value_grids"] > 0
    assert filtered["model"] == "default" and "goals_reached" in run.stdout
    for name in ("demo.png", "demo.gif"):
        assert (tmp_path / name).stat().st_size > 10_000


def test_demo_without_filter_exits_nonzero(tmp_path):
    """Its follower, planning on a map without the box, hits the box in IR-SIM on its own (lockstep): the demo
    shows a real save, and without the filter it exits 1."""
    run = subprocess.run([*HJRNO, "demo", "--no-filter", "--seconds", "10", "--no-gif", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 1, run.stdout + run.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    bare = summary["without_filter"]
    assert bare["collided"] is True and 0 < bare["collision_time_s"] < 10.0 and bare["goals_reached"] == 0
    assert "with_brt_node" not in summary
