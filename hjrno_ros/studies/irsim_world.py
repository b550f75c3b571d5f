"""A grid-map world in IR-SIM, the third-party robot simulator (``ir-sim`` 2.12.0), for the navigation benchmark.

The benchmark needs "a simulator nobody here wrote": IR-SIM's differential-drive kinematics with its
acceleration limits, a circular footprint, a grid map of obstacles, IR-SIM's own collision check and,
optionally, its 2-D LiDAR.  :class:`IrSimWorld` builds one such world headless and steps it; SI units
throughout (m, s, rad).

What this module relies on in IR-SIM 2.12.0 (read in its source and measured), and how it copes:

* ``import irsim`` picks a matplotlib backend at import time (``matplotlib.use`` of TkAgg, Qt5Agg, then
  Agg) and ``print``\\ s every failure to stdout.  It is imported lazily, with stdout swallowed, and the
  backend that was active before is restored.  ``headless=True`` then builds no figure, window,
  keyboard or mouse control; nothing is drawn or saved.
* It logs with loguru to a sink on ``sys.stdout`` at the environment's ``log_level``; ``"CRITICAL"``
  keeps it quiet (its first environment also removes loguru's default stderr handler, process-wide).
* A world comes from a YAML file only.  ``world: name:`` in it crashes the constructor (``TypeError:
  World.__init__() got multiple values for argument 'name'``); the world is named after the file.
  ``World`` itself accepts an occupancy ndarray as ``obstacle_map``, but a YAML file can carry only an
  image path (or a generator spec), so the grid is written as a PNG.  Both files live in a private
  temporary directory only while IR-SIM reads them (it never reads them again).  IR-SIM turns the
  image into ``grid[ix, iy] = 100 * (1 - gray[ny - 1 - iy, ix])`` (``np.fliplr(img.T)``: image rows
  from the top are y from the top), occupied where > 50, cell centres at
  ``offset + (index + 0.5) * width / nx``; the loaded grid is compared with the input every time.
* Differential drive (``kinematics: {name: diff}``) integrates ``[v, omega]`` by forward Euler over
  ``step_time``.  Before that, each command is clipped to ``[max(vel_min, u_prev - acce * step_time),
  min(vel_max, u_prev + acce * step_time)]``, where ``u_prev`` is the velocity applied in the previous
  step: ``acce = [a_max, alpha_max]`` limits the change of the applied velocity per step.
* Collision (``collision_mode: stop``) is judged after each step: the footprint (a 64-gon inscribed in
  the circle, 0.24 mm short of it at 0.2 m radius) against the map's occupied cells and their outline.
  It fires at contact (measured: no flag 0.1 mm from a wall face, flag at 0), so it is detected after
  the step that reaches the wall, up to one step's travel (v * step_time) into it.  The robot then
  stays where it is, and its velocity reads zero from the next step on.  The check also runs once at
  construction, so a start pose in collision reads ``collided`` at once.
* With ``people_walk_on`` the world runs IR-SIM's ``collision_mode: unobstructed_obstacles``: the robot still stops
  at a contact (and stays held while anything overlaps it), the pedestrians never stop (they walk on, through
  the robot, a wall they brush against). In ``stop`` mode a walker that touched anything stood there for good.
* The 2-D LiDAR scans on every step (its ``scan_time`` is only reported, never used) by casting every
  beam against every segment of the map outline the beams touch.  IR-SIM builds that outline as the
  union of one float box per occupied cell, centre +- half a cell; neighbouring boxes disagree in the
  last bits, so the union keeps slivers (hundreds to thousands of tiny rings) and a vertex at every
  cell corner.  Measured on a 384 x 384 map (0.05 m cells, rooms, doors, clutter): 1,766 rings and
  28,120 segments, 186 ms per 360-beam scan.  With ``lidar=True`` the outline is rebuilt from whole
  cell corners in index space (exact, so the union is clean), collinear vertices merged, then scaled
  to metres: 155 rings and 980 segments, 2.6 ms per scan, ranges equal to 1e-14 m.  The map object's
  outline, spatial index and the scene's geometry tree are replaced through IR-SIM's own
  ``set_original_geometry``/``refresh``/``build_tree``; the collision check reads the same lines.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import io
import json
import math
import os
import tempfile
from types import ModuleType
from typing import Any

import numpy as np

REST_SPEED = 0.02  # m/s: at or below it the robot was at rest at a contact (a person walked into it)

@dataclasses.dataclass(frozen=True)
class DiffDriveBase:
    """A differential-drive base with a circular footprint and its limits (IR-SIM's ``vel_*`` and ``acce``)."""

    radius: float  # m, circular footprint
    v_max: float  # m/s
    v_min: float  # m/s (< 0: reverses)
    omega_max: float  # rad/s, |angular velocity| limit
    a_max: float  # m/s^2, linear acceleration limit
    alpha_max: float  # rad/s^2, angular acceleration limit (IR-SIM's second acce entry)

    def __post_init__(self) -> None:
        values = dataclasses.asdict(self)
        if not all(math.isfinite(v) for v in values.values()):
            raise ValueError(f"DiffDriveBase needs finite values: {values}")
        if min(self.radius, self.omega_max, self.a_max, self.alpha_max) <= 0 or self.v_min > self.v_max:
            raise ValueError(f"DiffDriveBase needs radius, omega_max, a_max, alpha_max > 0, v_min <= v_max: {values}")


@functools.cache
def _irsim() -> ModuleType:
    """``import irsim`` without its import-time prints and with the caller's matplotlib backend kept."""
    import matplotlib

    backend = matplotlib.get_backend()
    with contextlib.redirect_stdout(io.StringIO()):
        import irsim
    if matplotlib.get_backend() != backend:
        matplotlib.use(backend)
    return irsim


def _write_png(path: str, obstacles: np.ndarray) -> None:
    """The grid as IR-SIM reads it: black = occupied, image row 0 = the cells of the largest y."""
    import matplotlib.image  # IR-SIM reads the map with matplotlib.image.imread

    gray = np.where(np.flipud(obstacles.T), 0, 255).astype(np.uint8)
    matplotlib.image.imsave(path, gray, cmap="gray", vmin=0, vmax=255)


def _cell_outline(obstacles: np.ndarray, origin: tuple[float, float], resolution: float) -> list[Any]:
    """Boundary rings (shapely LineStrings, metres) of the occupied cells, built on whole cell corners.

    The union is taken in cell-index space, where corners are exact integers, and collinear vertices
    are dropped before scaling; this is the same set of lines as IR-SIM's own outline without its
    slivers and per-cell vertices (see the module docstring).
    """
    import shapely  # IR-SIM's geometry library

    ix, iy = np.nonzero(obstacles)
    if ix.size == 0:
        return []
    union = shapely.simplify(shapely.union_all(shapely.box(ix, iy, ix + 1, iy + 1)), 0.0)
    rings = shapely.get_parts(shapely.boundary(union))
    offset = np.asarray(origin, dtype=float)
    return [shapely.transform(ring, lambda c: offset + c * resolution) for ring in rings]


@dataclasses.dataclass(frozen=True)
class Person:
    """A pedestrian: IR-SIM's omnidirectional agent walking through ``waypoints`` (m) in turn at up to ``speed``
    (m/s), steered by IR-SIM's social-force model (``sfm``: towards the goal, away from the others, the robot and
    walls); a disk of ``radius`` m.  (IR-SIM 2.12's ``rvo`` behaviour stalled a walker in a small walled room:
    it crept at 0.05 m/s away from its goal.)"""

    waypoints: tuple[tuple[float, float], ...]
    speed: float = 1.0
    radius: float = 0.2
    laps: int = 20  # the waypoint list is walked this many times (IR-SIM drops each goal once reached)

    def as_irsim(self) -> dict[str, Any]:
        (x0, y0), rest = self.waypoints[0], [*self.waypoints[1:], self.waypoints[0]]
        goals = [[float(x), float(y), 0.0] for _ in range(self.laps) for x, y in rest]
        s = float(self.speed)
        return {"number": 1, "kinematics": {"name": "omni"}, "shape": {"name": "circle", "radius": self.radius},
                "state": [float(x0), float(y0), 0.0], "goal": goals, "vel_max": [s, s], "vel_min": [-s, -s],
                "behavior": {"name": "sfm"}, "goal_threshold": 0.3}


class IrSimWorld:
    """One IR-SIM world: a grid map, one diff-drive robot and, optionally, pedestrians."""

    LIDAR_BEAMS = 360  # beams over a full turn, 1 degree apart
    LIDAR_RANGE_MAX = 10.0  # m (IR-SIM's default)

    def __init__(
        self,
        obstacles: np.ndarray,
        origin: tuple[float, float],
        resolution: float,
        base: DiffDriveBase,
        start: tuple[float, float, float],
        step_time: float = 0.05,
        lidar: bool = False,
        seed: int = 0,
        people: tuple[Person, ...] = (),
        people_walk_on: bool = False,
    ) -> None:
        """Build the world headless.

        Args:
            obstacles: bool array ``[ix, iy]`` (x first), True = occupied; cell ``(ix, iy)`` has its
                centre at ``origin + (ix + 0.5, iy + 0.5) * resolution``.  The map ends at its cells:
                put walls on the border to keep the robot in.
            origin: world coordinates (m) of the map's lower-left corner.
            resolution: cell size (m).
            base: the robot's footprint and limits.
            start: start pose ``(x, y, theta)`` (m, m, rad); the robot starts at rest.
            step_time: simulated seconds per :meth:`step`.
            lidar: give the robot IR-SIM's 2-D LiDAR (:attr:`LIDAR_BEAMS` beams, :attr:`LIDAR_RANGE_MAX`).
            seed: seed of IR-SIM's random generator (nothing here is random; kept for reproducibility).
            people: pedestrians IR-SIM moves each step (:class:`Person`); its LiDAR sees them and its collision
                check counts them.
            people_walk_on: a person walking into the robot at rest (|v| <= :data:`REST_SPEED` in the step of the
                contact, only people touching) walks on through it: the contact is counted in
                :attr:`rest_contacts` and does not set :attr:`collided`, and the robot, held while they overlap,
                goes on after (a person who bumps into a robot does not end its mission).  Any other contact sets
                :attr:`collided` for good.  Without it every contact does, as IR-SIM's flag.
        """
        obstacles = np.asarray(obstacles, dtype=bool)
        if obstacles.ndim != 2 or min(obstacles.shape) < 1:
            raise ValueError(f"obstacles must be a 2-D [ix, iy] array, got shape {obstacles.shape}")
        numbers = (*origin, resolution, *start, step_time)
        if len(origin) != 2 or len(start) != 3 or not all(math.isfinite(float(v)) for v in numbers):
            raise ValueError(f"origin (2), start (3), resolution and step_time must be finite: {numbers}")
        if resolution <= 0 or step_time <= 0:
            raise ValueError(f"resolution and step_time must be > 0: {resolution}, {step_time}")
        self.base = base
        self.step_time = float(step_time)
        self._steps = 0
        nx, ny = obstacles.shape
        robot: dict[str, Any] = {
            "kinematics": {"name": "diff"},
            "shape": {"name": "circle", "radius": float(base.radius)},
            "state": [float(v) for v in start],
            "vel_max": [float(base.v_max), float(base.omega_max)],
            "vel_min": [float(base.v_min), -float(base.omega_max)],
            "acce": [float(base.a_max), float(base.alpha_max)],
        }
        if lidar:
            n = self.LIDAR_BEAMS  # a sweep of 2 pi (n - 1) / n: n beams 2 pi / n apart, none doubled
            robot["sensors"] = [{"name": "lidar2d", "range_min": 0.0, "range_max": self.LIDAR_RANGE_MAX,
                                 "angle_range": 2 * math.pi * (n - 1) / n, "number": n, "noise": False}]
        irsim = _irsim()
        with tempfile.TemporaryDirectory(prefix="hjrno_irsim_") as folder:
            image = os.path.join(folder, "obstacles.png")
            _write_png(image, obstacles)
            world = {"width": nx * float(resolution), "height": ny * float(resolution),
                     "offset": [float(origin[0]), float(origin[1])], "step_time": self.step_time,
                     "collision_mode": "unobstructed_obstacles" if people_walk_on else "stop",
                     "control_mode": "auto", "obstacle_map": image}
            path = os.path.join(folder, "hjrno_irsim.yaml")  # JSON is YAML; no world name (it crashes)
            with open(path, "w") as f:
                json.dump({"world": world, "robot": [robot], **({"obstacle": [p.as_irsim() for p in people]}
                                                                 if people else {})}, f)
            self._env = irsim.make(path, headless=True, log_level="CRITICAL", seed=seed)
        try:
            loaded = self._env.get_map(resolution=float(resolution)).grid
            if loaded is None or loaded.shape != obstacles.shape or not np.array_equal(loaded > 50, obstacles):
                raise RuntimeError("IR-SIM read the obstacle image into a different grid")
            self._robot = self._env.robot_list[0]
            if lidar:
                self._use_cell_outline(obstacles, origin, float(resolution))
            self._robot.check_status()  # IR-SIM checks collisions only in step(); a start in collision shows now
        except BaseException:
            self._env.end(ending_time=0.0)
            raise
        self._closed = False
        self.people = tuple(people)
        self.people_walk_on = people_walk_on
        self.contact_speed: float | None = None  # |v| the robot had in the step that collided
        self.rest_contacts = 0  # people who walked into the robot at rest (people_walk_on only)
        self.min_people_clearance = math.inf  # m between the robot's and the people's disks, over the steps
        self.min_people_clearance_moving = math.inf  # the same over the steps the robot moved in
        self._touching = self._crashed = False
        self._track_contact()
        self._track_people()

    def _track_contact(self) -> None:
        """Sort a new contact: a person walking into the robot at rest (``people_walk_on``), else a crash."""
        touching = bool(self._robot.collision)
        if touching and not self._touching and not self._crashed:
            speed = abs(self.velocity[0])  # what IR-SIM applied in the step of the contact
            bumped = all(obj.shape != "map" for obj in self._robot.collision_obj) and speed <= REST_SPEED
            if self.people_walk_on and bumped:
                self.rest_contacts += 1
            else:
                self._crashed, self.contact_speed = True, speed
        self._touching = touching

    def _track_people(self) -> None:
        if not self.people:
            return
        x, y, _ = self.pose
        for person, obj in zip(self.people, self._people_objects(), strict=True):
            px, py = (float(v) for v in obj.state[:2, 0])
            gap = math.hypot(px - x, py - y) - person.radius - self.base.radius
            self.min_people_clearance = min(self.min_people_clearance, gap)
            if abs(self.velocity[0]) > REST_SPEED:
                self.min_people_clearance_moving = min(self.min_people_clearance_moving, gap)

    @property
    def people_positions(self) -> np.ndarray:
        """(k, 2) positions of the pedestrians, m."""
        return np.array([[float(v) for v in obj.state[:2, 0]] for obj in self._people_objects()]).reshape(-1, 2)

    @property
    def people_velocities(self) -> np.ndarray:
        """(k, 2) velocities of the pedestrians in the world frame, m/s: what IR-SIM applied in the last step (its
        ``velocity_xy``: an omni agent's body-frame velocity turned by its heading)."""
        return np.array([[float(v) for v in obj.velocity_xy[:2, 0]] for obj in self._people_objects()]).reshape(-1, 2)

    @property
    def people_radii(self) -> np.ndarray:
        """(k,) radii of the pedestrians' disks, m."""
        return np.array([float(person.radius) for person in self.people])

    def _people_objects(self) -> list[Any]:
        return [obj for obj in self._env.obstacle_list if obj.shape != "map"]

    def _use_cell_outline(self, obstacles: np.ndarray, origin: tuple[float, float], resolution: float) -> None:
        """Replace IR-SIM's map outline by :func:`_cell_outline` (same lines, ~50x faster LiDAR; module docstring)."""
        import shapely
        from shapely.strtree import STRtree

        maps = [obj for obj in self._env.objects if obj.shape == "map"]
        if not maps:  # no occupied cell: IR-SIM made no map object
            return
        (grid_map,) = maps
        rings = _cell_outline(obstacles, origin, resolution)
        grid_map.set_original_geometry(shapely.MultiLineString(rings))
        grid_map.refresh(sensor_step=False)  # the map's pose is the identity: geometry = outline
        grid_map.linestrings = rings  # what the LiDAR and the collision check query
        grid_map.geometry_tree = STRtree(rings)
        self._env.build_tree()
        self._robot.sensor_step()  # the scan taken at construction saw the old outline

    def step(self, linear: float, angular: float) -> None:
        """Advance one ``step_time`` with the command ``[linear m/s, angular rad/s]``.

        IR-SIM clips the command to the velocity and acceleration limits, moves the robot, scans and
        checks collision; after a collision the robot stays where it is (with ``people_walk_on``: while anything
        overlaps it).
        """
        if self._closed:
            raise RuntimeError("IrSimWorld is closed")
        self._env.step([float(linear), float(angular)])
        self._steps += 1
        self._track_contact()
        self._track_people()

    @property
    def pose(self) -> tuple[float, float, float]:
        """``(x, y, theta)`` of the robot in the world frame (m, m, rad), theta in [-pi, pi)."""
        x, y, theta = (float(v) for v in self._robot.state[:3, 0])
        return x, y, (theta + math.pi) % (2 * math.pi) - math.pi

    @property
    def velocity(self) -> tuple[float, float]:
        """The robot's actual ``(linear m/s, angular rad/s)``: the last command as IR-SIM limited it."""
        linear, angular = (float(v) for v in self._robot.velocity[:2, 0])
        return linear, angular

    @property
    def collided(self) -> bool:
        """The robot crashed: IR-SIM's collision flag (footprint touching an occupied cell or a person) set by a
        contact other than a person walking into it at rest (``people_walk_on``; without it, any contact)."""
        return self._crashed

    @property
    def time(self) -> float:
        """Simulated seconds since construction (IR-SIM's own clock rounds to 0.01 s)."""
        return self._steps * self.step_time

    def scan(self) -> tuple[np.ndarray, float, float, float] | None:
        """``(ranges m, angle_min rad, angle_increment rad, range_max m)`` of the last LiDAR scan, or None.

        Angles are in the robot frame (0 = ahead, counter-clockwise); a beam that hits nothing reads
        ``range_max``.  None when the world was built without a LiDAR.
        """
        sensor = self._robot.lidar
        if sensor is None:
            return None
        data = sensor.get_scan()
        return (np.array(data["ranges"], dtype=float), float(data["angle_min"]), float(data["angle_increment"]),
                float(data["range_max"]))

    def scan_points(self) -> np.ndarray:
        """The last LiDAR scan's returns ``(k, 2)`` in the world frame (m; beams that hit nothing left out), or none
        without a LiDAR."""
        scan = self.scan()
        if scan is None:
            return np.zeros((0, 2))
        ranges, angle_min, increment, range_max = scan
        hit = ranges < range_max - 1e-9
        x, y, theta = self.pose  # the LiDAR sits at the robot's centre
        angles = theta + angle_min + increment * np.arange(len(ranges))[hit]
        return np.stack([x + ranges[hit] * np.cos(angles), y + ranges[hit] * np.sin(angles)], -1)

    def close(self) -> None:
        """End the IR-SIM environment (its log sinks go with it); safe to call twice."""
        if not self._closed:
            self._closed = True
            self._env.end(ending_time=0.0)

    def __enter__(self) -> IrSimWorld:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
