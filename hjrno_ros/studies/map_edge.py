"""The map's edge: what the operator makes of V0 beyond a map's edge, a −resolution plateau or the
signed distance of a wall at the edge (``geometry.sample_walled``, what brt_node feeds it now).

Windows of Nav2's depot map as the node makes them (the model's window centred on the robot, V0 = the map's
signed distance − the node's default inflation), centred on free positions near the map's edge.  For each, the
default model's table from either V0, and two ground truths solved with hj_reachability on the model's grid with
the training data's solver settings: the walled world's (V0 with the wall: what lies beyond the edge is a wall)
and the plateau world's (the operator's own input, the error measured before).  Pooled over the windows: rel. L2
over all nodes, over the map's nodes and over the nodes beyond the edge, the RMS error on either part, the share of
the squared error beyond the edge, and the false-safe share (V > 0 predicted where the truth is ≤ 0, among the
truth's unsafe nodes; how many above the card's ε, and the largest V among them).

``python -m hjrno_ros.studies.map_edge [--map ../shared/maps/depot.yaml] [--model models/default] [--windows 16]
[--out benchmarks/results]`` prints the tables and writes ``map_edge.md``; a few minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import time
from pathlib import Path

import numpy as np

from hjrno_ros.core import geometry
from hjrno_ros.core.atomic import atomic_write
from hjrno_ros.core.map_file import load_map
from hjrno_ros.core.tables import markdown_table

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_MAP = ROOT.parent / "shared" / "maps" / "depot.yaml"
SOLVER = {"accuracy": "high", "tolerance": 5e-3, "max_horizon": 12.0, "criterion": "band"}  # diff_plans' settings
CLEARANCE = 0.5  # m: robot positions at least this far from obstacles
EDGE_BAND = (0.5, 3.0)  # m: and this far from the map's edge, so 20-70 % of a window lies beyond it
CASES = (("plateau", "plateau"), ("plateau", "wall"), ("wall", "wall"))  # (V0 the model reads, world of the truth)


def node_inflation(grid, resolution: float) -> float:
    """The node's default inflation (``footprint_radius`` 0, ``inflation_radius`` −1: ValueWorker.inflation)."""
    return max(grid.half_cell_diagonal, resolution / math.sqrt(2))


def edge_positions(sd: np.ndarray, origin, resolution: float, n: int, seed: int = 0) -> np.ndarray:
    """``n`` robot positions (n, 2), spread out (farthest-point order from a seeded draw), at cell centres at least
    CLEARANCE from obstacles and within EDGE_BAND of the map's edge."""
    ix, iy = np.nonzero(sd >= CLEARANCE)
    xy = np.asarray(origin) + (np.column_stack([ix, iy]) + 0.5) * resolution
    size = np.asarray(sd.shape) * resolution
    edge = np.minimum(xy - origin, np.asarray(origin) + size - xy).min(1)
    candidates = xy[(edge >= EDGE_BAND[0]) & (edge <= EDGE_BAND[1])]
    rng = np.random.default_rng(seed)
    chosen = [candidates[rng.integers(len(candidates))]]
    nearest = np.linalg.norm(candidates - chosen[0], axis=1)
    while len(chosen) < n:
        chosen.append(candidates[int(np.argmax(nearest))])
        nearest = np.minimum(nearest, np.linalg.norm(candidates - chosen[-1], axis=1))
    return np.array(chosen)


def window_v0(sd: np.ndarray, origin, resolution: float, points: np.ndarray, r: float, beyond: str) -> np.ndarray:
    """V0 at the window's x-y nodes as brt_node makes it, with ``beyond`` the edge "plateau" (as before) or
    "wall" (now)."""
    if beyond == "plateau":
        sd_at = geometry.sample_raster(sd, origin, resolution, points, outside=-resolution)
    else:
        sd_at = geometry.sample_walled(sd, origin, resolution, points)
    return (sd_at - r).astype(np.float32)


