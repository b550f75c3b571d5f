"""``hjrno``: the package's command line (no ROS needed).

    hjrno solve --scenario disk|room|air3d [--grid 40,40,12,20] [--out DIR]
    hjrno bench solver [--out benchmarks/results]
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

from . import __version__


def _shape(text: str) -> tuple[int, ...]:
    try:
        shape = tuple(int(v) for v in text.replace("x", ",").split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"grid must look like 40,40,12,20, got {text!r}") from None
    if any(n < 3 for n in shape):
        raise argparse.ArgumentTypeError(f"every grid axis needs at least 3 nodes, got {text!r}")
    return shape


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def cmd_solve(args: argparse.Namespace) -> int:
    """Solve one reference problem to V∞; write HDF5 (+ PNG) and print the convergence report."""
    from tqdm import tqdm

    from . import plotting, problems, versions
    from .h5store import write_solution
    from .solver import solve

    problem = problems.make_problem(args.scenario, args.grid)
    options = dict(problem.solve_options)
    options.update({k: v for k, v in (("max_horizon", args.max_horizon), ("tolerance", args.tolerance)) if v})
    options["accuracy"] = args.accuracy
    total = options.get("max_horizon", 40.0)
    with tqdm(total=total, unit="sim s", desc=f"solve {problem.name}", disable=args.quiet or args.json,
              bar_format="{l_bar}{bar}| {n:.1f}/{total:.0f} sim s [{elapsed}<{remaining}{postfix}]") as bar:

        def progress(t: float, delta: float, delta_band: float) -> None:
            bar.update(t - bar.n)
            bar.set_postfix_str(f"max|dV|/s {delta:.1e}, band {delta_band:.1e}")

        value, report = solve(problem.dynamics, problem.grid, problem.target, progress=progress, **options)
    meta = {
        "problem": problem.name,
        "description": problem.description,
        "dynamics": type(problem.dynamics).__name__,
        "params": problem.dynamics.params.as_dict(),
        "shapes": [s.as_dict() for s in problem.shapes],
        "report": report.as_dict(),
        "versions": versions.versions(),
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    out = Path(args.out)
    h5 = write_solution(out / f"{problem.name}.h5", problem.grid, problem.target, value, meta)
    png = None
    if not args.no_plot:
        png = plotting.brt_slices(out / f"{problem.name}.png", problem.grid, problem.target, value,
                                  title=f"{problem.name} {'x'.join(map(str, problem.grid.shape))}")
    result = {"problem": problem.name, "report": report.as_dict(), "peak_rss_mb": peak_rss_mb(),
              "brt_fraction": float((value <= 0).mean()), "h5": str(h5), "png": str(png) if png else None}
    if args.json:
        result["report"].pop("history")
        print(json.dumps(result))
    else:
        print(report.summary())
        print(f"BRT volume fraction {result['brt_fraction']:.4f}, peak RSS {result['peak_rss_mb']:.0f} MB")
        print(f"wrote {h5}" + (f" and {png}" if png else ""))
    return 0 if report.converged else 3


def cmd_bench(args: argparse.Namespace) -> int:
    from . import benchmarks

    return benchmarks.run(args.what, Path(args.out), quick=args.quick)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hjrno", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"hjrno_ros {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("solve", help="solve a reference problem to the converged V∞")
    p.add_argument("--scenario", default="disk", help="disk | room | air3d (default: disk)")
    p.add_argument("--grid", type=_shape, default=None, help="grid shape, e.g. 40,40,12,20 (car) or 51,40,50 (Air3D)")
    p.add_argument("--accuracy", default="high", choices=["low", "medium", "high", "very_high"])
    p.add_argument("--tolerance", type=float, default=None, help="max |dV| per simulated second to call it converged")
    p.add_argument("--max-horizon", type=float, default=None, help="backward-time budget, s")
    p.add_argument("--out", default="out", help="output folder (default: out)")
    p.add_argument("--no-plot", action="store_true", help="skip the PNG")
    p.add_argument("--json", action="store_true", help="print one JSON line instead of text")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_solve)

    p = sub.add_parser("bench", help="run a benchmark and write its results table")
    p.add_argument("what", choices=["solver"])
    p.add_argument("--out", default="benchmarks/results", help="results folder")
    p.add_argument("--quick", action="store_true", help="smallest case only (smoke run)")
    p.set_defaults(func=cmd_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, FloatingPointError) as err:
        print(f"hjrno {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
