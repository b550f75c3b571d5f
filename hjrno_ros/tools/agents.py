"""``hjrno agents --robot NAME``: a named robot's value tables against tracked agents (truth/agent_tables.py)."""

from __future__ import annotations

import argparse

from hjrno_ros.truth.agent_tables import add_arguments, main

__all__ = ["add_arguments", "run"]


def run(args: argparse.Namespace) -> int:
    """Solve and write the tables of the robot ``args.robot`` names (the navigation benchmark's robots)."""
    from hjrno_ros.studies.navigation import ROBOTS

    robot = ROBOTS[args.robot]
    return main(args, robot.params(), robot.radius)
