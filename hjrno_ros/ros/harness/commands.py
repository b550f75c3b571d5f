"""A simulated base's command link to brt_node: nominal TwistStamped commands out, each filtered answer matched
to the nominal it answers by stamp (latency, changed or not), and the value grids it publishes, logged."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import OccupancyGrid

from hjrno_ros.ros.brt_node.messages import occupancy_array


class StampedCommands:
    """Sends nominal commands on ``publisher`` and matches brt_node's answers to them by header stamp.

    ``keep``: how many unanswered commands to remember (None: all)."""

    def __init__(self, node: Any, publisher: Any, keep: int | None = None) -> None:
        self.node, self.publisher, self.keep = node, publisher, keep
        self._sent: dict[tuple[int, int], tuple[float, np.ndarray]] = {}

    def send(self, nominal: np.ndarray) -> None:
        msg = TwistStamped()
        msg.header.frame_id = "base_link"
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.twist.linear.x, msg.twist.angular.z = float(nominal[0]), float(nominal[1])
        self._sent[(msg.header.stamp.sec, msg.header.stamp.nanosec)] = (time.perf_counter(), nominal)
        if self.keep is not None and len(self._sent) > self.keep:
            self._sent.pop(next(iter(self._sent)))
        self.publisher.publish(msg)

    @property
    def unanswered(self) -> int:
        return len(self._sent)

    def forget(self) -> None:
        """Drop the unanswered commands (a new measurement starts)."""
        self._sent.clear()

    def answer(self, msg: TwistStamped) -> tuple[np.ndarray, float | None, bool]:
        """(filtered (linear, angular), latency s or None when it answers no command of ours (the node's
        fail-closed timer), changed against the nominal it answers)."""
        filtered = np.array([msg.twist.linear.x, msg.twist.angular.z])
        sent = self._sent.pop((msg.header.stamp.sec, msg.header.stamp.nanosec), None)
        if sent is None:
            return filtered, None, False
        return filtered, time.perf_counter() - sent[0], bool(np.abs(filtered - sent[1]).max() > 1e-6)


def unsafe_grid(msg: OccupancyGrid, t: float) -> tuple[float, tuple[float, float], float, np.ndarray]:
    """A value grid as the bases log it: (t, origin, resolution, unsafe mask [ix, iy])."""
    origin = (msg.info.origin.position.x, msg.info.origin.position.y)
    return t, origin, msg.info.resolution, occupancy_array(msg) >= 100
