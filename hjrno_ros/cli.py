"""``hjrno``: the package's command line (no ROS needed).

    hjrno solve --scenario disk|room|indoor|air3d [--robot paper|product|diff_drive] [--grid 40,40,12,20] [--out DIR]
    hjrno generate --experiment NAME [--config FILE] [--out DIR] [--shard K/N] [--workers W]
    hjrno merge | show | train | ensemble | export-onnx | evaluate | calibrate | simulate | demo   (see --help)
    hjrno bench solver|dataset|node|fuzz|depot|nav|people|tracker|signals|soak [--out DIR]
    hjrno agents --robot jackal|turtlebot3 [--out STEM]   (value tables against a moving person)

Results tables (evaluate, simulate, bench) go to ``out/bench`` unless ``--out`` says otherwise.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import resource
import shlex
import sys
import time
from pathlib import Path

from hjrno_ros import __version__
from hjrno_ros.studies.calibration import DEFAULT_MARGIN


def _shape(text: str) -> tuple[int, ...]:
    try:
        shape = tuple(int(v) for v in text.replace("x", ",").split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"grid must look like 40,40,12,20, got {text!r}") from None
    if any(n < 3 for n in shape):
        raise argparse.ArgumentTypeError(f"every grid axis needs at least 3 nodes, got {text!r}")
    return shape


def _frames(text: str) -> list[list[int]]:
    """'0,5;1,6;3,4' -> [[0, 5], [1, 6], [3, 4]]; 'none' -> [] (no member frames)."""
    if text.strip().lower() == "none":
        return []
    try:
        return [[int(k) for k in part.split(",")] for part in text.split(";")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"member frames must look like 0,5;1,6;3,4 or none, got {text!r}") from None


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def cmd_solve(args: argparse.Namespace) -> int:
    """Solve one reference problem to V∞; write HDF5 (+ PNG) and print the convergence report."""
    from tqdm import tqdm

    from hjrno_ros import versions
    from hjrno_ros.core.dynamics import car_preset
    from hjrno_ros.datasets.h5store import write_solution
    from hjrno_ros.studies import plotting
    from hjrno_ros.truth import problems
    from hjrno_ros.truth.solver import solve

    problem = problems.make_problem(args.scenario, args.grid, car_preset(args.robot) if args.robot else None)
    options = dict(problem.solve_options)
    options.update({k: v for k, v in (("max_horizon", args.max_horizon), ("tolerance", args.tolerance)) if v})
    options["accuracy"] = args.accuracy
    warmup = None
    if args.warmup:  # compile the step (and run one chunk) first, so report.wall_time is the solve alone
        warm = {**options, "max_horizon": options.get("chunk", 1.0)}
        warmup = solve(problem.dynamics, problem.grid, problem.target, **warm)[1].wall_time
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
              "brt_fraction": float((value <= 0).mean()), "h5": str(h5), "png": str(png) if png else None,
              "warmup_s": warmup}
    if args.json:
        result["report"].pop("history")
        print(json.dumps(result))
    else:
        print(report.summary())
        print(f"BRT volume fraction {result['brt_fraction']:.4f}, peak RSS {result['peak_rss_mb']:.0f} MB")
        print(f"wrote {h5}" + (f" and {png}" if png else ""))
    return 0 if report.converged else 3


def cmd_generate(args: argparse.Namespace) -> int:
    """Solve an experiment's train and test splits into HDF5 (resumable, shardable)."""
    from hjrno_ros.datasets import dataset

    config = dataset.load_config(args.experiment, args.config)
    overrides = (("grid", args.grid), ("n_train", args.n_train), ("n_test", args.n_test), ("seed", args.seed),
                 ("inflation", args.inflation))
    changes = {k: v for k, v in overrides if v is not None}
    if changes:
        config = dataclasses.replace(config, **changes)
    out = Path(args.out) if args.out else Path("data") / config.name
    if args.scheduler:
        from hjrno_ros.datasets.cluster import dask_executor

        with dask_executor(args.scheduler, args.workers) as executor:
            summary = dataset.generate(config, out, shard=args.shard, progress=not args.quiet, executor=executor)
    else:
        summary = dataset.generate(config, out, shard=args.shard, workers=args.workers, progress=not args.quiet)
    outputs = ", ".join(summary["outputs"]) or "none yet (other shards pending; then `hjrno merge`)"
    print(f"{config.name}: solved {summary['solved']} sample(s) in {summary['wall_s']:.1f} s, "
          f"{summary['not_converged']} not converged (flagged); outputs: {outputs} "
          f"({summary['bytes'] / 1e6:.1f} MB)")
    return 0


