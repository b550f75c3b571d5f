"""``brt_node``: filters velocity commands with the learned value function of the robot's map.

The node coordinates small components (docs/node.md has topics, QoS, status and every parameter)::

    map ─► MapInput (validate; signed distance in the worker)        ┐
    scan / costmap ─► ObservationSource (each its own timeout)        │
    odom [+ pose] ─► StateInput (x, y, v, θ in the map frame)         ├─► fail-closed check ─► filter ─► cmd_vel_out
    ValueWorker (own thread): window around the robot ─► V table ─────┘        ▲
    cmd_vel_in ────────────────────────────────────────────────────────────────┘

Each input answers "data, or the reason it is unusable now"; the check is a loop over them, and any
reason publishes a zero command instead of the filtered one.  The command callback never waits for
inference.  The node is managed: the worker starts on activate and is joined on deactivate, and before the
ROS context goes (:mod:`hjrno_ros.ros.brt_node.main`).
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseWithCovarianceStamped, Twist, TwistStamped
from nav_msgs.msg import OccupancyGrid, Odometry
from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import ParameterUninitializedException
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from std_msgs.msg import String
from std_srvs.srv import SetBool

from hjrno_ros.core import least_restrictive, safety_filter
from hjrno_ros.core.tracked_agents import with_agents
from hjrno_ros.ros.brt_node import messages, parameters, status
from hjrno_ros.ros.brt_node.config import NodeConfig
from hjrno_ros.ros.brt_node.inputs import MapData, MapInput, RobotState, StateInput
from hjrno_ros.ros.brt_node.interfaces import Interfaces, refuse_invalid_transitions
from hjrno_ros.ros.brt_node.observation_sources import (
    SOURCE_PARAMETERS,
    ObservationSource,
    fresh_agents,
    lost_agents,
)
from hjrno_ros.ros.brt_node.refinement import Refinement
from hjrno_ros.ros.brt_node.value_sources import load_agent_table, load_model
from hjrno_ros.ros.brt_node.value_worker import ValueWorker, table_state

NODE_NAME = "brt_node"


class StartupError(RuntimeError):
    """The node cannot run (bad model, bad parameters); main() logs one line and exits 1."""


class BrtNode(LifecycleNode):
    """Safety filter node, managed (lifecycle); see the module docstring and docs/node.md.

    configure: parameters, model, inputs, interfaces; activate: a clean state (the map is kept) and the worker;
    deactivate: the worker stops and nothing is published; cleanup: interfaces and model are dropped.
    ``start()`` does configure + activate (plain mode: ``autostart``)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self._log = status.ThrottledLog(self.get_logger())
        self.io: Interfaces | None = None  # publishers, subscriptions, timers, service: made by configure
        self.configured = self.active = self._plain = False
        self.startup_error = ""
        self.type_mismatch: list[str] = []
        for name, spec in parameters.PARAMETERS.items():
            self.declare_parameter(name, spec.declared_default(), spec.descriptor())
        for source in self._value("observation_sources") or []:  # read-only: known from the start
            for key, spec in SOURCE_PARAMETERS.items():
                self.declare_parameter(f"{source}.{key}", spec.declared_default(), spec.descriptor())
        self.config = NodeConfig()  # the declared defaults until configure reads the parameters
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)
        refuse_invalid_transitions(self)

    def _value(self, name: str) -> Any:
        """A parameter's value; None for one declared by type and never set (an empty list's default)."""
        try:
            return self.get_parameter(name).value
        except ParameterUninitializedException:
            return None

    # ------------------------------------------------------------------ lifecycle
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self._configure()
        except Exception as err:  # one clear line, no traceback
            self.startup_error = str(err) if isinstance(err, StartupError) else f"{type(err).__name__}: {err}"
            if not self._plain:  # plain mode: main() says it once
                self.get_logger().error(f"cannot configure: {self.startup_error}")
            self._destroy_interfaces()
            return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._reset()
        self.values.start()
        self.active = True
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        self.values.stop()
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release()
        return super().on_cleanup(state)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release()
        return super().on_shutdown(state)

    def start(self) -> None:
        """Plain mode: configure (if needed) and activate; StartupError when configuring fails."""
        self._plain = True
        if not self.configured and self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
            raise StartupError(self.startup_error)
        if not self.active:
            self.trigger_activate()

    def stop(self) -> None:
        """Stop working: join the worker (it publishes, so before the context goes) and the refinement."""
        self.active = False
        if hasattr(self, "values"):
            self.values.stop()

    def destroy_node(self) -> None:
        self.stop()
        super().destroy_node()

    def _release(self) -> None:
        self.stop()
        self._destroy_interfaces()
        self.configured = False
        for name in ("values", "maps", "sources", "states", "vf", "card", "agent_table"):
            self.__dict__.pop(name, None)

    # ------------------------------------------------------------------ set-up
    def _configure(self) -> None:
        cfg = NodeConfig.build({name: self._value(name) for name in parameters.PARAMETERS}, startup=True,
                               sources={name: {key: self._value(f"{name}.{key}") for key in SOURCE_PARAMETERS}
                                        for name in self._value("observation_sources") or []})
        if isinstance(cfg, str):
            raise StartupError(cfg)
        self.config = cfg
        try:
            self.card, self.vf, self.model_stem = load_model(cfg)
            self.agent_table = load_agent_table(cfg, self.vf.params)
        except ValueError as err:
            raise StartupError(str(err)) from None
        self._apply_settings(cfg)
        self.maps = MapInput(cfg.map_topic)
        # like the map, kept across activations; a tracking scan's tracks are agents of the agent table
        self.sources = [ObservationSource(source, self.agent_table) for source in cfg.sources]
        self._reset()
        self._create_interfaces(cfg)
        self.configured = True
        self.get_logger().info(
            f"model {self.model_stem} ({self.card.kind} on {self.vf.runtime}, window {self.vf.window[0]:g} x "
            f"{self.vf.window[1]:g} m, {self.vf.shape[0]}x{self.vf.shape[1]} nodes, {self.vf.params}); epsilon "
            f"{self.settings.epsilon:g} m, "
            f"{self.settings.mode}; {cfg.cmd_vel_in_topic} -> {cfg.cmd_vel_out_topic} "
            f"({'TwistStamped' if self._stamped else 'Twist'})")

    def _reset(self) -> None:
        """A clean state for an activation: inputs but the map, value table, decisions and counters."""
        cfg = self.config
        if hasattr(self, "values"):
            self.values.stop()
        self.counts = status.Counters()
        self.command_times = status.CommandTimes()
        self.enabled = True
        self.last_decision: safety_filter.Decision | None = None
        self._last_decision_time = -math.inf
        self._last_cmd: tuple[float, str] | None = None  # (monotonic s, header frame_id)
        self._last_nominal: tuple[float, float] | None = None  # (linear, angular) of the last filtered nominal
        self._last_output = (0.0, 0.0)  # (linear, angular) last published: what the base executes meanwhile
        self.states = StateInput(cfg.odom_topic, cfg.pose_topic)
        refinement = (Refinement(self.vf.grid, str(self.model_stem), cfg.refine_horizon, cfg.refine_stage,
                                 int(cfg.refine_cpus), from_target=self.card.kind == "solver")
                      if cfg.refine_horizon > 0 else None)
        self.values = ValueWorker(self.vf, self.maps, self.states, lambda: self.config, self._publish_value, self._log,
                                  refinement, self.sources)

    def _create_interfaces(self, cfg: NodeConfig) -> None:
        self._stamped = bool(cfg.enable_stamped_cmd_vel)
        sources = {s.config.name: self._guard(self._on_source(s)) for s in self.sources}
        self.io = Interfaces(self, cfg, {"map": self._guard(self._on_map), "odom": self._guard(self._on_odom),
                                         "pose": self._guard(self._on_pose), "cmd": self._on_cmd,
                                         "control": self._guard(self._on_control_timer),
                                         "status": self._guard(self._publish_status),
                                         "diagnostics": self._guard(self._publish_diagnostics),
                                         "enable": self._on_enable}, sources)

    def _destroy_interfaces(self) -> None:
        if getattr(self, "io", None) is not None:
            self.io.destroy()
            self.io = None

    def _guard(self, callback: Callable[..., None]) -> Callable[..., None]:
        """An exception in any callback would stop the executor (and the node): log it instead."""

        def run(*args: Any) -> None:
            try:
                callback(*args)
            except Exception as err:
                self._log("error", f"{callback.__name__} failed: {type(err).__name__}: {err}")

        return run

    # ------------------------------------------------------------------ parameters
    def _apply_settings(self, cfg: NodeConfig) -> None:
        self.settings = parameters.filter_settings(self.card, cfg, self.scale, self.vf.params)
        self.refined_settings, self.refined_from = parameters.refined_filter_settings(self.card, self.settings, cfg)
        if self.epsilon_below_calibrated:
            self.get_logger().warning(
                f"epsilon {self.settings.epsilon:g} m is below the model card's calibrated "
                f"{self.calibrated_epsilon:g} m: the calibrated false-safe guarantee does not hold")

    @property
    def scale(self) -> float:
        """The robot's length scale against the card's robot (1: the card's own)."""
        return getattr(getattr(self.vf, "scaling", None), "length", 1.0)

    @property
    def calibrated_epsilon(self) -> float | None:
        """The card's calibrated margin at the robot's size, m."""
        return None if self.card.epsilon is None else self.card.epsilon * self.scale

    @property
    def epsilon_below_calibrated(self) -> bool:
        """ε set below the card's calibrated margin: its false-safe guarantee is void."""
        return self.calibrated_epsilon is not None and self.settings.epsilon < self.calibrated_epsilon

    def _merged(self, params: list[Parameter]) -> NodeConfig | str:
        """The config after a live update, or why it is refused: the start-up sentinel epsilon = -1 may stay
        while other parameters change, but cannot be set live."""
        changes = {p.name: p.value for p in params if p.name in parameters.PARAMETERS}
        return self.config.with_values(changes, startup=all(p.name != "epsilon" for p in params))

    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        """Validate a live update as a whole (rclpy checked the descriptors' ranges for doubles)."""
        cfg = self._merged(params)
        problem = cfg if isinstance(cfg, str) else None
        return SetParametersResult(successful=problem is None, reason=problem or "")

    def _after_set_parameters(self, params: list[Parameter]) -> None:
        cfg = self._merged(params)
        if isinstance(cfg, str):  # accepted a moment ago; cannot happen, but never install an invalid set
            return
        names = {p.name for p in params}
        self.config = cfg
        if not self.configured:  # read again by configure
            return
        self._apply_settings(cfg)
        if "control_period" in names:
            self.io.control_timer.timer_period_ns = int(cfg.control_period * 1e9)
        if names & {"occupied_threshold", "costmap_threshold", "unknown_is_obstacle", "inflation_radius"}:
            self.maps.dirty = True
            self.values.wake()
        self.get_logger().info("parameters updated: " + ", ".join(f"{p.name}={p.value}" for p in params))

    # ------------------------------------------------------------------ inputs
    def _on_map(self, msg: OccupancyGrid) -> None:
        problem = self.maps.on_message(msg)
        if problem:
            keep = "keeping the previous map" if self.maps.current is not None else "no map yet: fail-closed"
            self._log("warning", f"map rejected: {problem}; {keep}")
            return
        self.values.wake()

    def _on_source(self, source: ObservationSource) -> Callable[[Any], None]:
        def on_message(msg: Any) -> None:
            problem = source.on_message(msg)
            if problem:
                self._log("warning", f"observation rejected: {problem}")
                return
            self.values.wake()  # a new table for every new observation

        on_message.__name__ = f"_on_{source.config.name}"
        return on_message

    def _on_odom(self, msg: Odometry) -> None:
        if not self.states.on_odom(msg):
            self.counts.add("odom")
            self._log("warning", "odometry with NaN/Inf or a zero or non-planar quaternion dropped")

    def _on_pose(self, msg: PoseWithCovarianceStamped) -> None:
        if not self.states.on_pose(msg):
            self.counts.add("pose")
            self._log("warning", "pose with NaN/Inf or a zero or non-planar quaternion dropped")

    # ------------------------------------------------------------------ the fail-closed check
    def check(self, now: float) -> tuple[str, dict[str, Any]]:
        """(fail-closed reason or "", the inputs' data so far: map, state, value)."""
        cfg, data = self.config, {}
        sources: list[tuple[str, Callable[[], tuple[Any, str]]]] = [
            ("map", lambda: self.maps.get(now, cfg.map_timeout)),
            ("state", lambda: self.states.get(now, cfg.odom_timeout, data["map"].frame_id)),
            ("speed", lambda: self._speed_check(data["state"])),
            *((f"source {s.config.name}", lambda s=s: s.get(now)) for s in self.sources if s.config.required),
            ("value", lambda: self.values.get(now, cfg.value_timeout)),
        ]
        if self.agent_table is not None:  # tracked agents: the fresh ones (a stale required source fails closed)
            sources.append(("agents", lambda: fresh_agents(self.sources, now, data["map"].frame_id,
                                                           held=data["value"].tracks)))
            sources.append(("tracked", lambda: (None, lost_agents(self.sources, data["value"].sources_version, now))))
        if self.settings.mode != "least_restrictive":  # these modes read V at the state itself
            sources.append(("value", lambda: self.values.covers(data["value"], data["state"])))
        for name, source in sources:
            value, reason = source()
            if reason:
                return reason, data
            data[name] = value
        return "", data

    def _speed_check(self, state: RobotState) -> tuple[float | None, str]:
        p, tol = self.vf.params, self.config.speed_tolerance
        if not p.v_min - tol <= state.v <= p.v_max + tol:
            return None, f"speed {state.v:.4g} m/s outside the model's range [{p.v_min:g}, {p.v_max:g}] m/s"
        return state.v, ""

    # ------------------------------------------------------------------ command path
    def _command(self, linear: float, angular: float, frame_id: str, header: Any = None) -> Twist | TwistStamped:
        stamp = self.get_clock().now().to_msg() if self._stamped and header is None else None
        return messages.command_message(linear, angular, self._stamped, header, stamp, frame_id)

    def _on_cmd(self, msg: Twist | TwistStamped) -> None:
        """Nominal command in, filtered command out; fast (no waiting on inference), never raises.  Inactive:
        nothing is published."""
        if not self.active:
            return
        t = msg.twist if self._stamped else msg
        if not messages.finite(t.linear.x, t.linear.y, t.linear.z, t.angular.x, t.angular.y, t.angular.z):
            self.counts.add("cmd")
            self._log("warning", "nominal command with NaN/Inf dropped")
            return
        now = time.monotonic()
        header = msg.header if self._stamped else None
        self._last_cmd = (now, header.frame_id if header is not None else "")
        self.counts.add("commands")
        if not self.enabled:
            self.io.cmd.publish(msg)
            self._last_output = (t.linear.x, t.angular.z)
            return
        start = time.perf_counter()
        try:
            self._filter(msg, t, header, now)
        except Exception as err:  # never let the command path die: fail closed
            self._log("error", f"filter failed ({type(err).__name__}: {err}); stopping")
            self.io.cmd.publish(self._command(0.0, 0.0, "", header))
            self._record(safety_filter.stop(math.nan, "filter failed"), now, stop=True)
        self.command_times.add(time.perf_counter() - start)

    def _filter(self, msg: Twist | TwistStamped, t: Twist, header: Any, now: float) -> None:
        reason, data = self.check(now)
        if reason:
            self.io.cmd.publish(self._command(0.0, 0.0, "", header))
            self._last_output = (0.0, 0.0)
            self._record(safety_filter.stop(math.nan, reason), now, stop=True)
            return
        decision = self._decide(data, (t.linear.x, t.angular.z))
        self._last_output = (decision.linear, decision.angular)
        planar = t.linear.y == t.linear.z == t.angular.x == t.angular.y == 0.0  # a planar base has no other axes
        self._last_nominal = (t.linear.x, t.angular.z)
        if decision.intervened or decision.clipped or not planar:
            self.io.cmd.publish(self._command(decision.linear, decision.angular, "", header))
            if decision.clipped or not planar:
                self.counts.add("clipped")
        else:
            self.io.cmd.publish(msg)  # within the limits and unchanged: bit for bit
        self._record(decision, now, stop=decision.reason.startswith("non-finite"))

    def _record(self, decision: safety_filter.Decision, now: float, stop: bool) -> None:
        """Count the decision; filter decisions (not fail-closed stops) drive the "intervening" state."""
        if not stop:
            self.last_decision, self._last_decision_time = decision, now
        if stop:
            self.counts.add("stops")
        elif decision.intervened:
            self.counts.add("interventions")

    def _on_control_timer(self) -> None:
        """While fail-closed and the last nominal command is recent, keep the robot stopped."""
        last = self._last_cmd
        if not (self.active and self.enabled) or last is None:
            return
        now = time.monotonic()
        if now - last[0] > self.config.stop_pub_timeout:
            return
        reason, _ = self.check(now)
        if reason:
            self.io.cmd.publish(self._command(0.0, 0.0, last[1]))
            self._last_output = (0.0, 0.0)
            self.counts.add("stops")

    def _on_enable(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        self.enabled = bool(request.data)
        response.success = True
        response.message = "filter enabled" if self.enabled else "filter bypassed: nominal commands pass unchanged"
        self._log("info" if self.enabled else "warning", response.message)
        return response

    # ------------------------------------------------------------------ outputs
    def _publish_value(self, values: np.ndarray, info: dict, m: MapData, state: RobotState) -> None:
        grid, arr = messages.value_messages(values, info, state.stamp_ns, m.stamp, self.config.value_clip)
        self.io.grid.publish(grid)
        self.io.value.publish(arr)

    def status(self) -> dict[str, Any]:
        """The status published as JSON on ``status_topic`` (also used by the diagnostics)."""
        now = time.monotonic()
        reason, data = self.check(now)
        return status.build(self._status_inputs(now, reason, data))

    def _status_inputs(self, now: float, reason: str, data: dict[str, Any]) -> status.StatusInputs:
        """The present's data for the status: V and W at the checked state, the inputs' ages and counters."""
        state, val = data.get("state"), data.get("value")
        value = certificate = None
        if state is not None and val is not None:
            p = self.vf.params
            s = table_state(state, val.theta, p.v_min, p.v_max)
            if self.values.covers(val, state)[0] is not None:
                value = float(val.table.value(s)[0])
            if self.settings.mode == "least_restrictive":
                certificate = float(self.certificate(data, self.settings.epsilon)(s[None])[0])
        refinement, odom = self.values.refinement, self.states.odom
        return status.StatusInputs(
            now=now, reason=reason, decision=self._present_decision(now, data), enabled=self.enabled, state=state,
            value=value, certificate=certificate, settings=self.settings,
            epsilon_calibrated=self.calibrated_epsilon, epsilon_below_calibrated=self.epsilon_below_calibrated,
            refined=(self.refined_settings.epsilon, self.refined_from) if refinement is not None else None,
            latest=self.values.value, map=self.maps.current, map_error=self.maps.error,
            maps_rejected=self.maps.rejected, odom_received=odom.received if odom else None,
            counts=self.counts.snapshot(), inferences=self.values.inferences, inference_errors=self.values.errors,
            filter_ms=self.command_times.summary(), type_mismatch=list(self.type_mismatch),
            refinement=refinement.status(self.maps.current) if refinement is not None else None,
            model=str(self.model_stem), runtime=self.vf.runtime, symmetry_average=self.card.symmetry_average,
            sources={src.config.name: src.status(now) for src in self.sources},
            reaction_ms=status.summary_ms(self.values.reaction_s),
            map_reaction_ms=status.summary_ms(self.values.map_reaction_s),
            signed_distance_ms=self.maps.signed_distance_ms)

    def _present_decision(self, now: float, data: dict[str, Any]) -> safety_filter.Decision | None:
        """What the filter would do now with the last nominal command, if one came within stop_pub_timeout."""
        recent = self._last_cmd is not None and now - self._last_cmd[0] <= self.config.stop_pub_timeout
        if not recent or self._last_nominal is None or "value" not in data:
            return None
        return self._decide(data, self._last_nominal)

    def _decide(self, data: dict[str, Any], nominal: tuple[float, float]) -> safety_filter.Decision:
        """The filter's decision on ``nominal`` (linear, angular) at the checked state and value table."""
        state, val, p = data["state"], data["value"], self.vf.params
        refined = val.source == "refined" and val.horizon >= self.refined_from
        settings = self.refined_settings if refined else self.settings
        if settings.mode == "least_restrictive":
            delay = max(time.monotonic() - state.received, 0.0) + self.config.command_latency
            return least_restrictive.decide(p, settings, self.certificate(data, settings.epsilon),
                                            state.vector(p.v_min, p.v_max), *nominal, self._last_output, delay)
        s = table_state(state, val.theta, p.v_min, p.v_max)
        values, grads = val.table.value_and_gradient(s)
        return safety_filter.filter_command(p, settings, s, float(values[0]), grads[0], *nominal)

    def certificate(self, data: dict[str, Any], epsilon: float) -> least_restrictive.Certificate:
        """W of the checked map and value table: the learned value less ε where the table holds the state, and the
        braking bound on the map's and live obstacles' clearance everywhere (ValueWorker.braking_clearances); with
        tracked agents, the least of that and each agent's relative value (core/tracked_agents.py)."""
        m, val = data["map"], data["value"]
        clearance, moving = self.values.braking_clearances(m, val.obstacles, data["state"].received)
        static = least_restrictive.certificate(self.vf.params, clearance, val.table, epsilon, moving)
        return with_agents(static, self.agent_table, data.get("agents"), self.config.footprint_radius,
                           data["state"].received)

    def _publish_status(self) -> None:
        if self.active:
            self.io.status.publish(String(data=json.dumps(self.status())))

    def _publish_diagnostics(self) -> None:
        if not self.active:
            return
        found = messages.command_type_mismatch(self, self.config.cmd_vel_in_topic, self.config.cmd_vel_out_topic,
                                               self._stamped)
        if found and found != self.type_mismatch:
            self.get_logger().warning("command type mismatch: " + "; ".join(found))
        self.type_mismatch = found
        self.io.diagnostics.publish(status.diagnostics(self.status(), self.get_name(), self.get_clock().now().to_msg()))


if __name__ == "__main__":
    from hjrno_ros.ros.brt_node.main import main

    sys.exit(main())
