"""What the node reports: counters, command-path timing, the status state and its diagnostics form."""

from __future__ import annotations

import collections
import dataclasses
import math
import threading
import time
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

STATUS_PERIOD = 0.1  # s
DIAGNOSTICS_PERIOD = 1.0  # s
LEVELS = {"ok": DiagnosticStatus.OK, "intervening": DiagnosticStatus.OK, "clipped": DiagnosticStatus.WARN,
          "bypassed": DiagnosticStatus.WARN, "unsafe_idle": DiagnosticStatus.WARN,
          "fail_closed": DiagnosticStatus.ERROR}
NESTED = ("dropped", "counts", "value_grid", "robot", "filter_ms", "refinement", "cmd_type_mismatch",
          "observation_sources", "observation_to_table_ms", "map_to_table_ms")


@dataclasses.dataclass
class Counters:
    cmd: int = 0  # non-finite commands dropped
    odom: int = 0  # non-finite odometry dropped
    pose: int = 0  # non-finite poses dropped
    commands: int = 0
    interventions: int = 0
    clipped: int = 0  # nominal commands outside the model's limits (or with non-planar axes), published clipped
    stops: int = 0  # zero commands published while fail-closed

    def __post_init__(self) -> None:
        self._lock = threading.Lock()

    def add(self, name: str, n: int = 1) -> None:
        with self._lock:
            setattr(self, name, getattr(self, name) + n)

    def snapshot(self) -> dict[str, int]:
        with self._lock:
            return dataclasses.asdict(self)


class CommandTimes:
    """Time spent in the command callback over the last 200 commands."""

    def __init__(self) -> None:
        self._times: collections.deque[float] = collections.deque(maxlen=200)

    def add(self, seconds: float) -> None:
        self._times.append(seconds)

    def summary(self) -> dict[str, float] | None:
        return summary_ms(self._times)


def summary_ms(seconds: Any) -> dict[str, float] | None:
    """p50, p95 and max of durations in seconds, as ms; None without any."""
    times = np.asarray(list(seconds)) * 1e3
    if not times.size:
        return None
    return {"p50": round(float(np.percentile(times, 50)), 3), "p95": round(float(np.percentile(times, 95)), 3),
            "max": round(float(times.max()), 3)}


class ThrottledLog:
    """``log(level, text)``: each distinct text at most once per ``period`` s (rclpy wants one severity per call
    site, so each level has its own call)."""

    def __init__(self, logger: Any, period: float = 5.0) -> None:
        self.logger, self.period = logger, period
        self._last: dict[str, float] = {}

    def __call__(self, level: str, text: str) -> None:
        now = time.monotonic()
        if now - self._last.get(text, -math.inf) < self.period:
            return
        if len(self._last) > 256:
            self._last.clear()
        self._last[text] = now
        if level == "error":
            self.logger.error(text)
        elif level == "warning":
            self.logger.warning(text)
        else:
            self.logger.info(text)


def mode(enabled: bool, reason: str, decision: Any, value: float, epsilon: float) -> tuple[str, str]:
    """(state, reason) of the status, for the present: bypassed; fail_closed; with a recent nominal command,
    intervening, clipped (the command exceeds the robot's limits and is cut to them) or ok as the filter would
    decide now (``decision``); without one, unsafe_idle when ``value`` ≤ ``epsilon`` (V and ε, or the
    least-restrictive certificate W and 0: the next command may be changed), else ok."""
    if not enabled:
        return "bypassed", "filter bypassed via ~/enable"
    if reason:
        return "fail_closed", reason
    if decision is not None:
        if decision.intervened:
            return "intervening", decision.reason
        return ("clipped", "nominal command beyond the robot's limits, clipped") if decision.clipped else \
            ("ok", decision.reason)
    if value <= epsilon:
        return "unsafe_idle", f"V = {value:.3f} m <= {epsilon:g} m with no recent command"
    return "ok", "pass"


def nan_if_none(x: float | None) -> float:
    return math.nan if x is None else x


