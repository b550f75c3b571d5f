"""The harness's one simulated base: a robot on brt_node's topics, on its own ROS context.

:class:`SimBase` publishes the map (latched), odometry in the map frame from its :class:`Plant` every physics step,
and its driver's nominal commands on ``cmd_vel_smoothed``; it steps the plant with the latest *filtered* command
from ``cmd_vel``, and a filtered command older than ``cmd_timeout`` counts as zero (a base's watchdog).
``direct``: no filter in the loop, the plant executes the nominal.  TwistStamped commands are matched to the node's
answers by stamp (latency; a change counts as an intervention; a stop that answers none is the node's fail-closed
timer); Twist commands are compared with the last nominal.  It logs what every user of the harness reads (trace,
latencies, interventions, value grids, map → value grid latency, the node's status).  With ``agents`` it also
publishes tracked agents (:func:`agents_message`: a perfect tracker's PointCloud2) for an ``agents`` observation
source.

The simulated robots (IR-SIM, the kinematic base of the depot check and the product scenes), the node bench's load
generator, the fuzzer and the DDS tests are all this node with another plant and driver: docs/design.md, "The
harness".
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np
from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import OccupancyGrid, Odometry
from rcl_interfaces.srv import SetParameters
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import LaserScan, PointCloud2, PointField
from std_msgs.msg import String
from std_srvs.srv import SetBool

from hjrno_ros.ros.brt_node.messages import LATCHED, occupancy_message, odometry_message
from hjrno_ros.ros.harness.commands import StampedCommands, unsafe_grid
from hjrno_ros.studies.navigation import STOPPED_SPEED, STOPPED_TURN

NODE_NAME = "brt_node"
AGENTS_QOS = 10  # reliable, volatile, depth 10: what a people tracker publishes (the node subscribes best effort)


class Plant(Protocol):
    """What a simulated base moves: a pose, a velocity, and one physics step under a (linear, angular) command."""

    def pose(self) -> tuple[float, float, float]:
        """(x, y, θ) in the map frame, m and rad."""

    def velocity(self) -> tuple[float, float]:
        """(linear, angular), m/s and rad/s."""

    def step(self, twist: np.ndarray, dt: float) -> str | None:
        """Execute ``twist`` for ``dt`` s; "collision" or "exit" when that ends the episode, else None."""


Driver = Callable[[np.ndarray, float], "np.ndarray | None"]
"""The nominal command (linear, angular) from the state (x, y, v, θ) and the episode's time; None: send nothing."""


@dataclasses.dataclass
class BaseLog:
    """What the base records while running (an episode); ``status`` and ``grids`` always."""

    trace: list = dataclasses.field(default_factory=list)  # (t, x, y, v, θ, changed) before each physics step
    latency_s: list = dataclasses.field(default_factory=list)  # nominal → filtered, matched by stamp
    grids: list = dataclasses.field(default_factory=list)  # (t, origin, resolution, unsafe mask [ix, iy])
    map_latency_s: list = dataclasses.field(default_factory=list)  # map sent → its value grid
    outputs: list = dataclasses.field(default_factory=list)  # (linear, angular): Twist answers, running
    commands: int = 0
    changed: int = 0  # answers that differ from their nominal, while running
    stopped: int = 0  # physics steps at rest (|v|, |ω| below STOPPED_*) while running
    stops_before: int = 0  # the node's fail-closed stop count when running began
    outcome: str | None = None  # "collision", "exit" or None
    ended_at: float | None = None  # s of the episode's clock
    status: dict = dataclasses.field(default_factory=dict)
    first_status_at: float | None = None  # monotonic s


@dataclasses.dataclass
class Rates:
    """Timing of a base: physics and odometry every ``physics_s`` (0: no timer, the user publishes), nominal commands
    every ``command_s`` (the same period: one timer, command first), and the watchdog: a filtered command older
    than ``cmd_timeout`` counts as zero."""

    physics_s: float = 0.02
    command_s: float = 0.05
    cmd_timeout: float = 0.25


