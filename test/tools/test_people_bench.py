"""``hjrno bench people`` end to end, short: IR-SIM pedestrians, the stop-zone baseline in lockstep and brt_node
with tracked agents over real DDS; the rows it writes and the safety it claims."""

import json

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("irsim")

from hjrno_ros.tools import people_bench  # noqa: E402


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
    with pytest.raises(ValueError, match="filters"):
        people_bench.run(tmp_path, filters=("magic",))
