"""``hjrno bench signals [--episodes N]``: SIGINT and SIGTERM at every start-up phase and in every lifecycle
state, under traffic.

Each trial starts brt_node (its own process, the bundled default, a private ROS domain) beside the harness's base
(:func:`~hjrno_ros.ros.harness.bench_driver.bench_base`: odometry at 50 Hz, TwistStamped commands at 20 Hz, LaserScans
at 10 Hz, a map every 2 s) and sends one signal at one moment:

- ``import``: 0–0.3 s after numpy's extension is mapped (the node's modules load);
- ``model_load``: 0–0.5 s after rclpy's extension is mapped (rclpy starts, the model loads);
- ``first_map``: at the node's first status (its first map and odometry just in);
- ``active``: 0.5–2 s into filtering under the traffic;
- ``unconfigured``: started with ``autostart`` false, spinning 1 s, nothing configured;
- ``inactive``: configured through ``~/change_state``, not activated;
- ``deactivated``: active, then deactivated;
- ``cleaned_up``: active, then deactivated and cleaned up (unconfigured again).

A trial passes when its moment was reached with the node alive, and the node then exited with code 0 within 15 s,
with no traceback and at most one line besides its own log lines.
"""

from __future__ import annotations

import json
import random
import signal
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from hjrno_ros.core.atomic import atomic_write
from hjrno_ros.core.tables import records_table

MOMENTS = ("import", "model_load", "first_map", "active", "unconfigured", "inactive", "deactivated", "cleaned_up")
MANAGED = ("unconfigured", "inactive")  # started with autostart false
SIGNALS = (signal.SIGINT, signal.SIGTERM)
MAP_PERIOD = 2.0  # s


def mapped(pid: int, library: str) -> bool:
    try:
        return library in Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return False


def wait(predicate, timeout: float, step: float = 0.01) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(step)
    return False


def publish_maps(base: Any, done: threading.Event) -> None:
    """A 20 m walled map every MAP_PERIOD s until ``done`` (a new stamp each time: the node recomputes)."""
    occupancy = np.zeros((200, 200), np.int8)
    occupancy[:3], occupancy[-3:], occupancy[:, :3], occupancy[:, -3:] = 100, 100, 100, 100
    k = 0
    while not done.is_set():
        k += 1
        base.publish_map(occupancy, 0.1, (-10.0, -10.0), sec=k)
        done.wait(MAP_PERIOD)


def trial(base: Any, lifecycle: Any, domain: int, moment: str, sig: int, rng: random.Random, model: str) -> dict:
    """One node process, one signal at ``moment``; what it did."""
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState

    from hjrno_ros.tools.node_process import brt_node_process

    answers: list[str] = []  # each request's answer: "none" (no answer within 10 s), "true" or "false"

    def change(transition_id: int) -> bool:  # a request that reached the last trial's node, still in the graph, is
        for _ in range(3):                     # lost: ask again
            answer = base.call(lifecycle, ChangeState.Request(transition=Transition(id=transition_id)), 10.0)
            answers.append("none" if answer is None else str(bool(answer.success)).lower())
            if answer is not None:
                return bool(answer.success)
        return False

    base.log.status, base.log.first_status_at = {}, None
    params = {"autostart": moment not in MANAGED, "observation_sources": "[scan]"}
    with brt_node_process(domain, params, model) as (proc, tail):
        reached = True
        if moment == "import":
            reached = wait(lambda: mapped(proc.pid, "_multiarray_umath"), 30.0)
            time.sleep(rng.uniform(0.0, 0.3))
        elif moment == "model_load":
            reached = wait(lambda: mapped(proc.pid, "_rclpy_pybind11"), 30.0)
            time.sleep(rng.uniform(0.0, 0.5))
        elif moment == "first_map":
            reached = wait(lambda: base.log.first_status_at is not None, 60.0)
        elif moment == "unconfigured":
            reached = wait(lambda: mapped(proc.pid, "_rclpy_pybind11"), 30.0)
            time.sleep(2.0)  # past the imports: spinning, unconfigured
        elif moment == "inactive":
            reached = wait(lambda: mapped(proc.pid, "_rclpy_pybind11"), 30.0)
            reached = reached and change(Transition.TRANSITION_CONFIGURE)
            time.sleep(0.5)
        else:
            reached = wait(lambda: base.log.status.get("state") not in (None, "fail_closed"), 60.0)  # filtering
            if moment == "active":
                time.sleep(rng.uniform(0.5, 2.0))
            else:
                reached = reached and change(Transition.TRANSITION_DEACTIVATE)
                if moment == "cleaned_up":
                    reached = reached and change(Transition.TRANSITION_CLEANUP)
                time.sleep(0.3)
        alive = proc.poll() is None
        sent = time.monotonic()
        proc.send_signal(sig)
        try:
            code = proc.wait(timeout=15.0)
        except Exception:  # subprocess.TimeoutExpired: still running
            code = None
        exit_s = time.monotonic() - sent
        log = tail(400)
    lines = [ln for ln in log.split(" | ") if ln.strip() and "[INFO]" not in ln and "[WARN]" not in ln]
    return {"moment": moment, "signal": signal.Signals(sig).name, "reached": reached and alive, "exit": code,
            "exit_s": round(exit_s, 2), "traceback": "Traceback" in log, "extra_lines": len(lines),
            "ok": reached and alive and code == 0 and "Traceback" not in log and len(lines) <= 1,
            "transitions": answers, "log": log if code != 0 or not (reached and alive) else ""}