def _sums(pred: np.ndarray, truth: np.ndarray, beyond: np.ndarray, epsilon: float) -> dict:
    """Sums for pooled metrics over a table (x, y first); ``beyond``: the x-y nodes beyond the map's edge."""
    err, ref = np.square(pred - truth, dtype=np.float64), np.square(truth, dtype=np.float64)
    out = np.broadcast_to(beyond[:, :, None, None], truth.shape)
    unsafe = truth <= 0
    return {"err": err.sum(), "ref": ref.sum(), "err_out": err[out].sum(), "ref_out": ref[out].sum(),
            "err_in": err[~out].sum(), "ref_in": ref[~out].sum(), "unsafe": int(unsafe.sum()),
            "n_in": int((~out).sum()), "n_out": int(out.sum()), "false_safe": int((unsafe & (pred > 0)).sum()),
            "past_epsilon": int((unsafe & (pred > epsilon)).sum()),
            "worst": float(pred[unsafe].max(initial=-np.inf))}


def run(map_path: str | Path = DEFAULT_MAP, model: str | Path = ROOT / "models" / "default", windows: int = 16,
        seed: int = 0, threads: int = 2) -> dict:
    """The study: per-window rows and the pooled metrics of each of CASES."""
    from hjrno_ros.learning.value_function import LearnedValueFunction
    from hjrno_ros.truth.solver import solve
    from hjrno_ros.truth.systems import robot_system

    start = time.perf_counter()
    mf = load_map(map_path)
    res, origin = mf.resolution, mf.origin
    sd = geometry.occupancy_signed_distance(mf.occupancy, res)  # unknown_is_obstacle, the node's default
    vf = LearnedValueFunction(model, device="cpu", threads=threads)
    r = node_inflation(vf.grid, res)
    dynamics = robot_system(vf.params)
    lo, hi = np.asarray(origin), np.asarray(origin) + np.asarray(mf.size)
    totals = {case: {} for case in CASES}
    rows, unconverged = [], 0
    for centre in edge_positions(sd, origin, res, windows, seed):
        points = vf.window_points(tuple(centre))
        beyond = np.any((points < lo) | (points > hi), -1)
        v0 = {b: window_v0(sd, origin, res, points, r, b) for b in ("plateau", "wall")}
        pred = {b: vf.table(v0[b]) for b in v0}
        truth = {}
        for world in ("plateau", "wall"):
            target = np.ascontiguousarray(np.broadcast_to(v0[world][:, :, None, None], vf.grid.shape))
            truth[world], solved = solve(dynamics, vf.grid, target, **SOLVER)
            unconverged += not solved.converged
        row = {"centre": f"({centre[0]:.2f}, {centre[1]:.2f})", "beyond": float(beyond.mean())}
        for case in CASES:
            sums = _sums(pred[case[0]], truth[case[1]], beyond, vf.card.margin())
            for k, v in sums.items():
                totals[case][k] = max(totals[case].get(k, -np.inf), v) if k == "worst" else totals[case].get(k, 0) + v
            row[case] = math.sqrt(sums["err"] / sums["ref"])
        rows.append(row)
    return {"rows": rows, "totals": totals, "inflation": r, "unconverged": unconverged, "map": _shown(map_path),
            "model": _shown(model), "shape": mf.occupancy.shape, "resolution": res, "card": vf.card,
            "wall_s": time.perf_counter() - start}


def _shown(path: str | Path) -> str:
    """``path`` relative to the checkout (``../shared/...``, ``models/...``) for the results file."""
    return os.path.relpath(Path(path).resolve(), ROOT)


def _ratio(a: float, b: float) -> float:
    return math.sqrt(a / b) if b > 0 else float("nan")