class SimBase(Node):
    """A simulated base on brt_node's topics (module docstring).  ``stamped``: TwistStamped commands, else Twist;
    ``scan``: a callable giving the LaserScan to publish every ``scan_every`` physics steps; ``agents``: likewise
    the tracked agents' PointCloud2 every ``agents_every`` steps on ``agents_topic``; ``keep_grids``: log the
    value grids; ``keep``: how many unanswered stamped commands to remember (None: all)."""

    def __init__(self, context: Any, plant: Plant | None, driver: Driver | None = None, *, name: str = "sim_base",
                 rates: Rates | None = None, stamped: bool = True, direct: bool = False,
                 scan: Callable[[Any], LaserScan] | None = None, scan_every: int = 0, keep_grids: bool = True,
                 keep: int | None = None, frame_id: str = "map", agents: Callable[[Any], PointCloud2] | None = None,
                 agents_every: int = 0, agents_topic: str = "tracked_agents") -> None:
        super().__init__(name, context=context)
        self.plant, self.driver, self.direct, self.frame_id = plant, driver, direct, frame_id
        self.rates = rates or Rates()
        self.stamped, self.keep_grids = stamped, keep_grids
        self.log = BaseLog()
        self.running = False
        self.t0 = time.monotonic()
        self.filtered, self.filtered_at = np.zeros(2), -math.inf
        self.nominal: np.ndarray | None = None  # the last one sent
        self._changed = False
        kind = TwistStamped if stamped else Twist
        self.map_pub = self.create_publisher(OccupancyGrid, "map", LATCHED)
        self.odom_pub = self.create_publisher(Odometry, "odom", 10)
        self.cmd_pub = self.create_publisher(kind, "cmd_vel_smoothed", 10)
        self.commands = StampedCommands(self, self.cmd_pub, keep=keep)
        self.create_subscription(kind, "cmd_vel", self.on_filtered, 50)
        self.create_subscription(OccupancyGrid, "brt/value_grid", self.on_grid, LATCHED)
        self.create_subscription(String, "brt/status", self.on_status, 10)
        self._map_sent: dict[tuple[int, int], float] = {}
        self.scan, self.scan_every, self._ticks = scan, scan_every, 0
        self.scan_pub = self.create_publisher(LaserScan, "scan", qos_profile_sensor_data) if scan else None
        self.agents, self.agents_every = agents, agents_every
        self.agents_pub = self.create_publisher(PointCloud2, agents_topic, AGENTS_QOS) if agents else None
        self._service_clients: dict[str, Any] = {}
        r = self.rates
        if r.physics_s > 0 and plant is not None:
            same = math.isclose(r.command_s, r.physics_s)
            self.create_timer(r.physics_s, self._command_and_step if same else self._step)
            if not same:
                self.create_timer(r.command_s, self._command)

    # ------------------------------------------------------------------ the episode
    def now(self) -> float:
        """s since the episode began."""
        return time.monotonic() - self.t0

    def begin(self) -> None:
        """Start the episode's clock and motion (brt_node filters); the node's stops count from here."""
        self.log.stops_before = self.log.status.get("counts", {}).get("stops", 0)
        self.running, self.t0 = True, time.monotonic()

    @property
    def ended(self) -> bool:
        return self.log.outcome is not None or bool(getattr(self.driver, "finished", False))

    def state(self) -> np.ndarray:
        """(x, y, v, θ) of the plant."""
        x, y, theta = self.plant.pose()
        return np.array([x, y, self.plant.velocity()[0], theta])

    # ------------------------------------------------------------------ timers
    def _command_and_step(self) -> None:
        self._command()
        self._step()

    def _command(self) -> None:
        """The driver's nominal command, sent (or executed directly)."""
        if not self.running or self.ended or self.driver is None:
            return
        nominal = self.driver(self.state(), self.now())
        if nominal is not None:
            self.send(np.asarray(nominal, float))

    def _step(self) -> None:
        """One physics step with the latest fresh filtered command, then odometry (and a scan, agents when due)."""
        if self.running and not self.ended:
            t = self.now()
            (x, y, theta), (v, omega) = self.plant.pose(), self.plant.velocity()
            self.log.trace.append((t, x, y, v, theta, self._changed))
            self.log.stopped += abs(v) < STOPPED_SPEED and abs(omega) < STOPPED_TURN
            fresh = time.monotonic() - self.filtered_at <= self.rates.cmd_timeout
            outcome = self.plant.step(self.filtered if fresh else np.zeros(2), self.rates.physics_s)
            if outcome is not None:
                self.log.outcome, self.log.ended_at = outcome, t
        self.publish_odometry()
        self._ticks += 1
        if self.scan is not None and self._ticks % self.scan_every == 0:
            self.scan_pub.publish(self.scan(self.get_clock().now().to_msg()))
        if self.agents is not None and self._ticks % self.agents_every == 0:
            self.agents_pub.publish(self.agents(self.get_clock().now().to_msg()))

    def odometry(self) -> Odometry:
        """The plant's odometry message, stamped now."""
        (x, y, theta), (v, _) = self.plant.pose(), self.plant.velocity()
        return odometry_message(x, y, theta, v, self.frame_id, self.get_clock().now().to_msg())

    def publish_odometry(self) -> None:
        self.odom_pub.publish(self.odometry())

    # ------------------------------------------------------------------ commands
    def send(self, nominal: np.ndarray) -> None:
        """One nominal command to the node (``direct``: straight to the plant)."""
        self.log.commands += 1
        self.nominal = nominal
        if self.direct:
            self.filtered, self.filtered_at, self._changed = nominal, time.monotonic(), False
        elif self.stamped:
            self.commands.send(nominal)
        else:
            msg = Twist()
            msg.linear.x, msg.angular.z = float(nominal[0]), float(nominal[1])
            self.cmd_pub.publish(msg)

    def on_filtered(self, msg: TwistStamped | Twist) -> None:
        """A filtered command from the node: the plant's next command; latency and intervention logged."""
        self.filtered_at = time.monotonic()
        if not self.stamped:
            self.filtered = np.array([msg.linear.x, msg.angular.z])
            if self.running:
                self.log.outputs.append(tuple(self.filtered))
            self._changed = self.nominal is not None and bool(np.abs(self.filtered - self.nominal).max() > 1e-6)
            self.log.changed += self.running and self._changed
            return
        self.filtered, latency, changed = self.commands.answer(msg)
        if latency is None:  # the node's fail-closed timer: a stop that answers no command
            return
        self.log.latency_s.append(latency)
        self._changed = changed
        self.log.changed += self.running and changed

    # ------------------------------------------------------------------ map, grids, status
    def publish_map(self, occupancy: np.ndarray, resolution: float, origin: tuple[float, float],
                    sec: int | None = None) -> None:
        """Latch a map (stamped now, or at ``sec`` s); its value grid's latency is logged when it comes."""
        msg = occupancy_message(occupancy, resolution, origin, self.frame_id)
        if sec is None:
            msg.header.stamp = self.get_clock().now().to_msg()
        else:
            msg.header.stamp.sec = sec
        self._map_sent[(msg.header.stamp.sec, msg.header.stamp.nanosec)] = time.perf_counter()
        self.map_pub.publish(msg)

    def on_grid(self, msg: OccupancyGrid) -> None:
        stamp = msg.info.map_load_time
        sent = self._map_sent.pop((stamp.sec, stamp.nanosec), None)
        if sent is not None:
            self.log.map_latency_s.append(time.perf_counter() - sent)
        if self.keep_grids:
            self.log.grids.append(unsafe_grid(msg, self.now()))

    def on_status(self, msg: String) -> None:
        if self.log.first_status_at is None:
            self.log.first_status_at = time.monotonic()
        self.log.status = json.loads(msg.data)

    # ------------------------------------------------------------------ the node's services
    def client(self, kind: str) -> Any:
        """The node's ``set_parameters`` or ``enable`` service client (made once)."""
        if kind not in self._service_clients:
            srv = {"set_parameters": SetParameters, "enable": SetBool}[kind]
            self._service_clients[kind] = self.create_client(srv, f"/{NODE_NAME}/{kind}")
        return self._service_clients[kind]

    def call(self, client: Any, request: Any, timeout: float = 5.0) -> Any:
        """Call a service (a client, or the name of one of the node's: set_parameters, enable) from another thread
        than the executor's; the response, or None when it is unavailable or does not answer within ``timeout`` s."""
        client = self.client(client) if isinstance(client, str) else client
        if not client.wait_for_service(timeout_sec=timeout):
            return None
        future = client.call_async(request)
        end = time.monotonic() + timeout
        while not future.done() and time.monotonic() < end:
            time.sleep(0.005)
        return future.result() if future.done() else None