def run(out: Path, signals: int = 32, model: str | None = None, seed: int = 0, progress=print) -> int:
    """``signals`` trials, round-robin over MOMENTS × SIGNALS; writes signals.{md,json}; 1 if any trial failed."""
    from lifecycle_msgs.srv import ChangeState

    from hjrno_ros.ros.brt_node.value_sources import resolve_model
    from hjrno_ros.ros.harness.bench_driver import bench_base
    from hjrno_ros.ros.harness.spin import spin_in_background
    from hjrno_ros.tools.benchmarks import machine
    from hjrno_ros.tools.node_process import free_domain

    stem = str(resolve_model(model or ""))
    rng, domain = random.Random(seed), free_domain()
    cases = [(m, s) for _ in range(signals) for m in MOMENTS for s in SIGNALS][:signals]
    base, stop = spin_in_background(domain, lambda c: bench_base(c, (-4.0, -4.0, 0.0), 0.3, scan_rate=10.0))
    lifecycle = base.create_client(ChangeState, "/brt_node/change_state")
    done = threading.Event()
    maps = threading.Thread(target=publish_maps, args=(base, done), daemon=True)
    rows, started = [], time.monotonic()
    try:
        base.running = True  # commands at 20 Hz throughout
        maps.start()
        for moment, sig in cases:
            row = trial(base, lifecycle, domain, moment, sig, rng, stem)
            rows.append(row)
            progress(f"{moment:<12} {row['signal']:<7} exit {row['exit']} in {row['exit_s']} s"
                     f"{'' if row['ok'] else '  FAILED'}")
    finally:
        done.set()
        maps.join(timeout=5.0)
        stop()
    summary = []
    for m in MOMENTS:
        for name in (sig.name for sig in SIGNALS):
            mine = [r for r in rows if (r["moment"], r["signal"]) == (m, name)]
            if mine:
                summary.append({"moment": m, "signal": name, "runs": len(mine),
                                "moment_reached": sum(r["reached"] for r in mine),
                                "exit_0": sum(r["exit"] == 0 for r in mine),
                                "tracebacks": sum(r["traceback"] for r in mine),
                                "max_exit_s": max(r["exit_s"] for r in mine)})
    failed = [r for r in rows if not r["ok"]]
    note = (f"`hjrno bench signals --signals {signals}` on {machine()}, {time.strftime('%Y-%m-%d')}: {len(rows)} "
            f"trials of brt_node ({Path(stem).name}) under traffic, {len(failed)} failed, "
            f"{time.monotonic() - started:.0f} s. Pass: the moment reached with the node alive, then exit 0 within "
            "15 s, no traceback, at most one line besides the node's log lines.")
    out.mkdir(parents=True, exist_ok=True)
    text = "\n".join(["# Signals", "", note, "", *records_table(summary)]) + "\n"
    atomic_write(out / "signals.md", lambda tmp: Path(tmp).write_text(text))
    atomic_write(out / "signals.json", lambda tmp: Path(tmp).write_text(json.dumps({"note": note, "trials": rows},
                                                                                    indent=1)))
    progress(text)
    return int(bool(failed))
