"""``hjrno bench tracker`` short: the laser tracker against IR-SIM's walkers, lockstep; its rows and files."""

import json

import pytest

pytest.importorskip("irsim")

from hjrno_ros.tools import tracker_bench  # noqa: E402


def test_the_tracker_knows_most_walkers_in_view_and_their_velocities(tmp_path):
    row = tracker_bench.measure("plan1000001", episodes=1, seconds=15.0)
    assert row["people_in_view"] > 20
    assert row["vouched_share"] > 0.7  # most walkers in view are agents; the rest keep the motion margin
    assert row["velocity_error_p50"] < 0.15 and row["position_error_p95"] < 0.15
    assert row["deviation"] == 0.3 and 0 <= row["over_deviation_share"] < 0.2


def test_the_tracker_bench_writes_its_table_and_json(tmp_path):
    assert tracker_bench.run(tmp_path, episodes=1, maps=("plan1000001",), progress=lambda m: None, seconds=10.0) == 0
    report = json.loads((tmp_path / "tracker.json").read_text())
    assert [r["map"] for r in report["rows"]] == ["plan1000001"]
    assert "| plan1000001 | 1 |" in (tmp_path / "tracker.md").read_text()
