"""The ``agents`` observation source: tracked agents as a PointCloud2 (the harness's builder, parsed back), its
refusals, the fresh agents the node reads, scan returns at a tracked agent kept out of the motion margin, and the
IR-SIM harness's perfect tracker (over DDS)."""

from __future__ import annotations

import math
import os
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from sensor_msgs.msg import LaserScan, PointCloud2, PointField  # noqa: E402

from hjrno_ros.core.tracked_agents import Agents  # noqa: E402
from hjrno_ros.ros.brt_node.interfaces import SOURCE_SUBSCRIPTIONS  # noqa: E402
from hjrno_ros.ros.brt_node.observation_sources import (  # noqa: E402
    AGENT_MATCH,
    RETURN_DEPTH,
    SOURCE_TYPES,
    ObservationSource,
    SourceConfig,
    fresh_agents,
    live_obstacles,
    lost_agents,
    parse_agents,
)
from hjrno_ros.ros.harness.sim_base import agents_message  # noqa: E402

DOMAIN = 101 + os.getpid() % 50  # apart from the other DDS tests' domains
POSITIONS = np.array([[1.0, 2.0], [-3.5, 0.25], [0.0, -1.0]])
VELOCITIES = np.array([[0.5, 0.0], [0.0, -1.25], [0.0, 0.0]])
RADII = np.array([0.25, 0.3, 0.5])


def agents_source(name: str = "people", **values) -> ObservationSource:
    cfg = SourceConfig.build(name, {"type": "agents", **values})
    assert isinstance(cfg, SourceConfig), cfg
    return ObservationSource(cfg)


def test_the_harness_cloud_parses_back_in_every_float_layout():
    for dtype in ("<f4", ">f4", "<f8", ">f8"):
        msg = agents_message(POSITIONS, VELOCITIES, RADII, None, dtype=dtype)
        assert msg.is_bigendian == (dtype[0] == ">") and {f.datatype for f in msg.fields} == \
            {PointField.FLOAT64 if dtype[-1] == "8" else PointField.FLOAT32}
        positions, velocities, radii = parse_agents(msg, 0.2)
        assert positions == pytest.approx(POSITIONS) and velocities == pytest.approx(VELOCITIES)
        assert radii == pytest.approx(RADII)
    bare = agents_message(POSITIONS, VELOCITIES, None, None)  # no radius field: the source's agent_radius
    assert parse_agents(bare, 0.35)[2] == pytest.approx([0.35] * 3)
    flipped = agents_message(POSITIONS, VELOCITIES, RADII, None, dtype=">f4")
    flipped.is_bigendian = False  # the same bytes read little-endian are other numbers
    try:
        misread = parse_agents(flipped, 0.2)[0]
    except ValueError:  # as implausible numbers
        misread = None
    assert misread is None or not np.allclose(misread, POSITIONS)
    empty = agents_message(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), None)
    assert [a.shape for a in parse_agents(empty, 0.2)] == [(0, 2), (0, 2), (0,)]


def test_padded_points_and_rows_of_an_organised_cloud_are_read_by_their_steps():
    layout = np.dtype({"names": ["vy", "x", "y", "vx", "radius"], "formats": ["<f4", "<f8", "<f4", "<f4", "<f4"],
                       "offsets": [0, 8, 20, 24, 28], "itemsize": 36})  # other order, gaps, a float64
    points = np.zeros((2, 3), layout)  # height 2, width 3, each row padded by 8 bytes
    for name, column in (("x", [0, 1, 2, 3, 4, 5]), ("y", [10, 11, 12, 13, 14, 15]), ("vx", [1] * 6),
                         ("vy", [-1] * 6), ("radius", [0.2] * 6)):
        points[name] = np.reshape(column, (2, 3))
    msg = PointCloud2()
    msg.height, msg.width, msg.point_step, msg.row_step = 2, 3, 36, 3 * 36 + 8
    msg.fields = [PointField(name=n, offset=layout.fields[n][1], datatype=PointField.FLOAT64 if n == "x" else
                             PointField.FLOAT32, count=1) for n in layout.names]
    rows = np.zeros((2, msg.row_step), np.uint8)
    rows[:, :3 * 36] = points.view(np.uint8).reshape(2, -1)
    msg.data = rows.tobytes()
    positions, velocities, radii = parse_agents(msg, 0.5)
    assert positions == pytest.approx(np.stack([np.arange(6), 10 + np.arange(6)], -1))
    assert velocities == pytest.approx(np.tile([1.0, -1.0], (6, 1))) and radii == pytest.approx([0.2] * 6)


