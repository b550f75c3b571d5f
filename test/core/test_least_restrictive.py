"""The least-restrictive filter (core/least_restrictive.py) and the braking bound (core/braking.py) on a solved
differential-drive table: it passes what lowers nothing, changes only what moves toward danger and by no more
than needed, and careless drivers (goal-seeking, straight, reversing, spinning) never collide under it."""

import math

import numpy as np
import pytest
from scipy.interpolate import RegularGridInterpolator

from hjrno_ros.core.braking import braking_value
from hjrno_ros.core.dynamics import DiffDriveParams
from hjrno_ros.core.geometry import Box, union_sdf
from hjrno_ros.core.grids import GridSpec, car_grid
from hjrno_ros.core.least_restrictive import certificate, decide, filter_least_restrictive, step
from hjrno_ros.core.safety_filter import FilterSettings
from hjrno_ros.core.value_table import ReversingTable, ValueTable
from hjrno_ros.studies.closed_loop import base_step
from hjrno_ros.truth.solver import solve
from hjrno_ros.truth.systems import DiffDrive

ROBOT = DiffDriveParams(a_max=1.0, v_min=-1.0)  # the reference robot: 1 m/s, 1 rad/s, reverses
WALLS = (Box((2.5, 0.0), (0.5, 4.0)), Box((-1.5, 2.5), (2.5, 0.5)))  # walls at x in [2, 3] and y in [2, 3]
SETTINGS = FilterSettings(mode="least_restrictive", dt=0.05)


GRID = car_grid((32, 32, 9, 16), v_range=(0.0, 1.0))


def _clearance(points: np.ndarray) -> np.ndarray:
    """The walls grown by h/√2 of the table's grid, as brt_node grows its map (docs/design.md, "Inflation")."""
    return union_sdf(WALLS, points) - GRID.half_cell_diagonal


@pytest.fixture(scope="module")
def table():
    grid = GRID
    target = np.ascontiguousarray(np.broadcast_to(_clearance(grid.states()[..., 0, 0, :2])[:, :, None, None],
                                                  grid.shape), np.float32)
    value, report = solve(DiffDrive(DiffDriveParams(a_max=1.0)), grid, target, tolerance=1e-3, max_horizon=12.0,
                          criterion="band")
    assert report.converged
    return ReversingTable(ValueTable(grid, value))


@pytest.fixture(scope="module")
def cert(table):
    return certificate(ROBOT, _clearance, table, 0.0)


def test_braking_bound_is_below_the_solved_value(table):
    """Braking straight is one strategy, so its least clearance lower-bounds V: with the l the solver saw (sampled at
    its nodes) to the solver's accuracy, with the exact l to the grid's interpolation error (h/√2: the table's l
    dips below the exact clearance along the ridges of l, between the walls)."""
    rng = np.random.default_rng(0)
    grid = table.grid
    seen = RegularGridInterpolator((grid.axis(0), grid.axis(1)), _clearance(grid.states()[..., 0, 0, :2]))
    nodes = grid.states().reshape(-1, 4)
    nodes = nodes[(np.abs(nodes[:, :2]) < 4).all(1)]  # the open edges of the window are extrapolated
    nodes = nodes[rng.choice(len(nodes), 4000, replace=False)]
    assert np.all(braking_value(ROBOT, seen, nodes) <= table.value(nodes) + 2e-2)  # measured: 0.017 on 46 of 83k
    s = np.column_stack([rng.uniform(-4, 1.5, 4000), rng.uniform(-4, 1.5, 4000), rng.uniform(-1, 1, 4000),
                         rng.uniform(-math.pi, math.pi, 4000)])
    assert np.all(braking_value(ROBOT, _clearance, s) <= table.value(s) + grid.half_cell_diagonal)
    at_rest = s.copy()
    at_rest[:, 2] = 0.0
    assert np.allclose(braking_value(ROBOT, _clearance, at_rest), _clearance(s[:, :2]))  # exact at rest
    assert np.all(braking_value(DiffDriveParams(d0=0.1), _clearance, s) == -np.inf)  # no bound with drift at rest


def _least_gap_while_braking(state: np.ndarray, person: np.ndarray, speed: float, dt: float = 1e-3) -> float:
    """Simulated: the robot brakes at a_max from ``state`` while a point ``person`` walks straight at it at ``speed``;
    the least distance between them before the robot is at rest."""
    x, v, heading = state[:2].copy(), state[2], np.array([math.cos(state[3]), math.sin(state[3])])
    least = np.linalg.norm(person - x)
    while abs(v) > 0:
        v_next = math.copysign(max(abs(v) - ROBOT.a_max * dt, 0.0), v)
        x += 0.5 * (v + v_next) * dt * heading
        towards = x - person
        person = person + speed * dt * towards / max(np.linalg.norm(towards), 1e-12)
        v = v_next
        least = min(least, np.linalg.norm(person - x))
    return float(least)


