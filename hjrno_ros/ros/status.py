"""What the node reports: counters, command-path timing, the status state and its diagnostics form."""

from __future__ import annotations

import collections
import dataclasses
import threading
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

STATUS_PERIOD = 0.1  # s
DIAGNOSTICS_PERIOD = 1.0  # s
LEVELS = {"ok": DiagnosticStatus.OK, "intervening": DiagnosticStatus.OK, "bypassed": DiagnosticStatus.WARN,
          "unsafe_idle": DiagnosticStatus.WARN, "fail_closed": DiagnosticStatus.ERROR}
NESTED = ("dropped", "counts", "value_grid", "robot", "filter_ms", "refinement")


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
        times = np.asarray(self._times) * 1e3
        if not times.size:
            return None
        return {"p50": round(float(np.percentile(times, 50)), 3), "p95": round(float(np.percentile(times, 95)), 3),
                "max": round(float(times.max()), 3)}


def mode(enabled: bool, reason: str, decision: Any, value: float, epsilon: float) -> tuple[str, str]:
    """(state, reason) of the status, for the present: bypassed; fail_closed; with a recent nominal command,
    intervening or ok as the filter would decide now (``decision``); without one, unsafe_idle when
    V ≤ ε (the next command will be changed), else ok."""
    if not enabled:
        return "bypassed", "filter bypassed via ~/enable"
    if reason:
        return "fail_closed", reason
    if decision is not None:
        return ("intervening", decision.reason) if decision.intervened else ("ok", decision.reason)
    if value <= epsilon:
        return "unsafe_idle", f"V = {value:.3f} m <= epsilon {epsilon:g} m with no recent command"
    return "ok", "pass"


def diagnostics(status: dict[str, Any], name: str, stamp: Any) -> DiagnosticArray:
    """The status as one DiagnosticStatus: OK (ok, intervening), WARN (bypassed), ERROR (fail_closed)."""
    flat = {k: v for k, v in status.items() if k not in NESTED}
    if status.get("epsilon_below_calibrated"):
        entry_level = max(LEVELS[status["state"]], DiagnosticStatus.WARN)
    else:
        entry_level = LEVELS[status["state"]]
    flat.update({f"dropped_{k}": v for k, v in status["dropped"].items()})
    flat.update(status["counts"])
    entry = DiagnosticStatus(level=entry_level, name=f"{name}: BRT safety filter",
                             message=status["reason"], hardware_id="hjrno_ros",
                             values=[KeyValue(key=k, value=str(v)) for k, v in flat.items()])
    msg = DiagnosticArray(status=[entry])
    msg.header.stamp = stamp
    return msg