def malformed() -> dict[str, PointCloud2]:
    """Each refusal's cloud, named by the words its one line must hold."""
    good = lambda **kw: agents_message(kw.get("p", POSITIONS), kw.get("v", VELOCITIES),  # noqa: E731
                                       kw.get("r", RADII), None)
    out = {"no field": good(), "datatype 5": good(), "bytes": good(), "NaN or Inf": good(p=[[1, math.nan]] * 3),
           "at 11 m/s": good(v=[[11.0, 0.0]] * 3), "radius of 0": good(r=[0.0, 0.2, 0.2]),
           "6 m": good(r=[6.0, 0.2, 0.2]), "1001 points": good(p=np.zeros((1001, 2)), v=np.zeros((1001, 2)),
                                                                r=np.full(1001, 0.2))}
    out["no field"].fields = out["no field"].fields[:3]
    out["datatype 5"].fields[0].datatype = PointField.INT32
    out["bytes"].data = bytes(out["bytes"].data)[:-1]
    inf = good(v=[[0.0, math.inf]] * 3)
    out["NaN or Inf values"] = inf
    return out


def test_malformed_clouds_are_refused_with_one_line_and_the_last_good_agents_kept():
    source = agents_source(timeout=0.0)
    assert source.on_message(agents_message(POSITIONS, VELOCITIES, RADII, None, "map")) is None
    good = source.current
    assert good.agents.received == good.received and good.agents.positions == pytest.approx(POSITIONS)
    for rejected, (words, msg) in enumerate(malformed().items(), 1):
        problem = source.on_message(msg)
        assert problem is not None and words in problem and "\n" not in problem, (words, problem)
        assert problem.startswith("people: ") and source.rejected == rejected
        assert source.current is good
    status = source.status(time.monotonic())
    assert status["agents"] == 3 and status["rejected"] == len(malformed()) and status["type"] == "agents"
    assert source.on_message(agents_message(np.zeros((0, 2)), np.zeros((0, 2)), None, None, "map")) is None
    assert source.status(time.monotonic())["agents"] == 0  # an empty cloud: no agents, valid


def test_agents_sources_are_configured_subscribed_and_checked():
    assert "agents" in SOURCE_TYPES and set(SOURCE_SUBSCRIPTIONS) == set(SOURCE_TYPES)
    assert SOURCE_SUBSCRIPTIONS["agents"][0] is PointCloud2
    assert agents_source().config.agent_radius == 0.2
    assert agents_source(agent_radius=1).config.agent_radius == 1.0
    for bad in (0.0, 6.0, True, "x"):
        assert "agent_radius" in SourceConfig.build("people", {"type": "agents", "agent_radius": bad})


def test_fresh_agents_merges_the_fresh_sources_and_names_a_stale_or_foreign_one():
    now = time.monotonic()
    assert fresh_agents([], now, "map") == (None, "")
    front, back = agents_source("front", timeout=0.5), agents_source("back", timeout=0.5, required=False)
    assert "no data from observation source 'front'" in fresh_agents([front, back], now, "map")[1]
    front.on_message(agents_message(POSITIONS[:2], VELOCITIES[:2], RADII[:2], None, "map"))
    agents, reason = fresh_agents([front, back], time.monotonic(), "map")  # back: optional, never heard, left out
    assert reason == "" and len(agents) == 2 and agents.received == front.current.received
    time.sleep(0.01)
    back.on_message(agents_message(POSITIONS[2:], VELOCITIES[2:] + [[1.0, 0.0]], RADII[2:], None, "map"))
    agents, reason = fresh_agents([front, back], time.monotonic(), "map")
    later = back.current.received + 0.2  # each agent where its own data puts it, whenever predicted
    assert agents.received == front.current.received and agents.predicted(later - agents.received) == \
        pytest.approx(np.concatenate([POSITIONS[:2] + VELOCITIES[:2] * (later - front.current.received),
                                      POSITIONS[2:] + np.array([[1.0, 0.0]]) * 0.2]))
    stale = back.current.received + 0.6  # both stale: the required one is named, the optional one left out
    assert "observation source 'front' is" in fresh_agents([front, back], stale, "map")[1]
    assert fresh_agents([back], stale, "map") == (None, "")
    back.on_message(agents_message(POSITIONS, VELOCITIES, RADII, None, "odom"))
    agents, reason = fresh_agents([front, back], time.monotonic(), "map")
    assert agents is None and "'back' frame 'odom' != map frame 'map'" in reason


def test_a_table_made_with_agents_that_went_stale_is_not_used():
    """An optional agents source let the table leave its people without the motion margin: once it is stale, that
    table is refused (until the next one, made without it); a table made while it was silent is fine."""
    scan, people = ObservationSource(SourceConfig("scan", timeout=0.0)), agents_source(timeout=0.5, required=False)
    people.on_message(agents_message(POSITIONS, VELOCITIES, RADII, None, "map"))
    made_with, made_without = (1, people.current.version), (1, -1)
    now = time.monotonic()
    assert lost_agents([scan, people], made_with, now) == ""
    assert "agents of 'people', which are now stale" in lost_agents([scan, people], made_with, now + 0.6)
    assert lost_agents([scan, people], made_without, now + 0.6) == ""


