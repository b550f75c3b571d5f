"""The laser people tracker: clusters, tracks followed scan to scan, what it vouches for and what it leaves to the
motion margin, on a ray-cast laser of 1° beams."""

from __future__ import annotations

import numpy as np
import pytest

from hjrno_ros.core.scan_tracker import ScanTracker, TrackerSettings, clusters

RADIUS = 0.2  # m: the people's
PERIOD = 0.1  # s between scans


def laser(disks: list[tuple[np.ndarray, float]], sensor=(0.0, 0.0), beams: int = 360) -> np.ndarray:
    """The nearest hit of each beam (evenly over a turn, from ``sensor``) on the ``disks`` (centre, radius), in beam
    order; beams that hit nothing are left out."""
    o = np.asarray(sensor, float)
    angles = np.arange(beams) * 2 * np.pi / beams
    d = np.stack([np.cos(angles), np.sin(angles)], -1)
    best = np.full(beams, np.inf)
    for centre, r in disks:
        c = np.asarray(centre, float) - o
        b = d @ c
        disc = b * b - (c @ c - r * r)
        hit = np.where(disc >= 0, b - np.sqrt(np.maximum(disc, 0.0)), np.inf)
        best = np.minimum(best, np.where(hit > 0, hit, np.inf))
    keep = np.isfinite(best)
    return o + d[keep] * best[keep, None]


def walk(tracker: ScanTracker, start, velocity, scans: int, t0: float = 0.0, others=()) -> None:
    for k in range(scans):
        t = t0 + k * PERIOD
        people = [(np.asarray(start) + np.asarray(velocity) * t, RADIUS), *others]
        tracker.update(laser(people), np.zeros(2), t, 100.0 + t)


def test_returns_split_at_gaps_and_join_across_the_scans_seam():
    points = np.array([[1.0, 0.0], [1.0, 0.1], [3.0, 0.0], [3.0, 0.1], [1.0, -0.1]])
    parts = clusters(points, 0.3)
    assert sorted(map(sorted, parts)) == [[0, 1, 4], [2, 3]]
    assert clusters(np.zeros((0, 2)), 0.3) == []


def test_a_walking_person_becomes_an_agent_with_its_velocity_and_a_disk_around_it():
    tracker = ScanTracker()
    walk(tracker, (3.0, -1.0), (-0.8, 0.6), 3)
    assert len(tracker.agents()) == 0  # seen three times: not yet vouched for
    walk(tracker, (3.0, -1.0), (-0.8, 0.6), 4, t0=0.3)
    agents = tracker.agents()
    assert len(agents) == 1 and agents.received == pytest.approx(100.6)
    truth = np.array([3.0, -1.0]) + np.array([-0.8, 0.6]) * 0.6
    assert agents.velocities[0] == pytest.approx([-0.8, 0.6], abs=0.1)  # well within the tables' δ, 0.3 m/s
    assert np.linalg.norm(agents.positions[0] - truth) + RADIUS <= agents.radii[0]  # the person inside its disk
    assert agents.radii[0] <= RADIUS + 0.15


def test_only_the_confirmed_tracks_returns_are_marked_theirs():
    tracker = ScanTracker()
    wall = [((x, 2.0), 0.05) for x in np.arange(-1.0, 1.01, 0.05)]  # a row of posts: one 2 m wide cluster
    walk(tracker, (2.0, 0.0), (0.0, 0.5), 6, others=wall)
    points = laser([((2.0, 0.25), RADIUS), *wall])
    tracker.update(points, np.zeros(2), 0.6, 100.6)
    theirs = tracker.confirmed_returns()
    assert len(tracker.agents()) == 1 and theirs.shape == (len(points),)
    assert np.all(np.linalg.norm(points[theirs] - [2.0, 0.3], axis=-1) < 0.3)
    assert np.all(points[~theirs, 1] > 1.5)  # the wall's returns: no person, left to the motion margin


def test_what_does_not_fit_a_steady_walk_is_not_vouched_for():
    jumpy = ScanTracker()  # a cluster that jumps to and fro (two people taking turns): no constant velocity
    for k in range(8):
        y = 0.12 * (k % 2)
        jumpy.update(laser([((2.0, y), RADIUS)]), np.zeros(2), k * PERIOD, k * PERIOD)
    assert len(jumpy.tracks) == 1 and jumpy.tracks[0].hits == 8 and len(jumpy.agents()) == 0
    fast = ScanTracker(TrackerSettings(speed_max=1.0))  # faster than the tables
    walk(fast, (4.0, 0.0), (-1.3, 0.0), 8)
    assert len(fast.agents()) == 0


