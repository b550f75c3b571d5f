"""A scan source with ``track_people``: a walker seen in its LaserScans becomes a tracked agent, whose returns keep
no motion margin; what the tracker does not vouch for keeps it; its parameters and refusals."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")

from sensor_msgs.msg import LaserScan  # noqa: E402

from hjrno_ros.core.tracked_agents import read_agent_table  # noqa: E402
from hjrno_ros.ros.brt_node.config import NodeConfig  # noqa: E402
from hjrno_ros.ros.brt_node.observation_sources import (  # noqa: E402
    ObservationSource,
    SourceConfig,
    fresh_agents,
    live_obstacles,
    lost_agents,
    update_trackers,
)
from hjrno_ros.ros.brt_node.parameters import PARAMETERS  # noqa: E402
from hjrno_ros.ros.brt_node.value_sources import load_agent_table  # noqa: E402

ROOT = Path(__file__).resolve().parents[3]
BEAMS = 360
POSTS = [((-2.0, y), 0.05) for y in np.arange(-1.0, 1.01, 0.05)]  # a 2 m row of posts the map lacks: no person


def scan_at(t: float, disks) -> LaserScan:
    """A 1° LaserScan from the origin at stamp ``t`` s of the ``disks`` (centre, radius): each beam's nearest hit."""
    angles = -math.pi + np.arange(BEAMS) * 2 * math.pi / BEAMS
    d = np.stack([np.cos(angles), np.sin(angles)], -1)
    ranges = np.full(BEAMS, math.inf)
    for centre, r in disks:
        b = d @ np.asarray(centre)
        disc = b * b - (np.dot(centre, centre) - r * r)
        ranges = np.minimum(ranges, np.where((disc >= 0) & (b > 0), b - np.sqrt(np.maximum(disc, 0)), math.inf))
    msg = LaserScan()
    msg.header.frame_id = "laser"
    msg.header.stamp.sec, msg.header.stamp.nanosec = int(t), int(round((t % 1) * 1e9))
    msg.angle_min, msg.angle_increment = -math.pi, 2 * math.pi / BEAMS
    msg.range_min, msg.range_max = 0.05, 10.0
    msg.ranges = [float(r) for r in ranges]
    return msg


def tracking_scan(**values) -> ObservationSource:
    cfg = SourceConfig.build("scan", {"type": "scan", "track_people": True, **values})
    assert isinstance(cfg, SourceConfig), cfg
    return ObservationSource(cfg, read_agent_table(ROOT / "models" / "agents_jackal"))


def test_a_walker_in_the_scans_becomes_an_agent_and_only_its_returns_lose_the_margin():
    source = tracking_scan()
    here = lambda _: (0.0, 0.0, 0.0)  # noqa: E731 - the robot at the origin
    nothing = lambda pts: np.full(len(pts), 9.0)  # noqa: E731 - no static obstacle near
    for k in range(6):
        t = 10.0 + 0.1 * k
        source.on_message(scan_at(t, [((2.0, -1.0 + 0.5 * (t - 10.0)), 0.2), *POSTS]))
        update_trackers([source], time.monotonic(), here, nothing)
    now = time.monotonic()
    agents, reason = fresh_agents([source], now, "map")
    assert reason == "" and len(agents) == 1 and agents.received == source.current.received
    assert agents.velocities[0] == pytest.approx([0.0, 0.5], abs=0.1)
    assert agents.positions[0] == pytest.approx([2.0, -0.75], abs=0.1)
    assert fresh_agents([source], now, "map", scans=False) == (None, "")  # what live_obstacles is given
    obstacles, versions, reason = live_obstacles([source], now, "map", here, nothing, None, 1.0)
    kept, grown = obstacles
    assert reason == "" and versions == (6,) and (kept.approach, grown.approach) == (0.0, 1.0)
    assert len(kept.points) > 3 and np.all(np.linalg.norm(kept.points - agents.positions[0], axis=-1) < 0.5)
    assert len(grown.points) > 20 and np.all(grown.points[:, 0] < -1.5)  # the posts keep the motion margin
    assert source.status(now)["agents"] == 1 and source.status(now)["tracks"] == 1
    made_with = (source.current.version,)
    assert lost_agents([source], made_with, now) == ""
    assert "agents of 'scan', which are now stale" in lost_agents([source], made_with, now + 0.6)
    assert fresh_agents([source], now + 0.6, "map") == (None, "")  # stale: the scan's own check fails closed


def test_the_tracks_a_table_was_made_with_stay_agents_after_the_tracker_moves_on():
    """A table left a track's returns without the margin; if the next scan's fit no longer vouches for it, the
    command path still judges against it until a table made without it serves."""
    source = tracking_scan()
    here, nothing = (lambda _: (0.0, 0.0, 0.0)), (lambda pts: np.full(len(pts), 9.0))
    for k in range(6):
        source.on_message(scan_at(10.0 + 0.1 * k, [((2.0, -1.0 + 0.05 * k), 0.2)]))
        update_trackers([source], time.monotonic(), here, nothing)
    held = (source.tracked[1],)
    assert len(held[0]) == 1
    source.on_message(scan_at(10.6, [((2.0, -0.45), 0.2)]))  # a jump of 0.2 m: no steady walk fits
    update_trackers([source], time.monotonic(), here, nothing)
    now = time.monotonic()
    assert len(fresh_agents([source], now, "map")[0]) == 0
    agents, _ = fresh_agents([source], now, "map", held=held)
    assert len(agents) == 1 and agents.positions[0] == pytest.approx(held[0].positions[0])


def test_a_new_walker_keeps_the_margin_until_confirmed():
    source = tracking_scan()
    here, nothing = (lambda _: (0.0, 0.0, 0.0)), (lambda pts: np.full(len(pts), 9.0))
    for k in range(2):
        source.on_message(scan_at(5.0 + 0.1 * k, [((1.5, 0.1 * k), 0.2)]))
        update_trackers([source], time.monotonic(), here, nothing)
    now = time.monotonic()
    assert len(fresh_agents([source], now, "map")[0]) == 0
    kept, grown = live_obstacles([source], now, "map", here, nothing, None, 1.0)[0]
    assert len(kept.points) == 0 and len(grown.points) > 3


def test_track_people_is_for_scans_and_needs_the_agent_tables():
    assert "track_people is for scan sources" in SourceConfig.build("c", {"type": "costmap", "track_people": True})
    assert SourceConfig.build("s", {}).track_people is False
    cfg = NodeConfig.build({name: spec.default for name, spec in PARAMETERS.items()} | {"observation_sources": ["s"]},
                           startup=True, sources={"s": {"track_people": True}})
    assert isinstance(cfg, NodeConfig), cfg
    with pytest.raises(ValueError, match="track_people needs the agent_table parameter"):
        load_agent_table(cfg, None)
