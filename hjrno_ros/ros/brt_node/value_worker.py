"""The value worker: the node's own thread that keeps a value table around the robot.

At ``inference_rate`` it installs new maps (signed distance), and when the robot has left the window's centre,
the table is half ``value_timeout`` old or (a slice model's (v, θ) stencil, which spans what the robot reaches in
``STENCIL_HORIZON_S``) the robot is half way to its edge, it predicts V∞ on a window centred on the robot (a table
model: every speed and heading at once) and swaps the table in atomically.
With observation sources every new observation wakes it and makes a new table: V0 on the window is the minimum
of the map's signed distance and the fresh sources' (their obstacles off the map grown by the motion margin, but
those at a tracked agent, whose own value the node's certificate holds).
With background refinement (and no observation sources), the refined table of the current map replaces the
operator's while the robot is inside it.  It runs at a lower scheduling priority, so a busy CPU serves commands first.
``get`` is the value input of the fail-closed check.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import os
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from hjrno_ros.core import geometry
from hjrno_ros.core.braking import Clearance
from hjrno_ros.core.grids import wrap_angle
from hjrno_ros.core.point_obstacles import PointObstacles
from hjrno_ros.core.tracked_agents import Agents
from hjrno_ros.core.value_source import ValueSource
from hjrno_ros.ros.brt_node.config import NodeConfig
from hjrno_ros.ros.brt_node.inputs import MapData, MapInput, RobotState, StateInput
from hjrno_ros.ros.brt_node.observation_sources import (
    ObservationSource,
    fresh_agents,
    live_obstacles,
    update_trackers,
)
from hjrno_ros.ros.brt_node.parameters import obstacle_threshold
from hjrno_ros.ros.brt_node.refinement import Refinement

INFERENCE_NICE = 10  # the worker thread's nice value above the node's
STENCIL_HORIZON_S = 0.25  # s: a slice model's stencil holds what the robot reaches in this time (state age,
# command latency, one control period and the next inference, with the recompute at half of it)


@dataclasses.dataclass(frozen=True)
class ValueData:
    table: Any  # ValueTable or ReversingTable: the window's whole table, its (v, θ) stencil, or the refined map
    center: tuple[float, float]
    v: float
    theta: float
    computed: float  # monotonic s
    map_version: int
    latency_ms: float
    grid_info: dict  # origin/resolution/size of the published value grid
    source: str = "operator"  # or "refined"
    horizon: float = 0.0  # refined: simulated s of solver behind the table
    obstacles: tuple[PointObstacles, ...] = ()  # the live sources' obstacles the table was made with
    sources_version: tuple[int, ...] = ()  # their data versions
    tracks: tuple[Agents, ...] = ()  # the tracking scans' agents whose returns the table left without the margin


def table_state(state: RobotState, table_theta: float, v_lo: float, v_hi: float) -> np.ndarray:
    """(x, y, v, θ) to look up in a table whose stencil is centred on heading ``table_theta``: speed clipped
    to the model's range, heading unwrapped to within π of the centre (the stencil's headings are not
    wrapped, so −π + 0.05 must read as π + 0.05 beside a table made at π − 0.05, not clamp to its edge)."""
    s = state.vector(v_lo, v_hi)
    s[3] = table_theta + float(wrap_angle(s[3] - table_theta))
    return s


def map_distance(m: MapData, points: np.ndarray) -> np.ndarray:
    """The map's signed distance (m) at x-y ``points`` (..., 2).  Beyond the map, with ``unknown_is_obstacle``, that of
    a wall at the map's edge (minus the distance to the map: :func:`geometry.sample_walled`); without it, the nearest
    edge cell's value."""
    if m.unknown_is_obstacle:
        return geometry.sample_walled(m.sd, m.origin, m.resolution, points)
    return geometry.sample_raster(m.sd, m.origin, m.resolution, points)


def lower_thread_priority(nice: int) -> None:
    """Give the calling thread a higher nice value (Linux: per thread); a no-op where not allowed."""
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), os.getpriority(os.PRIO_PROCESS, 0) + nice)
    except (AttributeError, OSError):
        pass


