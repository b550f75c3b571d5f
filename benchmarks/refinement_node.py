"""brt_node with the background refinement on a static map: when its stages reach the filter, and what
the nice-19 solver process costs the command path.

Runs of ``hjrno bench node``'s load (the node in its own process, the bench's 20 m × 20 m map at
0.05 m, odometry 50 Hz, TwistStamped commands 20 Hz) with the map published once: refine_horizon = 0
(the operator's windows only), then refine_horizon = ``--horizon`` with stages of ``--stage`` simulated s,
once per ``--refine-cpus`` value (the node's ``refine_cpus``: 0 = all cores but one for the solver).
Per run: command latency p50/p95/p99 over the whole run, the node's CPU share (the solver's child
process not included), and for the refined runs each stage's simulated s and the child's wall time (from
the node's log).

    .venv/bin/python benchmarks/refinement_node.py --seconds 150 --horizon 32 --stage 4 \\
        --refine-cpus 0,2 --out benchmarks/results/refinement
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import time
from pathlib import Path

from hjrno_ros.brt_node import bench_drive, resolve_model
from hjrno_ros.grids import GridSpec
from hjrno_ros.node_process import brt_node_process, free_domain

from hjrno_ros import checkpoint, map_refinement, node_bench

STAGE_LINE = re.compile(r"refined value for map \d+: ([\d.]+) simulated s \((\w+ ?\w*)\), ([\d.]+) s wall")


def one_run(seconds: float, horizon: float, stage: float, cpus: int = 0) -> dict:
    domain = free_domain()
    params = {"enable_stamped_cmd_vel": True, "refine_horizon": horizon, "refine_stage": stage, "refine_cpus": cpus}
    with brt_node_process(domain, params) as (proc, log_tail):
        marks: dict[str, float] = {}
        raw = bench_drive(domain, node_bench.bench_maps(1), node_bench.RESOLUTION, node_bench.ORIGIN,
                          node_bench.POSE, node_bench.SPEED, seconds, map_period=seconds + 1.0,
                          on_ready=lambda: marks.update(cpu0=node_bench._cpu_seconds(proc.pid), t0=time.monotonic()),
                          on_done=lambda: marks.update(cpu1=node_bench._cpu_seconds(proc.pid), t1=time.monotonic()),
                          alive=lambda: proc.poll() is None)
        log = log_tail(400)
    lat = raw["cmd_latency_s"]
    stages = [{"simulated_s": float(a), "state": b, "child_wall_s": float(c)} for a, b, c in STAGE_LINE.findall(log)]
    refinement = raw["status"].get("refinement") or {}
    return {"refine_horizon": horizon, "refine_stage": stage if horizon else None,
            "refine_cpus": cpus if horizon else None, "solver_cores": refinement.get("cpus"),
            "cmd_p50_ms": node_bench._percentile_ms(lat, 50), "cmd_p95_ms": node_bench._percentile_ms(lat, 95),
            "cmd_p99_ms": node_bench._percentile_ms(lat, 99), "cmd_matched": f"{len(lat)}/{raw['cmd_sent']}",
            "node_cpu_share": round((marks["cpu1"] - marks["cpu0"]) / (marks["t1"] - marks["t0"]), 3),
            "value_source_at_end": raw["status"].get("value_source"),
            "refinement_at_end": refinement or None, "stages": stages}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=150.0)
    ap.add_argument("--horizon", type=float, default=32.0)
    ap.add_argument("--stage", type=float, default=4.0)
    ap.add_argument("--refine-cpus", default="0", help="comma-separated refine_cpus values, one refined run each")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/refinement"))
    args = ap.parse_args()
    rows = [one_run(args.seconds, 0.0, args.stage)]
    rows += [one_run(args.seconds, args.horizon, args.stage, int(c)) for c in args.refine_cpus.split(",")]
    far = tuple(o + node_bench.SIZE * node_bench.RESOLUTION for o in node_bench.ORIGIN)
    model_grid = GridSpec.from_dict(checkpoint.load_card(resolve_model(""))["grid"])
    shape = " x ".join(map(str, map_refinement.map_grid(model_grid, node_bench.ORIGIN, far).shape))
    machine = f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
    note = (f"benchmarks/refinement_node.py on {machine}, {time.strftime('%Y-%m-%d')}: {args.seconds:g} s of the node "
            f"benchmark's load per run, its {far[0] - node_bench.ORIGIN[0]:g} m square map ({node_bench.SIZE} x "
            f"{node_bench.SIZE} cells) published once; refined run: "
            f"refine_horizon {args.horizon:g} s, refine_stage {args.stage:g} s (solver grid {shape}). "
            "node_cpu_share excludes the solver's child process; child_wall_s counts from the child's model load "
            "(the warm start's inference is in it).")
    keys = ["refine_horizon", "refine_cpus", "solver_cores", "cmd_p50_ms", "cmd_p95_ms", "cmd_p99_ms", "cmd_matched",
            "node_cpu_share", "value_source_at_end"]
    lines = ["# brt_node with background refinement", "", note, "", "| " + " | ".join(keys) + " |",
             "|" + " --- |" * len(keys)]
    lines += ["| " + " | ".join(str(r[k]) for k in keys) + " |" for r in rows]
    lines += ["", "Stages of the refined runs (from the node's log):", "",
              "| refine_cpus | simulated s | state | child wall s |", "| --- | --- | --- | --- |"]
    lines += [f"| {r['refine_cpus']} | {s['simulated_s']:g} | {s['state']} | {s['child_wall_s']:g} |"
              for r in rows[1:] for s in r["stages"]]
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "refinement_node.md").write_text("\n".join(lines) + "\n")
    (args.out / "refinement_node.json").write_text(json.dumps({"note": note, "rows": rows}, indent=1))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
