"""``hjrno bench node``: brt_node under a realistic load over real DDS, against the design targets.

The node runs in its own process (``python -m hjrno_ros.ros.brt_node.main``, TwistStamped commands, the
bundled model unless one is given) so its CPU time and peak RSS are its own.  A driver in this
process (:class:`hjrno_ros.ros.harness.bench_driver.BenchDriver`) publishes a
20 m × 20 m map at 0.05 m (400 × 400 cells, transient local) with walls and boxes, odometry of a
robot in free space at 50 Hz and nominal commands at 20 Hz, and republishes a changed map every
second.  Measured:

* command → filtered command latency (matched by the stamp the node copies through), p50/p95/p99;
* map → value grid latency (matched by ``info.map_load_time`` = the map's stamp): DDS transfer of
  the map, validation, signed distance, V0 sampling, inference (a table model: the whole (v, θ) table of the
  window; a slice model: its (v, θ) stencil), publishing;
* start-up: spawn → first status (model loaded, interfaces up) and spawn → filtering (status ok: map,
  odometry and the first value table), and the node's RSS once it filters, before the load (idle RSS);
* the node's CPU share (CPU seconds / wall seconds over the measured window; 1.0 = one core) and
  peak RSS (VmHWM, start-up included);
* a baseline: the same node bypassed (``~/enable`` false) for up to 10 s more, so the command
  latency of rclpy + DDS alone on this machine is next to the filter's.

Targets: command latency p95 ≤ 5 ms, map → value grid p95 ≤ 150 ms.  Driver and node share the
machine's cores, so the numbers include that contention.
"""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from hjrno_ros.core.tables import records_table
from hjrno_ros.tools.node_process import brt_node_process, free_domain

RESOLUTION = 0.05  # m
SIZE = 400  # cells per side: 20 m
ORIGIN = (-10.0, -10.0)  # m
POSE = (0.0, 0.0, 0.3)  # x, y, yaw of the robot: free space, > 2 m from everything
SPEED = 0.5  # m/s
CMD_TARGET_MS = 5.0
MAP_TARGET_MS = 150.0
SCAN_TARGET_MS = 60.0


def bench_maps(count: int = 3) -> list[np.ndarray]:
    """Occupancy rasters ``[ix, iy]``: border walls, a few boxes, one box that moves between maps."""
    maps = []
    for k in range(count):
        occ = np.zeros((SIZE, SIZE), np.int8)
        occ[:8], occ[-8:], occ[:, :8], occ[:, -8:] = 100, 100, 100, 100
        occ[60:100, 240:260] = 100  # box near (-6, 2.5)
        occ[260:300, 60:90] = 100  # box near (4, -6)
        occ[300:310, 150:330] = 100  # wall segment at x = 5
        occ[240:260, 100:116] = -1  # an unknown patch
        shift = 20 * k  # moving box near (-5, -5 + k)
        occ[90:110, 90 + shift:110 + shift] = 100
        maps.append(occ)
    return maps


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime + stime


