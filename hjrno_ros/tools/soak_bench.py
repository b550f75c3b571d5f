"""``hjrno bench soak [--seconds 1800]``: brt_node through a shift, not in CI.

The node (its own process, the bundled default, a LaserScan observation source) runs beside the harness's base
(:func:`~hjrno_ros.ros.harness.bench_driver.bench_base`): odometry and TwistStamped commands at 20 Hz, LaserScans at
10 Hz (walls and a person who walks from side to side), a map every 2 s (the node bench's maps in turn, one box
moving).  Reported: the node's RSS every 10 s and its least-squares slope after the first minute (target ≤ 0.5
MB/min); every filtered command checked finite and within the model's limits (|linear| ≤ max(|v_min|, v_max),
|angular| ≤ ω_max; target 0 otherwise); command latency p50 / p95 / p99 / max over the whole run; every
fail-closed stop with the node's reason, counted.
"""

from __future__ import annotations

import collections
import json
import math
import time
from pathlib import Path

import numpy as np

from hjrno_ros.core.atomic import atomic_write
from hjrno_ros.core.tables import records_table

SAMPLE_S = 10.0  # s between RSS samples
WARMUP_S = 60.0  # s left out of the RSS slope
MAP_PERIOD = 2.0  # s
RSS_SLOPE_TARGET = 0.5  # MB/min


def rss_slope(samples: list[tuple[float, float]]) -> float | None:
    """Least-squares slope of (s, MB) samples after WARMUP_S, MB/min; None with fewer than 3."""
    kept = [(t, m) for t, m in samples if t >= WARMUP_S]
    if len(kept) < 3:
        return None
    t, m = np.array(kept).T
    return float(np.polyfit(t / 60.0, m, 1)[0])


def run(out: Path, seconds: float = 1800.0, model: str | None = None, progress=print) -> int:
    """The soak; writes soak.{md,json}; 1 when a target is missed."""
    from geometry_msgs.msg import TwistStamped

    from hjrno_ros.core.model_card import ModelCard
    from hjrno_ros.ros.brt_node.value_sources import resolve_model
    from hjrno_ros.ros.harness.bench_driver import bench_base
    from hjrno_ros.ros.harness.sim_base import Rates
    from hjrno_ros.ros.harness.spin import spin_in_background
    from hjrno_ros.tools.benchmarks import machine
    from hjrno_ros.tools.node_bench import ORIGIN, POSE, RESOLUTION, SPEED, _rss_mb, bench_maps
    from hjrno_ros.tools.node_process import brt_node_process, free_domain

    stem = resolve_model(model or "")
    limits = ModelCard.load(stem).dynamics
    turn_limit = getattr(limits, "omega_max", None) or limits.kappa_max * max(abs(limits.v_min), limits.v_max)
    outputs = collections.Counter()
    domain = free_domain()

    def make(context):
        base = bench_base(context, POSE, SPEED, scan_rate=10.0, rates=Rates(0.05, 0.05))
        base.create_subscription(TwistStamped, "cmd_vel", check, 50)  # beside the base's own
        return base

    def check(msg) -> None:
        linear, angular = msg.twist.linear.x, msg.twist.angular.z
        outputs["total"] += 1
        if not (math.isfinite(linear) and math.isfinite(angular)):
            outputs["non_finite"] += 1
        elif abs(linear) > max(abs(limits.v_min), limits.v_max) + 1e-9 or abs(angular) > turn_limit + 1e-9:
            outputs["beyond_limits"] += 1

    params = {"enable_stamped_cmd_vel": True, "observation_sources": "[scan]"}
    maps, rss, stops = bench_maps(), [], collections.Counter()
    with brt_node_process(domain, params, stem) as (proc, tail):
        base, stop = spin_in_background(domain, make)
        try:
            base.publish_map(maps[0], RESOLUTION, ORIGIN, sec=1)
            end = time.monotonic() + 120.0
            while base.log.status.get("state") not in ("ok", "intervening", "clipped"):
                if time.monotonic() > end or proc.poll() is not None:
                    raise RuntimeError(f"brt_node did not start filtering: {tail()}")
                time.sleep(0.05)
            base.running, start, k, last_state = True, time.monotonic(), 1, ""
            next_map, next_sample = start + MAP_PERIOD, start
            while (now := time.monotonic()) - start < seconds and proc.poll() is None:
                if now >= next_map:
                    k += 1
                    base.publish_map(maps[(k - 1) % len(maps)], RESOLUTION, ORIGIN, sec=k)
                    next_map += MAP_PERIOD
                if now >= next_sample:
                    rss.append((round(now - start, 1), round(_rss_mb(proc.pid, "VmRSS"), 1)))
                    next_sample += SAMPLE_S
                    if len(rss) % 18 == 0:
                        progress(f"{now - start:6.0f} s: RSS {rss[-1][1]} MB, {outputs['total']} outputs")
                state = base.log.status.get("state", "")
                if state == "fail_closed" and last_state != "fail_closed":
                    stops[base.log.status.get("reason", "?").split(":")[0][:80]] += 1
                last_state = state
                time.sleep(0.05)
            base.running = False
            time.sleep(0.5)
            status, alive = dict(base.log.status), proc.poll() is None
            latency = np.asarray(base.log.latency_s) * 1e3
            sent = len(latency) + base.commands.unanswered
        finally:
            stop()
    slope = rss_slope(rss)
    row = {"seconds": round(seconds), "alive": alive, "commands": sent, "answered": int(latency.size),
           "cmd_p50_ms": round(float(np.percentile(latency, 50)), 2), "cmd_p95_ms": round(float(np.percentile(
               latency, 95)), 2), "cmd_p99_ms": round(float(np.percentile(latency, 99)), 2),
           "cmd_max_ms": round(float(latency.max()), 1), "outputs": outputs["total"],
           "non_finite": outputs["non_finite"], "beyond_limits": outputs["beyond_limits"],
           "rss_first_MB": rss[0][1], "rss_last_MB": rss[-1][1],
           "rss_slope_MB_per_min": None if slope is None else round(slope, 3),
           "fail_closed_stops": sum(stops.values()), "node_stop_count": (status.get("counts") or {}).get("stops")}
    met = (alive and row["non_finite"] == 0 and row["beyond_limits"] == 0 and slope is not None
           and slope <= RSS_SLOPE_TARGET)
    note = (f"`hjrno bench soak --seconds {seconds:g}` on {machine()}, {time.strftime('%Y-%m-%d')}: brt_node "
            f"({Path(stem).name}) in its own process with a scan source; odometry and TwistStamped commands 20 Hz, "
            f"scans 10 Hz, a 400x400 map every {MAP_PERIOD:g} s. RSS sampled every {SAMPLE_S:g} s, slope after "
            f"{WARMUP_S:g} s (target <= {RSS_SLOPE_TARGET} MB/min); outputs checked finite and within the card's "
            "limits (target 0 otherwise); fail-closed stops counted by reason as the status showed them (10 Hz).")
    reasons = [{"reason": r, "count": n} for r, n in stops.most_common()] or [{"reason": "(none)", "count": 0}]
    text = "\n".join(["# Soak", "", note, "", *records_table([row]), "", "Fail-closed stops by reason:", "",
                      *records_table(reasons)]) + "\n"
    out.mkdir(parents=True, exist_ok=True)
    atomic_write(out / "soak.md", lambda t: Path(t).write_text(text))
    atomic_write(out / "soak.json", lambda t: Path(t).write_text(json.dumps(
        {"note": note, "row": row, "stops": dict(stops), "rss": rss, "final_status": status}, indent=1)))
    progress(text)
    return 0 if met else 1
