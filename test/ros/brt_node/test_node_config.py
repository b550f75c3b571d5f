"""NodeConfig: the parameter table as one typed value, and the status built from explicit data."""

from __future__ import annotations

import dataclasses
import math
import types

import pytest

pytest.importorskip("rclpy")

from hjrno_ros.core.safety_filter import FilterSettings  # noqa: E402
from hjrno_ros.ros.brt_node import status  # noqa: E402
from hjrno_ros.ros.brt_node.config import NodeConfig  # noqa: E402
from hjrno_ros.ros.brt_node.parameters import PARAMETERS  # noqa: E402


def test_node_config_has_one_field_per_parameter_with_its_default_and_type():
    fields = {f.name: f for f in dataclasses.fields(NodeConfig) if f.name != "sources"}  # sources: their own table
    assert set(fields) == set(PARAMETERS)
    for name, spec in PARAMETERS.items():
        assert fields[name].type == type(spec.default).__name__, name
        default = getattr(NodeConfig(), name)
        assert default == spec.default or (math.isnan(default) and math.isnan(spec.default)), name


def test_node_config_converts_integers_and_refuses_bad_sets_with_one_line():
    values = NodeConfig().as_dict()
    cfg = NodeConfig.build({**values, "inflation_radius": 0, "epsilon": 1}, startup=True)
    assert isinstance(cfg, NodeConfig) and cfg.inflation_radius == 0.0 and isinstance(cfg.epsilon, float)
    refused = NodeConfig.build({**values, "map_kind": "lidar"}, startup=True)
    assert refused == "map_kind must be one of ['occupancy', 'costmap'], got 'lidar'"
    assert "epsilon" in NodeConfig.build(values, startup=False)  # -1 (the card's) only at start-up
    live = cfg.with_values({"decay_rate": 2})
    assert isinstance(live, NodeConfig) and live.decay_rate == 2.0 and cfg.decay_rate == 4.0  # a new value
    assert "decay_rate" in cfg.with_values({"decay_rate": "fast"})


def inputs(**changes) -> status.StatusInputs:
    base = dict(now=10.0, reason="", decision=None, enabled=True, state=None, value=None, certificate=None,
                settings=FilterSettings(0.2, "least_restrictive"), epsilon_calibrated=0.1,
                epsilon_below_calibrated=False, refined=None, latest=None, map=None, map_error="", maps_rejected=0,
                odom_received=None, counts={k: 0 for k in ("cmd", "odom", "pose", "commands", "interventions",
                                                           "clipped", "stops")},
                inferences=0, inference_errors=0, filter_ms=None, type_mismatch=[], refinement=None, model="m",
                runtime="onnxruntime",
                symmetry_average=None)
    return status.StatusInputs(**{**base, **changes})


def test_status_is_built_from_explicit_data():
    st = status.build(inputs(reason="no map yet"))
    assert st["state"] == "fail_closed" and st["reason"] == "no map yet" and st["robot"] is None
    robot = types.SimpleNamespace(x=1.0, y=2.0, v=0.5, theta=0.25, frame_id="map")
    latest = types.SimpleNamespace(latency_ms=3.456, computed=9.5, grid_info={"w": 32}, source="operator")
    st = status.build(inputs(state=robot, certificate=0.4, value=0.6, latest=latest, odom_received=9.9,
                             refined=(0.05, 4.0)))
    assert st["state"] == "ok" and st["certificate"] == 0.4 and st["robot"]["frame_id"] == "map"
    assert st["value_age_s"] == 0.5 and st["odom_age_s"] == pytest.approx(0.1) and st["inference_latency_ms"] == 3.46
    assert (st["refine_epsilon"], st["refine_epsilon_from_s"]) == (0.05, 4.0)
    assert status.build(inputs(state=robot, certificate=-0.1))["state"] == "unsafe_idle"  # W ≤ 0, no command
    assert status.build(inputs(enabled=False))["state"] == "bypassed"