class ValueWorker:
    """Owns the value table; ``start``/``stop`` its thread.  ``publish(values, info, map, state)`` is called
    from the worker after each new table; ``log(level, text)`` reports errors."""

    def __init__(self, vf: ValueSource, maps: MapInput, states: StateInput, cfg: Callable[[], NodeConfig],
                 publish: Callable[[np.ndarray, dict, MapData, RobotState], None],
                 log: Callable[[str, str], None], refinement: Refinement | None = None,
                 sources: list[ObservationSource] | None = None) -> None:
        self.vf, self.maps, self.states, self.cfg, self.publish, self.log = vf, maps, states, cfg, publish, log
        self.refinement = refinement
        self.sources = list(sources or [])
        self.reaction_s: collections.deque[float] = collections.deque(maxlen=200)  # observation received -> table
        self.map_reaction_s: collections.deque[float] = collections.deque(maxlen=200)  # map received -> its 1st table
        self.value: ValueData | None = None
        self.error = ""  # the last inference failure; "" after a success
        self.inferences = self.errors = 0
        self._dv = float(vf.grid.spacings[2])
        p = vf.params  # the speed and heading a slice model's stencil reaches either side of the state
        self.reach = (max(0.5 * self._dv, p.a_max * STENCIL_HORIZON_S),
                      max(0.5 * float(vf.grid.spacings[3]), p.turn_rate_max * STENCIL_HORIZON_S))
        wx, wy = vf.window
        nx, ny = vf.shape
        h = min(wx / (nx - 1), wy / (ny - 1))  # square value-grid cells, at least the model's resolution
        self.grid_shape, self.grid_resolution = (int(round(wx / h)) + 1, int(round(wy / h)) + 1), h
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ thread
    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def native_id(self) -> int | None:
        return self._thread.native_id if self._thread is not None else None

    def start(self) -> None:
        if self._thread is not None and self._thread.is_alive():
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name="brt_value_worker", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        """Stop the thread (before the ROS context goes: it publishes)."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None and self._thread.is_alive():
            self._thread.join(timeout=timeout)
        self._thread = None
        if self.refinement is not None:
            self.refinement.stop()

    def wake(self) -> None:
        self._wake.set()

    def _loop(self) -> None:
        lower_thread_priority(INFERENCE_NICE)
        while not self._stop.is_set():
            self._wake.wait(1.0 / self.cfg().inference_rate)
            self._wake.clear()
            if self._stop.is_set():
                break
            try:
                self.step()
            except Exception as err:  # fail closed until the next successful inference
                self.errors += 1
                first = str(err).splitlines()[0] if str(err) else ""
                self.error = f"inference failed: {type(err).__name__}: {first}"
                if not self._stop.is_set():
                    self.log("error", self.error)

    # ------------------------------------------------------------------ work
    def inflation(self, map_resolution: float = 0.0, model_grid: bool = True) -> float:
        """The inflation in metres: ``footprint_radius`` plus ``inflation_radius``, or for -1 half the cell diagonal
        of the coarser of the model grid and the map (interpolating either between its nodes can overestimate the
        clearance by that much: docs/design.md, "Inflation"); ``model_grid`` False: of the map alone (what the
        braking bound, which reads the map and not the model's grid, needs)."""
        cfg = self.cfg()
        radius = cfg.inflation_radius
        if radius >= 0:
            return cfg.footprint_radius + float(radius)
        grid = self.vf.grid.half_cell_diagonal if model_grid else 0.0
        return cfg.footprint_radius + max(grid, map_resolution / math.sqrt(2))

    def clearance(self, m: MapData, points: np.ndarray, obstacles: tuple[PointObstacles, ...] = ()) -> np.ndarray:
        """The braking bound's clearance at x-y ``points``: the map's signed distance, or the live ``obstacles``'
        distance where less, minus the footprint and the map's own interpolation margin (m)."""
        sd = map_distance(m, points)
        for obstacle in obstacles:
            sd = np.minimum(sd, obstacle.distance(points))
        return sd - self.inflation(m.resolution, model_grid=False)

    def stop_time(self) -> float:
        """s: the robot's longest stop, from its top speed at a_max."""
        p = self.vf.params
        return max(abs(p.v_min), abs(p.v_max)) / p.a_max

    def moving_horizon(self) -> float:
        """s: how long a live obstacle that is not on the static map may approach before the robot, at its top
        speed, has stopped: the time to stop, ``command_latency`` and the largest source timeout (the oldest data
        the node filters with).  The value table's V0 grows such obstacles by their speed times this; the braking
        bound by the data's actual age and the robot's own stop (docs/design.md, "Moving obstacles")."""
        timeout = max((s.config.timeout for s in self.sources), default=0.0)
        return self.stop_time() + self.cfg().command_latency + timeout

    def moving_margin(self) -> float:
        """m: the value table's margin around live obstacles off the static map, ``obstacle_speed_max`` times
        :meth:`moving_horizon`."""
        return self.cfg().obstacle_speed_max * self.moving_horizon()

    def braking_clearances(self, m: MapData, obstacles: tuple[PointObstacles, ...], now: float
                           ) -> tuple[Clearance, tuple[Clearance, float] | None]:
        """The braking bound's clearances: of the map and the obstacles that stand still, and of those that may
        approach as at monotonic time ``now`` (grown by their speed over their data's age then), with their speed
        (None without such obstacles); core/braking.py, core/least_restrictive.py (``at``: later times)."""
        still = tuple(o for o in obstacles if not o.approach)
        moving = tuple(o for o in obstacles if o.approach)

        def approaching(points: np.ndarray) -> np.ndarray:
            least = np.min([o.distance(points) - o.approach * max(now - o.received, 0.0) for o in moving], axis=0)
            return least - self.inflation(m.resolution, model_grid=False)

        static = lambda points: self.clearance(m, points, still)  # noqa: E731
        return static, ((approaching, max(o.approach for o in moving)) if moving else None)

    def live_obstacles(self, m: MapData, state: RobotState, now: float
                       ) -> tuple[tuple[PointObstacles, ...], tuple[int, ...], str]:
        """The fresh sources' obstacles in the map frame, their versions, or why a required source is unusable.
        What a fresh agents source tracks, or a tracking scan's confirmed tracks, is not grown by the motion margin:
        the node's certificate holds each agent's own value (both need the agent table).  Tracking scans are fed to
        their trackers first."""
        if not self.sources:
            return (), (), ""
        pose_at = lambda stamp: self.states.pose_at(stamp, state)  # noqa: E731
        static_distance = lambda pts: map_distance(m, pts)  # noqa: E731
        update_trackers(self.sources, now, pose_at, static_distance)
        agents, reason = fresh_agents(self.sources, now, m.frame_id, scans=False)
        if reason:
            return (), (), reason
        obstacles, versions, reason = live_obstacles(self.sources, now, m.frame_id, pose_at, static_distance, agents,
                                                     self.cfg().obstacle_speed_max)
        return tuple(obstacles), versions, reason

    def v0(self, m: MapData, points: np.ndarray) -> np.ndarray:
        """V0 at x-y ``points`` (..., 2): the map's signed distance minus the inflation (float32, m)."""
        v0 = map_distance(m, points)
        return (v0 - self.inflation(m.resolution)).astype(np.float32)

    def step(self) -> None:
        cfg = self.cfg()
        problem = self.maps.install(obstacle_threshold(cfg), bool(cfg.unknown_is_obstacle))
        if problem:
            self.log("warning", f"map rejected: {problem}")
        m = self.maps.current
        if m is None:
            return
        refined = None
        if self.refinement is not None:
            self.refinement.step(m, self.v0, self.log)
        now = time.monotonic()
        state, _ = self.states.get(now, cfg.odom_timeout, m.frame_id)
        if state is None:
            return
        if self.refinement is not None and not self.sources:  # a refined table holds the static map only
            refined = self.refinement.usable(m, state)
        obstacles, versions, reason = self.live_obstacles(m, state, now)
        if reason:  # the node's check names the source and fails closed; no table without it
            return
        if not self._stale(m, state, refined, now, cfg) and versions == getattr(self.value, "sources_version", ()):
            return
        start = time.perf_counter()
        p = self.vf.params
        center = (state.x, state.y)
        v = min(max(state.v, p.v_min), p.v_max)
        if refined is None:
            if not self.vf.predicts:  # a solver card: no operator, wait for the solver's table
                return
            points = self.vf.window_points(center)
            v0 = self.v0(m, points)
            horizon = self.moving_horizon()
            for obstacle in obstacles:  # live sources; approaching ones over the data's life and top speed's stop
                d = obstacle.distance(points) - obstacle.approach * horizon - self.inflation(m.resolution)
                v0 = np.minimum(v0, d.astype(np.float32))
            table = self.vf.local_table(v0, center, v, state.theta, reach=self.reach)
        else:
            table = refined.table
        if cfg.filter_mode != "least_restrictive":  # the other modes read ∇V: make it here, not on a command
            table.prepare_gradient()
        latency = 1e3 * (time.perf_counter() - start)
        nodes = self.vf.window_points(center, self.grid_shape)
        states = np.concatenate([nodes, np.broadcast_to([v, state.theta], (*nodes.shape[:2], 2))], -1)
        values = table.value(states).astype(np.float32)  # (Nx, Ny)
        h = self.grid_resolution
        info = {"frame_id": m.frame_id, "origin": [float(nodes[0, 0, 0] - h / 2), float(nodes[0, 0, 1] - h / 2)],
                "resolution": h, "width": self.grid_shape[0], "height": self.grid_shape[1], "v": v,
                "theta": state.theta, "center": list(center), "inflation_radius": self.inflation(m.resolution),
                "source": "refined" if refined else "operator"}
        previous = self.value.sources_version if self.value is not None else ()
        new_map = m.version != getattr(self.value, "map_version", None) and m.version != self.maps.recomputed_version
        tracks = tuple(s.tracked[1] for s, version in zip(self.sources, versions, strict=True)
                       if s.tracked is not None and s.tracked[0] == version)
        self.value = ValueData(table, center, v, state.theta, time.monotonic(), m.version, latency, info,
                               info["source"], refined.horizon if refined else 0.0, obstacles, versions, tracks)
        self._record_reaction(versions, previous)
        if new_map:
            self.map_reaction_s.append(time.monotonic() - m.received)
        self.error = ""
        self.inferences += 1
        if not self._stop.is_set():
            self.publish(values, info, m, state)

    def _record_reaction(self, versions: tuple[int, ...], previous: tuple[int, ...]) -> None:
        """For each observation that is new in this table: seconds from its receipt to the table."""
        now = time.monotonic()
        for k, (source, version) in enumerate(zip(self.sources, versions, strict=True)):
            data = source.current
            if version >= 0 and (k >= len(previous) or previous[k] != version) and data and data.version == version:
                self.reaction_s.append(now - data.received)

    def _stale(self, m: MapData, state: RobotState, refined: Any, now: float, cfg: NodeConfig) -> bool:
        """Whether the table must be recomputed for this map and state."""
        val = self.value
        return bool(self.error or val is None or val.map_version != m.version
                    or (val.table is not refined.table if refined else val.source != "operator")
                    or math.hypot(state.x - val.center[0], state.y - val.center[1]) > self.recenter_distance(cfg)
                    or now - val.computed > 0.5 * cfg.value_timeout
                    or not (self.whole_table or refined) and (  # the state is half way to a stencil's edge
                        abs(state.v - val.v) > 0.5 * self.reach[0]
                        or abs(float(wrap_angle(state.theta - val.theta))) > 0.5 * self.reach[1]))

    @property
    def whole_table(self) -> bool:
        """Whether each table holds every speed and heading of its window (a table model)."""
        return self.vf.whole_table

    def recenter_distance(self, cfg: NodeConfig) -> float:
        """m: ``recenter_distance``, at most a quarter of the window's width (a small robot's window is small)."""
        return min(cfg.recenter_distance, 0.25 * min(self.vf.window))

    # ------------------------------------------------------------------ the value input
    def get(self, now: float, timeout: float) -> tuple[ValueData | None, str]:
        """The latest table, or why there is none usable (a failed inference, none yet, too old)."""
        if self.error:
            return None, self.error
        val = self.value
        if val is None:
            return None, "no value function yet (waiting for inference or the solver)"
        age = now - val.computed
        if age > timeout:
            return None, f"value is {age:.2f} s old (value_timeout {timeout:g} s)"
        return val, ""

    def covers(self, val: ValueData, state: RobotState) -> tuple[ValueData | None, str]:
        """``val`` if its table holds ``state``, or why not (the modes that read V at the state itself need it;
        least_restrictive judges such a state by the braking bound instead)."""
        p = self.vf.params
        s = state.vector(p.v_min, p.v_max)
        if not bool(val.table.inside(s, axes=(0, 1))):
            return None, (f"state ({s[0]:.4g}, {s[1]:.4g}) outside the value window centred at "
                          f"({val.center[0]:.4g}, {val.center[1]:.4g})")
        grid = val.table.grid
        if not self.whole_table and not grid.lo[2] - self._dv <= s[2] <= grid.hi[2] + self._dv:
            return None, f"speed {s[2]:.4g} m/s outside the value table's stencil [{grid.lo[2]:.2f}, {grid.hi[2]:.2f}]"
        return val, ""