def test_braking_bound_against_an_approaching_person_lower_bounds_the_gap_while_braking():
    """A person who may walk at u m/s toward the robot comes u·|v|/a_max nearer while it brakes: with that term the
    bound stays below the least gap of a simulated stop against a person walking straight at the robot; without
    it (the person taken as still) it is above that gap, and at rest it is the clearance itself."""
    rng = np.random.default_rng(1)
    free = lambda pts: np.full(np.shape(pts)[:-1], np.inf)  # noqa: E731 - no map obstacle
    speed, worse = 1.0, 0
    for _ in range(200):
        state = np.array([0.0, 0.0, rng.uniform(-1, 1), rng.uniform(-math.pi, math.pi)])
        person = rng.uniform(-3, 3, 2)
        clearance = lambda pts, p=person: np.linalg.norm(np.asarray(pts) - p, axis=-1)  # noqa: E731
        bound = braking_value(ROBOT, free, state[None], moving=(clearance, speed))[0]
        gap = _least_gap_while_braking(state, person, speed)
        assert bound <= gap + 2e-3  # the simulation's own step: measured 0.9 mm at worst
        worse += braking_value(ROBOT, clearance, state[None])[0] > gap + 2e-3
        at_rest = state.copy()
        at_rest[2] = 0.0
        at_rest_bound = braking_value(ROBOT, free, at_rest[None], moving=(clearance, speed))[0]
        assert at_rest_bound == pytest.approx(np.linalg.norm(person))  # the robot is at the origin
    assert worse >= 190  # measured: all 200 (every state moves)


def _decide(cert, state, linear, angular):
    return decide(ROBOT, SETTINGS, cert, np.asarray(state, float), linear, angular)


def test_far_from_obstacles_every_command_passes(cert):
    for nominal in ((1.0, 0.0), (0.5, -1.0), (-1.0, 0.3), (0.0, 1.0)):
        d = _decide(cert, (-2.0, -2.0, 0.5, 0.7), *nominal)
        assert not d.intervened and (d.linear, d.angular) == nominal


def test_at_rest_beside_a_wall_only_motion_toward_it_is_changed(cert):
    """At rest inside the margin (W < 0: 0.02 m inside the grown wall ahead, 0.21 m from the wall itself): turning
    in place and backing away pass unchanged, driving into the wall does not."""
    state = (2.02 - GRID.half_cell_diagonal, 0.0, 0.0, 0.0)
    assert cert(np.array([state]))[0] == pytest.approx(-0.02, abs=1e-6)  # rest: W = l, exactly
    spin = _decide(cert, state, 0.0, 1.0)
    assert not spin.intervened and (spin.linear, spin.angular) == (0.0, 1.0)
    back = _decide(cert, state, -0.5, 0.0)
    assert not back.intervened and back.linear == -0.5
    forward = _decide(cert, state, 1.0, 0.0)
    assert forward.intervened and forward.linear < 0.05
    nxt = step(ROBOT, np.array([state]), np.array([[forward.linear, forward.angular]]), SETTINGS.dt)
    assert cert(nxt)[0] >= cert(np.array([state]))[0] - 1e-9  # what it sends does not lower W


def test_the_change_is_no_larger_than_needed(cert):
    """Heading for the wall at speed, W still positive: the filter slows the robot without taking over its turn, and
    its command is closer to the nominal than the optimal safe control (full braking and turning)."""
    state = np.array([1.0, -1.0, 1.0, 0.0])
    d = _decide(cert, state, 1.0, 0.2)
    assert d.intervened and 0.0 <= d.linear < 1.0
    assert abs(d.angular - 0.2) < 0.5
    optimal = np.array([state[2] - ROBOT.a_max * SETTINGS.dt, 1.0])
    assert np.hypot(d.linear - 1.0, (d.angular - 0.2) / 2) < np.hypot(optimal[0] - 1.0, (optimal[1] - 0.2) / 2)


