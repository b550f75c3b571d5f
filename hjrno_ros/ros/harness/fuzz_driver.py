"""The DDS fuzzer: drives a running brt_node with a random mix of valid and hostile inputs and checks
every command it publishes.

:func:`fuzz_drive` publishes, on a private ROS domain, maps (200 × 200 cells at 0.1 m, origin (−10, −10), with
walls and boxes; and hostile ones: NaN/Inf/zero resolutions, wrong data lengths, values beyond −1..100, rotated,
tilted, mirrored, zero or NaN origin quaternions, far origins, tiny and huge cells, other frames), odometry and
poses (valid, and NaN/Inf/huge positions and speeds, subnormal speeds, tilted/mirrored/zero/NaN quaternions),
Twist commands (within the limits, beyond them, non-planar, NaN/Inf/huge) and parameter sets through
``/brt_node/set_parameters`` (wrong types, NaN, Inf, out-of-range values, unset; and now and then a sane set so
the node filters again).  Every command the node publishes must be finite, planar (linear.y/z and angular.x/y
zero) and within the model's limits: v_min ≤ linear ≤ v_max and |angular| ≤ κ_max·max(|v|, |v′|), v′ = linear
clipped to v ± a_max·dt, for one of the odometry speeds (clipped to [v_min, v_max], as the node does) and control
periods the node can have had (those sent in the last ``RACE_WINDOW`` seconds and the one before: odometry and
commands race).  Used by test/tools/test_fuzz.py (≤ 45 s) and ``hjrno bench fuzz`` (minutes, with RSS).
"""

from __future__ import annotations

import array
import collections
import json
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseWithCovarianceStamped, Twist
from nav_msgs.msg import OccupancyGrid, Odometry
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from std_msgs.msg import String

from hjrno_ros.core.dynamics import RobotParams
from hjrno_ros.core.model_card import ModelCard
from hjrno_ros.core.safety_filter import turn_bound
from hjrno_ros.ros.brt_node.messages import LATCHED, finite, planar_yaw
from hjrno_ros.ros.brt_node.parameters import PARAMETERS
from hjrno_ros.ros.brt_node.value_sources import resolve_model
from hjrno_ros.ros.harness.sim_base import SimBase
from hjrno_ros.ros.harness.spin import spin_in_background

POSE_TOPIC = "amcl_pose"  # the node under test runs with pose_topic:=amcl_pose, so poses are fuzzed too
RES, ORIGIN, SIZE = 0.1, (-10.0, -10.0), 200  # the valid map: 20 m × 20 m
RACE_WINDOW = 2.0  # s: odometry speeds and control periods sent this long before an output may be the node's
RATES = {"odom": 30.0, "cmd": 20.0, "pose": 2.0, "map": 0.8, "params": 0.6}  # Hz, on average
CLASSES = ("map_valid", "map_odd", "map_hostile", "odom_valid", "odom_odd", "odom_hostile", "pose_valid",
           "pose_hostile", "cmd_valid", "cmd_beyond", "cmd_nonplanar", "cmd_hostile", "param_sets", "params_sane")
HOSTILE = (math.nan, math.inf, -math.inf, 1e308, -1e308, 1e20, -1e20, 5e-324, -5e-324, 1e-310)
SANE = {"filter_mode": "blend", "odom_timeout": 0.5, "value_timeout": 1.0, "control_period": 0.05,
        "inference_rate": 10.0, "occupied_threshold": 50, "unknown_is_obstacle": True, "map_timeout": 0.0,
        "stop_pub_timeout": 2.0, "inflation_radius": -1.0, "recenter_distance": 1.0, "speed_tolerance": 0.05}


def model_limits(model: str | None = None) -> RobotParams:
    """The robot limits of the model the node loads (its card's dynamics)."""
    return ModelCard.load(resolve_model(str(model) if model else "")).dynamics


def angular_bound(p: RobotParams, v: float, linear: float, dt: float) -> float:
    """The largest |angular| the filter passes (safety_filter.turn_bound): ω_max, or for a car κ_max·max(|v|, |v′|),
    v′ = ``linear`` clipped to what the base reaches from v within a_max·dt."""
    return float(turn_bound(p, np.array([0.0, 0.0, v, 0.0]), np.float64(linear), dt))


def quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of Rz(yaw)·Ry(pitch)·Rx(roll)."""
    cr, sr, cp, sp, cy, sy = (f(a / 2) for a in (roll, pitch, yaw) for f in (math.cos, math.sin))
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy)


class FuzzDriver(SimBase):
    """The harness's base without a plant (it publishes everything itself, ``step``): the fuzz inputs out, and the
    node's outputs checked as they arrive."""

    def __init__(self, context: Any, seed: int, limits: RobotParams) -> None:
        super().__init__(context, None, name="brt_fuzz_driver", stamped=False, keep_grids=False)
        self.rng = np.random.default_rng(seed)
        self.limits = limits
        self.pose_pub = self.create_publisher(PoseWithCovarianceStamped, POSE_TOPIC, LATCHED)
        self.params = self.client("set_parameters")
        self._lock = threading.Lock()
        self.sent = collections.Counter({c: 0 for c in CLASSES})
        self.speeds: collections.deque[tuple[float, float]] = collections.deque([(0.0, 0.0)], maxlen=2000)
        self.periods: collections.deque[tuple[float, float]] = collections.deque([(0.0, 0.05)], maxlen=200)
        self.nominals: collections.deque[tuple[float, float, float]] = collections.deque(maxlen=200)
        self.outputs = self.passed = self.moving = self.stops = 0
        self.violations: list[dict] = []
        self.status: dict = {}
        self.status_times: list[float] = []
        self.states = collections.Counter()
        self.modes = collections.Counter()
        self.params_accepted = self.params_rejected = 0
        self.rejections = collections.Counter()
        self.pose = [0.0, 0.0, 0.0]  # x, y, yaw of the robot in the map
        self.speed, self.speed_until = 0.5, 0.0
        self.map_sec = 0
        self.maps = [self._valid_map(k) for k in range(4)]

    # ------------------------------------------------------------------ outputs
    def on_status(self, msg: String) -> None:
        now = time.monotonic()
        try:
            status = json.loads(msg.data)
        except ValueError:
            status = {"state": "unparsable"}
        with self._lock:
            self.status_times.append(now)
            self.status = status
            self.states[status.get("state")] += 1
            self.modes[status.get("filter_mode")] += 1

    def _candidates(self, history: collections.deque, now: float) -> list[float]:
        """Values sent in the last RACE_WINDOW s, and the last one before."""
        recent = [v for t, v in history if t >= now - RACE_WINDOW]
        before = [v for t, v in history if t < now - RACE_WINDOW]
        return recent + before[-1:]

    def on_filtered(self, msg: Twist) -> None:
        now = time.monotonic()
        p = self.limits
        lin, ang = msg.linear.x, msg.angular.z
        with self._lock:
            self.outputs += 1
            speeds = [min(max(v, p.v_min), p.v_max) for v in self._candidates(self.speeds, now)]
            periods = self._candidates(self.periods, now)
            nominal = any(n[1] == lin and n[2] == ang for n in self.nominals if n[0] >= now - 1.0)
        problems = []
        values = (msg.linear.x, msg.linear.y, msg.linear.z, msg.angular.x, msg.angular.y, msg.angular.z)
        if not finite(*values):
            problems.append("non-finite")
        if values[1:5] != (0.0, 0.0, 0.0, 0.0):
            problems.append("non-planar")
        if not p.v_min <= lin <= p.v_max:
            problems.append("linear beyond [v_min, v_max]")
        bound = max((angular_bound(p, v, lin, dt) for v in speeds for dt in periods), default=0.0)
        if finite(lin, ang) and not abs(ang) <= bound * (1 + 1e-9) + 1e-12:
            problems.append("angular beyond the bound")
        with self._lock:
            if problems:
                self.violations.append({"t": round(now, 3), "problems": problems, "out": list(values),
                                        "bound": bound, "speeds": speeds, "periods": periods,
                                        "status": {k: self.status.get(k) for k in ("state", "reason", "filter_mode")}})
            elif lin == 0.0 and ang == 0.0:
                self.stops += 1
            elif nominal:
                self.passed += 1
            else:
                self.moving += 1

    # ------------------------------------------------------------------ inputs
    def _valid_map(self, k: int) -> np.ndarray:
        occ = np.zeros((SIZE, SIZE), np.int8)  # [ix, iy]
        occ[:3], occ[-3:], occ[:, :3], occ[:, -3:] = 100, 100, 100, 100
        rng = np.random.default_rng(1000 + k)
        for _ in range(8):
            x, y = rng.integers(10, SIZE - 30, 2)
            w, h = rng.integers(3, 25, 2)
            occ[x:x + w, y:y + h] = 100
        x, y = rng.integers(10, SIZE - 30, 2)
        occ[x:x + 15, y:y + 15] = -1
        return occ

    def _map_msg(self, occ: np.ndarray, res: float = RES, origin: tuple[float, float] = ORIGIN,
                 q: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0), frame: str = "map") -> OccupancyGrid:
        msg = OccupancyGrid()
        self.map_sec += 1
        msg.header.frame_id = frame
        msg.header.stamp.sec = self.map_sec
        msg.info.resolution = float(res)
        msg.info.width, msg.info.height = int(occ.shape[0]), int(occ.shape[1])
        msg.info.origin.position.x, msg.info.origin.position.y = float(origin[0]), float(origin[1])
        o = msg.info.origin.orientation
        o.x, o.y, o.z, o.w = (float(c) for c in q)
        msg.data = array.array("b", np.ascontiguousarray(occ.T, np.int8).tobytes())
        return msg

    def send_map(self, kind: str | None = None) -> None:
        rng = self.rng
        occ = self.maps[rng.integers(len(self.maps))]
        kind = kind or str(rng.choice(["valid"] * 5 + ["odd"] * 3 + ["hostile"] * 4))
        if kind == "valid":
            msg = self._map_msg(occ)
        elif kind == "odd":  # accepted, but far from the usual
            choice = rng.integers(7)
            if choice == 0:
                msg = self._map_msg(occ, q=(0.0, 0.0, 0.0, float(rng.choice([2.0, 1e-3, -1.0]))))  # not normalised
            elif choice == 1:
                msg = self._map_msg(occ, res=float(rng.choice([1e-6, 1e-3, 10.0, 1e3])))
            elif choice == 2:
                msg = self._map_msg(occ, origin=(float(rng.choice([1e6, -1e12, 1e20])), -10.0))
            elif choice == 3:
                msg = self._map_msg(occ, frame=str(rng.choice(["odom", ""])))
            elif choice == 4:
                msg = self._map_msg(np.full((1, 1), int(rng.choice([0, 100, -1])), np.int8))
            elif choice == 5:
                big = np.zeros((800, 800), np.int8)
                big[::50, :] = 100
                msg = self._map_msg(big, res=0.025)
            else:
                msg = self._map_msg(np.full((SIZE, SIZE), int(rng.choice([-1, 100, 0])), np.int8))
        else:
            choice = rng.integers(8)
            msg = self._map_msg(occ)
            if choice == 0:
                msg.info.resolution = float(rng.choice([math.nan, math.inf, 0.0, -0.1, -math.inf]))
            elif choice == 1:
                msg.data = msg.data[:int(rng.integers(0, len(msg.data)))]
            elif choice == 2:
                msg.info.width, msg.info.height = int(rng.choice([0, 2 ** 32 - 1])), int(rng.choice([SIZE, 0]))
            elif choice == 3:
                bad = occ.copy()
                bad[rng.integers(SIZE), rng.integers(SIZE)] = int(rng.choice([-128, -2, 101, 127]))
                msg = self._map_msg(bad)
            elif choice == 4:  # rotated, tilted, mirrored
                msg = self._map_msg(occ, q=quaternion(*[(0.0, 0.0, 0.5), (0.3, 0.0, 0.0), (math.pi, 0.0, 0.0),
                                                        (0.0, 0.0, math.pi)][rng.integers(4)]))
            elif choice == 5:
                msg = self._map_msg(occ, q=[(0.0, 0.0, 0.0, 0.0), (math.nan, 0.0, 0.0, 1.0),
                                            (0.0, 0.0, math.inf, 1.0), (1e-9, 0.0, 0.0, 1e-9)][rng.integers(4)])
            elif choice == 6:
                msg = self._map_msg(occ, origin=(float(rng.choice([math.nan, math.inf])), 0.0))
            else:
                msg.info.width = SIZE + 1
        self.sent["map_" + kind] += 1
        self.map_pub.publish(msg)

    def _move(self, now: float) -> None:
        """The robot's pose: a random walk over the valid map, now and then a jump (near walls and boxes too)."""
        rng = self.rng
        if rng.random() < 0.01:
            self.pose = [float(rng.uniform(-9.5, 9.5)), float(rng.uniform(-9.5, 9.5)), float(rng.uniform(-4, 4))]
        else:
            self.pose[0] = float(np.clip(self.pose[0] + rng.normal(0, 0.02) + 0.02 * math.cos(self.pose[2]), -9.7, 9.7))
            self.pose[1] = float(np.clip(self.pose[1] + rng.normal(0, 0.02) + 0.02 * math.sin(self.pose[2]), -9.7, 9.7))
            self.pose[2] += float(rng.normal(0, 0.05))
        if now >= self.speed_until:  # hold each speed 1-2 s, so that the race window mostly holds one
            self.speed = float(rng.choice([rng.uniform(0, 1), rng.uniform(0, 1), 0.0, 1.0, 1.04, -0.03, 1e-310,
                                           5e-324, 0.02]))
            self.speed_until = now + float(rng.uniform(1.0, 2.0))

    def send_odom(self, now: float, kind: str | None = None) -> None:
        """One odometry message: ``kind`` valid, odd (accepted, unusual) or hostile (dropped); random if None."""
        rng = self.rng
        if kind is None:
            self._move(now)
        msg = Odometry()
        msg.header.frame_id = "odom"
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.child_frame_id = "base_link"
        x, y, yaw = self.pose
        v = self.speed
        q = quaternion(float(rng.normal(0, 0.02)), float(rng.normal(0, 0.02)), yaw)
        kind = kind or str(rng.choice(["valid"] * 8 + ["odd", "hostile", "hostile"]))
        if kind == "odd":  # accepted: a speed beyond the model's range, a far position, a non-normalised q
            choice = rng.integers(3)
            if choice == 0:
                v = float(rng.choice([5.0, -2.0, 1e6, 1e300]))
            elif choice == 1:
                x = float(rng.choice([1e20, -1e12, 1e300]))
            else:
                q = tuple(c * float(rng.choice([3.0, 1e-4, 1e100])) for c in q)
        elif kind == "hostile":  # dropped by the node
            choice = rng.integers(3)
            if choice == 0:
                x, y, v = (float(rng.choice(HOSTILE[:3])) if rng.random() < 0.5 else c for c in (x, y, v))
                if finite(x, y, v):
                    v = math.nan
            elif choice == 1:
                q = quaternion(*[(0.5, 0.0, yaw), (0.0, -0.4, yaw), (math.pi, 0.0, yaw)][rng.integers(3)])
            else:
                q = [(0.0, 0.0, 0.0, 0.0), (math.nan, 0.0, 0.0, 1.0), (0.0, math.inf, 0.0, 1.0),
                     (1e200, 0.0, 0.0, 1e200)][rng.integers(4)]
        msg.pose.pose.position.x, msg.pose.pose.position.y = x, y
        msg.pose.pose.orientation.x, msg.pose.pose.orientation.y, msg.pose.pose.orientation.z, \
            msg.pose.pose.orientation.w = (float(c) for c in q)
        msg.twist.twist.linear.x = v
        msg.twist.twist.angular.z = float(rng.normal(0, 0.3))
        accepted = finite(x, y, v) and planar_yaw(msg.pose.pose.orientation) is not None
        self.sent["odom_" + kind] += 1
        with self._lock:
            if accepted:  # the node's speed from now on (it drops the others)
                self.speeds.append((time.monotonic(), v))
        self.odom_pub.publish(msg)

    def send_pose(self, kind: str | None = None) -> None:
        rng = self.rng
        msg = PoseWithCovarianceStamped()
        msg.header.frame_id = "map"
        msg.header.stamp = self.get_clock().now().to_msg()
        x, y, yaw = self.pose
        q = quaternion(0.0, 0.0, yaw)
        kind = kind or ("valid" if rng.random() < 0.7 else "hostile")
        if kind == "hostile":
            choice = rng.integers(4)
            if choice == 0:
                x = float(rng.choice(HOSTILE))
            elif choice == 1:
                q = quaternion(float(rng.choice([0.5, math.pi])), 0.0, yaw)
            elif choice == 2:
                q = (0.0, 0.0, 0.0, float(rng.choice([0.0, math.nan])))
            else:
                msg.header.frame_id = "odom"
        msg.pose.pose.position.x, msg.pose.pose.position.y = x, y
        o = msg.pose.pose.orientation
        o.x, o.y, o.z, o.w = (float(c) for c in q)
        self.sent["pose_" + kind] += 1
        self.pose_pub.publish(msg)

    def send_cmd(self, now: float) -> None:
        rng = self.rng
        p = self.limits
        msg = Twist()
        kind = str(rng.choice(["valid"] * 5 + ["beyond"] * 2 + ["nonplanar", "hostile"]))
        lin = float(rng.uniform(p.v_min, p.v_max))
        speed = max(abs(self.speed), 0.05)
        ang = float(rng.uniform(-1, 1) * angular_bound(p, speed, speed, 0.0) * 0.9)
        if kind == "beyond":
            lin = float(rng.choice([lin, -0.5, 1.5, 3.0, 1e300, p.v_max + 1e-9]))
            ang = float(rng.choice([ang, 3.0, -5.0, -1e300, 1e-310]))
        msg.linear.x, msg.angular.z = lin, ang
        if kind == "nonplanar":
            field = ["linear.y", "linear.z", "angular.x", "angular.y"][rng.integers(4)]
            setattr(getattr(msg, field.split(".")[0]), field.split(".")[1], float(rng.choice([0.2, -1.0, 5e-324])))
        elif kind == "hostile":
            field = ["linear.x", "linear.y", "linear.z", "angular.x", "angular.y", "angular.z"][rng.integers(6)]
            setattr(getattr(msg, field.split(".")[0]), field.split(".")[1], float(rng.choice(HOSTILE[:3])))
        self.sent["cmd_" + kind] += 1
        with self._lock:
            self.nominals.append((now, msg.linear.x, msg.angular.z))
        self.cmd_pub.publish(msg)

    def _parameter(self, name: str, value: Any) -> ParameterMsg:
        if value is None:
            pv = ParameterValue(type=ParameterType.PARAMETER_NOT_SET)
        elif isinstance(value, bool):
            pv = ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=value)
        elif isinstance(value, int):
            pv = ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=value)
        elif isinstance(value, float):
            pv = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value)
        elif isinstance(value, str):
            pv = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value)
        else:
            pv = ParameterValue(type=ParameterType.PARAMETER_DOUBLE_ARRAY, double_array_value=[float(v) for v in value])
        return ParameterMsg(name=name, value=pv)

    def _random_value(self, name: str) -> Any:
        rng = self.rng
        spec = PARAMETERS[name]
        kind = rng.integers(10)
        if kind == 0:
            return None
        if kind == 1:
            return [float(rng.normal())]
        if kind == 2:
            return str(rng.choice(["", "x", "switch", "qp", "1.0"]))
        if kind == 3:
            return bool(rng.integers(2))
        if kind == 4:
            return int(rng.choice([-1, 0, 1, 5, 50, 101, 2 ** 63 - 1]))
        if kind == 5:
            return float(rng.choice(HOSTILE))
        if name == "filter_mode":
            return str(rng.choice(["blend", "switch", "qp"]))
        if spec.lo is not None:
            return float(rng.uniform(spec.lo, spec.hi)) if rng.random() < 0.7 else float(rng.choice([spec.lo, spec.hi]))
        return float(rng.uniform(-1.0, 1.0))

    def send_params(self, sane: bool = False, timeout: float = 3.0) -> None:
        """One SetParameters request: random names and values, or (``sane``) values the node filters with."""
        rng = self.rng
        if sane:
            values: dict[str, Any] = dict(SANE)
            values["filter_mode"] = str(rng.choice(["blend", "switch", "qp", "qp"]))
            values["epsilon"] = float(rng.choice([0.0, 0.1, 0.3, rng.uniform(0, 0.5)]))
            values["unknown_is_obstacle"] = bool(rng.random() < 0.8)
        else:
            names = [str(n) for n in rng.choice(list(PARAMETERS), int(rng.integers(1, 4)), replace=False)]
            values = {n: self._random_value(n) for n in names}
        self.sent["params_sane" if sane else "param_sets"] += 1
        request = SetParameters.Request(parameters=[self._parameter(n, v) for n, v in values.items()])
        if not self.params.service_is_ready():
            return
        period = values.get("control_period")
        if isinstance(period, int | float) and not isinstance(period, bool) and math.isfinite(period):
            with self._lock:  # the node may use it before its answer arrives
                self.periods.append((time.monotonic(), float(period)))
        future = self.params.call_async(request)
        end = time.monotonic() + timeout
        while not future.done() and time.monotonic() < end:
            time.sleep(0.005)
        if not future.done() or future.result() is None:
            self.rejections["no answer"] += 1
            return
        for result in future.result().results:
            if result.successful:
                self.params_accepted += 1
            else:
                self.params_rejected += 1
                self.rejections[result.reason.split(":")[0][:60]] += 1

    def step(self, now: float, due: dict[str, float]) -> None:
        """Publish whatever is due at ``now`` (exponential gaps around RATES)."""
        for name, at in due.items():
            if now < at:
                continue
            if name == "odom":
                self.send_odom(now)
            elif name == "cmd":
                self.send_cmd(now)
            elif name == "pose":
                self.send_pose()
            elif name == "map":
                self.send_map()
            else:
                self.send_params(sane=self.rng.random() < 0.35)
            due[name] = time.monotonic() + float(self.rng.exponential(1.0 / RATES[name]))


