"""Driver nodes on their own context and ROS domain: spun in a background thread (benches, fuzzing), or driven in
the calling thread for a stretch of real time once brt_node filters (the simulated bases)."""

from __future__ import annotations

import threading
import time
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


def drive_base(domain_id: int, make: Callable[[Any], Any], seconds: float, ready: Callable[[Any], bool],
               done: Callable[[Any], bool], timeout: float = 120.0) -> Any:
    """A simulated base ``make(context)`` (with ``log.status``, ``begin()`` and ``running``) on a fresh context of
    ``domain_id``: spun until ``ready(base.log)`` (brt_node filtering; RuntimeError with the node's reason after
    ``timeout`` s), then ``begin()`` and driven for ``seconds`` of real time or until ``done(base)``; returned
    after its executor, node and context are shut down."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    base = make(context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(base)
    try:
        deadline = time.monotonic() + timeout
        while not ready(base.log):
            if time.monotonic() > deadline:
                raise RuntimeError(f"brt_node did not start filtering within {timeout:g} s: "
                                   f"{base.log.status.get('reason', 'no status received')}")
            executor.spin_once(timeout_sec=0.05)
        base.begin()
        end = time.monotonic() + seconds
        while time.monotonic() < end and not done(base):
            executor.spin_once(timeout_sec=0.01)
        base.running = False
        return base
    finally:
        executor.shutdown(timeout_sec=2.0)
        base.destroy_node()
        rclpy.shutdown(context=context)