def _rss_mb(pid: int, field: str = "VmHWM") -> float:
    """Peak (VmHWM) or current (VmRSS) resident memory of a process, MB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def _percentile_ms(values: list[float], q: float) -> float | None:
    return round(float(np.percentile(np.asarray(values) * 1e3, q)), 2) if values else None


def run(out: Path, seconds: float = 30.0, model: Path | None = None, scan_rate: float = 0.0,
        obstacle_speed_max: float = 0.0) -> int:
    """Benchmark a brt_node process for ``seconds`` of driving; print a table, write node.md/node.json
    (``scan_rate`` > 0: with a LaserScan source at that rate, Hz, written to node_scan.md/json; with
    ``obstacle_speed_max`` > 0 its returns off the map may approach at that speed, m/s, and the certificate varies
    in time: node_scan_moving.md/json)."""
    from hjrno_ros.ros.harness.bench_driver import bench_drive  # rclpy only when the benchmark runs

    if not seconds > 0:
        raise ValueError(f"seconds must be > 0, got {seconds}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    domain = free_domain()
    spawned = time.monotonic()
    params = {"enable_stamped_cmd_vel": True}
    if scan_rate > 0:
        params.update({"observation_sources": "[scan]", "obstacle_speed_max": obstacle_speed_max})
    with brt_node_process(domain, params, model) as (proc, log_tail):
        marks: dict[str, float] = {}

        def on_ready() -> None:
            marks["idle_rss"] = _rss_mb(proc.pid, "VmRSS")
            marks["cpu0"], marks["wall0"] = _cpu_seconds(proc.pid), time.monotonic()

        def on_done() -> None:
            marks["cpu1"], marks["wall1"] = _cpu_seconds(proc.pid), time.monotonic()

        try:
            raw = bench_drive(domain, bench_maps(), RESOLUTION, ORIGIN, POSE, SPEED, seconds,
                              bypass_seconds=min(10.0, seconds / 3), on_ready=on_ready, on_done=on_done,
                              alive=lambda: proc.poll() is None, scan_rate=scan_rate)
            cpu_share = (marks["cpu1"] - marks["cpu0"]) / (marks["wall1"] - marks["wall0"])
            peak = _rss_mb(proc.pid)
        except RuntimeError as err:
            raise RuntimeError(f"node benchmark failed: {err} (node log: {log_tail()})") from None
    cmd_lat, map_lat, status = raw["cmd_latency_s"], raw["map_latency_s"], raw["status"]
    bypass = raw["bypass_latency_s"]
    row = {
        "cmd_p50_ms": _percentile_ms(cmd_lat, 50),
        "cmd_p95_ms": _percentile_ms(cmd_lat, 95),
        "cmd_p99_ms": _percentile_ms(cmd_lat, 99),
        "cmd_matched": f"{len(cmd_lat)}/{raw['cmd_sent']}",
        "bypass_p50_ms": _percentile_ms(bypass, 50),
        "bypass_p95_ms": _percentile_ms(bypass, 95),
        "map_p50_ms": _percentile_ms(map_lat, 50),
        "map_p95_ms": _percentile_ms(map_lat, 95),
        "maps_matched": f"{len(map_lat)}/{raw['maps_sent']}",
        "node_map_p50_ms": (status.get("map_to_table_ms") or {}).get("p50"),
        "node_map_p95_ms": (status.get("map_to_table_ms") or {}).get("p95"),
        "signed_distance_ms_last": status.get("signed_distance_ms"),
        "inference_ms_last": status.get("inference_latency_ms"),
        "callback_p95_ms": (status.get("filter_ms") or {}).get("p95"),
        "first_status_s": round(raw["first_status_at"] - spawned, 2) if raw["first_status_at"] else None,
        "filtering_s": round(raw["ready_at"] - spawned, 2),
        "node_cpu_share": round(cpu_share, 3),
        "node_idle_rss_MB": round(marks["idle_rss"]),
        "node_peak_rss_MB": round(peak),
        **({"scan_rate_hz": scan_rate,
            "scan_to_table_p50_ms": (status.get("observation_to_table_ms") or {}).get("p50"),
            "scan_to_table_p95_ms": (status.get("observation_to_table_ms") or {}).get("p95")} if scan_rate > 0 else {}),
        "load_avg_1m": round(os.getloadavg()[0], 2),  # other work on the machine inflates the tails
        "cmd_target_met": bool(cmd_lat) and _percentile_ms(cmd_lat, 95) <= CMD_TARGET_MS,
        "map_target_met": bool(map_lat) and _percentile_ms(map_lat, 95) <= MAP_TARGET_MS,
    }
    machine = f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
    model_shown = status.get("model", "bundled model")
    if os.path.isabs(model_shown) and Path(model_shown).is_relative_to(Path.cwd()):
        model_shown = os.path.relpath(model_shown)  # results files name no machine's paths
    note = (f"`hjrno bench node` on {machine}, {time.strftime('%Y-%m-%d')}: {seconds:g} s of driving over Fast DDS, "
            f"node in its own process ({model_shown}), map {SIZE}x{SIZE} cells at "
            f"{RESOLUTION} m republished every 1 s, odometry 50 Hz, TwistStamped commands 20 Hz. Targets: command "
            f"latency p95 <= {CMD_TARGET_MS:g} ms, map -> value grid p95 <= {MAP_TARGET_MS:g} ms. node_cpu_share is "
            "CPU seconds / wall seconds (1.0 = one core); first_status_s / filtering_s: spawn -> first status / -> "
            "status ok (map, odometry, first value table); idle RSS: when it first filters, before the load; "
            "peak RSS includes start-up; node_map_* is the node's own time from a map's receipt to the first value "
            "table made with it (the rest of map_* is DDS and the driver's side); callback_p95_ms is the time "
            "inside the node's command callback (last 200 commands); bypass_* is the same node with the filter "
            f"bypassed via ~/enable ({min(10.0, seconds / 3):g} s after the main run): the rclpy + DDS baseline. "
            "The driver shares the cores."
            + (f" With a LaserScan observation source at {scan_rate:g} Hz (720 beams, walls and a person who moves): "
               "scan_to_table_* is the node's own time from a scan's receipt to the value table made with it, over "
               f"the last 200 scans (target p95 <= {SCAN_TARGET_MS:g} ms)." if scan_rate > 0 else "")
            + (f" obstacle_speed_max {obstacle_speed_max:g} m/s: returns off the map may approach, and the "
               "certificate varies in time (one batched lookup at three times a command)."
               if scan_rate > 0 and obstacle_speed_max > 0 else ""))
    keys = list(row)
    lines = ["# Node benchmark", "", note, "", *records_table([row], keys)]
    name = ("node_scan" + ("_moving" if obstacle_speed_max > 0 else "")) if scan_rate > 0 else "node"
    (out / f"{name}.md").write_text("\n".join(lines) + "\n")
    (out / f"{name}.json").write_text(json.dumps({"machine": machine, "note": note, "rows": [row],
                                               "final_status": status}, indent=1))
    width = max(map(len, keys))
    print("\n".join(f"{k:<{width}}  {row[k]}" for k in keys))
    print(f"wrote {out / (name + '.md')}")
    return 0