def test_a_person_unseen_is_coasted_with_a_growing_disk_then_dropped():
    s = TrackerSettings()
    tracker = ScanTracker(s)
    walk(tracker, (3.0, 0.0), (0.0, 0.5), 6)
    seen = tracker.agents()
    tracker.update(np.zeros((0, 2)), np.zeros(2), 0.7, 100.7)  # occluded
    coasted = tracker.agents()
    assert len(coasted) == 1
    assert coasted.positions[0] == pytest.approx(seen.positions[0] + seen.velocities[0] * 0.2, abs=1e-6)
    assert coasted.radii[0] == pytest.approx(seen.radii[0] + s.deviation * 0.2)
    tracker.update(np.zeros((0, 2)), np.zeros(2), 0.5 + s.coast + 0.05, 101.1)
    assert len(tracker.agents()) == 0 and tracker.tracks == []


def test_two_people_are_two_tracks_and_an_old_scan_changes_nothing():
    tracker = ScanTracker()
    walk(tracker, (2.0, -2.0), (0.0, 0.5), 8, others=[])
    for k in range(8):
        t = 0.8 + k * PERIOD
        people = [((2.0, -2.0 + 0.5 * t), RADIUS), ((-3.0, 1.0 - 0.7 * (t - 0.8)), RADIUS)]
        tracker.update(laser(people), np.zeros(2), t, t)
    agents = tracker.agents()
    order = np.argsort(agents.positions[:, 0])
    assert agents.velocities[order].ravel() == pytest.approx([0.0, -0.7, 0.0, 0.5], abs=0.1)
    before = agents.positions.copy()
    assert not tracker.update(laser([((0.0, 0.0), RADIUS)]), np.zeros(2), 1.45, 1.45)  # older than the last
    assert tracker.agents().positions == pytest.approx(before)


def test_after_a_turn_the_track_is_vouched_for_again_with_the_new_velocity():
    tracker = ScanTracker()
    walk(tracker, (2.0, -1.0), (0.0, 0.8), 6)  # up at 0.8 m/s, then back down from y = -0.6 + 0.8·0.1
    turn = np.array([2.0, -1.0 + 0.8 * 0.5])
    for k in range(1, 4):
        tracker.update(laser([(turn + np.array([0.0, -0.8]) * 0.1 * k, RADIUS)]), np.zeros(2), 0.5 + 0.1 * k, 0.0)
        if k == 1:  # the turn itself: no constant velocity fits the last three observations
            assert len(tracker.agents()) == 0
    agents = tracker.agents()
    assert len(agents) == 1 and agents.velocities[0] == pytest.approx([0.0, -0.8], abs=0.1)


def test_a_duplicate_scan_is_refused_and_a_restarted_clock_starts_the_tracks_over():
    tracker = ScanTracker()
    walk(tracker, (2.0, 0.0), (0.0, 0.5), 6)
    assert not tracker.update(laser([((2.0, 0.25), RADIUS)]), np.zeros(2), 0.5, 0.5)  # the last scan's stamp
    assert len(tracker.agents()) == 1 and len(tracker.confirmed_returns()) == len(laser([((2.0, 0.25), RADIUS)]))
    assert tracker.update(laser([((-1.0, 1.0), RADIUS)]), np.zeros(2), 0.0, 9.0)  # the clock restarted
    assert len(tracker.tracks) == 1 and tracker.tracks[0].hits == 1 and len(tracker.agents()) == 0


def test_a_slow_laser_still_fits_three_observations():
    tracker = ScanTracker()
    for k in range(5):  # 4 Hz: two scans in the 0.4 s window, where any two fit a line
        t = 0.25 * k
        y = 0.5 * t + (0.12 if k == 4 else 0.0)  # the last one off the walk
        tracker.update(laser([((2.0, y), RADIUS)]), np.zeros(2), t, t)
    assert len(tracker.tracks[0].times) == 3 and len(tracker.agents()) == 0
