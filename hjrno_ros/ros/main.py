"""The ``brt_node`` executable: imports the node only after SIGINT/SIGTERM handling is in place, so an
interrupt at any moment of start-up (rclpy, torch and the model load take seconds) ends in one line."""

from __future__ import annotations

import signal
import sys


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    signal.signal(signal.SIGINT, _interrupt)
    signal.signal(signal.SIGTERM, _interrupt)
    try:
        from hjrno_ros.ros.node import main as run_node
    except KeyboardInterrupt:
        print("[brt_node]: interrupted during start-up", file=sys.stderr)
        return 0
    return run_node(argv)


if __name__ == "__main__":
    sys.exit(main())
