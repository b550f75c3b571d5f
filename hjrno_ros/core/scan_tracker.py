"""People tracked on a laser's returns: clusters of returns off the static map, followed scan to scan (numpy only).

A laser cannot tell a person walking away from one walking at the robot, so an untracked return is given room to
approach at ``obstacle_speed_max`` over the robot's stop (docs/design.md, "Moving obstacles").  A track measures the
velocity, and a confirmed track becomes a tracked agent with its own relative value (core/tracked_agents.py), as a
perfect tracker's agent would.  What the tracker does not vouch for stays an untracked return with the margin:

* a cluster wider than a person (``max_extent``: an unmapped wall, a parked cart), or one seen fewer than
  ``confirm`` times;
* a track whose recent positions fit no constant velocity (``max_residual``: two people merging, a swap, the turn
  itself; after a turn the observations before it drop out, :func:`fit_recent`);
* a track faster than the agent tables cover (``speed_max``).

A confirmed track that is missed by a scan (occlusion) stays an agent for ``coast`` s, predicted at its velocity,
its radius grown by the agents' deviation δ over the time unseen.  The velocity's error against the truth is part
of δ, the deviation the tables were solved for; ``hjrno bench tracker`` measures it in IR-SIM.
Points are ``(N, 2)`` in the map frame, in the scan's beam order; times are seconds.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from hjrno_ros.core.tracked_agents import Agents, AgentTable

ARC_CENTRE = math.pi / 4  # beams evenly spread over a disk hit it on average this many radii in front of its centre
LEAST_FIT = 3  # observations a velocity is fitted to at least (two always fit a line), whatever the scan rate


@dataclasses.dataclass(frozen=True)
class TrackerSettings:
    """How returns become people (lengths m, times s, speeds m/s)."""

    agent_radius: float = 0.2  # a person's radius, for the centre behind a cluster's arc
    cluster_gap: float = 0.3  # neighbouring returns this close are one object
    max_extent: float = 1.0  # a wider cluster is not a person
    gate: float = 0.3  # a cluster this far beyond a track's predicted position (and speed_max's reach) is another
    window: float = 0.4  # the velocity is fitted to observations of the last window seconds (fit_recent)
    confirm: int = 4  # observations before a track is an agent
    max_residual: float = 0.02  # rms m of the constant-velocity fit above which a track is not trusted
    coast: float = 0.5  # a confirmed track unseen for this long is dropped
    speed_max: float = 1.5  # faster tracks are left untracked (the agent tables' speeds)
    deviation: float = 0.3  # the agents' deviation from their velocity: radius growth while unseen
    position_error: float = 0.1  # added to a track's radius: the centre behind the arc is an estimate

    @classmethod
    def for_table(cls, table: AgentTable, agent_radius: float) -> TrackerSettings:
        """The settings for agents read with ``table``: its fastest speed and its deviation δ."""
        return cls(agent_radius=agent_radius, speed_max=table.speeds[-1], deviation=table.deviation)


def clusters(points: np.ndarray, gap: float) -> list[np.ndarray]:
    """Indices of ``points`` (N, 2), in beam order, split where neighbours are more than ``gap`` apart; the last
    cluster joins the first when they meet across the scan's seam."""
    if len(points) == 0:
        return []
    cuts = np.nonzero(np.linalg.norm(np.diff(points, axis=0), axis=-1) > gap)[0] + 1
    parts = np.split(np.arange(len(points)), cuts)
    if len(parts) > 1 and np.linalg.norm(points[-1] - points[0]) <= gap:
        parts = [np.concatenate([parts[-1], parts[0]]), *parts[1:-1]]
    return parts


def detections(points: np.ndarray, sensor: np.ndarray, s: TrackerSettings
               ) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """The person-sized clusters of ``points`` (N, 2) seen from ``sensor`` (2,): centres (k, 2), the arc's centroid
    moved ARC_CENTRE radii away from the sensor, radii (k,) covering the cluster's returns, and their indices."""
    centres, radii, members = [], [], []
    for idx in clusters(points, s.cluster_gap):
        p = points[idx]
        if np.linalg.norm(p.max(0) - p.min(0)) > s.max_extent:
            continue
        mean = p.mean(0)
        ray = mean - sensor
        centre = mean + ARC_CENTRE * s.agent_radius * ray / max(float(np.linalg.norm(ray)), 1e-9)
        centres.append(centre)
        radii.append(max(s.agent_radius, float(np.linalg.norm(p - centre, axis=-1).max())))
        members.append(idx)
    return np.array(centres).reshape(-1, 2), np.array(radii), members


@dataclasses.dataclass
class Track:
    """One object's observations within the window (at least LEAST_FIT): times (s), centres and radii (m); its
    constant-velocity fit."""

    times: list[float]
    centres: list[np.ndarray]
    radii: list[float]
    hits: int = 1
    returns: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, int))  # its indices in the last scan
    position: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(2))  # at times[-1], fitted
    velocity: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(2))
    residual: float = 0.0  # rms m of the fit

    @property
    def radius(self) -> float:
        """The largest radius seen within the window."""
        return max(self.radii)

    def predicted(self, t: float) -> np.ndarray:
        return self.position + self.velocity * (t - self.times[-1])

    def add(self, t: float, centre: np.ndarray, radius: float, window: float, max_residual: float) -> None:
        """One more observation; the fit over the last ``window`` s (:func:`fit_recent`)."""
        self.times.append(t)
        self.centres.append(centre)
        self.radii.append(radius)
        self.hits += 1
        n = len(self.times)  # the window's, and at least LEAST_FIT (a slow laser)
        keep = [k for k, tk in enumerate(self.times) if tk >= t - window - 1e-9 or k >= n - LEAST_FIT]
        self.times, self.centres, self.radii = ([x[k] for k in keep] for x in (self.times, self.centres, self.radii))
        self.position, self.velocity, self.residual = fit_recent(np.array(self.times), np.array(self.centres),
                                                                 max_residual)


