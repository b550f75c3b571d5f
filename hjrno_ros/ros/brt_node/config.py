"""NodeConfig: brt_node's parameters as one typed, immutable value, built once per accepted parameter set.

The table of names, defaults, ranges and descriptions is :data:`~hjrno_ros.ros.brt_node.parameters.PARAMETERS`
(also the source of docs/node.md's table and config/brt_node.yaml); this class gives the node's components
attributes instead of string look-ups.  A test keeps its fields and types equal to the table's.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from hjrno_ros.ros.brt_node.observation_sources import SourceConfig
from hjrno_ros.ros.brt_node.parameters import PARAMETERS, normalise, validate


def _default(name: str) -> Any:
    return PARAMETERS[name].default


@dataclasses.dataclass(frozen=True)
class NodeConfig:
    """One accepted parameter set: float parameters are floats, every range and choice checked."""

    # Topics and message types (start-up only).
    map_topic: str = _default("map_topic")
    odom_topic: str = _default("odom_topic")
    pose_topic: str = _default("pose_topic")
    cmd_vel_in_topic: str = _default("cmd_vel_in_topic")
    cmd_vel_out_topic: str = _default("cmd_vel_out_topic")
    enable_stamped_cmd_vel: bool = _default("enable_stamped_cmd_vel")
    value_grid_topic: str = _default("value_grid_topic")
    value_topic: str = _default("value_topic")
    status_topic: str = _default("status_topic")
    # Lifecycle and model (start-up only).
    autostart: bool = _default("autostart")
    model_path: str = _default("model_path")
    inference_runtime: str = _default("inference_runtime")
    device: str = _default("device")
    inference_threads: int = _default("inference_threads")
    # The filter.
    epsilon: float = _default("epsilon")
    filter_mode: str = _default("filter_mode")
    blend_width: float = _default("blend_width")
    decay_rate: float = _default("decay_rate")
    value_clip: float = _default("value_clip")
    speed_tolerance: float = _default("speed_tolerance")
    control_period: float = _default("control_period")
    command_latency: float = _default("command_latency")
    stop_pub_timeout: float = _default("stop_pub_timeout")
    # The robot (start-up only; -1 / NaN = the model card's).
    robot_model: str = _default("robot_model")
    a_max: float = _default("a_max")
    omega_max: float = _default("omega_max")
    kappa_max: float = _default("kappa_max")
    v_max: float = _default("v_max")
    v_min: float = _default("v_min")
    tracking_error: float = _default("tracking_error")
    footprint_radius: float = _default("footprint_radius")
    # The map and V0.
    map_kind: str = _default("map_kind")
    occupied_threshold: int = _default("occupied_threshold")
    costmap_threshold: int = _default("costmap_threshold")
    unknown_is_obstacle: bool = _default("unknown_is_obstacle")
    inflation_radius: float = _default("inflation_radius")
    observation_sources: list = dataclasses.field(default_factory=list)
    obstacle_speed_max: float = _default("obstacle_speed_max")
    agent_table: str = _default("agent_table")
    # The value worker and input validity.
    inference_rate: float = _default("inference_rate")
    recenter_distance: float = _default("recenter_distance")
    odom_timeout: float = _default("odom_timeout")
    map_timeout: float = _default("map_timeout")
    value_timeout: float = _default("value_timeout")
    # Background refinement.
    refine_horizon: float = _default("refine_horizon")
    refine_stage: float = _default("refine_stage")
    refine_cpus: int = _default("refine_cpus")
    refine_epsilon: float = _default("refine_epsilon")

    # The observation sources' own parameters (``<name>.type``, ...), one SourceConfig per observation_sources name.
    sources: tuple[SourceConfig, ...] = ()

    @classmethod
    def build(cls, values: Mapping[str, Any], startup: bool = False,
              sources: Mapping[str, Mapping[str, Any]] | None = None) -> NodeConfig | str:
        """The config for ``values`` (every name of PARAMETERS; integers accepted for floats) and each observation
        source's ``{key: value}`` (keys of SOURCE_PARAMETERS), or one line saying why they are unusable.
        ``startup``: the card's epsilon (-1) is allowed."""
        cfg, problem = normalise(dict(values))
        problem = problem or validate(cfg, startup=startup)
        if problem:
            return problem
        names = list(cfg["observation_sources"])
        if len(set(names)) != len(names):
            return f"observation_sources names a source twice: {names}"
        built = [SourceConfig.build(name, dict((sources or {}).get(name, {}))) for name in names]
        problem = next((b for b in built if isinstance(b, str)), None)
        if problem:
            return problem
        return cls(**{name: cfg[name] for name in PARAMETERS}, sources=tuple(built))

    def with_values(self, changes: Mapping[str, Any], startup: bool = False) -> NodeConfig | str:
        """This config with ``changes`` applied (a live parameter update; the sources are read-only), or why that
        set is unusable."""
        cfg, problem = normalise({**self.as_dict(), **changes})
        problem = problem or validate(cfg, startup=startup)
        return problem if problem else dataclasses.replace(self, **{name: cfg[name] for name in changes
                                                                     if name in PARAMETERS})

    def as_dict(self) -> dict[str, Any]:
        """The PARAMETERS values (the sources' own parameters apart)."""
        return {name: getattr(self, name) for name in PARAMETERS}