def agents_message(positions: np.ndarray, velocities: np.ndarray, radii: np.ndarray | None, stamp: Any,
                   frame: str = "map", dtype: str = "<f4") -> PointCloud2:
    """Tracked agents as brt_node's ``agents`` source reads them: a PointCloud2, one point per agent with fields
    x, y, vx, vy (m, m/s) and radius (m; none when ``radii`` is None), of numpy ``dtype`` (``<f4``; ``>f8``:
    big-endian FLOAT64), one row; ``stamp`` None: zero."""
    names = ["x", "y", "vx", "vy", *(["radius"] if radii is not None else [])]
    columns = [*np.asarray(positions, float).reshape(-1, 2).T, *np.asarray(velocities, float).reshape(-1, 2).T]
    if radii is not None:
        columns.append(np.asarray(radii, float).reshape(-1))
    kind = np.dtype(dtype)
    msg = PointCloud2()
    msg.header.frame_id = frame
    if stamp is not None:
        msg.header.stamp = stamp
    msg.height, msg.width = 1, len(columns[0])
    datatype = PointField.FLOAT64 if kind.itemsize == 8 else PointField.FLOAT32
    msg.fields = [PointField(name=n, offset=i * kind.itemsize, datatype=datatype, count=1)
                  for i, n in enumerate(names)]
    msg.is_bigendian, msg.is_dense = kind.byteorder == ">", True
    msg.point_step, msg.row_step = len(names) * kind.itemsize, len(names) * kind.itemsize * msg.width
    msg.data = np.stack(columns, -1).astype(kind).tobytes() if msg.width else b""
    return msg