def fit(times: np.ndarray, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The least-squares constant velocity through ``centres`` (n, 2) at ``times`` (n,): the position at the last
    time, the velocity, and the rms residual (m); a single observation stands still."""
    if len(times) < 2:
        return centres[-1].copy(), np.zeros(2), 0.0
    dt = times - times.mean()
    velocity = (dt[:, None] * (centres - centres.mean(0))).sum(0) / max(float((dt * dt).sum()), 1e-12)
    line = centres.mean(0) + dt[:, None] * velocity
    residual = float(np.sqrt(((centres - line) ** 2).sum(-1).mean()))
    return line[-1], velocity, residual


def fit_recent(times: np.ndarray, centres: np.ndarray, max_residual: float, least: int = LEAST_FIT
               ) -> tuple[np.ndarray, np.ndarray, float]:
    """:func:`fit` to the most recent observations that fit within ``max_residual`` (at least ``least`` of them):
    after a turn the observations before it are dropped, so the track is vouched for again with the new velocity
    once ``least`` observations since fit (the residual of the shortest fit otherwise)."""
    for n in range(len(times), min(least, len(times)) - 1, -1):
        out = fit(times[-n:], centres[-n:])
        if out[2] <= max_residual:
            break
    return out


class ScanTracker:
    """Tracks followed from scan to scan (:meth:`update`), confirmed ones read as :class:`Agents` (:meth:`agents`)."""

    def __init__(self, settings: TrackerSettings = TrackerSettings()) -> None:
        self.settings = settings
        self.tracks: list[Track] = []
        self.time = -math.inf  # the last scan's time (s)
        self.received = 0.0  # its receipt (monotonic s)
        self.returns = 0  # how many returns it had

    def update(self, points: np.ndarray, sensor: np.ndarray, t: float, received: float) -> bool:
        """One scan's returns off the map (N, 2) seen from ``sensor`` at time ``t``, received at ``received``
        (monotonic): clusters matched to tracks nearest first within the gate, the others start tracks, tracks
        unseen for ``coast`` s end.  False, and nothing changed, for a scan no newer than the last by less than
        ``coast`` (a duplicate or reordered one); one older by more is a new clock (a simulation or a log
        restarted): the tracks start over."""
        s = self.settings
        if t <= self.time - s.coast:
            self.tracks, self.time = [], -math.inf
        if t <= self.time:
            return False
        dt = t - self.time if math.isfinite(self.time) else 0.0
        points = np.asarray(points, float).reshape(-1, 2)
        centres, radii, members = detections(points, np.asarray(sensor, float), s)
        free = set(range(len(centres)))
        for track in self.tracks:
            track.returns = np.zeros(0, int)
        if self.tracks and len(centres):
            gaps = np.linalg.norm(np.array([k.predicted(t) for k in self.tracks])[:, None] - centres[None], axis=-1)
            reach = s.gate + s.speed_max * dt
            for flat in np.argsort(gaps, axis=None):
                i, j = divmod(int(flat), len(centres))
                if gaps[i, j] > reach:
                    break
                track = self.tracks[i]
                if j in free and track.times[-1] < t:
                    track.add(t, centres[j], radii[j], s.window, s.max_residual)
                    track.returns = members[j]
                    free.discard(j)
        self.tracks = [k for k in self.tracks if t - k.times[-1] <= s.coast]
        self.tracks += [Track([t], [centres[j]], [float(radii[j])], returns=members[j], position=centres[j].copy())
                        for j in sorted(free)]
        self.time, self.received, self.returns = t, received, len(points)
        return True

    def confirmed(self, track: Track) -> bool:
        """A track the tracker vouches for: seen often enough, fitting a constant velocity, within the tables."""
        s = self.settings
        return (track.hits >= s.confirm and len(track.times) >= LEAST_FIT and track.residual <= s.max_residual
                and float(np.hypot(*track.velocity)) <= s.speed_max)

    def confirmed_returns(self) -> np.ndarray:
        """Which of the last scan's returns (bool, as given to :meth:`update`) belong to a confirmed track: they are
        that agent, whose own value covers its motion."""
        mask = np.zeros(self.returns, bool)
        for track in self.tracks:
            if self.confirmed(track):
                mask[track.returns] = True
        return mask

    def agents(self) -> Agents:
        """The confirmed tracks as agents at the last scan's time (received then): positions predicted from their
        last observation, radii grown by the position error and by δ over the time unseen."""
        s, t = self.settings, self.time
        kept = [k for k in self.tracks if self.confirmed(k)]
        positions = np.array([k.predicted(t) for k in kept]).reshape(-1, 2)
        velocities = np.array([k.velocity for k in kept]).reshape(-1, 2)
        radii = np.array([k.radius + s.position_error + s.deviation * (t - k.times[-1]) for k in kept])
        return Agents(positions, velocities, radii.reshape(-1), self.received)
