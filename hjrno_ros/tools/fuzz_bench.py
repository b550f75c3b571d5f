"""``hjrno bench fuzz``: brt_node under a long DDS fuzz, and what map size costs.

The node runs in its own process (``python -m hjrno_ros.ros.brt_node.main``, the bundled model unless one is given,
``pose_topic:=amcl_pose``) on a private ROS domain; :func:`hjrno_ros.ros.harness.fuzz_driver.fuzz_drive` (the driver of
test/tools/test_fuzz.py) sends it a random mix of valid and hostile maps, odometry, poses, commands and parameter sets
for ``seconds`` (default 180) and checks every command it publishes.  Reported: messages by class; crashes (the
process died, exited non-zero on SIGINT, or printed a traceback); hangs (status gaps over 1 s); non-finite
outputs and outputs beyond the limits; error lines in the node's log; the node's VmRSS every 5 s after a 30 s
warm-up with its least-squares slope (MB/min).  Targets: 0 crashes, 0 hangs, 0 non-finite or beyond-limit
outputs, RSS growth ≤ 1 MB/min; the command exits 1 when one is missed.

Map size (before the soak, in this process): :func:`geometry.occupancy_signed_distance` on square maps of 400²,
2000² (100 m × 100 m at 0.05 m; target ≤ 2 s) and 4000² cells, and :func:`geometry.sample_raster` for one model
window (32 × 32 points) on each, which should not grow with the map.
"""

from __future__ import annotations

import json
import os
import re
import signal
import time
from pathlib import Path

import numpy as np

from hjrno_ros.core import geometry
from hjrno_ros.core.tables import markdown_table, records_table
from hjrno_ros.tools.node_bench import _rss_mb
from hjrno_ros.tools.node_process import brt_node_process

SOAK_S = 180.0  # default fuzzing time
MAP_SIZES = (400, 2000, 4000)  # cells per side
MAP_RESOLUTION = 0.05  # m
SD_TARGET_S = 2.0  # for 2000² cells
RSS_WARMUP_S = 30.0
RSS_PERIOD_S = 5.0
RSS_TARGET_MB_MIN = 1.0
HANG_S = 1.0  # a status gap longer than this counts as a hang (status is 10 Hz)


