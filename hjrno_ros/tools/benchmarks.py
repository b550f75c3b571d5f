"""Benchmarks that print a table and write results files (Markdown + JSON).

``solver``: converged solve time and peak memory per grid size, the product robot model beside the
paper's (disk, room, an indoor scene at three grids, with the time ratio), plus Air3D.  Each case runs
in its own process (``hjrno solve --json``) so peak RSS and JIT compilation are that case's alone.
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

import numpy as np

from hjrno_ros.core.tables import records_table

SOLVER_GRIDS = ("32,32,9,16", "40,40,12,20", "50,50,15,24")
SOLVER_CASES = [(name, grid) for name in ("disk", "room", "indoor") for grid in SOLVER_GRIDS]
ROBOTS = ("paper", "product")
AIR3D_CASE = ("air3d", "51,40,50")


def machine() -> str:
    return f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"


def _solve_case(out: Path, name: str, grid: str, robot: str | None) -> dict:
    """One ``hjrno solve --json`` process: its report, peak RSS and the table's safety statistics."""
    from hjrno_ros.datasets.h5store import read_solution

    cmd = [sys.executable, "-m", "hjrno_ros.cli", "solve", "--scenario", name, "--grid", grid, "--json",
           "--no-plot", "--quiet", "--warmup", "--out", str(out / "tmp")] + (["--robot", robot] if robot else [])
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    total = time.perf_counter() - start
    if proc.returncode not in (0, 3):
        raise RuntimeError(f"bench case {name} {grid} {robot or ''} failed: {proc.stderr.strip().splitlines()[-1:]}")
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    result["process_wall_s"] = total
    if robot:
        from hjrno_ros.truth.solver import rise_with_speed

        spec, target, value, _ = read_solution(result["h5"])
        rest = int(np.argmin(np.abs(spec.axis(2))))
        result["unsafe_at_rest"] = float((value[:, :, rest] <= 0).mean())
        result["obstacle_at_rest"] = float((target[:, :, rest] <= 0).mean())
        rise = rise_with_speed(spec, value)
        result["max_rise_with_speed"] = float(rise.max())
        result["rising_share"] = float((rise > 1e-6).mean())
    return result


def _row(name: str, grid: str, results: dict[str, dict]) -> dict:
    shape = [int(v) for v in grid.split(",")]
    row = {"problem": name, "grid": "x".join(map(str, shape)), "points_M": round(math.prod(shape) / 1e6, 3)}
    for robot, r in results.items():
        rep = r["report"]
        row[f"{robot}_converged"] = rep["converged"]
        row[f"{robot}_horizon_s"] = rep["horizon"]
        row[f"{robot}_solve_s"] = round(rep["wall_time"], 1)
        row[f"{robot}_unsafe_at_rest"] = round(r["unsafe_at_rest"], 3)
        row[f"{robot}_max_rise_m"] = float(f"{r['max_rise_with_speed']:.2g}")
    paper, product = results["paper"], results["product"]
    ratio = paper["report"]["wall_time"] / product["report"]["wall_time"]
    cold = [r["report"]["wall_time"] + r["warmup_s"] for r in (paper, product)]
    # the paper model stopped by its horizon budget: its time is a lower bound, so is the ratio
    capped = "" if paper["report"]["converged"] else " (paper capped: >=)"
    row["speedup"] = f"{ratio:.1f}{capped}"
    row["speedup_first_call"] = f"{cold[0] / cold[1]:.1f}{capped}"
    row["compile_s"] = round(product["warmup_s"], 1)
    row["obstacle_at_rest"] = round(product["obstacle_at_rest"], 3)
    row["peak_rss_MB"] = f"{round(paper['peak_rss_mb'])}/{round(product['peak_rss_mb'])}"
    return row


def bench_solver(out: Path, quick: bool = False, only: tuple[str, ...] = ()) -> list[dict]:
    """Product vs paper per (problem, grid), one process each; the quick run does the 32x32x9x16 disk;
    ``only``: these problems (the table keeps the other problems' rows of an earlier run)."""
    known = {name for name, _ in SOLVER_CASES} | {AIR3D_CASE[0]}
    if set(only) - known:
        raise ValueError(f"unknown solver bench problems {sorted(set(only) - known)}; choose from {sorted(known)}")
    rows = []
    cases = SOLVER_CASES[:1] if quick else [c for c in SOLVER_CASES if not only or c[0] in only]
    for name, grid in cases:
        results = {robot: _solve_case(out, name, grid, robot) for robot in ROBOTS}
        rows.append(_row(name, grid, results))
        print(" | ".join(f"{k}={v}" for k, v in rows[-1].items()), flush=True)
    if not quick and (not only or AIR3D_CASE[0] in only):
        r = _solve_case(out, *AIR3D_CASE, None)
        rep = r["report"]
        rows.append({"problem": "air3d", "grid": AIR3D_CASE[1].replace(",", "x"),
                     "points_M": round(math.prod(int(v) for v in AIR3D_CASE[1].split(",")) / 1e6, 3),
                     "paper_converged": rep["converged"], "paper_horizon_s": rep["horizon"],
                     "paper_solve_s": round(rep["wall_time"], 1), "compile_s": round(r["warmup_s"], 1),
                     "peak_rss_MB": round(r["peak_rss_mb"])})
        print(" | ".join(f"{k}={v}" for k, v in rows[-1].items()), flush=True)
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
    lines = [f"# {title}", "", note, "", *records_table(rows, keys)]
    return "\n".join(lines) + "\n"