def cmd_merge(args: argparse.Namespace) -> int:
    from hjrno_ros.datasets import dataset

    outputs = dataset.merge(Path(args.out), [Path(s) for s in args.shards])
    print("wrote " + ", ".join(map(str, outputs)))
    return 0


def cmd_show(args: argparse.Namespace) -> int:
    from hjrno_ros.datasets import dataset
    from hjrno_ros.studies import plotting

    split = dataset.load_split(args.dataset)
    out = Path(args.out) if args.out else Path(args.dataset).with_suffix(".png")
    plotting.dataset_samples(out, split, args.samples)
    print(f"wrote {out}")
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    """Train an operator on an experiment's dataset; writes safetensors + model card."""
    import torch

    from hjrno_ros.learning.training import TrainConfig, train

    if args.threads:
        torch.set_num_threads(args.threads)
    data = args.data or f"data/{args.experiment}"
    out = args.out or f"out/models/{Path(data).name}_{args.model}"
    try:
        model_config = json.loads(args.model_config) if args.model_config else {}
    except json.JSONDecodeError as err:
        raise ValueError(f"--model-config is not JSON: {err}") from None
    cfg = TrainConfig(data=data, model=args.model, model_config=model_config, epochs=args.epochs,
                      slices_per_epoch=args.slices_per_epoch, batch=args.batch, lr=args.lr, seed=args.seed,
                      max_minutes=args.max_minutes, out=out, allow_unconverged=args.allow_unconverged,
                      augment=args.augment, level_set_weight=args.level_set_weight,
                      level_set_width=args.level_set_width, angle_pair_weight=args.angle_pair_weight,
                      init=args.init or "", table=args.table)
    weights = train(cfg, progress=not args.quiet)
    print(f"wrote {weights} and {Path(out).name}.json")
    return 0


def cmd_ensemble(args: argparse.Namespace) -> int:
    """Save several trained models as one whose output is their mean."""
    from hjrno_ros.learning import combine

    command = "hjrno " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    weights = combine.combine(args.model, args.out, command, pessimism=args.pessimism)
    print(f"wrote {weights} and {Path(args.out).name}.json ({len(args.model)} members); "
          f"calibrate it before use: hjrno calibrate --model {args.out}")
    return 0


def cmd_export_onnx(args: argparse.Namespace) -> int:
    """Export trained models to ONNX beside their weights (what brt_node runs without torch), recorded in the card."""
    from hjrno_ros.learning.onnx_export import export_model

    for stem in args.model:
        record = export_model(stem)
        print(f"wrote {Path(stem).with_name(record['file'])} (sha256 {record['sha256'][:12]}…) and its card entry")
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    from hjrno_ros.learning import checkpoint
    from hjrno_ros.studies import evaluation

    if args.superres:
        data = args.data or checkpoint.folders_with_test_split(checkpoint.load_card(args.model.split(",")[0]))[0]
        table = evaluation.superresolution(args.model.split(","), data, args.superres, args.samples, args.out)
        print(Path(table).read_text())
        return 0
    figures = Path(args.out) / "figures" if args.figure else None
    rows = evaluation.evaluate(args.model, args.data, train_limit=args.train_limit, figures=figures,
                               unconverged=args.allow_unconverged)
    for row in rows:
        table = evaluation.record(row, args.out)
        print(" | ".join(f"{k}={v}" for k, v in row.items()))
    print(f"updated {table}")
    if args.into_card:
        print(f"wrote metrics into {evaluation.record_in_card(args.model, rows)}")
    return 0


def _models(items: list[str] | None) -> dict[str, str]:
    """LABEL=STEM pairs (a bare STEM is labelled by its file name); default: the bundled model."""
    items = items or ["fno=models/default"]
    pairs = [i.split("=", 1) if "=" in i else [Path(i).name, i] for i in items]
    return {label: stem for label, stem in pairs}


