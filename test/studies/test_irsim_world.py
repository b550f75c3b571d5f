"""IrSimWorld: IR-SIM (third-party) kinematics, limits, collision, map orientation and LiDAR through the wrapper."""

import dataclasses
import math
import tempfile
import time

import numpy as np
import pytest

from hjrno_ros.studies.irsim_world import DiffDriveBase, IrSimWorld

BASE = DiffDriveBase(radius=0.2, v_max=0.5, v_min=-0.3, omega_max=1.5, a_max=1.0, alpha_max=3.0)
DT = 0.05
EPS = 1e-9


def walled(nx: int, ny: int) -> np.ndarray:
    """An [ix, iy] grid with occupied border cells."""
    occ = np.zeros((nx, ny), dtype=bool)
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
    return occ


@pytest.mark.parametrize("lidar", [False, True])
def test_driving_into_a_wall_collides_where_the_wall_is(lidar):
    occ = walled(100, 80)  # 5 m x 4 m from (-1, -2)
    occ[70:72, :] = True  # wall face at x = -1 + 70 * 0.05 = 2.5
    face = 2.5
    with IrSimWorld(occ, (-1.0, -2.0), 0.05, BASE, (0.0, 0.0, 0.0), step_time=DT, lidar=lidar) as world:
        assert not world.collided
        before = world.pose
        while not world.collided and world.time < 15.0:
            before = world.pose
            world.step(BASE.v_max, 0.0)
        assert world.collided
        x, y, theta = world.pose
        # the flag fires in the step that reaches the wall: in contact, less than one step's travel in
        assert before[0] + BASE.radius < face
        assert face - EPS <= x + BASE.radius <= face + BASE.v_max * DT + EPS
        assert abs(y) < EPS and abs(theta) < EPS
        # IR-SIM's "stop" collision mode: the robot stays put and its velocity drops to zero
        for _ in range(3):
            world.step(BASE.v_max, 0.5)
        assert world.pose == (x, y, theta)
        assert world.velocity == (0.0, 0.0)
        assert world.collided


def test_commands_are_limited_by_irsim():
    occ = np.zeros((60, 60), dtype=bool)  # open 6 m x 6 m, no map object at all
    with IrSimWorld(occ, (0.0, 0.0), 0.1, BASE, (3.0, 3.0, 0.0), step_time=DT) as world:
        assert world.velocity == (0.0, 0.0)
        previous = (0.0, 0.0)
        for command in [(5.0, 10.0)] * 30 + [(-5.0, -10.0)] * 30:
            x0, y0, th0 = world.pose
            world.step(*command)
            v, w = world.velocity
            assert BASE.v_min - EPS <= v <= BASE.v_max + EPS
            assert abs(w) <= BASE.omega_max + EPS
            assert abs(v - previous[0]) <= BASE.a_max * DT + EPS
            assert abs(w - previous[1]) <= BASE.alpha_max * DT + EPS
            if previous == (0.0, 0.0):  # from rest: one step of acceleration at most, and it moves
                assert 0 < v <= BASE.a_max * DT + EPS and 0 < w <= BASE.alpha_max * DT + EPS
            # the pose moved with the velocity IR-SIM reports (forward Euler over one step)
            x1, y1, th1 = world.pose
            assert x1 == pytest.approx(x0 + v * math.cos(th0) * DT, abs=1e-12)
            assert y1 == pytest.approx(y0 + v * math.sin(th0) * DT, abs=1e-12)
            assert math.remainder(th1 - th0 - w * DT, 2 * math.pi) == pytest.approx(0.0, abs=1e-12)
            previous = (v, w)
            if command[0] > 0 and world.time > 1.0:
                assert (v, w) == pytest.approx((BASE.v_max, BASE.omega_max))  # limits reached, not exceeded
        assert (v, w) == pytest.approx((BASE.v_min, -BASE.omega_max))
        assert world.time == pytest.approx(60 * DT)
        assert not world.collided


