"""The harness's simulated base on its own (no brt_node on its domain): direct driving moves the plant, and with the
filter in the loop a base that hears no filtered command holds still (its watchdog), as a real base does."""

from __future__ import annotations

import os

import numpy as np
import pytest

pytest.importorskip("rclpy")

from hjrno_ros.core.dynamics import DiffDriveParams  # noqa: E402
from hjrno_ros.ros.harness.plants import KinematicPlant  # noqa: E402
from hjrno_ros.ros.harness.sim_base import SimBase  # noqa: E402
from hjrno_ros.ros.harness.spin import drive_base  # noqa: E402

DOMAIN = 60 + os.getpid() % 40  # apart from the DDS tests' domains
ROBOT = DiffDriveParams(v_max=0.5, v_min=-0.5, tracking_error=0.0)  # no disturbance: a held base stays put


def drive(direct: bool, seconds: float = 1.5) -> SimBase:
    def make(context) -> SimBase:
        plant = KinematicPlant(ROBOT, np.zeros(4), lambda xy: "exit" if xy[0] > 0.3 else None)
        return SimBase(context, plant, lambda state, t: np.array([0.5, 0.0]), direct=direct)

    return drive_base(DOMAIN, make, seconds, lambda log: True, lambda base: base.ended)


def test_a_direct_base_executes_its_driver_until_the_plant_ends_the_episode():
    base = drive(direct=True)
    trace = np.array(base.log.trace)
    assert base.log.outcome == "exit" and 0.5 < base.log.ended_at < 1.5, base.log
    assert trace[-1, 1] > 0.25 and np.all(np.diff(trace[:, 1]) >= -1e-9)  # forward, never back
    assert base.log.commands > 5 and base.log.latency_s == []  # no node: nothing answered


def test_a_base_without_filtered_commands_holds_still():
    base = drive(direct=False, seconds=1.0)
    trace = np.array(base.log.trace)
    assert base.log.outcome is None and base.log.commands > 5
    assert np.abs(trace[:, 1:4]).max() == 0.0  # at rest where it began: a stale command is a stop
    assert base.log.stopped == len(trace)