def run(what: str, out: Path, quick: bool = False, only: tuple[str, ...] = (), model: str | None = None,
        scan_rate: float = 0.0, obstacle_speed: float = 0.0) -> int:
    out.mkdir(parents=True, exist_ok=True)
    if what == "node":
        from hjrno_ros.tools import node_bench

        return node_bench.run(out, seconds=10.0 if quick else 30.0, model=Path(model) if model else None,
                              scan_rate=scan_rate, obstacle_speed_max=obstacle_speed)
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
    rows = bench_solver(out, quick, only)
    note = (f"`hjrno bench solver` on {machine()}, {time.strftime('%Y-%m-%d')}, one run. JAX CPU, float32, accuracy "
            "high (WENO3 + RK3), converged when max |dV| per simulated second < 1e-3 (disk: over the interior; room, "
            "indoor (scene 3 of the indoor family) and Air3D: over the band near V = 0; horizon budget 40 s disk, "
            "60 s room and indoor, 10 s Air3D). paper: the HJRNO paper's car (||d|| <= 0.1 m/s); product: the product "
            "robot (||d|| <= 0.1 |v|); both a = kappa = v_max = 1, v in [0, 1] (docs/design.md, 'Robot models'). "
            "Each case runs in its own process, which first compiles the solver step with a one-chunk solve "
            "(compile_s: that warm-up, the same for both models since their parameters are traced values); "
            "*_solve_s: the converged solve after it; speedup = paper_solve_s / product_solve_s, speedup_first_call "
            "the same with each warm-up added (a fresh process's first solve). A paper solve that ran out of its "
            "horizon budget is marked: its time is to the cap, the ratio a lower bound. "
            "*_unsafe_at_rest: share of the v = 0 slice with V <= 0 "
            "(obstacle_at_rest: with l <= 0). *_max_rise_m: the largest rise of V towards higher |v| between "
            "neighbouring speed nodes, interior. peak_rss_MB: paper/product.")
    return write_table(out, "solver_quick" if quick else "solver", "Solver benchmark", rows, note)


def write_table(out: Path, stem: str, title: str, rows: list[dict], note: str) -> int:
    """Write the table; rows of an earlier run for other cases (first column) are kept."""
    old = out / f"{stem}.json"
    if old.exists():  # fresh rows take the place of the old rows of their case, in the old order
        key = next(iter(rows[0]))
        fresh: dict = {}
        for r in rows:
            fresh.setdefault(r[key], []).append(r)
        merged = []
        for r in json.loads(old.read_text())["rows"]:
            if r.get(key) not in fresh:
                merged.append(r)
            elif fresh[r[key]]:
                merged += fresh[r[key]]
                fresh[r[key]] = []
        rows = merged + [r for group in fresh.values() for r in group]
    (out / f"{stem}.md").write_text(_markdown(title, rows, note))
    (out / f"{stem}.json").write_text(json.dumps({"machine": machine(), "note": note, "rows": rows}, indent=1))
    print(f"wrote {out / (stem + '.md')}")
    return 0