def fuzz_drive(domain_id: int, seconds: float, seed: int = 0, model: str | None = None,
               alive: Callable[[], bool] = lambda: True, on_tick: Callable[[float], None] | None = None,
               ready_timeout: float = 90.0) -> dict:
    """Fuzz the brt_node running on ``domain_id`` (started with ``pose_topic:=amcl_pose``) for ``seconds``.

    Waits until it filters (a valid map, pose and odometry), fuzzes, then sends sane parameters and valid inputs
    and waits (≤ 10 s) until it filters again.  ``on_tick(elapsed)`` is called about once a second while fuzzing.
    Returns counts by class, outputs, violations, status gaps, parameter answers and the node's last status."""
    driver, stop = spin_in_background(domain_id, lambda c: FuzzDriver(c, seed, model_limits(model)))
    filtering = ("ok", "intervening", "unsafe_idle")

    def settle(timeout: float) -> bool:
        """Valid inputs until the node filters (or ``timeout``)."""
        driver.send_map("valid")
        driver.pose = [-4.0, -4.0, 0.3]
        end = time.monotonic() + timeout
        pose_at = 0.0
        while time.monotonic() < end and alive():
            now = time.monotonic()
            driver.speed, driver.speed_until = 0.3, now + 1.0
            driver.send_odom(now, "valid")
            if now - pose_at > 0.5:
                driver.send_pose("valid")
                pose_at = now
            if driver.status.get("state") in filtering:
                return True
            time.sleep(0.03)
        return False

    try:
        ready = settle(ready_timeout)
        result: dict[str, Any] = {"ready": ready}
        start = time.monotonic()
        if ready:
            with driver._lock:
                driver.status_times.clear()
            due = {name: start for name in RATES}
            tick = start
            while time.monotonic() - start < seconds and alive():
                now = time.monotonic()
                driver.step(now, due)
                if on_tick is not None and now - tick >= 1.0:
                    tick = now
                    on_tick(now - start)
                time.sleep(max(0.0, min(due.values()) - time.monotonic()))
        fuzzed = time.monotonic() - start
        driver.send_params(sane=True)
        recovered = settle(15.0) if alive() else False
        time.sleep(0.3)
        with driver._lock:
            times = np.asarray(driver.status_times)
            gaps = np.diff(times) if len(times) > 1 else np.array([math.inf])
            result.update({
                "seconds": round(fuzzed, 1), "recovered": recovered, "sent": dict(driver.sent),
                "outputs": driver.outputs, "passed_unchanged": driver.passed, "filtered_moving": driver.moving,
                "stops": driver.stops, "violations": list(driver.violations),
                "statuses": len(times), "max_status_gap_s": round(float(gaps.max()), 3),
                "status_gaps_over_1s": int((gaps > 1.0).sum()), "states": dict(driver.states),
                "filter_modes": dict(driver.modes), "params_accepted": driver.params_accepted,
                "params_rejected": driver.params_rejected, "rejections": dict(driver.rejections.most_common(12)),
                "status": dict(driver.status)})
        return result
    finally:
        stop()

