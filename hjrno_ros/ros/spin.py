"""A driver node spinning on its own context and ROS domain in a background thread (benches, fuzzing)."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import rclpy
from rclpy.executors import SingleThreadedExecutor


def spin_in_background(domain_id: int, make: Callable[[Any], Any]) -> tuple[Any, Callable[[], None]]:
    """(node, stop): ``make(context)`` built on a fresh context of ``domain_id`` and spun by its own executor
    thread; ``stop()`` shuts executor, node and context down."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = make(context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()

    def stop() -> None:
        executor.shutdown(timeout_sec=2.0)
        node.destroy_node()
        rclpy.shutdown(context=context)
        spinner.join(timeout=2.0)

    return node, stop