def test_turning_in_place_changes_only_theta():
    occ = walled(40, 40)
    with IrSimWorld(occ, (0.0, 0.0), 0.1, BASE, (2.0, 2.0, 3.0), step_time=DT) as world:
        theta = 3.0
        for _ in range(30):
            world.step(0.0, BASE.omega_max)
            theta += world.velocity[1] * DT
            x, y, th = world.pose
            assert (x, y) == (2.0, 2.0)
            assert -math.pi <= th < math.pi
            assert math.remainder(th - theta, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
        assert theta - 3.0 > 1.5  # it did turn, through +-pi
        assert world.pose[2] < 0


def test_map_orientation():
    nx, ny, res, origin = 80, 70, 0.05, (0.5, -1.0)
    occ = np.zeros((nx, ny), dtype=bool)
    occ[60:64, 10:14] = True  # x in [3.5, 3.7], y in [-0.5, -0.3]: centre (3.6, -0.4)
    base = dataclasses.replace(BASE, radius=0.1)

    def collides(x: float, y: float) -> bool:
        with IrSimWorld(occ, origin, res, base, (x, y, 0.0), step_time=DT) as world:
            at_start = world.collided
            world.step(0.0, 0.0)
            assert world.collided == at_start
            return at_start

    def centre(ix: float, iy: float) -> tuple[float, float]:
        return origin[0] + (ix + 0.5) * res, origin[1] + (iy + 0.5) * res

    assert centre(61.5, 11.5) == pytest.approx((3.6, -0.4))
    assert collides(3.6, -0.4)
    assert not collides(*centre(nx - 1 - 61.5, 11.5))  # mirrored in x
    assert not collides(*centre(61.5, ny - 1 - 11.5))  # mirrored in y (image rows upside down)
    assert not collides(*centre(11.5, 61.5))  # transposed (image rows taken as x)
    # the block's faces are where the cells say, to a centimetre: 1 cm off is free, 1 cm in collides
    for x, y in [(3.5 - 0.1, -0.4), (3.7 + 0.1, -0.4), (3.6, -0.5 - 0.1), (3.6, -0.3 + 0.1)]:
        dx, dy = np.sign(round(x - 3.6, 6)) * 0.01, np.sign(round(y + 0.4, 6)) * 0.01
        assert not collides(x + dx, y + dy)
        assert collides(x - dx, y - dy)


def rectangle_ranges(x: float, y: float, angles: np.ndarray, box: tuple[float, float, float, float],
                     range_max: float) -> np.ndarray:
    """Ranges from (x, y) inside the free rectangle box = (x0, x1, y0, y1) to its walls, along world angles."""
    c, s = np.cos(angles), np.sin(angles)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 0, (box[1] - x) / c, np.where(c < 0, (box[0] - x) / c, np.inf))
        ty = np.where(s > 0, (box[3] - y) / s, np.where(s < 0, (box[2] - y) / s, np.inf))
    return np.minimum(np.minimum(tx, ty), range_max)


def test_lidar_ranges_and_speed():
    occ = walled(200, 200)  # 10 m x 10 m
    occ[120:122, :] = True  # the free room is x in [0.05, 6.0], y in [0.05, 9.95]
    x, y, theta = 3.0, 5.0, 0.4
    with IrSimWorld(occ, (0.0, 0.0), 0.05, BASE, (x, y, theta), step_time=DT, lidar=True) as world:
        ranges, angle_min, increment, range_max = world.scan()
        n = IrSimWorld.LIDAR_BEAMS
        assert ranges.shape == (n,) and range_max == IrSimWorld.LIDAR_RANGE_MAX
        assert increment == pytest.approx(2 * math.pi / n) and angle_min == pytest.approx(-math.pi + math.pi / n)
        angles = angle_min + increment * np.arange(n)  # robot frame
        expected = rectangle_ranges(x, y, theta + angles, (0.05, 6.0, 0.05, 9.95), range_max)
        assert np.abs(ranges - expected).max() < 1e-6
        ahead = np.argmin(np.abs(angles + theta))  # the beam closest to world +x: the wall 3 m away
        assert ranges[ahead] == pytest.approx(3.0, abs=0.05)

        durations = []
        for _ in range(10):
            t0 = time.perf_counter()
            world.step(0.0, 0.0)  # IR-SIM scans on every step
            durations.append(time.perf_counter() - t0)
        assert np.median(durations) < 0.05
        assert np.abs(world.scan()[0] - expected).max() < 1e-6


