"""The ``brt_node`` executable: imports the node only after SIGINT/SIGTERM handling is in place, so an
interrupt at any moment of start-up (rclpy, torch and the model load take seconds) ends in one line."""

from __future__ import annotations

import os
import signal
import sys

_interrupted = False


def _interrupt(signum: int, frame: object) -> None:
    global _interrupted
    _interrupted = True
    raise KeyboardInterrupt


def interrupted() -> bool:
    """Whether SIGINT/SIGTERM arrived (a failure after it is the interrupt's, not a start-up error)."""
    return _interrupted


def main(argv: list[str] | None = None) -> int:
    signal.signal(signal.SIGINT, _interrupt)
    signal.signal(signal.SIGTERM, _interrupt)
    try:
        from hjrno_ros.ros.node import main as run_node
    except BaseException:
        if not _interrupted:
            raise
        # an extension module interrupted while loading may turn the interrupt into an ImportError (numpy does)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        print("[brt_node]: interrupted during start-up", file=sys.stderr, flush=True)
        os._exit(0)  # half-imported extensions may not finalise cleanly; nothing has started yet
    return run_node(argv)


if __name__ == "__main__":
    sys.exit(main())
