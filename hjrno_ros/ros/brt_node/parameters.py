"""brt_node's parameters: one table (defaults, units, ranges, read-only), validation, the docs table.

Float parameters accept integers (``-p inflation_radius:=0``): they are declared with dynamic typing
and every numeric value is converted to float before use; a non-numeric value is rejected with one line.
``docs/node.md``'s parameter table is :func:`markdown_table` (a test keeps it current).
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.parameter import Parameter

from hjrno_ros.core import safety_filter, tables
from hjrno_ros.core.dynamics import CAR_MODEL, DIFF_DRIVE_MODEL, RobotParams
from hjrno_ros.core.model_card import ModelCard

if TYPE_CHECKING:  # the config is built from this module's table
    from hjrno_ros.ros.brt_node.config import NodeConfig


@dataclasses.dataclass(frozen=True)
class Param:
    default: Any
    description: str
    lo: float | None = None  # inclusive range, also in the descriptor
    hi: float | None = None
    read_only: bool = False  # topics, types, model: start-up only

    def declared_default(self) -> Any:
        """What ``declare_parameter`` gets: the default, or for an empty list the string-array type (rclpy
        cannot type an empty list)."""
        return Parameter.Type.STRING_ARRAY if self.default == [] else self.default

    def descriptor(self) -> ParameterDescriptor:
        extra: dict[str, Any] = {"read_only": self.read_only}
        if isinstance(self.default, list) and self.default:
            extra["dynamic_typing"] = True  # [0, 0, 0] as well as [0.0, 0.0, 0.0]
        elif isinstance(self.default, float):
            extra["dynamic_typing"] = True  # integers too; validate() converts and checks
            if self.lo is not None:
                extra["floating_point_range"] = [FloatingPointRange(from_value=float(self.lo), to_value=float(self.hi),
                                                                    step=0.0)]
        elif isinstance(self.default, int) and not isinstance(self.default, bool) and self.lo is not None:
            extra["integer_range"] = [IntegerRange(from_value=int(self.lo), to_value=int(self.hi), step=1)]
        return ParameterDescriptor(description=self.description, **extra)


MAP_KINDS = ("occupancy", "costmap")
RUNTIMES = ("auto", "onnx", "torch")  # inference_runtime
ROBOT_MODEL_NAMES = {"diff_drive": DIFF_DRIVE_MODEL, "car": CAR_MODEL}  # parameter value -> card dynamics.model
PARAMETERS: dict[str, Param] = {
    "autostart": Param(True, "configure and activate at start (plain mode); false: wait for a lifecycle manager "
                             "(Nav2's, with bond_timeout 0)", read_only=True),
    "map_topic": Param("map", "OccupancyGrid topic (reliable, transient local, depth 1)", read_only=True),
    "odom_topic": Param("odom", "Odometry topic (sensor-data QoS); speed = twist.linear.x", read_only=True),
    "pose_topic": Param("", "optional PoseWithCovarianceStamped in the map frame (e.g. amcl_pose); '' = pose from "
                            "odometry", read_only=True),
    "cmd_vel_in_topic": Param("cmd_vel_smoothed", "nominal velocity command in", read_only=True),
    "cmd_vel_out_topic": Param("cmd_vel", "filtered velocity command out", read_only=True),
    "enable_stamped_cmd_vel": Param(False, "TwistStamped instead of Twist on both command topics (Nav2 Jazzy)",
                                    read_only=True),
    "value_grid_topic": Param("brt/value_grid", "V slice at the robot's speed/heading as a costmap-palette "
                                                "OccupancyGrid", read_only=True),
    "value_topic": Param("brt/value", "V slice in metres, Float32MultiArray (row-major, x fastest)", read_only=True),
    "status_topic": Param("brt/status", "JSON status (std_msgs/String, 10 Hz)", read_only=True),
    "model_path": Param("", "model stem or .json/.safetensors path, or the name of a bundled model (v5); '' = the "
                            "bundled models/default", read_only=True),
    "inference_runtime": Param("auto", "auto (onnxruntime when the model card lists an ONNX export, else torch) | "
                                       "onnx | torch", read_only=True),
    "device": Param("", "inference device: '' = cuda when available else cpu, or cpu, cuda, cuda:N", read_only=True),
    "inference_threads": Param(1, "CPU threads for inference (keeps cores free for the command path)", 1, 64,
                               read_only=True),
    "epsilon": Param(-1.0, "m: intervene when V <= epsilon; -1 (startup only) = the model card's value, else 0.1"),
    "filter_mode": Param("least_restrictive", "least_restrictive (the admissible command closest to the nominal: "
                                              "the next state's certificate falls no faster than decay_rate, not "
                                              "at all at or below 0) | blend (ramp over blend_width above epsilon) "
                                              "| switch (only at V <= epsilon) | qp (smallest change keeping dV/dt "
                                              ">= -decay_rate (V - epsilon))"),
    "blend_width": Param(0.2, "m: blend mode ramps from safe to nominal over (epsilon, epsilon + blend_width]",
                         1e-3, 10.0),
    "decay_rate": Param(4.0, "1/s: how fast the certificate (least_restrictive) or V - epsilon (qp) may fall "
                             "towards 0 under the worst disturbance", 1e-3, 100.0),
    "value_clip": Param(1.0, "m: value grid palette, V <= 0 -> 100, V >= value_clip -> 0", 1e-3, 100.0),
    "robot_model": Param("diff_drive", "diff_drive (turns at up to omega_max, in place too) | car (curvature up to "
                                       "kappa_max); must be the model card's model", read_only=True),
    "a_max": Param(-1.0, "m/s^2: the robot's acceleration limit; -1 = the model card's robot", read_only=True),
    "omega_max": Param(-1.0, "rad/s: a diff_drive robot's turn-rate limit; -1 = the model card's robot",
                       read_only=True),
    "kappa_max": Param(-1.0, "1/m: a car's curvature limit; -1 = the model card's robot", read_only=True),
    "v_max": Param(-1.0, "m/s: the robot's top speed; -1 = the model card's robot", read_only=True),
    "v_min": Param(math.nan, "m/s: the robot's lowest speed (< 0: it reverses); NaN = the card's v_min/v_max times "
                             "v_max", read_only=True),
    "tracking_error": Param(-1.0, "delta: the robot's tracking error per unit speed, ||d|| <= delta*|v| + d0; -1 = the "
                                  "model card's robot. The robot must have the card's dimensionless numbers "
                                  "(docs/node.md, 'The robot')", read_only=True),
    "footprint_radius": Param(0.0, "m: the robot's radius, added to the inflation", 0.0, 5.0, read_only=True),
    "speed_tolerance": Param(0.05, "m/s: speeds this far outside the model's [v_min, v_max] fail closed", 0.0, 1.0),
    "map_kind": Param("occupancy", "occupancy (map_server: cells >= occupied_threshold are obstacles) | costmap "
                                   "(a Nav2 costmap as OccupancyGrid: cells >= costmap_threshold)", read_only=True),
    "occupied_threshold": Param(50, "occupancy >= threshold is an obstacle (map_kind occupancy)", 0, 100),
    "costmap_threshold": Param(99, "map_kind costmap: cost >= threshold is an obstacle; 99 = Nav2's inscribed cost "
                                   "(the footprint's inscribed radius is already inflated), 100 = lethal only", 0, 100),
    "unknown_is_obstacle": Param(True, "unknown cells (-1) and space beyond the map are obstacles"),
    "observation_sources": Param([], "live sources beside the map (LaserScan, a rolling costmap), each configured by "
                                     "<name>.type, <name>.topic, <name>.timeout, ... (docs/node.md, 'Observation "
                                     "sources'); [] = the map alone", read_only=True),
    "obstacle_speed_max": Param(1.0, "m/s: how fast a live source's obstacles that are not on the static map "
                                     "(people) may approach; the value table grows them by this times the robot's "
                                     "time to stop, command_latency and the source's timeout, the braking bound by "
                                     "this times their data's age and the stop from the robot's own speed", 0.0, 10.0,
                                read_only=True),
    "agent_table": Param("", "tracked agents' relative value tables: a stem or the name of a bundled one "
                             "(agents_jackal, agents_turtlebot3), solved for this robot by `hjrno agents`; needed by "
                             "an 'agents' observation source; '' = none (docs/node.md, 'Tracked agents')",
                         read_only=True),
    "inflation_radius": Param(-1.0, "m: obstacles grown by this much beyond footprint_radius (V0 = signed distance "
                                    "- footprint_radius - inflation_radius); -1 = h/sqrt(2) of the coarser of the "
                                    "model grid (at the robot's size) and the map (makes the interpolated V0 "
                                    "conservative)", -1.0, 5.0),
    "inference_rate": Param(10.0, "Hz: how often the inference thread checks whether to recompute", 0.1, 100.0),
    "recenter_distance": Param(1.0, "m: recompute when the robot is this far from the window centre", 0.01, 100.0),
    "odom_timeout": Param(0.5, "s: older odometry (receipt time) fails closed", 0.01, 60.0),
    "map_timeout": Param(0.0, "s: older maps fail closed; 0 = never (map_server publishes once)", 0.0, 1e6),
    "value_timeout": Param(1.0, "s: older value tables fail closed; recomputed every value_timeout/2", 0.05, 60.0),
    "control_period": Param(0.05, "s: stop-republish timer period; also dt of v_cmd = v + u1*dt", 1e-3, 1.0),
    "command_latency": Param(0.05, "s: from a filtered command to the wheels; least_restrictive judges each command "
                                   "from the state this far (plus the odometry's age) ahead, the last command held "
                                   "meanwhile", 0.0, 1.0),
    "refine_horizon": Param(0.0, "s: simulated time the HJ solver refines the operator's value over the whole map, "
                                 "warm-started from it, in a background process (nice 19); the filter uses each "
                                 "refined stage for as long as that map stands; 0 = off (static maps, docs/node.md)",
                            0.0, 600.0, read_only=True),
    "refine_stage": Param(4.0, "s: simulated time between the refined tables handed to the filter", 0.5, 600.0,
                          read_only=True),
    "refine_cpus": Param(0, "CPU cores the refinement process may run on (the highest-numbered of the node's); "
                            "0 = all but one, so the command path keeps a core to itself", 0, 1024, read_only=True),
    "refine_epsilon": Param(-1.0, "m: epsilon while the filter reads a refined table; -1 = the model card's "
                                  "refine_epsilon (hjrno calibrate --refine T) from stage T s on, before that stage "
                                  "or without one the value of epsilon"),
    "stop_pub_timeout": Param(2.0, "s: keep publishing zeros while fail-closed until this long after the last "
                                   "nominal command; 0 = only answer commands", 0.0, 60.0),
}


def _number(name: str, value: Any) -> float | str:
    """``value`` as a float, or a reason why it is not a number."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return f"{name} must be a number, got {type(value).__name__} {value!r}"
    return float(value)