def scan_msg(ranges: list[float]) -> LaserScan:
    msg = LaserScan()
    msg.header.frame_id = "laser"
    msg.angle_min, msg.angle_increment = -math.pi, 2 * math.pi / len(ranges)
    msg.range_min, msg.range_max = 0.05, 10.0
    msg.ranges = [float(r) for r in ranges]
    return msg


def test_returns_at_a_tracked_agent_keep_their_disks_and_the_others_the_motion_margin():
    scan, people = ObservationSource(SourceConfig("scan", timeout=0.0)), agents_source(timeout=0.0)
    scan.on_message(scan_msg([1.0, 3.0, math.inf, math.inf]))  # returns at (-1, 0) and (0, -3), off the map
    people.on_message(agents_message([[-1.5, -0.5]], [[0.5, 0.5]], [0.2], None, "map"))  # at (-1, 0) in 1 s
    nothing = lambda pts: np.full(len(pts), 9.0)  # noqa: E731 - no static obstacle near
    agents, _ = fresh_agents([scan, people], time.monotonic(), "map")

    def disks(agents: Agents | None, now: float) -> tuple[np.ndarray, np.ndarray]:
        obstacles, versions, reason = live_obstacles([scan, people], now, "map", lambda _: (0.0, 0.0, 0.0), nothing,
                                                     agents, 1.0)
        assert reason == "" and versions == (1, 1) and len(obstacles) == 2  # the agents source adds no disks
        kept, grown = obstacles
        assert (kept.margin, grown.margin) == (RETURN_DEPTH, RETURN_DEPTH) and (kept.approach, grown.approach) == (0, 1)
        return kept.points, grown.points

    kept, grown = disks(agents, agents.received + 1.0)  # the agent predicted onto the return behind the robot
    assert kept == pytest.approx(np.array([[-1.0 - RETURN_DEPTH, 0.0]]))
    assert grown == pytest.approx(np.array([[0.0, -3.0 - RETURN_DEPTH]]))
    kept, grown = disks(agents, agents.received)  # now: 0.71 m from it, beyond 0.2 + AGENT_MATCH
    assert math.hypot(0.5, 0.5) > 0.2 + AGENT_MATCH and len(kept) == 0 and len(grown) == 2
    assert len(disks(None, agents.received + 1.0)[0]) == 0  # without agents (no agent table): all grown


def test_irsim_people_are_published_as_a_perfect_trackers_agents():
    """A walker's IR-SIM velocity is its step's displacement over the step; the harness's base publishes the
    people as a reliable PointCloud2 that the node's best-effort agents subscription hears and parses."""
    pytest.importorskip("irsim")
    from hjrno_ros.ros.harness.irsim_base import IrSimPlant
    from hjrno_ros.ros.harness.sim_base import Rates, SimBase
    from hjrno_ros.studies.irsim_world import DiffDriveBase, IrSimWorld, Person

    occ = np.zeros((100, 60), bool)
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
    base = DiffDriveBase(radius=0.2, v_max=0.5, v_min=-0.3, omega_max=1.5, a_max=1.0, alpha_max=3.0)
    walker = Person(((1.5, 0.0), (1.5, 1.5)), speed=0.8, radius=0.25)
    with IrSimWorld(occ, (-1.0, -2.0), 0.05, base, (0.0, 0.0, 0.0), step_time=0.05, people=(walker,)) as world:
        assert world.people_velocities == pytest.approx(np.zeros((1, 2)))
        assert world.people_radii == pytest.approx([0.25])
        for _ in range(5):
            before = world.people_positions
            world.step(0.0, 0.0)
            assert world.people_velocities == pytest.approx((world.people_positions - before) / 0.05, abs=1e-9)
        assert world.people_velocities[0, 1] > 0.3  # walking towards (1.5, 1.5)
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=DOMAIN)
        source = agents_source(topic="tracked_agents")
        agents = lambda stamp: agents_message(world.people_positions, world.people_velocities,  # noqa: E731
                                              world.people_radii, stamp)
        sim = SimBase(context, IrSimPlant(world), None, rates=Rates(0.05, 0.05), agents=agents, agents_every=2)
        listener = Node("listener", context=context)
        kind, qos = SOURCE_SUBSCRIPTIONS["agents"]
        listener.create_subscription(kind, "tracked_agents", source.on_message, qos)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(sim)
        executor.add_node(listener)
        try:
            deadline = time.monotonic() + 10.0
            while source.current is None and time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.05)
        finally:
            executor.shutdown(timeout_sec=2.0)
            sim.destroy_node()
            listener.destroy_node()
            rclpy.shutdown(context=context)
        assert source.current is not None and source.rejected == 0, source.error
        assert source.current.frame_id == "map" and source.current.stamp_ns > 0
        assert source.current.agents.positions == pytest.approx(world.people_positions, abs=1e-6)
        assert source.current.agents.radii == pytest.approx([0.25])
