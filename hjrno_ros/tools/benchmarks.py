"""Benchmarks that print a table and write results files (Markdown + JSON).

``solver``: converged solve time and peak memory per grid size.  Each case runs in its own
process (``hjrno solve --json``) so peak RSS is that case's alone.
``dataset``: the paper's "Dataset Time" and "Data Size" columns per scenario family.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

SOLVER_CASES = [
    ("disk", "32,32,9,16"),
    ("disk", "40,40,12,20"),
    ("disk", "50,50,15,24"),
    ("room", "40,40,12,20"),
    ("air3d", "51,40,50"),
]


def machine() -> str:
    return f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"


def bench_solver(out: Path, quick: bool = False) -> list[dict]:
    rows = []
    for name, grid in SOLVER_CASES[:1] if quick else SOLVER_CASES:
        cmd = [sys.executable, "-m", "hjrno_ros.cli", "solve", "--scenario", name, "--grid", grid, "--json",
               "--no-plot", "--out", str(out / "tmp")]
        start = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True)
        total = time.perf_counter() - start
        if proc.returncode not in (0, 3):
            raise RuntimeError(f"bench case {name} {grid} failed: {proc.stderr.strip().splitlines()[-1:]}")
        result = json.loads(proc.stdout.strip().splitlines()[-1])
        report = result["report"]
        shape = [int(v) for v in grid.split(",")]
        row = {
            "problem": name,
            "grid": "x".join(map(str, shape)),
            "points_M": round(math.prod(shape) / 1e6, 3),
            "converged": report["converged"],
            "horizon_s": report["horizon"],
            "solve_wall_s": round(report["wall_time"], 1),
            "process_wall_s": round(total, 1),
            "peak_rss_MB": round(result["peak_rss_mb"]),
            "brt_fraction": round(result["brt_fraction"], 4),
        }
        rows.append(row)
        print(" | ".join(f"{k}={v}" for k, v in row.items()), flush=True)
    shutil.rmtree(out / "tmp", ignore_errors=True)
    return rows


DATASET_FAMILIES = ("single", "two", "indoor", "velocity", "parametric", "air3d")


def bench_dataset(out: Path, samples: int, families: tuple[str, ...]) -> list[dict]:
    """Per-sample solve cost and stored bytes per family at its default config, times the paper's counts."""
    from hjrno_ros.datasets import dataset

    rows = []
    for family in families:
        config = dataset.load_config(family)
        probe = dataclasses.replace(config, name=f"bench-{family}", n_train=samples, n_test=0)
        root = out / "tmp" / family
        shutil.rmtree(root, ignore_errors=True)
        summary = dataset.generate(probe, root, progress=False)
        per_sample = summary["wall_s"] / samples
        bytes_per_sample = summary["bytes"] / samples
        count = config.n_train + config.n_test
        row = {
            "experiment": family,
            "grid": "x".join(map(str, config.grid)),
            "train/test": f"{config.n_train}/{config.n_test}",
            "measured_samples": samples,
            "converged": f"{samples - summary['not_converged']}/{samples}",
            "s_per_sample": round(per_sample, 1),
            "dataset_time_h": round(per_sample * count / 3600, 2),
            "MB_per_sample": round(bytes_per_sample / 1e6, 2),
            "data_size_MB": round(bytes_per_sample * count / 1e6),
        }
        rows.append(row)
        print(" | ".join(f"{k}={v}" for k, v in row.items()), flush=True)
    shutil.rmtree(out / "tmp", ignore_errors=True)
    return rows


def _markdown(title: str, rows: list[dict], note: str) -> str:
    keys = list(rows[0])
    lines = [f"# {title}", "", note, "", "| " + " | ".join(keys) + " |", "|" + " --- |" * len(keys)]
    lines += ["| " + " | ".join(str(r[k]) for k in keys) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def run(what: str, out: Path, quick: bool = False, only: tuple[str, ...] = (), model: str | None = None) -> int:
    out.mkdir(parents=True, exist_ok=True)
    if what == "node":
        from hjrno_ros.tools import node_bench

        return node_bench.run(out, seconds=10.0 if quick else 30.0, model=Path(model) if model else None)
    if model:
        raise ValueError("--model is for the node benchmark only")
    if what == "dataset":
        samples = 1 if quick else 3
        families = only or (DATASET_FAMILIES[:1] if quick else DATASET_FAMILIES)
        unknown = set(families) - set(DATASET_FAMILIES)
        if unknown:
            raise ValueError(f"unknown families {sorted(unknown)}; choose from {', '.join(DATASET_FAMILIES)}")
        rows = bench_dataset(out, samples, families)
        note = (f"`hjrno bench dataset` on {machine()}, {time.strftime('%Y-%m-%d')}, one solver process. "
                f"Measured: {samples} training sample(s) per family at its default config "
                "(config/experiments/*.yaml), solved and stored; dataset_time_h and data_size_MB are that "
                "per-sample cost times the paper's sample count (train + test), not a full run.")
        return write_table(out, "dataset_quick" if quick else "dataset", "Dataset benchmark", rows, note)
    if what != "solver":
        raise ValueError(f"unknown benchmark {what!r}")
    rows = bench_solver(out, quick)
    note = (f"`hjrno bench solver` on {machine()}, {time.strftime('%Y-%m-%d')}. JAX CPU, float32, accuracy high "
            "(WENO3 + RK3), converged when max |dV| per simulated second < 1e-3 (disk: over the interior; room "
            "and Air3D: over the band near V = 0). solve_wall_s includes JIT compilation; process_wall_s adds "
            "imports and start-up.")
    return write_table(out, "solver_quick" if quick else "solver", "Solver benchmark", rows, note)


def write_table(out: Path, stem: str, title: str, rows: list[dict], note: str) -> int:
    """Write the table; rows of an earlier run for other cases (first column) are kept."""
    old = out / f"{stem}.json"
    if old.exists():
        key = next(iter(rows[0]))
        fresh = {r[key] for r in rows}
        kept = [r for r in json.loads(old.read_text())["rows"] if r.get(key) not in fresh]
        rows = kept + rows
    (out / f"{stem}.md").write_text(_markdown(title, rows, note))
    (out / f"{stem}.json").write_text(json.dumps({"machine": machine(), "note": note, "rows": rows}, indent=1))
    print(f"wrote {out / (stem + '.md')}")
    return 0