def test_no_command_is_admissible_gives_the_safest(cert):
    """Inside the tube (too fast, too close): nothing keeps W, so the command that keeps it highest: braking."""
    state = np.array([[1.6, 0.0, 1.0, 0.0]])
    out, changed, w = filter_least_restrictive(ROBOT, SETTINGS, cert, state, np.array([[1.0, 0.0]]))
    assert changed[0] and w[0] < 0.2 and out[0, 0] <= 1.0 - ROBOT.a_max * SETTINGS.dt + 1e-9


@pytest.mark.parametrize("driver", ["goal", "straight", "reverse", "spin"])
def test_careless_drivers_never_collide(cert, driver):
    """200 careless robots for 15 s each (random disturbance ‖d‖ ≤ 0.1·|v|), commands filtered every 50 ms: no
    contact with the walls, spinning robots never changed, goal-seekers still get somewhere."""
    rng = np.random.default_rng(hash(driver) % 2**32)
    n, dt = 200, SETTINGS.dt
    x = np.column_stack([rng.uniform(-4, 1.5, 4 * n), rng.uniform(-4, 1.5, 4 * n), np.zeros(4 * n),
                         rng.uniform(-math.pi, math.pi, 4 * n)])
    x = x[_clearance(x[:, :2]) > 0.1][:n]
    goals = np.column_stack([np.full(n, 4.0), rng.uniform(-3, 3, n)])  # behind the wall: careless drivers hit it
    start = x.copy()
    touched, changed, steps = np.zeros(n, bool), 0, 0
    for _ in range(int(15 / dt)):
        if driver == "goal":
            err = np.arctan2(goals[:, 1] - x[:, 1], goals[:, 0] - x[:, 0]) - x[:, 3]
            err = (err + math.pi) % (2 * math.pi) - math.pi
            nominal = np.column_stack([np.cos(err).clip(0, 1), np.clip(2 * err, -1, 1)])
        else:
            nominal = np.tile({"straight": (1.0, 0.0), "reverse": (-1.0, 0.0), "spin": (0.0, 1.0)}[driver], (n, 1))
        out, ch, _ = filter_least_restrictive(ROBOT, SETTINGS, cert, x, nominal)
        changed, steps = changed + ch.sum(), steps + n
        x = base_step(ROBOT, x, out, dt, dt, rng)
        touched |= union_sdf(WALLS, x[:, :2]) <= 0  # the exact walls
    assert not touched.any(), f"{touched.sum()} robots touched a wall"
    if driver == "spin":
        assert changed == 0
    if driver == "goal":
        assert np.mean(np.linalg.norm(x[:, :2] - start[:, :2], axis=1)) > 1.0


def test_step_reaches_the_command_without_overshoot_and_never_underestimates_the_distance():
    """Over a long delay the speed stops at the command (a base holds its setpoint); the distance is taken at the
    faster of the old and new speed (a base may jump to its new speed at once, as IR-SIM's does)."""
    s = np.array([[0.0, 0.0, 0.062, 0.0]])
    later = step(ROBOT, s, np.array([[0.0, 0.0]]), 0.1, period=0.05)
    assert later[0, 2] == 0.0 and later[0, 0] == pytest.approx(0.062 * 0.1)
    faster = step(ROBOT, np.array([[0.0, 0.0, 0.0, 0.0]]), np.array([[1.0, 0.0]]), 0.05)
    assert faster[0, 2] == pytest.approx(0.05) and faster[0, 0] == pytest.approx(0.05 * 0.05)


def test_a_command_is_judged_where_the_robot_will_be_when_it_acts(cert):
    """Heading for the wall at speed: judged from the state now a forward command passes, judged from the state
    after 0.2 s more of the same command (odometry age, the way to the wheels) it is slowed."""
    state = np.array([1.2, 0.0, 1.0, 0.0])
    now = decide(ROBOT, SETTINGS, cert, state, 1.0, 0.0)
    later = decide(ROBOT, SETTINGS, cert, state, 1.0, 0.0, previous=(1.0, 0.0), delay=0.2)
    assert later.intervened and later.linear < now.linear


