"""brt_node as a child process on its own DDS domain (for the node benchmark and the demo)."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path


def free_domain() -> int:
    """A ROS_DOMAIN_ID for this process (Linux: ids ≤ 101 keep DDS ports out of the ephemeral range)."""
    return 1 + os.getpid() % 101


@contextlib.contextmanager
def brt_node_process(domain: int, params: dict[str, object], model: str | Path | None = None
                     ) -> Iterator[tuple[subprocess.Popen, callable]]:
    """Start ``python -m hjrno_ros.ros.brt_node.main`` with ``-p name:=value`` parameters; yields (process, log_tail)
    where ``log_tail()`` returns its last lines; SIGINT (then kill) on exit."""
    cmd = [sys.executable, "-m", "hjrno_ros.ros.brt_node.main", "--ros-args"]
    for name, value in {**params, **({"model_path": str(model)} if model else {})}.items():
        cmd += ["-p", f"{name}:={str(value).lower() if isinstance(value, bool) else value}"]
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain)}
    with tempfile.TemporaryFile("w+") as log:
        proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT, text=True)

        def tail(lines: int = 3) -> str:
            log.seek(0)
            return " | ".join(log.read().strip().splitlines()[-lines:])

        try:
            yield proc, tail
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