def test_no_lidar_no_files_and_close(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    world = IrSimWorld(walled(20, 20), (0.0, 0.0), 0.1, BASE, (1.0, 1.0, 0.0))
    assert world.scan() is None
    assert list(tmp_path.iterdir()) == []  # the YAML and PNG are gone once IR-SIM has read them
    world.close()
    world.close()
    with pytest.raises(RuntimeError):
        world.step(0.1, 0.0)
    with pytest.raises(ValueError):
        IrSimWorld(np.zeros(5, dtype=bool), (0.0, 0.0), 0.1, BASE, (1.0, 1.0, 0.0))
    with pytest.raises(ValueError):
        DiffDriveBase(radius=0.2, v_max=0.5, v_min=-0.3, omega_max=1.5, a_max=math.inf, alpha_max=3.0)


def test_two_worlds_step_independently():
    """IR-SIM binds module-level parameters per environment; two live worlds keep their own step_time."""
    fast = dataclasses.replace(BASE, a_max=100.0)
    occ = np.zeros((50, 50), dtype=bool)
    with (IrSimWorld(occ, (0.0, 0.0), 0.1, fast, (1.0, 1.0, 0.0), step_time=0.05) as a,
          IrSimWorld(occ, (0.0, 0.0), 0.1, fast, (1.0, 1.0, 0.0), step_time=0.1, lidar=True) as b):
        for _ in range(4):
            a.step(0.5, 0.0)
            b.step(0.5, 0.0)
        assert a.pose[0] == pytest.approx(1.0 + 4 * 0.5 * 0.05)
        assert b.pose[0] == pytest.approx(1.0 + 4 * 0.5 * 0.1)
        assert (a.time, b.time) == pytest.approx((0.2, 0.4))


def test_pedestrians_walk_are_seen_by_the_lidar_and_their_contacts_are_timed():
    """A person IR-SIM moves (social force, omni) walks between two points at 1 m/s and the LiDAR sees them; a robot
    that drives into a person standing still collides (IR-SIM's check) with its speed at contact recorded, whether
    or not people walk on after bumping into a robot at rest."""
    from hjrno_ros.studies.irsim_world import Person

    occ = walled(160, 80)  # 8 m x 4 m from (-1, -2)
    walker = Person(((1.5, 0.0), (5.5, 0.0)), speed=1.0)
    with IrSimWorld(occ, (-1.0, -2.0), 0.05, BASE, (0.0, 0.0, 0.0), step_time=DT, lidar=True,
                    people=(walker,)) as world:
        ranges, angle_min, increment, _ = world.scan()
        ahead = int(round(-angle_min / increment))
        assert ranges[ahead] == pytest.approx(1.5 - walker.radius, abs=0.02)  # the person's near side
        assert world.min_people_clearance == pytest.approx(1.5 - walker.radius - BASE.radius, abs=1e-6)
        for _ in range(20):
            world.step(0.0, 0.0)
        x, y = world.people_positions[0]
        assert 2.1 < x < 2.6 and abs(y) < 0.3  # about 1 s at 1 m/s towards (5.5, 0), pushed off the robot
        assert world.contact_speed is None and not world.collided
    standing = Person(((1.0, 0.0), (1.0, 0.0)), speed=0.01)
    for walk_on in (False, True):  # driving into a person is a crash either way
        with IrSimWorld(occ, (-1.0, -2.0), 0.05, BASE, (0.0, 0.0, 0.0), step_time=DT, people=(standing,),
                        people_walk_on=walk_on) as world:
            while not world.collided and world.time < 10.0:
                world.step(BASE.v_max, 0.0)
            assert world.collided and world.contact_speed == pytest.approx(BASE.v_max)
            assert world.min_people_clearance <= 1e-9 and world.rest_contacts == 0  # the disks touched


def test_a_person_walking_into_the_robot_at_rest_ends_the_episode_only_without_walk_on():
    """A walker whose path crosses a robot at rest touches it.  IR-SIM's stop mode freezes both for good (the robot
    crashed, at speed 0); with ``people_walk_on`` the contact is counted, the walker walks on and the robot drives
    on after it, and only the gaps kept while moving count as the robot's."""
    from hjrno_ros.studies.irsim_world import Person

    occ = walled(160, 80)
    for walk_on in (False, True):
        walker = Person(((3.0, 0.0), (-0.9, 0.0)), speed=1.0)
        with IrSimWorld(occ, (-1.0, -2.0), 0.05, BASE, (0.0, 0.0, 0.0), step_time=DT, people=(walker,),
                        people_walk_on=walk_on) as world:
            for _ in range(100):  # 5 s: the walker reaches the robot after about 3 s
                world.step(0.0, 0.0)
            assert world.min_people_clearance < 0.0  # they touched
            for _ in range(20):
                world.step(BASE.v_max, 0.0)
            if walk_on:
                assert not world.collided and world.contact_speed is None and world.rest_contacts == 1
                assert world.pose[0] > 0.2 and world.min_people_clearance_moving > 0.0  # drove on, clear of them
            else:
                assert world.collided and world.contact_speed == 0.0 and world.rest_contacts == 0
                assert world.pose[0] == 0.0 and world.min_people_clearance_moving == math.inf


def test_scan_messages_read_inf_where_irsim_saw_nothing():
    pytest.importorskip("rclpy")
    from builtin_interfaces.msg import Time

    from hjrno_ros.ros.harness.irsim_base import scan_message

    msg = scan_message((np.array([1.0, 10.0, 3.0]), -0.5, 0.5, 10.0), Time(sec=3))
    assert list(msg.ranges) == [1.0, math.inf, 3.0] and msg.angle_max == pytest.approx(0.5)
    assert msg.header.stamp.sec == 3