def cmd_calibrate(args: argparse.Namespace) -> int:
    """Split-conformal ε for a model, written into its card (the node's default margin)."""
    from hjrno_ros.studies import held_out
    from hjrno_ros.studies.calibration import calibrate_model

    folders = held_out.data_folders(args.data, args.model, args.allow_unconverged)
    entry = calibrate_model(args.model, folders, args.alpha, args.beta, args.draws, args.seed, args.margin,
                            write=not args.dry_run, unconverged=args.allow_unconverged,
                            average=args.symmetry_average, frames=args.member_frames, refine=args.refine)
    what = f"refine_epsilon (tables refined {args.refine:g} simulated s)" if args.refine else "epsilon"
    before, after = entry["fresh_before"], entry["fresh_after"]
    print(f"{what} = {entry['epsilon']:.4f} m (margin {entry['margin']:g} m, alpha {args.alpha}, beta {args.beta}, "
          f"n {entry['n']}, rank {entry['rank']}, {entry['scenarios']} calibration scenarios from "
          f"{', '.join(folders)}; {'symmetry-averaged' if entry['symmetry_average'] else 'plain'} model)")
    print(f"P(V_gt<=0 | V_pred>eps) upper bound {entry['precision_bound']:.2e} (estimate "
          f"{entry['precision_estimate']:.2e})")
    for name, r in (("before (eps=0)", before), ("after", after)):
        print(f"fresh split {name}: miss rate {r['miss_rate']:.4f}, false-safe rate {r['false_safe_rate']:.2e}, "
              f"conservative rate {r['conservative_rate']:.4f}")
    written = "refine_epsilon and refine_calibration" if args.refine else "epsilon and symmetry_average"
    print("dry run: card unchanged" if args.dry_run else f"wrote {written} into {args.model}.json")
    return 0