def test_a_state_no_certificate_covers_stops_the_robot():
    """A car whose disturbance moves it at rest (d₀ > 0) has no braking bound: where its table does not hold the
    state, or every command leaves the table, nothing vouches for any command and the filter sends (0, 0)."""
    from hjrno_ros.core.dynamics import CarParams

    car = CarParams()  # the paper's car, d0 = 0.1 m/s
    grid = GridSpec((-5.0, -5.0, 0.4, -0.2), (5.0, 5.0, 0.6, 0.2), (8, 8, 2, 2))  # a slice model's stencil
    stencil = ValueTable(grid, np.ones(grid.shape))
    cert = certificate(car, _clearance, stencil, 0.0)
    outside = decide(car, SETTINGS, cert, np.array([0.0, 0.0, 0.9, 0.0]), 0.9, 0.0)
    assert (outside.linear, outside.angular, outside.intervened) == (0.0, 0.0, True)
    assert outside.reason.startswith("non-finite certificate")
    inside = decide(car, SETTINGS, cert, np.array([0.0, 0.0, 0.5, 0.0]), 0.5, 0.0)
    assert (inside.linear, inside.angular, inside.intervened) == (0.5, 0.0, False)
    out, changed, _ = filter_least_restrictive(car, SETTINGS, cert, np.array([[0.0, 0.0, 0.6, 0.0]]),
                                               np.array([[1.0, 0.0]]), np.array([[1.0, 0.0]]), 0.2)
    assert changed[0] and np.array_equal(out[0], (0.0, 0.0))  # by the time it acts, the speed has left the table


def _back_away(cert, steps: int = 60) -> tuple[float, float]:
    """The robot at rest at the origin facing +x reverses at full speed through the filter: (least x, last x)."""
    state, least = np.array([0.0, 0.0, 0.0, 0.0]), 0.0
    for _ in range(steps):
        d = decide(ROBOT, SETTINGS, cert, state, -1.0, 0.0)
        state = step(ROBOT, state[None], np.array([[d.linear, d.angular]]), SETTINGS.dt)[0]
        least = min(least, state[0])
    return least, state[0]


def test_backing_away_from_a_person_stops_short_of_the_wall_behind():
    """W is the least of its parts: the static map's, and a person's (as tracked agents add theirs).  With the
    person 0.5 m ahead W is below 0; reversing away raises the person's part, so W alone lets the robot run
    backwards into the wall 0.6 m behind (the wall's part binds only once the robot is too fast to stop).  What
    stands still (the certificate's floor) keeps the rule too: the robot backs away and stops before the wall."""
    static = certificate(ROBOT, lambda pts: np.asarray(pts)[..., 0] + 0.6)  # a wall behind the robot, x = -0.6

    def cert(states: np.ndarray) -> np.ndarray:
        person = np.linalg.norm(np.asarray(states)[..., :2] - [0.5, 0.0], axis=-1) - 0.85  # within its margin
        return np.minimum(static(states), person)

    assert cert(np.zeros((1, 4)))[0] < 0
    reached_the_wall = _back_away(cert)[0] <= -0.6
    cert.floor = static
    least, last = _back_away(cert)
    assert -0.6 < least and last < -0.2  # it backed away from the person, and stopped before the wall
    assert reached_the_wall  # without the floor


def test_speed_near_a_person_within_the_motion_margin_is_held_by_the_braking_bound():
    """Within the motion margin of an untracked person the braking bound falls with any speed (the person comes
    u·|v|/a_max nearer while the robot stops): the robot stays at rest, as passive safety asks."""
    wall = lambda pts: np.asarray(pts)[..., 0] + 0.6  # noqa: E731
    person = lambda pts: np.linalg.norm(np.asarray(pts) - [0.5, 0.0], axis=-1) - 0.85  # noqa: E731
    cert = certificate(ROBOT, wall, None, 0.0, moving=(person, 1.0))
    assert cert(np.zeros((1, 4)))[0] < 0 and hasattr(cert, "floor")
    assert _back_away(cert) == (0.0, 0.0)


def _walk_at_the_robot(seed: int, age_of, time_varying: bool = True, steps: int = 200) -> tuple[bool, float]:
    """A careless driver asks for full speed ahead; a person (disks' radii 0.5 m in all) starts 2.5-4.5 m ahead and,
    after up to 2 s, walks at 1 m/s straight at the robot.  A scan sees them every 0.1 s; the certificate grows
    them by 1 m/s times ``age_of(seconds since the scan)``, and with ``time_varying`` by 1 m/s more per second
    after now (``at``).  Returns (the robot moved into the contact, how far it got)."""
    rng = np.random.default_rng(seed)
    free = lambda pts: np.full(np.shape(pts)[:-1], np.inf)  # noqa: E731 - nothing on the map
    state, person = np.zeros(4), np.array([rng.uniform(2.5, 4.5), rng.uniform(-0.5, 0.5)])
    starts = rng.uniform(0.0, 2.0)
    for k in range(steps):
        t = k * SETTINGS.dt
        if k % 2 == 0:
            seen, seen_at = person.copy(), t
        grown = 0.5 + age_of(t - seen_at)
        near = lambda pts, p=seen, r=grown: np.linalg.norm(np.asarray(pts) - p, axis=-1) - r  # noqa: E731
        cert = certificate(ROBOT, free, None, 0.0, moving=(near, 1.0))
        if not time_varying:  # the same W, taken as it is now for the next state too
            frozen = lambda states, c=cert: c(states)  # noqa: E731
            frozen.floor, cert = cert.floor, frozen
        d = decide(ROBOT, SETTINGS, cert, state, 1.0, 0.0)
        state = step(ROBOT, state[None], np.array([[d.linear, d.angular]]), SETTINGS.dt)[0]
        if t >= starts:
            person = person + SETTINGS.dt * (state[:2] - person) / np.linalg.norm(state[:2] - person)
        if np.linalg.norm(state[:2] - person) <= 0.5:
            return abs(state[2]) > 0.02, state[0]
    return False, state[0]


