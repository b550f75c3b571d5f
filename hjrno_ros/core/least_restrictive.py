"""The least-restrictive filter: the admissible command closest to the nominal one (numpy only).

The filter reads a *certificate* W(s), a lower bound of the robot's value function V (:func:`certificate`): the
larger of the learned value less its calibrated margin, V̂ − ε, where the learned table covers the state, and
the braking bound of :mod:`hjrno_ros.core.braking`, which holds everywhere.  W > 0 says the state is safe.

A command u is **admissible** when the state it leads to over one control period dt, s⁺ (:func:`step`, the base
turning the twist into controls as :func:`~hjrno_ros.core.safety_filter.twist_to_control` says), keeps

    W(s⁺) − (δ·|v̄| + d₀)·dt ≥ b(W(s)),   b(w) = w·exp(−γ·dt) for w > 0,   b(w) = w for w ≤ 0,

with the disturbance's worst displacement over the period taken off (W is 1-Lipschitz in position) and γ the decay
rate: while safe, W may fall towards 0 no faster than exp(−γ t); at or below 0 it must not fall at all. A command
that lowers nothing passes, wherever the robot is: turning in place (rest is exact, V(x, y, 0, θ) = l for every θ),
backing or turning away from a wall.  The filter passes the nominal command when it is admissible; otherwise the
admissible command closest to it (in units of the limits), found on a grid of commands (with the nominal's own speed
and turn among the levels) and refined on the segment towards the nominal; if no command is admissible, the one that
keeps W highest (the optimal safe control, the limit of the rule).  For a robot that rests safely (d₀ = 0) the
linear commands tried lie between 0 and the nominal's: the filter brakes and steers, never adds speed nor reverses
against the nominal.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from hjrno_ros.core.braking import Clearance, braking_value
from hjrno_ros.core.dynamics import RobotParams, disturbance_bound, turn_gain
from hjrno_ros.core.grids import wrap_angle
from hjrno_ros.core.safety_filter import (
    Decision,
    FilterSettings,
    clip_to_limits,
    stop,
    turn_bound,
    twist_to_control,
)

Certificate = Callable[[np.ndarray], np.ndarray]  # states (..., 4) -> W (...), m; may have .at(seconds)
LINEAR_LEVELS, TURN_LEVELS, SEGMENT_POINTS = 7, 9, 16


def at_time(cert: Certificate, seconds: float) -> Certificate:
    """``cert`` for states ``seconds`` after now: a time-varying certificate's ``at`` (tracked agents move), else
    ``cert`` itself."""
    shift = getattr(cert, "at", None)
    return shift(seconds) if shift is not None else cert


def certificate(params: RobotParams, clearance: Clearance, table=None, epsilon: float = 0.0,
                moving: tuple[Clearance, float] | None = None, elapsed: float = 0.0) -> Certificate:
    """W(s) = max(V̂(s) − ε, braking bound) where ``table`` (``value``, ``inside``) covers s, else the braking
    bound alone: a state the learned table does not reach is judged by the bound that needs no model.
    ``moving``: the clearance now of obstacles that may approach, and their speed u (:func:`braking_value`); W then
    varies in time: ``at(seconds)`` is W for states that many seconds after now, those obstacles u·seconds nearer
    (``elapsed``: this certificate's seconds after now), and ``over(states, seconds)`` is W for each state that many
    seconds after this certificate's time, in one lookup."""

    def over(states: np.ndarray, seconds: np.ndarray | float = 0.0) -> np.ndarray:
        states = np.asarray(states, float)
        then = None
        if moving is not None:
            near, speed = moving
            later = elapsed + np.asarray(seconds, float)[..., None]  # per state, over its braking path's points
            then = ((lambda points: near(points) - speed * later), speed)
        bound = braking_value(params, clearance, states, moving=then)
        if table is None:
            return bound
        grid = table.grid
        if 3 not in grid.periodic:  # a stencil's headings are not wrapped: unwrap to within π of its centre
            centre = 0.5 * (grid.lo[3] + grid.hi[3])
            states = states.copy()
            states[..., 3] = centre + wrap_angle(states[..., 3] - centre)
        learned = np.where(table.inside(states), table.value(states) - epsilon, -np.inf)
        return np.maximum(learned, bound)

    def w(states: np.ndarray) -> np.ndarray:
        return over(states)

    if moving is not None:  # what stands still: kept by the rule while W is at or below 0 (filter_least_restrictive)
        w.floor = lambda states: braking_value(params, clearance, np.asarray(states, float))
        w.at = lambda seconds: certificate(params, clearance, table, epsilon, moving, seconds)
        w.over = over
    return w


def step(params: RobotParams, states: np.ndarray, twists: np.ndarray, dt: float,
         period: float | None = None) -> np.ndarray:
    """The states ``(..., 4)`` after the base follows ``twists`` ``(..., 2)`` for ``dt`` without disturbance: its speed
    moves toward the command (within [v_min, v_max]) at up to a_max and holds it there, it turns as
    :func:`~hjrno_ros.core.safety_filter.twist_to_control` says over its control ``period`` (default ``dt``).  The
    distance covered is taken at the faster of the two speeds (a base may reach its new speed at once, as IR-SIM's
    does, or keep its old one for most of the period): never less than the robot can travel toward an obstacle."""
    period = period or dt
    control = twist_to_control(params, states, twists, period)
    v = states[..., 2]
    target = np.clip(twists[..., 0], params.v_min, params.v_max)
    v1 = v + np.clip(target - v, -params.a_max * dt, params.a_max * dt)
    v_move = np.where(v * v1 >= 0, np.where(np.abs(v1) > np.abs(v), v1, v), 0.5 * (v + v1))
    theta1 = states[..., 3] + turn_gain(params, 0.5 * (v + v1)) * control[..., 1] * dt
    theta_mid = 0.5 * (states[..., 3] + theta1)
    x1 = states[..., 0] + v_move * np.cos(theta_mid) * dt
    y1 = states[..., 1] + v_move * np.sin(theta_mid) * dt
    return np.stack([x1, y1, v1, (theta1 + np.pi) % (2 * np.pi) - np.pi], -1)


def required(settings: FilterSettings, w: np.ndarray) -> np.ndarray:
    """b(W): the least W the next state may have."""
    return np.where(w > 0, w * math.exp(-settings.decay_rate * settings.dt), w)


def _after(params: RobotParams, settings: FilterSettings, states: np.ndarray,
           twists: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the states after each twist ``(n, k, 2)`` from ``states`` ``(n, 4)``, the disturbance's reach over dt)."""
    s = np.broadcast_to(states[:, None], (*twists.shape[:2], 4))
    nxt = step(params, s, twists, settings.dt)
    return nxt, disturbance_bound(params, 0.5 * (s[..., 2] + nxt[..., 2])) * settings.dt


def _grid(params: RobotParams, states: np.ndarray, nominal: np.ndarray, dt: float) -> np.ndarray:
    """Commands ``(n, k, 2)`` to try: linear levels between 0 and the nominal's (d₀ = 0) or over the speed range, and
    the nominal's own, each with turn levels across its whole turn bound and the nominal's own turn (so "slower on
    the same arc" and "turn in place as asked" are candidates exactly, not only their nearest grid points)."""
    if params.d0 > 0:
        lo, hi = np.full(len(states), params.v_min), np.full(len(states), params.v_max)
    else:
        lo, hi = np.minimum(nominal[:, 0], 0.0), np.maximum(nominal[:, 0], 0.0)
    linear = np.concatenate([lo[:, None] + (hi - lo)[:, None] * np.linspace(0.0, 1.0, LINEAR_LEVELS),
                             nominal[:, :1]], 1)
    bound = turn_bound(params, states[:, None], linear, dt)
    turns = np.concatenate([bound[..., None] * np.linspace(-1.0, 1.0, TURN_LEVELS),
                            np.clip(nominal[:, None, 1:], -bound[..., None], bound[..., None])], -1)
    grid = np.stack([np.broadcast_to(linear[..., None], turns.shape), turns], -1)
    return grid.reshape(len(states), -1, 2)


def _distance(params: RobotParams, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """How far commands ``a`` are from ``b`` in units of the limits (speed range, turn range at top speed)."""
    scale = np.array([params.v_max - params.v_min, 2.0 * params.turn_rate_max])
    return np.linalg.norm((a - b) / scale, axis=-1)


def ahead(params: RobotParams, settings: FilterSettings, states: np.ndarray, previous: np.ndarray | None,
          delay: float) -> tuple[np.ndarray, np.ndarray]:
    """(the states when a command sent now takes effect, the most W can have lost meanwhile): the base keeps
    executing the ``previous`` twists ``(n, 2)`` for ``delay`` s (the state's age and the command's way to the
    wheels), and the disturbance moves it at most (δ·|v̄| + d₀)·delay."""
    if previous is None or delay <= 0:
        return states, np.zeros(len(states))
    later = step(params, states, np.asarray(previous, float), delay, settings.dt)
    return later, disturbance_bound(params, 0.5 * (states[:, 2] + later[:, 2])) * delay


def _three(cert: Certificate, here: np.ndarray, states: np.ndarray, nxt: np.ndarray, delay: float,
           dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """W at the states now, after ``delay`` and one period later; one lookup for a static certificate or one that
    answers for several times at once (``over``: approaching obstacles), else three, each at its time (tracked
    agents)."""
    if not hasattr(cert, "at"):
        return tuple(np.split(cert(np.concatenate([here, states, nxt])), 3))
    if hasattr(cert, "over"):  # one lookup at the three times
        n = len(here)
        seconds = np.concatenate([np.zeros(n), np.full(n, delay), np.full(n, delay + dt)])
        return tuple(np.split(cert.over(np.concatenate([here, states, nxt]), seconds), 3))
    return cert(here), at_time(cert, delay)(states), at_time(cert, delay + dt)(nxt)


def filter_least_restrictive(params: RobotParams, settings: FilterSettings, cert: Certificate, states: np.ndarray,
                             nominal: np.ndarray, previous: np.ndarray | None = None,
                             delay: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Commands ``(n, 2)``, changed ``(n,)`` and W at the states ``(n,)`` for nominal twists ``(n, 2)`` (clipped to
    the limits first; a change by clipping alone does not count as changed).  With ``delay`` > 0 the commands are
    judged from the states :func:`ahead` (``previous``: the twists the base executes until then).  Where no
    certificate covers the state a command acts at (W = −∞: beyond a car's table, which has no braking bound) the
    command is (0, 0) and W −∞."""
    here, nominal = np.asarray(states, float), np.asarray(nominal, float)
    states, lag = ahead(params, settings, here, previous, delay)
    nominal = clip_to_limits(params, states, nominal, settings.dt)
    nxt, drift = _after(params, settings, states, nominal[:, None])
    w_here, w_now, w_next = _three(cert, here, states, nxt[:, 0], delay, settings.dt)
    need = required(settings, w_now - lag)
    blind = ~np.isfinite(w_now)  # no table and no bound where the command acts (a car, d₀ > 0): fail closed
    later = at_time(cert, delay + settings.dt)  # the certificate when the command has acted
    floor_need = _floor_need(settings, getattr(at_time(cert, delay), "floor", None), states, w_now - lag, lag)
    changed = blind | ~(w_next - drift[:, 0] - lag >= need)
    if floor_need is not None:
        changed |= ~(later.floor(nxt[:, 0]) - drift[:, 0] - lag >= floor_need)
    out = nominal.copy()
    search = changed & ~blind  # only the commands the nominal fails are searched (most pass: a cheap common case)
    if search.any():
        out[search] = _closest_admissible(params, settings, later, states[search], nominal[search], lag[search],
                                          need[search], None if floor_need is None else floor_need[search])
    out[blind] = 0.0
    return out, changed, np.where(blind, -np.inf, w_here)


def _floor_need(settings: FilterSettings, floor: Certificate | None, states: np.ndarray, w: np.ndarray,
                lag: np.ndarray) -> np.ndarray | None:
    """The least the certificate's ``floor`` (what stands still) may have at the next state: b(floor) where W ``w``
    is at or below 0, −∞ elsewhere; None without a floor or where W > 0 at every state (the command path's common
    case).  Below 0, W is the least of its parts and a command that does not lower it may still run into another
    part (backing from a person within the motion margin into a wall): the rule holds for what stands still too."""
    if floor is None or not np.any(w <= 0):
        return None
    return np.where(w <= 0, required(settings, floor(states) - lag), -np.inf)


def _closest_admissible(params: RobotParams, settings: FilterSettings, cert: Certificate, states: np.ndarray,
                        nominal: np.ndarray, lag: np.ndarray, need: np.ndarray,
                        floor_need: np.ndarray | None = None) -> np.ndarray:
    """For inadmissible nominal commands: the admissible command nearest each on the grid, moved along the
    segment toward its nominal as far as stays admissible; where none is admissible, the highest W (where W is at
    or below 0: of those that keep the floor's rule, if any do)."""

    def judged(twists: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """W after each twist, whether it is admissible, whether it keeps the floor's rule."""
        nxt, drift = _after(params, settings, states, twists)
        w = cert(nxt) - drift - lag[:, None]
        kept = np.ones(w.shape, bool)
        if floor_need is not None:
            kept = cert.floor(nxt) - drift - lag[:, None] >= floor_need[:, None]
        return w, (w >= need[:, None]) & kept, kept

    tries = _grid(params, states, nominal, settings.dt)
    w, ok, kept = judged(tries)
    distance = _distance(params, tries, nominal[:, None])
    # none admissible: the highest W (among the commands that keep the floor's rule, if any), nearest the nominal
    w = np.where(kept | ~kept.any(1, keepdims=True), w, -np.inf)
    safest = w >= w.max(1, keepdims=True) - 1e-9
    best = np.where(ok.any(1), np.where(ok, distance, np.inf).argmin(1), np.where(safest, distance, np.inf).argmin(1))
    out = tries[np.arange(len(states)), best]
    out[~np.isfinite(w.max(1))] = 0.0  # every command leaves what the certificate covers: stop
    refine = ok.any(1)
    if refine.any():  # the admissible point nearest the nominal on the segment nominal -> best
        t = np.linspace(0.0, 1.0, SEGMENT_POINTS + 1)[1:]
        seg = np.broadcast_to(nominal[:, None], (len(states), len(t), 2)).copy()
        seg[refine] = nominal[refine, None] + t[:, None] * (out[refine] - nominal[refine])[:, None]
        seg_ok = judged(seg)[1][refine]
        first = seg_ok.argmax(1)  # t = 1 (the best grid command) is admissible
        out[refine] = seg[refine][np.arange(refine.sum()), first]
    return out


def decide(params: RobotParams, settings: FilterSettings, cert: Certificate, state: np.ndarray, linear: float,
           angular: float, previous: tuple[float, float] | None = None, delay: float = 0.0) -> Decision:
    """One command through the filter as a :class:`~hjrno_ros.core.safety_filter.Decision` (``value`` is W at the
    state; ``previous``, ``delay``: :func:`ahead`); anything non-finite fails closed."""
    state = np.asarray(state, float)
    if not np.all(np.isfinite(state)):
        return stop(math.nan, "non-finite state")
    if not (math.isfinite(linear) and math.isfinite(angular)):
        return stop(math.nan, "non-finite nominal command")
    nominal = np.array([[linear, angular]])
    clipped = bool(np.any(clip_to_limits(params, state[None], nominal, settings.dt) != nominal))
    out, changed, w = filter_least_restrictive(params, settings, cert, state[None], nominal,
                                               None if previous is None else np.array([previous], float), delay)
    value = float(w[0])
    if not math.isfinite(value):
        return stop(math.nan, "non-finite certificate: no value table or braking bound covers the state")
    if not np.all(np.isfinite(out)):
        return stop(value, "non-finite filtered command")
    if changed[0]:
        return Decision(float(out[0, 0]), float(out[0, 1]), True, value, "closest admissible", clipped)
    if clipped:
        return Decision(float(out[0, 0]), float(out[0, 1]), False, value, "clipped to limits", True)
    return Decision(float(linear), float(angular), False, value, "pass")