def normalise(cfg: dict[str, Any]) -> tuple[dict[str, Any], str | None]:
    """``cfg`` with float parameters as floats (integers accepted), or a reason why a value is unusable."""
    out = dict(cfg)
    for name, spec in PARAMETERS.items():
        if isinstance(spec.default, list) and out.get(name) is None:  # an undeclared-type empty list
            out[name] = []
        if name in out and isinstance(spec.default, float):
            value = _number(name, out[name])
            if isinstance(value, str):
                return cfg, value
            out[name] = value
    return out, None


def validate(cfg: dict[str, Any], startup: bool = False) -> str | None:
    """A reason why the (normalised) parameter set is unusable, or None."""
    for name, spec in PARAMETERS.items():
        value = cfg[name]
        if name == "v_min" and math.isnan(value):  # NaN: the card's
            continue
        if isinstance(value, float) and not math.isfinite(value):
            return f"{name} must be finite, got {value}"
        if spec.lo is not None and not spec.lo <= value <= spec.hi:
            return f"{name} must lie in [{spec.lo:g}, {spec.hi:g}], got {value}"
    names = cfg["observation_sources"]
    if not isinstance(names, list | tuple) or not all(isinstance(n, str) and n for n in names):
        return f"observation_sources must be a list of source names, got {names!r}"
    eps = cfg["epsilon"]
    if eps < 0 and not (startup and eps == -1.0):
        return f"epsilon must be finite and >= 0 (-1 = model card, at startup only), got {eps}"
    if cfg["map_kind"] not in MAP_KINDS:
        return f"map_kind must be one of {list(MAP_KINDS)}, got {cfg['map_kind']!r}"
    if cfg["inference_runtime"] not in RUNTIMES:
        return f"inference_runtime must be one of {list(RUNTIMES)}, got {cfg['inference_runtime']!r}"
    if cfg["filter_mode"] not in safety_filter.MODES:
        return f"filter_mode must be one of {list(safety_filter.MODES)}, got {cfg['filter_mode']!r}"
    if cfg["robot_model"] not in ROBOT_MODEL_NAMES:
        return f"robot_model must be one of {list(ROBOT_MODEL_NAMES)}, got {cfg['robot_model']!r}"
    for name in ("a_max", "omega_max", "kappa_max", "v_max", "tracking_error"):
        if not (cfg[name] == -1.0 or (cfg[name] > 0 if name != "tracking_error" else cfg[name] >= 0)):
            return f"{name} must be -1 (the model card's) or {'>= 0' if name == 'tracking_error' else '> 0'}, " \
                   f"got {cfg[name]}"
    r = cfg["inflation_radius"]
    if not (r >= 0 or r == -1.0):
        return f"inflation_radius must be >= 0, or -1 (h/sqrt(2) of the model grid), got {r}"
    r_eps = cfg["refine_epsilon"]
    if not (r_eps >= 0 or r_eps == -1.0):
        return f"refine_epsilon must be >= 0, or -1 (the value of epsilon), got {r_eps}"
    return None