def report(result: dict, command: str) -> str:
    """The Markdown of ``map_edge.md``: the setup, the pooled table, the per-window table."""
    card = result["card"]
    n = len(result["rows"])
    beyond = np.mean([row["beyond"] for row in result["rows"]])
    lines = [
        "# The map's edge: the V0 beyond it",
        "",
        f"`{command}` on {platform.machine()}, Python {platform.python_version()}, {time.strftime('%Y-%m-%d')}, "
        f"{result['wall_s'] / 60:.1f} min: map `{result['map']}` ({result['shape'][0]} x {result['shape'][1]} cells "
        f"at {result['resolution']:g} m), model `{result['model']}` ({card.dynamics.model}, its own robot), "
        f"{n} windows ({card.window[0]:g} m x {card.window[1]:g} m, {card.grid.shape[0]} x {card.grid.shape[1]} "
        f"nodes, every (v, θ) node of the table) centred on free positions {CLEARANCE:g} m or more from obstacles "
        f"and {EDGE_BAND[0]:g}-{EDGE_BAND[1]:g} m from the map's edge ({100 * beyond:.0f} % of the nodes beyond "
        f"it); V0 = signed distance − {result['inflation']:.3f} m (the node's default inflation). Truths: "
        f"hj_reachability on the model's grid ({SOLVER['accuracy']}, band tolerance {SOLVER['tolerance']:g}, ≤ "
        f"{SOLVER['max_horizon']:g} s; {result['unconverged']} of {2 * n} solves not converged). V0 beyond the edge: "
        "*plateau* −resolution − r (before), *wall* −(distance to the map) − r (`geometry.sample_walled`, now); "
        "world: the V0 the truth was solved for. Pooled over the windows; false safe: V > 0 predicted where the "
        f"truth is ≤ 0, among the truth's unsafe nodes; V > ε: of those, predicted above the card's ε "
        f"{card.margin():.3f} m.",
        "",
    ]
    table = []
    for case in CASES:
        t = result["totals"][case]
        table.append([case[0], case[1], f"{_ratio(t['err'], t['ref']):.4f}", f"{_ratio(t['err_in'], t['ref_in']):.4f}",
                      f"{math.sqrt(t['err_in'] / t['n_in']):.4f}", f"{_ratio(t['err_out'], t['ref_out']):.4f}",
                      f"{math.sqrt(t['err_out'] / max(t['n_out'], 1)):.4f}",
                      f"{100 * t['err_out'] / t['err']:.1f} %",
                      f"{t['false_safe'] / max(t['unsafe'], 1):.2e} ({t['false_safe']})", f"{t['worst']:.3f}",
                      t["past_epsilon"]])
    lines += markdown_table(["V0 read", "world", "rel. L2 all", "rel. L2 on the map", "RMS on the map (m)",
                             "rel. L2 beyond", "RMS beyond (m)", "sq. error beyond", "false safe (nodes)",
                             "its largest V (m)", "V > ε (nodes)"], table)
    lines += ["", "Per window, rel. L2 over all its nodes:", ""]
    lines += markdown_table(["centre (m)", "beyond the edge", *(f"{a} V0, {b} world" for a, b in CASES)],
                            [[row["centre"], f"{100 * row['beyond']:.0f} %", *(f"{row[c]:.4f}" for c in CASES)]
                             for row in result["rows"]])
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hjrno_ros.studies.map_edge", description=__doc__.split("\n")[0])
    parser.add_argument("--map", default=str(DEFAULT_MAP), help="map_server YAML (default: ../shared/maps/depot.yaml)")
    parser.add_argument("--model", default=str(ROOT / "models" / "default"), help="model stem")
    parser.add_argument("--windows", type=int, default=16, help="windows near the edge (default 16)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"), help="folder of map_edge.md")
    args = parser.parse_args(argv)
    result = run(args.map, args.model, args.windows, args.seed)
    command = "python -m hjrno_ros.studies.map_edge" + (f" --windows {args.windows}" if args.windows != 16 else "")
    text = report(result, command)
    print(text)
    atomic_write(Path(args.out) / "map_edge.md", lambda tmp: Path(tmp).write_text(text))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
