"""brt_node's input parsing and limits without DDS: quaternions, map origins, the map edge, the
command limits, raster sampling independent of the map's size, status states."""

from __future__ import annotations

import math
import types

import numpy as np
import pytest

pytest.importorskip("rclpy")

from hjrno_ros.core import geometry, safety_filter  # noqa: E402
from hjrno_ros.core.dynamics import CarParams  # noqa: E402
from hjrno_ros.ros.brt_node import status  # noqa: E402
from hjrno_ros.ros.brt_node.inputs import MapRejected, parse_map  # noqa: E402
from hjrno_ros.ros.brt_node.messages import occupancy_message, planar_yaw  # noqa: E402


def quat(x: float, y: float, z: float, w: float) -> types.SimpleNamespace:
    return types.SimpleNamespace(x=x, y=y, z=z, w=w)


def test_planar_yaw_normalises_and_refuses_tilted_or_mirrored():
    s, c = math.sin(0.05), math.cos(0.05)
    assert planar_yaw(quat(0, 0, 10 * s, 10 * c)) == pytest.approx(0.1)  # before: 1.52 rad
    assert planar_yaw(quat(0, 0, 0.5, 0)) == pytest.approx(math.pi)
    assert planar_yaw(quat(1, 0, 0, 0)) is None  # mirrored (π about x)
    assert planar_yaw(quat(math.sin(0.2), 0, 0, math.cos(0.2))) is None  # 0.4 rad roll
    assert planar_yaw(quat(math.sin(0.05), 0, 0, math.cos(0.05))) == pytest.approx(0.0)  # 0.1 rad: a ramp
    for bad in ((0, 0, 0, 0), (0, 0, math.nan, 1), (0, 0, math.inf, 1), (0, 0, 1e200, 1e200)):
        assert planar_yaw(quat(*bad)) is None


def map_with_origin(q: tuple[float, float, float, float]):
    msg = occupancy_message(np.zeros((20, 10), np.int8), 0.1, (-1.0, -1.0))
    o = msg.info.origin.orientation
    o.x, o.y, o.z, o.w = q
    return msg


def test_map_origins_must_be_axis_aligned():
    assert parse_map(map_with_origin((0.0, 0.0, 0.0, 3.0)), 1, 0.0).origin == (-1.0, -1.0)  # not normalised: fine
    for q, words in (((0.0, 0.0, 0.5, 0.0), "rotated"), ((1.0, 0.0, 0.0, 0.0), "mirrored"),
                     ((0.3, 0.0, 0.0, 1.0), "tilted"), ((0.0, 0.0, 0.0, 0.0), "zero")):
        with pytest.raises(MapRejected, match=words):
            parse_map(map_with_origin(q), 1, 0.0)


def test_the_map_edge_bounds_the_signed_distance():
    """A free map without an unknown border: the distance never exceeds the distance to its edge."""
    res = 0.1
    free = np.zeros((200, 100), np.int8)
    sd = geometry.occupancy_signed_distance(free, res)
    centres = (np.arange(200) + 0.5) * res
    assert sd[0, 50] == pytest.approx(res / 2) and sd[100, 50] == pytest.approx(5.0 - res / 2 + res / 2, abs=res)
    assert np.all(sd[:, 50] <= np.minimum(centres, 20.0 - centres) + 1e-5)
    assert sd.max() <= 5.0 + 1e-5  # before: the whole diagonal, 22 m
    plain = geometry.occupancy_signed_distance(free, res, unknown_is_obstacle=False)
    assert plain.max() > 20.0  # without unknown_is_obstacle the edge is not an obstacle, as documented


def test_sample_raster_reads_only_the_window():
    """A 1e5 × 1e5 raster (a zero-stride view: converting it whole would need 80 GB) samples fine."""
    huge = np.broadcast_to(np.float32(2.5), (100_000, 100_000))
    pts = np.stack(np.meshgrid(np.linspace(100, 110, 32), np.linspace(200, 210, 32), indexing="ij"), -1)
    assert np.allclose(geometry.sample_raster(huge, (0.0, 0.0), 0.05, pts), 2.5)


def test_commands_are_clipped_to_the_limits_even_in_the_blend_band():
    p, settings = CarParams(), safety_filter.FilterSettings(epsilon=0.2, mode="blend", blend_width=0.2)
    state, grad = np.array([0.0, 0.0, 0.5, 0.0]), np.array([0.0, 0.0, -0.1, 0.1])
    far = safety_filter.filter_command(p, settings, state, 5.0, grad, 0.7, -0.3)
    assert (far.linear, far.angular, far.intervened, far.clipped) == (0.7, -0.3, False, False)
    for linear, angular in ((5.0, 0.0), (1e308, 0.0), (-1.0, 0.0), (0.5, 100.0), (0.5, -1e308)):
        for value in (5.0, 0.3, 0.1):  # far, in the blend band (before: 5 m/s -> 3.22 m/s), at the margin
            d = safety_filter.filter_command(p, settings, state, value, grad, linear, angular)
            bound = p.kappa_max * max(0.5, min(max(d.linear, 0.5 - p.a_max * settings.dt), 0.5 + p.a_max * settings.dt))
            assert p.v_min <= d.linear <= p.v_max and abs(d.angular) <= bound + 1e-12, (linear, angular, value, d)
            assert d.clipped


def test_status_state_is_the_present_one():
    decision = safety_filter.Decision(0.1, 0.2, True, -0.1, "blend")
    assert status.mode(False, "", None, 5.0, 0.2)[0] == "bypassed"
    assert status.mode(True, "no map", decision, 5.0, 0.2) == ("fail_closed", "no map")
    assert status.mode(True, "", decision, -0.1, 0.2) == ("intervening", "blend")
    assert status.mode(True, "", None, 5.7, 0.2) == ("ok", "pass")  # before: "intervening" on a fresh V of 5.7
    assert status.mode(True, "", None, 0.1, 0.2)[0] == "unsafe_idle"  # before: "ok"
