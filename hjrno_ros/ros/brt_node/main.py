"""The ``brt_node`` executable.  SIGINT/SIGTERM handling is installed before the node is imported, so an
interrupt at any moment of start-up (rclpy, torch and the model load take seconds) ends in one line, and
rclpy's own handler is off so the worker stops before the ROS context shuts down."""

from __future__ import annotations

import os
import signal
import sys

_interrupted = False
SPIN_WAKE_S = 0.2  # s: the longest the executor waits, so an interrupt is handled within it in any state


def _interrupt(signum: int, frame: object) -> None:
    global _interrupted
    _interrupted = True
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    signal.signal(signal.SIGINT, _interrupt)
    signal.signal(signal.SIGTERM, _interrupt)
    try:
        import rclpy
        from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        from hjrno_ros.ros.brt_node.node import NODE_NAME, BrtNode, StartupError
    except BaseException:
        if not _interrupted:
            raise
        # an extension module interrupted while loading may turn the interrupt into an ImportError (numpy does)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        print("[brt_node]: interrupted during start-up", file=sys.stderr, flush=True)
        os._exit(0)  # half-imported extensions may not finalise cleanly; nothing has started yet
    logger = rclpy.logging.get_logger(NODE_NAME)
    try:
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
        node = BrtNode()
    except KeyboardInterrupt:
        logger.info("interrupted during start-up")
        rclpy.try_shutdown()
        return 0
    except Exception as err:  # e.g. a parameter override of the wrong type: one line
        logger.fatal(f"cannot start: {type(err).__name__}: {err}")
        rclpy.try_shutdown()
        return 1
    # One executor thread: measured here, a relay's p95 latency was 1.4 ms single-threaded vs 6.6 ms
    # with rclpy's MultiThreadedExecutor. Inference runs in the node's own worker thread anyway.
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    code = 0
    try:
        if node.get_parameter("autostart").value:
            node.start()  # plain mode; with autostart false a lifecycle manager configures and activates
        while rclpy.ok():  # a bounded wait: unconfigured, nothing wakes the executor, and SIGINT waits for a wake-up
            executor.spin_once(timeout_sec=SPIN_WAKE_S)
    except StartupError as err:
        if not _interrupted:  # an interrupt during the model load can surface as an import error
            logger.fatal(f"cannot start: {err}")
            code = 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second interrupt must not break the clean stop
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        node.stop()
        executor.shutdown(timeout_sec=2.0)
        node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