def obstacle_threshold(cfg: NodeConfig) -> int:
    """The occupancy value from which a map cell is an obstacle, for the map's kind."""
    return int(cfg.costmap_threshold if cfg.map_kind == "costmap" else cfg.occupied_threshold)


def filter_settings(card: ModelCard, cfg: NodeConfig, scale: float = 1.0,
                    robot: RobotParams | None = None) -> safety_filter.FilterSettings:
    """The filter's settings: ``epsilon``, or for -1 the card's calibrated margin (a length: times ``scale``, the
    robot's size against the card's robot) plus, for the modes that judge the present state only, the ``robot``'s
    sampling margin over one control period (least_restrictive looks one period ahead instead)."""
    dt = float(cfg.control_period)
    ahead = cfg.filter_mode == "least_restrictive"
    sampled = safety_filter.sampling_margin(robot, dt) if robot is not None and not ahead else 0.0
    eps = cfg.epsilon if cfg.epsilon >= 0 else card.margin() * scale + sampled
    return safety_filter.FilterSettings(epsilon=float(eps), mode=cfg.filter_mode,
                                        blend_width=float(cfg.blend_width), dt=float(cfg.control_period),
                                        decay_rate=float(cfg.decay_rate))


def refined_filter_settings(card: ModelCard, settings: safety_filter.FilterSettings,
                            cfg: NodeConfig) -> tuple[safety_filter.FilterSettings, float]:
    """The filter's settings on a refined table and the stage (simulated s) from which they hold:
    ``refine_epsilon`` if set (>= 0), from the first stage; for -1 the card's refine_epsilon from the stage
    it was calibrated at (``hjrno calibrate --refine``); before that stage, or without one, ``settings``."""
    eps = cfg.refine_epsilon
    if eps >= 0:
        return dataclasses.replace(settings, epsilon=float(eps)), 0.0
    if card.refine_epsilon is None:
        return settings, 0.0
    return dataclasses.replace(settings, epsilon=card.refine_epsilon), card.refine_horizon


def markdown_table(table: dict[str, Param] | None = None) -> str:
    """A parameter table of docs/node.md: ``table`` (default PARAMETERS; the sources' own is SOURCE_PARAMETERS)."""
    rows = []
    for name, p in (PARAMETERS if table is None else table).items():
        default = f'"{p.default}"' if isinstance(p.default, str) else str(p.default).lower() \
            if isinstance(p.default, bool) else repr(p.default)
        span = f"{p.lo:g} .. {p.hi:g}" if p.lo is not None else ""
        live = "no" if p.read_only else "yes"
        rows.append([f"`{name}`", f"`{default}`", span, live, p.description.replace("|", "/")])
    return "\n".join(tables.markdown_table(["name", "default", "range", "live", "description"], rows)) + "\n"