@dataclasses.dataclass(frozen=True)
class StatusInputs:
    """Everything the status reports, gathered by the node at one instant (``now``, monotonic s)."""

    now: float
    reason: str  # fail-closed reason, "" if none
    decision: Any  # the filter's decision on the last recent nominal command, or None
    enabled: bool
    state: Any  # RobotState or None
    value: float | None  # V at the state where the table covers it
    certificate: float | None  # the least-restrictive certificate W at the state
    settings: Any  # FilterSettings in force
    epsilon_calibrated: float | None
    epsilon_below_calibrated: bool
    refined: tuple[float, float] | None  # (refine epsilon, from stage s) when refinement runs
    latest: Any  # the worker's newest value table (latency_ms, computed, grid_info, source) or None
    map: Any  # MapData or None
    map_error: str
    maps_rejected: int
    odom_received: float | None
    counts: dict[str, int]
    inferences: int
    inference_errors: int
    filter_ms: dict[str, float] | None
    type_mismatch: list[str]
    refinement: dict[str, Any] | None
    model: str
    runtime: str
    symmetry_average: Any
    sources: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)  # per observation source
    reaction_ms: dict[str, float] | None = None  # observation received -> value table, last 200
    map_reaction_ms: dict[str, float] | None = None  # map received -> its first value table, last 200
    signed_distance_ms: float | None = None  # the last map's signed distance


def build(s: StatusInputs) -> dict[str, Any]:
    """The status JSON of a configured node (docs/node.md, "Status JSON")."""
    ahead = s.certificate is not None
    name, why = mode(s.enabled, s.reason, s.decision, nan_if_none(s.certificate if ahead else s.value),
                     0.0 if ahead else s.settings.epsilon)
    m, latest, counts, state = s.map, s.latest, s.counts, s.state
    robot = None if state is None else {"x": round(state.x, 4), "y": round(state.y, 4), "v": round(state.v, 4),
                                        "theta": round(state.theta, 4), "frame_id": state.frame_id}
    return {
        "state": name, "reason": why, "value": s.value, "certificate": s.certificate, "robot": robot,
        "epsilon": s.settings.epsilon,
        "epsilon_calibrated": s.epsilon_calibrated,
        "epsilon_below_calibrated": s.epsilon_below_calibrated,
        "refine_epsilon": s.refined[0] if s.refined is not None else None,
        "refine_epsilon_from_s": s.refined[1] if s.refined is not None else None,
        "filter_mode": s.settings.mode,
        "inference_latency_ms": round(latest.latency_ms, 2) if latest else None,
        "filter_ms": s.filter_ms,
        "value_age_s": round(s.now - latest.computed, 3) if latest else None,
        "odom_age_s": round(s.now - s.odom_received, 3) if s.odom_received is not None else None,
        "map_age_s": round(s.now - m.received, 3) if m else None,
        "map_stamp": [m.stamp.sec, m.stamp.nanosec] if m else None,
        "last_map_error": s.map_error,
        "cmd_type_mismatch": list(s.type_mismatch),
        "dropped": {**{k: counts[k] for k in ("cmd", "odom", "pose")}, "map": s.maps_rejected},
        "counts": {**{k: counts[k] for k in ("commands", "interventions", "clipped", "stops")},
                   "inferences": s.inferences, "inference_errors": s.inference_errors},
        "value_grid": latest.grid_info if latest else None,
        "value_source": latest.source if latest else None,
        "refinement": s.refinement,
        "model": s.model,
        "runtime": s.runtime,
        "symmetry_average": s.symmetry_average,
        "observation_sources": s.sources,
        "observation_to_table_ms": s.reaction_ms,
        "map_to_table_ms": s.map_reaction_ms,
        "signed_distance_ms": None if s.signed_distance_ms is None else round(s.signed_distance_ms, 2),
    }


def diagnostics(status: dict[str, Any], name: str, stamp: Any) -> DiagnosticArray:
    """The status as one DiagnosticStatus: OK (ok, intervening), WARN (clipped, bypassed, unsafe_idle), ERROR
    (fail_closed)."""
    flat = {k: v for k, v in status.items() if k not in NESTED}
    if status.get("epsilon_below_calibrated") or status.get("cmd_type_mismatch"):
        entry_level = max(LEVELS[status["state"]], DiagnosticStatus.WARN)
    else:
        entry_level = LEVELS[status["state"]]
    flat.update({f"dropped_{k}": v for k, v in status["dropped"].items()})
    flat.update(status["counts"])
    flat["cmd_type_mismatch"] = "; ".join(status["cmd_type_mismatch"])
    entry = DiagnosticStatus(level=entry_level, name=f"{name}: BRT safety filter",
                             message=status["reason"], hardware_id="hjrno_ros",
                             values=[KeyValue(key=k, value=str(v)) for k, v in flat.items()])
    msg = DiagnosticArray(status=[entry])
    msg.header.stamp = stamp
    return msg
