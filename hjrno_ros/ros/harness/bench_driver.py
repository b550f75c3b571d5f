"""The load generator of ``hjrno bench node``: a :class:`~hjrno_ros.ros.harness.sim_base.SimBase` holding a static
robot (odometry at 50 Hz), sending TwistStamped commands at 20 Hz while running (latency matched by stamp), maps
(latency to their value grid, matched by ``info.map_load_time`` = the map's stamp) and optionally LaserScans."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import LaserScan
from std_srvs.srv import SetBool

from hjrno_ros.ros.harness.plants import HeldPlant
from hjrno_ros.ros.harness.sim_base import Rates, SimBase
from hjrno_ros.ros.harness.spin import spin_in_background


def bench_base(context: Any, pose: tuple[float, float, float], speed: float, scan_rate: float = 0.0,
               rates: Rates | None = None) -> SimBase:
    """A robot held at ``pose`` reporting ``speed``, commanding (speed, 0.1) while running (odometry at 50 Hz and
    commands at 20 Hz unless ``rates`` say otherwise); ``scan_rate`` > 0: :func:`walking_person_scan` at that rate."""
    base = SimBase(context, HeldPlant(*pose, speed), lambda state, t: np.array([speed, 0.1]),
                   name="brt_bench_driver", rates=rates, keep_grids=False)
    if scan_rate > 0:
        publisher = base.create_publisher(LaserScan, "scan", qos_profile_sensor_data)
        count = iter(range(1 << 62))
        base.create_timer(1.0 / scan_rate, lambda: publisher.publish(
            walking_person_scan(next(count), base.get_clock().now().to_msg())))
    return base


def walking_person_scan(k: int, stamp: Any) -> LaserScan:
    """The ``k``-th of a 720-beam scan sequence at 10 Hz: a ring of walls 4 m away and a person 2.5 m ahead who walks
    from side to side."""
    msg = LaserScan()
    msg.header.frame_id, msg.header.stamp = "laser", stamp
    msg.angle_min, msg.angle_increment, msg.range_min, msg.range_max = -math.pi, math.pi / 360, 0.05, 12.0
    msg.angle_max = msg.angle_min + 719 * msg.angle_increment
    angles = msg.angle_min + msg.angle_increment * np.arange(720)
    ranges = np.full(720, 4.0)
    person = 0.6 * math.sin(0.8 * k / 10.0)  # lateral offset, m
    bearing = math.atan2(person, 2.5)
    ranges[np.abs(angles - bearing) < 0.12] = math.hypot(2.5, person)
    msg.ranges = ranges.tolist()
    return msg


def bench_drive(domain_id: int, maps: list[np.ndarray], resolution: float, origin: tuple[float, float],
                pose: tuple[float, float, float], speed: float, seconds: float, bypass_seconds: float = 0.0,
                map_period: float = 1.0, ready_timeout: float = 120.0, on_ready: Callable[[], None] | None = None,
                on_done: Callable[[], None] | None = None, alive: Callable[[], bool] = lambda: True,
                scan_rate: float = 0.0) -> dict:
    """Run the bench base against a brt_node on ``domain_id``.

    Waits until the node filters (status ok), calls ``on_ready``, sends commands for ``seconds`` while
    publishing the next of ``maps`` every ``map_period``, calls ``on_done``; then, if ``bypass_seconds``
    > 0, bypasses the filter (``~/enable`` false) and sends commands for that long again: the same
    process and DDS path without the filter, a baseline for the command latency.  Returns raw
    latencies (s), counts and the node's last status.
    """
    driver, stop = spin_in_background(domain_id, lambda c: bench_base(c, pose, speed, scan_rate))
    log = driver.log
    try:
        driver.publish_map(maps[0], resolution, origin, sec=1)
        end = time.monotonic() + ready_timeout
        while log.status.get("state") != "ok":
            if time.monotonic() > end or not alive():
                raise RuntimeError(f"brt_node did not become ready: {log.status.get('reason', 'no status')}")
            time.sleep(0.05)
        log.map_latency_s.clear()  # the first map also waited for odometry and start-up
        ready_at = time.monotonic()
        if on_ready is not None:
            on_ready()
        driver.running = True
        start = time.monotonic()
        k = 1
        while time.monotonic() - start + map_period <= seconds and alive():
            time.sleep(map_period)
            k += 1
            driver.publish_map(maps[(k - 1) % len(maps)], resolution, origin, sec=k)
        time.sleep(max(0.0, seconds - (time.monotonic() - start)))
        driver.running = False
        if on_done is not None:
            on_done()
        time.sleep(0.5)  # let the last outputs arrive
        sent = len(log.latency_s) + driver.commands.unanswered
        result = {"cmd_latency_s": list(log.latency_s), "cmd_sent": sent,
                  "map_latency_s": list(log.map_latency_s), "maps_sent": k - 1, "status": dict(log.status),
                  "bypass_latency_s": [], "bypass_sent": 0, "first_status_at": log.first_status_at,
                  "ready_at": ready_at}
        if bypass_seconds > 0 and alive():
            if driver.call("enable", SetBool.Request(data=False)) is None:
                raise RuntimeError("brt_node's ~/enable service did not answer")
            log.latency_s.clear()
            driver.commands.forget()
            driver.running = True
            time.sleep(bypass_seconds)
            driver.running = False
            time.sleep(0.5)
            result["bypass_latency_s"] = list(log.latency_s)
            result["bypass_sent"] = len(log.latency_s) + driver.commands.unanswered
        return result
    finally:
        stop()