def add_arguments(p) -> None:
    """``hjrno bench``'s arguments (an argparse parser)."""
    p.add_argument("what", choices=["solver", "dataset", "node", "fuzz", "depot", "nav", "people", "tracker",
                                       "signals", "soak"])
    p.add_argument("--out", default="out/bench", help="results folder (default: out/bench)")
    p.add_argument("--quick", action="store_true", help="smallest case only (smoke run)")
    p.add_argument("--only", default=None, help="dataset bench: families; solver bench: problems (comma-separated)")
    p.add_argument("--model", default=None, help="node, depot and nav benches: model stem (default: models/default)")
    p.add_argument("--seconds", type=float, default=None, help="fuzz: seconds (180); soak: (1800); depot, nav, people: "
                   "per episode")
    p.add_argument("--episodes", type=int, default=None, help="depot: episodes (200); nav: per case (3); people: (2); "
                   "tracker: (4); signals: trials (32)")
    p.add_argument("--scan-rate", type=float, default=0.0, help="node bench: also LaserScans at this rate, Hz")
    p.add_argument("--obstacle-speed", type=float, default=None,
                   help="people bench: obstacle_speed_max (1.0 m/s); node bench with --scan-rate: (0)")
    p.add_argument("--scan-timeout", type=float, default=None, help="people bench: the scan source's timeout (0.5 s)")
    p.add_argument("--agent-table", default=None, help="people bench: the tracked agents' tables (models/agents_ROBOT)")
    p.add_argument("--after-rest-contact", choices=("continue", "end"), default="continue",
                   help="people bench: a person who walked into the robot at rest walks on and the episode goes on "
                   "(continue, the default), or the episode ends (end)")
    for name in ("robots", "maps", "drivers", "filters"):  # nav_bench.ROBOTS, MAPS, DRIVERS, FILTERS
        p.add_argument(f"--{name}", default=None, help=f"nav bench: comma-separated {name} (default: all); people "
                       "bench: its filters and drivers, one robot and one map; tracker bench: its maps")


def dispatch_args(args) -> int:
    """Run the bench that :func:`add_arguments`' parsed ``args`` name."""
    return dispatch(args.what, Path(args.out), quick=args.quick, only=args.only, model=args.model,
                    episodes=args.episodes, seconds=args.seconds, scan_rate=args.scan_rate,
                    obstacle_speed=args.obstacle_speed, agent_table=args.agent_table, scan_timeout=args.scan_timeout,
                    after_rest_contact=args.after_rest_contact,
                    select={k: getattr(args, k) for k in ("robots", "maps", "drivers", "filters")})


def dispatch(what: str, out: Path, quick: bool = False, only: str | None = None, model: str | None = None,
             episodes: int | None = None, seconds: float | None = None, select: dict | None = None,
             scan_rate: float = 0.0, obstacle_speed: float | None = None, agent_table: str | None = None,
             scan_timeout: float | None = None, after_rest_contact: str = "continue") -> int:
    """``hjrno bench WHAT``: the depot check, the navigation benchmark and the fuzz soak (each its own module), or
    :func:`run`'s benches.  ``select``: the navigation benchmark's robots, maps, drivers and filters."""
    if what == "nav":
        from hjrno_ros.tools import nav_bench

        return nav_bench.run(out, episodes=episodes or 3, model=model, seconds=seconds,
                             **{k: tuple(v.split(",")) for k, v in (select or {}).items() if v})
    if what == "people":
        from hjrno_ros.tools import people_bench

        chosen, drivers = (select or {}).get("filters"), (select or {}).get("drivers")
        return people_bench.run(out, episodes=episodes or 2, seconds=seconds, model=model,
                                drivers=tuple(drivers.split(",")) if drivers else people_bench.BLIND,
                                obstacle_speed_max=1.0 if obstacle_speed is None else obstacle_speed,
                                robot_name=((select or {}).get("robots") or "jackal").split(",")[0],
                                map_name=((select or {}).get("maps") or people_bench.DEFAULT_MAP).split(",")[0],
                                filters=tuple(chosen.split(",")) if chosen else people_bench.FILTERS,
                                agent_table=agent_table, scan_timeout=scan_timeout or people_bench.SCAN_TIMEOUT,
                                after_rest_contact=after_rest_contact)
    if what == "tracker":
        from hjrno_ros.tools import tracker_bench

        maps = (select or {}).get("maps")
        return tracker_bench.run(out, episodes=episodes or 4, **({"maps": tuple(maps.split(","))} if maps else {}))
    if what == "soak":
        from hjrno_ros.tools import soak_bench

        return soak_bench.run(out, seconds=seconds or 1800.0, model=model)
    if what == "signals":
        from hjrno_ros.tools import signal_bench

        return signal_bench.run(out, signals=episodes or 32, model=model)
    episodes = 200 if episodes is None else episodes
    if what == "depot":
        from hjrno_ros.tools import depot_check

        return depot_check.run(out, episodes=episodes, seconds=12.0 if seconds is None else seconds, model=model)
    if what == "fuzz":
        from hjrno_ros.tools import fuzz_bench

        return fuzz_bench.run(out, seconds=fuzz_bench.SOAK_S if seconds is None else seconds,
                              model=Path(model) if model else None)
    if scan_rate and what != "node":
        raise ValueError("--scan-rate is for the node benchmark only")
    return run(what, out, quick=quick, only=tuple(only.split(",")) if only else (), model=model, scan_rate=scan_rate,
               obstacle_speed=obstacle_speed or 0.0)