def cmd_simulate(args: argparse.Namespace) -> int:
    """Closed-loop comparison of safety filters; writes closed_loop.{md,csv,json,png} (or, with --scenes, the
    product robot's scenes: scenes.md)."""
    if args.scenes:
        from hjrno_ros.studies import product_scenes

        return product_scenes.main(args.out)
    import torch

    from hjrno_ros.studies import filter_study, held_out, plotting
    from hjrno_ros.studies.closed_loop import EpisodeSettings

    torch.set_num_threads(args.threads)
    models = _models(args.model)
    folders = held_out.data_folders(args.data, next(iter(models.values())), args.allow_unconverged)
    study = filter_study.run_study(folders, models, args.episodes, args.seed, args.truth_epsilon, args.part,
                                   EpisodeSettings(duration=args.duration, careless=args.careless),
                                   filters=args.filters.split(",") if args.filters else None,
                                   progress=(lambda m: None) if args.quiet else print,
                                   unconverged=args.allow_unconverged, inflation_at=args.inflation_at,
                                   refine=args.refine, robot=args.robot, worlds=args.worlds,
                                   **({"decay_rate": args.decay_rate} if args.decay_rate else {}))
    out = Path(args.out)
    command = "hjrno " + " ".join(sys.argv[1:]) if sys.argv[0].endswith("hjrno") else "hjrno simulate ..."
    md, _, _ = filter_study.write_tables(study, out, command)
    plotting.closed_loop_figure(out / "closed_loop.png", study["first_world"], study["traces"], study["rows"])
    print(md.read_text())
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    """Live demo: brt_node + a path follower in IR-SIM over ROS 2; exit 1 if the robot collided."""
    from hjrno_ros.tools import demo

    return demo.run(Path(args.out), args.seconds, args.seed, args.model, use_filter=not args.no_filter,
                    gif=not args.no_gif)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hjrno", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"hjrno_ros {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("solve", help="solve a reference problem to the converged V∞")
    p.add_argument("--scenario", default="disk", help="disk | room | indoor | air3d (default: disk)")
    p.add_argument("--robot", default=None, choices=["paper", "product", "diff_drive"],
                   help="car problems: the robot model (default: paper, the reproduction's car; docs/design.md, "
                   "'Robot models')")
    p.add_argument("--grid", type=_shape, default=None, help="grid shape, e.g. 40,40,12,20 (car) or 51,40,50 (Air3D)")
    p.add_argument("--accuracy", default="high", choices=["low", "medium", "high", "very_high"])
    p.add_argument("--tolerance", type=float, default=None, help="max |dV| per simulated second to call it converged")
    p.add_argument("--max-horizon", type=float, default=None, help="backward-time budget, s")
    p.add_argument("--out", default="out", help="output folder (default: out)")
    p.add_argument("--no-plot", action="store_true", help="skip the PNG")
    p.add_argument("--json", action="store_true", help="print one JSON line instead of text")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--warmup", action="store_true", help="compile the solver step with a one-chunk solve first, "
                   "so the reported wall time excludes compilation (the benchmark's setting)")
    p.set_defaults(func=cmd_solve)

    p = sub.add_parser("generate", help="solve an experiment's datasets (resumable, shardable)")
    p.add_argument("--experiment", required=True, help="single | two | indoor | velocity | parametric | air3d | ci")
    p.add_argument("--config", default=None, help="YAML file (default: config/experiments/EXPERIMENT.yaml)")
    p.add_argument("--out", default=None, help="experiment folder (default: data/EXPERIMENT)")
    p.add_argument("--grid", type=_shape, default=None, help="override the config's grid, e.g. 32,32,9,16")
    p.add_argument("--n-train", type=int, default=None, help="override the number of training samples")
    p.add_argument("--n-test", type=int, default=None, help="override the number of test samples")
    p.add_argument("--seed", type=int, default=None, help="override the config's seed: sample i uses seed + i, "
                   "so another seed gives new scenarios")
    p.add_argument("--inflation", type=float, default=None, help="m: solve for obstacles grown by this much "
                   "(target l - inflation; car families; h/sqrt(2) of the grid makes it conservative)")
    p.add_argument("--shard", default=None, help="K/N: only samples with index mod N == K")
    p.add_argument("--workers", type=int, default=1, help="solver processes (default 1)")
    p.add_argument("--scheduler", default=None, help="solve on Dask distributed: a scheduler address "
                   "(tcp://host:8786) or 'local' (a local cluster of --workers processes); docs/training.md")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_generate)

    p = sub.add_parser("merge", help="combine shard folders into consolidated train/test files")
    p.add_argument("--out", required=True, help="experiment folder to complete")
    p.add_argument("shards", nargs="*", help="other shard folders of the same experiment")
    p.set_defaults(func=cmd_merge)

    p = sub.add_parser("show", help="PNG of a dataset's obstacles and BRT slices")
    p.add_argument("--dataset", required=True, help="a train.h5 or test.h5 file")
    p.add_argument("--samples", type=int, default=4, help="how many samples (default 4)")
    p.add_argument("--out", default=None, help="PNG path (default: next to the dataset)")
    p.set_defaults(func=cmd_show)

    p = sub.add_parser("train", help="train a neural operator on a generated dataset")
    p.add_argument("--experiment", default="single", help="dataset name under data/ (default: single)")
    p.add_argument("--data", default=None, help="dataset folder with train.h5/test.h5 (default: data/EXPERIMENT)")
    p.add_argument("--model", default="fno", choices=["fno", "tno", "cnn"])
    p.add_argument("--model-config", default=None, help='JSON overrides, e.g. \'{"width": 32}\'')
    p.add_argument("--epochs", type=int, default=10)
    p.add_argument("--slices-per-epoch", type=int, default=8192)
    p.add_argument("--batch", type=int, default=16)
    p.add_argument("--lr", type=float, default=3e-3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-minutes", type=float, default=30.0, help="wall-time budget (checkpoint and stop)")
    p.add_argument("--threads", type=int, default=0, help="torch CPU threads (default: torch's choice; 1 is "
                   "faster when other jobs share the cores)")
    p.add_argument("--out", default=None, help="model stem (default: out/models/DATA_MODEL)")
    p.add_argument("--allow-unconverged", action="store_true", help="also train and test on samples whose solve "
                   "missed the convergence tolerance (counted in the card)")
    p.add_argument("--augment", action="store_true", help="draw each training slice under a random one of the "
                   "car's 8 exact symmetries (quarter turns, reflections; needs a square window)")
    p.add_argument("--level-set-weight", type=float, default=0.0, help="extra loss weight λ near V∞ = 0: each "
                   "point's squared error counts 1 + λ exp(-(V∞/width)²) times (default 0: plain relative L2)")
    p.add_argument("--level-set-width", type=float, default=0.2, help="width of that weight in metres (default 0.2)")
    p.add_argument("--angle-pair-weight", type=float, default=0.0, help="add this weight times the rel. L2 of V's "
                   "change to the next grid angle (the sign of dV/dtheta picks the safe turn); half of each batch "
                   "is then the other half's angle neighbours (default 0: off)")
    p.add_argument("--init", default=None, help="start from this model stem's weights (fine-tuning; fresh "
                   "optimiser and schedule, same --model and --model-config)")
    p.add_argument("--table", action="store_true", help="an FNO that predicts the whole (v, theta) table in one "
                   "pass (one output channel per node; --batch and --slices-per-epoch then count tables)")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("ensemble", help="save trained models as one whose output is their mean (then calibrate it)")
    p.add_argument("--model", action="append", required=True, help="member model stem (repeat, at least 2; same "
                   "inputs and datasets)")
    p.add_argument("--pessimism", type=float, default=0.0, help="k >= 0: output mean - k * std of the members "
                   "(lower where they disagree; default 0, the mean)")
    p.add_argument("--out", required=True, help="model stem of the ensemble")
    p.set_defaults(func=cmd_ensemble)
    p = sub.add_parser("export-onnx", help="export models to ONNX for brt_node's onnxruntime (train does it too)")
    p.add_argument("--model", action="append", required=True, help="model stem (repeat for several)")
    p.set_defaults(func=cmd_export_onnx)

    p = sub.add_parser("evaluate", help="paper-style metrics of a trained model; updates the results table")
    p.add_argument("--model", required=True, help="model stem or .safetensors/.json path (--superres: comma list)")
    p.add_argument("--data", default=None, help="dataset folder (default: the one in the model card)")
    p.add_argument("--out", default="out/bench", help="results folder (default: out/bench)")
    p.add_argument("--train-limit", type=int, default=20, help="training samples scored (default 20)")
    p.add_argument("--into-card", action="store_true", help="also write the test metrics into the model card "
                   "(the first --data folder's as the headline)")
    p.add_argument("--figure", action="store_true", help="also write a ground truth | prediction | error PNG")
    p.add_argument("--superres", type=int, default=0, help="zero-shot super-resolution test at this factor")
    p.add_argument("--samples", type=int, default=3, help="test samples solved at the fine grid (--superres)")
    p.add_argument("--allow-unconverged", action="store_true", help="also score samples whose solve missed the "
                   "convergence tolerance (the row's n_train/n_test says so)")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("calibrate", help="split-conformal safety margin epsilon, written into the model card")
    p.add_argument("--model", default="models/default", help="model stem (default: models/default)")
    p.add_argument("--data", default=None, help="dataset folders, comma-separated (default: the card's); the "
                   "first half of each test split calibrates, the second half tests")
    p.add_argument("--margin", type=float, default=DEFAULT_MARGIN, help="delta, m: the margin the ground-truth "
                   "filter needs in closed loop (see hjrno simulate); calibration covers {V_gt <= delta} "
                   f"(default {DEFAULT_MARGIN})")
    p.add_argument("--alpha", type=float, default=0.002, help="allowed miss rate P(V_pred > eps | V_gt <= delta) "
                   "(default 0.002)")
    p.add_argument("--beta", type=float, default=0.05, help="1 - confidence")
    p.add_argument("--draws", type=int, default=20000, help="calibration draws")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--dry-run", action="store_true", help="report only; leave the card as it is")
    p.add_argument("--allow-unconverged", action="store_true", help="also use test scenarios whose solve did not "
                   "meet the convergence tolerance (their ground truth is approximate)")
    p.add_argument("--symmetry-average", action=argparse.BooleanOptionalAction, default=None,
                   help="average the model over the window's 8 symmetries (exactly equivariant, 8x inference "
                   "cost) or not; recorded in the card with epsilon, so evaluate, simulate and the node use it "
                   "(default: the card's setting)")
    p.add_argument("--member-frames", type=_frames, default=None,
                   help="ensembles: the D4 elements (0-7, slices.symmetry) each member predicts in, averaged per "
                   "member, e.g. '0,5;1,6;3,4' (one pass per element); recorded in the card with epsilon "
                   "(default: the card's; 'none' clears)")
    p.add_argument("--refine", type=float, default=0.0, help="s: calibrate the model's tables after this many "
                   "simulated s of the solver warm-started from them (brt_node's refine_horizon) instead; writes "
                   "refine_epsilon, which the node and simulate --refine use from that stage on (default 0: off)")
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("simulate", help="closed-loop episodes: collisions and interventions per safety filter")
    p.add_argument("--model", action="append", help="LABEL=STEM of a learned filter, repeatable "
                   "(default: fno=models/default)")
    p.add_argument("--data", default=None, help="dataset folders, comma-separated (default: the first model "
                   "card's); worlds are the second halves of their test splits")
    p.add_argument("--part", default="fresh", choices=["fresh", "calibration", "all"],
                   help="held-out scenarios to run: the fresh half of each test split (default), the calibration "
                   "half, or all of them (a folder of one scenario too)")
    p.add_argument("--allow-unconverged", action="store_true", help="also use test scenarios whose solve did not "
                   "meet the convergence tolerance (their ground truth is approximate)")
    p.add_argument("--episodes", type=int, default=500, help="at least this many episodes per filter")
    p.add_argument("--duration", type=float, default=20.0, help="episode length, s")
    p.add_argument("--truth-epsilon", type=float, default=DEFAULT_MARGIN, help="delta: margin of the ground-truth "
                   f"filter (sampled-data and grid error), m (default {DEFAULT_MARGIN})")
    p.add_argument("--filters", default=None, help="only filters whose names start with these, comma-separated")
    p.add_argument("--decay-rate", type=float, default=None,
                   help="qp mode: dV/dt >= -rate (V - eps), 1/s (default: the node's, 4)")
    p.add_argument("--inflation-at", default="input", choices=["input", "output"],
                   help="datasets solved with --inflation r: the models read l - r, as brt_node feeds them "
                   "(default), or read l with r taken off their output (exact for the true operator)")
    p.add_argument("--refine", type=float, default=0.0, help="also filter with each model's table refined by this "
                   "many simulated s of the solver warm-started from it (brt_node's refine_horizon), s")
    p.add_argument("--robot", default=None, choices=["turtlebot3"], help="drive this robot instead of the worlds' "
                   "car: worlds, margins and episodes at its size, a_max from each world's a_max/(kappa v^2)")
    p.add_argument("--worlds", type=int, default=None, help="only the first N held-out worlds (episodes spread "
                   "over them)")
    p.add_argument("--careless", action="store_true", help="also reversing (if the robot can) and spin-in-place "
                   "drivers, 1 episode in 10 each")
    p.add_argument("--scenes", choices=["product"], default=None,
                   help="instead: the product robot's scenes (rest by a wall, dead end, reversing, spin, inside a "
                   "wall) in every filter mode against the solver's table; writes scenes.md")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    p.add_argument("--out", default="out/bench", help="results folder (default: out/bench)")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("demo", help="brt_node keeps a Nav2-like path follower safe in IR-SIM, live over ROS 2")
    p.add_argument("--seconds", type=float, default=60.0, help="driving time (default 60)")
    p.add_argument("--seed", type=int, default=4, help="episode seed (start and goals on the demo's floor plan)")
    p.add_argument("--model", default=None, help="model stem for brt_node (default: the bundled model)")
    p.add_argument("--no-filter", action="store_true", help="drive without brt_node (to see the difference)")
    p.add_argument("--no-gif", action="store_true", help="only the PNG")
    p.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("bench", help="run a benchmark and write its results table")
    from hjrno_ros.tools import benchmarks  # numpy only at import: the parser stays light

    benchmarks.add_arguments(p)
    p.set_defaults(func=benchmarks.dispatch_args)

    p = sub.add_parser("agents", help="ground-truth value tables against a tracked moving agent (a person)")
    from hjrno_ros.tools import agents  # numpy only at import

    agents.add_arguments(p)
    p.set_defaults(func=agents.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, FloatingPointError, RuntimeError) as err:
        print(f"hjrno {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