def map_costs(sizes: tuple[int, ...] = MAP_SIZES, repeats: int = 3) -> list[dict]:
    """Signed distance and one window's sampling time per map size (best of ``repeats``; 1 for the largest)."""
    rows = []
    rng = np.random.default_rng(0)
    window = np.stack(np.meshgrid(np.linspace(-5, 5, 32), np.linspace(-5, 5, 32), indexing="ij"), -1)
    for n in sizes:
        occ = np.zeros((n, n), np.int8)
        occ[:4], occ[-4:], occ[:, :4], occ[:, -4:] = 100, 100, 100, 100
        for x, y, w, h in zip(*(rng.integers(0, n - 40, n // 20) for _ in range(2)),
                              *(rng.integers(4, 40, n // 20) for _ in range(2)), strict=True):
            occ[x:x + w, y:y + h] = 100
        occ[rng.random((n, n)) < 0.01] = -1
        times = []
        for _ in range(repeats if n <= 2000 else 1):
            start = time.perf_counter()
            sd = geometry.occupancy_signed_distance(occ, MAP_RESOLUTION, 50, True)
            times.append(time.perf_counter() - start)
        centre = n * MAP_RESOLUTION / 2
        sample = []
        for _ in range(200):
            start = time.perf_counter()
            geometry.sample_raster(sd, (0.0, 0.0), MAP_RESOLUTION, window + centre, outside=-MAP_RESOLUTION)
            sample.append(time.perf_counter() - start)
        rows.append({"cells": f"{n}x{n}", "extent_m": round(n * MAP_RESOLUTION, 1),
                     "signed_distance_s": round(min(times), 3),
                     "sample_window_us": round(float(np.median(sample)) * 1e6, 1)})
        del sd, occ
    return rows


def _rss_slope(samples: list[tuple[float, float]]) -> float | None:
    """MB per minute, least squares over (s, MB) samples."""
    if len(samples) < 3:
        return None
    t, mb = np.asarray(samples).T
    return float(np.polyfit(t / 60.0, mb, 1)[0])


def run(out: Path, seconds: float = SOAK_S, model: Path | None = None, seed: int = 40, name: str = "fuzz") -> int:
    """Measure the map costs, fuzz a brt_node process for ``seconds``; print a table, write ``name``.md/json."""
    from hjrno_ros.ros.harness.fuzz_driver import fuzz_drive  # rclpy only when the benchmark runs
    from hjrno_ros.tools.benchmarks import machine

    if not seconds > 0:
        raise ValueError(f"seconds must be > 0, got {seconds}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    costs = map_costs()
    domain = 1 + (os.getpid() + 60) % 100
    rss: list[tuple[float, float]] = []
    with brt_node_process(domain, {"pose_topic": "amcl_pose"}, model) as (proc, log_tail):
        def on_tick(elapsed: float) -> None:
            if elapsed >= RSS_WARMUP_S and (not rss or elapsed - rss[-1][0] >= RSS_PERIOD_S) and proc.poll() is None:
                rss.append((elapsed, _rss_mb(proc.pid, "VmRSS")))

        result = fuzz_drive(domain, seconds, seed=seed, model=str(model) if model else None,
                            alive=lambda: proc.poll() is None, on_tick=on_tick)
        died = proc.poll() is not None
        peak = _rss_mb(proc.pid) if not died else float("nan")
        proc.send_signal(signal.SIGINT)
        try:
            code = proc.wait(timeout=20.0)
        except Exception:  # noqa: BLE001 - a hang on exit counts as a crash below
            code = None
        log = log_tail(100_000).split(" | ")
    errors: dict[str, int] = {}
    for line in log:
        if "ERROR" in line or "FATAL" in line:
            key = re.sub(r"\[\d+\.\d+\]", "", line)
            key = re.sub(r"[-+]?\d[\d.e+-]*", "#", key)[:160]  # one entry per kind of error
            errors[key] = errors.get(key, 0) + 1
    status = result.get("status", {})
    if os.path.isabs(status.get("model", "")) and Path(status["model"]).is_relative_to(Path.cwd()):
        status["model"] = os.path.relpath(status["model"])  # results files name no machine's paths
    violations = result.get("violations", [])
    nonfinite = sum("non-finite" in v["problems"] for v in violations)
    crashes = int(died) + int(code != 0) + int(any("Traceback" in line for line in log))
    slope = _rss_slope(rss)
    sent = result.get("sent", {})
    row = {
        "fuzz_s": result.get("seconds"),
        "messages": sum(sent.values()),
        "crashes": crashes,
        "hangs": result.get("status_gaps_over_1s"),
        "max_status_gap_s": result.get("max_status_gap_s"),
        "outputs": result.get("outputs"),
        "non_finite_outputs": nonfinite,
        "outputs_beyond_limits": len(violations) - nonfinite,
        "recovered": result.get("recovered"),
        "error_lines": sum(errors.values()),
        "rss_start_MB": round(rss[0][1]) if rss else None,
        "rss_end_MB": round(rss[-1][1]) if rss else None,
        "rss_slope_MB_min": round(slope, 2) if slope is not None else None,
        "peak_rss_MB": round(peak) if peak == peak else None,
    }
    row["targets_met"] = bool(result.get("ready") and crashes == 0 and not violations and row["hangs"] == 0
                              and slope is not None and slope <= RSS_TARGET_MB_MIN)
    sd_2000 = next(r["signed_distance_s"] for r in costs if r["cells"] == "2000x2000")
    note = (f"`hjrno bench fuzz` on {machine()}, {time.strftime('%Y-%m-%d')}: brt_node in its own process "
            f"({model or 'models/default'}, pose_topic amcl_pose) fuzzed over Fast DDS for {row['fuzz_s']} s "
            f"(seed {seed}) with a random mix of valid and hostile maps, odometry, poses, Twist commands and "
            "parameter sets (hjrno_ros/ros/harness/fuzz_driver.py). crashes: died, non-zero exit on SIGINT or a "
            "traceback; "
            f"hangs: status gaps over {HANG_S:g} s; beyond limits: linear outside [v_min, v_max] or |angular| > "
            "kappa_max max(|v|, |v'|) for the odometry speeds and control periods of the last 2 s; RSS: VmRSS "
            f"every {RSS_PERIOD_S:g} s after {RSS_WARMUP_S:g} s, least-squares slope. Targets: 0 crashes, hangs, "
            f"non-finite and beyond-limit outputs, RSS growth <= {RSS_TARGET_MB_MIN:g} MB/min. Map costs: "
            f"occupancy_signed_distance at {MAP_RESOLUTION} m (2000x2000 target <= {SD_TARGET_S:g} s: "
            f"{'met' if sd_2000 <= SD_TARGET_S else 'missed'}) and sample_raster of one 32x32 model window.")
    keys = list(row)
    classes = sorted(sent)
    lines = ["# Fuzz benchmark", "", note, "", *records_table([row], keys), "", "Messages by class:", "",
             *records_table([sent], classes), "", "Map size:", "",
             *markdown_table(["cells", "extent (m)", "signed distance (s)", "sample one window (µs)"],
                             ([r["cells"], r["extent_m"], r["signed_distance_s"], r["sample_window_us"]]
                              for r in costs))]
    if errors:
        lines += ["", "Error lines in the node's log (numbers as #):", ""]
        lines += [f"- {n} × `{k.strip()}`" for k, n in sorted(errors.items(), key=lambda kv: -kv[1])]
    (out / f"{name}.md").write_text("\n".join(lines) + "\n")
    (out / f"{name}.json").write_text(json.dumps({
        "machine": machine(), "note": note, "rows": [row], "sent": sent, "map_costs": costs, "rss": rss,
        "errors": errors, "violations": violations[:50],
        "fuzz": {k: v for k, v in result.items() if k not in ("violations", "sent")}}, indent=1, default=str))
    width = max(map(len, keys))
    print("\n".join(f"{k:<{width}}  {row[k]}" for k in keys))
    print("messages: " + ", ".join(f"{c} {sent[c]}" for c in classes))
    print("map size: " + "; ".join(f"{r['cells']}: signed distance {r['signed_distance_s']} s, window "
                                   f"{r['sample_window_us']} us" for r in costs))
    for k, n in sorted(errors.items(), key=lambda kv: -kv[1]):
        print(f"error x{n}: {k.strip()}")
    print(f"wrote {out / (name + '.md')}")
    return 0 if row["targets_met"] else 1
