"""``hjrno agents``: a robot's value tables against tracked agents (truth/agent_tables.py), for a named robot of the
benchmarks or for any differential-drive base given by its limits (the node's own parameters)."""

from __future__ import annotations

import argparse
import dataclasses

from hjrno_ros.core.dynamics import DiffDriveParams
from hjrno_ros.core.tracked_agents import robot_options
from hjrno_ros.truth import agent_tables

LIMITS = ("v_min", "v_max", "a_max", "omega_max", "tracking_error")


def add_arguments(p) -> None:
    """The robot (a name, its limits, or a name with some limits changed) and the solver's arguments."""
    p.add_argument("--robot", default=None, help="a benchmark robot's limits and radius: jackal or turtlebot3")
    for name in LIMITS:
        p.add_argument(f"--{name.replace('_', '-')}", type=float, default=None,
                       help=f"the robot's {name} (SI; as the node's parameter of that name)")
    p.add_argument("--radius", type=float, default=None, help="the robot's footprint radius, m (the node's "
                   "footprint_radius)")
    agent_tables.add_arguments(p)


def robot_of(args: argparse.Namespace) -> tuple[DiffDriveParams, float, str]:
    """(limits, footprint radius, name) from ``--robot`` and the limit options, which override the named robot's;
    without a name every limit and the radius are needed (ValueError, one line)."""
    from hjrno_ros.studies.navigation import ROBOTS

    given = {name: getattr(args, name) for name in (*LIMITS, "radius") if getattr(args, name) is not None}
    if args.robot is not None:
        if args.robot not in ROBOTS:
            raise ValueError(f"--robot {args.robot!r}: known robots are {', '.join(sorted(ROBOTS))}")
        named = ROBOTS[args.robot]
        robot = dataclasses.replace(named.params(), **{k: v for k, v in given.items() if k != "radius"})
        radius = given.get("radius", named.radius)
        same = robot == named.params() and radius == named.radius
        return robot, radius, args.robot if same else f"{args.robot} (changed)"
    missing = [f"--{name.replace('_', '-')}" for name in (*LIMITS[:4], "radius") if name not in given]
    if missing:
        raise ValueError(f"give --robot NAME or the robot's limits: missing {' '.join(missing)}")
    robot = DiffDriveParams(**{k: v for k, v in given.items() if k != "radius"})
    return robot, given["radius"], "robot"


def run(args: argparse.Namespace) -> int:
    """Solve and write the tables; exit 2 with one line for a robot or output that is not given."""
    try:
        robot, radius, name = robot_of(args)  # DiffDriveParams checks the limits
        if not 0 < radius <= 5:
            raise ValueError(f"--radius must be in (0, 5] m, got {radius:g}")
    except ValueError as err:
        print(f"hjrno agents: {err}")
        return 2
    if args.out is None:
        if name != args.robot:
            print("hjrno agents: give --out STEM for a robot other than a named one")
            return 2
        args.out = f"models/agents_{name}"
    options = f"--robot {name}" if name == args.robot else robot_options(robot, radius)
    return agent_tables.main(args, robot, radius, name, options)