def test_a_person_seen_by_ageing_scans_never_meets_the_robot_moving():
    """The motion margin at the data's actual age: the certificate grows an untracked person by 1 m/s over the
    scan's age and varies in time (``at``), so the next state is judged with the person nearer still.  A careless
    driver never reaches them moving (40 random starts), and gets further than with the margin of the source's
    whole timeout (0.5 s).  Judging the next state with W as it is now, instead, lets the robot drive into them."""
    at_age = [_walk_at_the_robot(seed, lambda age: age) for seed in range(40)]
    at_timeout = [_walk_at_the_robot(seed, lambda age: 0.5) for seed in range(40)]
    frozen = [_walk_at_the_robot(seed, lambda age: age, time_varying=False) for seed in range(40)]
    assert not any(moved for moved, _ in at_age) and not any(moved for moved, _ in at_timeout)
    assert np.mean([x for _, x in at_age]) > np.mean([x for _, x in at_timeout]) + 0.15  # measured: 1.40 m, 1.14 m
    assert sum(moved for moved, _ in frozen) >= 30  # measured: all 40


def test_a_certificate_with_approaching_obstacles_varies_in_time():
    wall = lambda pts: np.asarray(pts)[..., 0] + 5.0  # noqa: E731
    person = lambda pts: np.linalg.norm(np.asarray(pts) - [2.0, 0.0], axis=-1)  # noqa: E731
    cert, still = certificate(ROBOT, wall, None, 0.0, moving=(person, 1.0)), certificate(ROBOT, wall)
    states = np.array([[0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.5, 0.0]])
    assert cert.at(0.3)(states) == pytest.approx(cert(states) - 0.3)  # the person 0.3 m nearer
    assert cert.at(0.3).floor(states) == pytest.approx(cert.floor(states))  # what stands still does not move
    seconds = np.array([0.1, 0.4])  # one lookup for states at different times
    assert cert.over(states, seconds) == pytest.approx([cert.at(0.1)(states[:1])[0], cert.at(0.4)(states[1:])[0]])
    assert not hasattr(still, "at")


class _AgeingPerson:
    """A wall 0.6 m behind the robot (the floor: what stands still) and a person 0.5 m ahead deep in their margin,
    whose part of W falls by 2 m/s after now (faster than the robot can back away from them), so no command keeps
    the rule and the filter falls back on the highest W."""

    def __init__(self, elapsed: float = 0.0, floor: bool = True):
        self.elapsed, self.has_floor = elapsed, floor
        self.static = certificate(ROBOT, lambda pts: np.asarray(pts)[..., 0] + 0.6)

    def at(self, seconds: float) -> "_AgeingPerson":
        return _AgeingPerson(seconds, self.has_floor)

    def __getattr__(self, name: str):
        if name == "floor" and self.has_floor:
            return self.static
        raise AttributeError(name)

    def __call__(self, states: np.ndarray) -> np.ndarray:
        person = np.linalg.norm(np.asarray(states)[..., :2] - [0.5, 0.0], axis=-1) - 1.35 - 2.0 * self.elapsed
        return np.minimum(self.static(states), person)


def test_with_no_admissible_command_the_highest_w_still_keeps_the_floor():
    """Nothing keeps the rule, and the highest W is to back away from the person as fast as asked: without the
    floor the robot does so into the wall; with it, the fallback takes the highest W among the commands that keep
    the floor's rule, and the robot stops short of the wall."""
    assert _back_away(_AgeingPerson(floor=False))[0] <= -0.6
    least, last = _back_away(_AgeingPerson())
    assert -0.6 < least and last < -0.1
