"""Datasets of solved scenarios: (l, V∞, parameters) samples in HDF5, generated resumably.

Layout of an experiment folder ``ROOT``:

    ROOT/experiment.json              the config it was generated with (a rerun must match it)
    ROOT/samples/<split>/000123.h5    one solved sample, written atomically (tmp file + rename)
    ROOT/<split>.h5                   all samples of a split, consolidated atomically once complete

A killed run leaves only whole sample files (at worst a stray ``.tmp``, ignored and removed), so a
rerun solves exactly the missing ones.  ``--shard K/N`` takes the samples whose index i has
i mod N = K, so any batch scheduler can run shards; :func:`merge` consolidates sample folders
from one or several shard outputs.  Non-converged samples are kept but flagged (``converged``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import Executor, ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import yaml

from hjrno_ros import versions
from hjrno_ros.core.grids import GridSpec
from hjrno_ros.datasets.h5store import atomic_h5
from hjrno_ros.truth.scenarios import FAMILIES, Scenario, make_scenario, parametric_test_diagonal, parametric_train_grid
from hjrno_ros.truth.solver import ACCURACIES, CRITERIA, solve

SAMPLE_FORMAT = "hjrno-sample-1"
SPLIT_FORMAT = "hjrno-dataset-1"
SPLITS = ("train", "test")
TEST_SEED_OFFSET = 1_000_000  # test samples never share a seed with training samples
_SOLVER_KEYS = {"accuracy", "tolerance", "max_horizon", "criterion", "chunk"}
_CONFIG_KEYS = {"name", "family", "grid", "n_train", "n_test", "seed", "options", "solver", "parametric_grid",
                "inflation", "accel_ratio"}


def _fail(message: str) -> None:
    raise ValueError(message)


@dataclasses.dataclass(frozen=True)
class ExperimentConfig:
    """What to generate: a scenario family, sample counts, the grid and the solver settings."""

    name: str
    family: str
    grid: tuple[int, ...]
    n_train: int
    n_test: int
    seed: int = 0
    options: dict = dataclasses.field(default_factory=dict)  # fixed scenario options for every sample
    solver: dict = dataclasses.field(default_factory=dict)  # keyword arguments of solver.solve
    parametric_grid: int = 10  # parametric family: train on an n x n lattice of (a_max, kappa_max)
    inflation: float = 0.0  # m: car targets are l − inflation (obstacles grown by it; see :meth:`target`)
    accel_ratio: tuple[float, float] | None = None  # per-sample a_max, log-uniform in [lo, hi] (κ = v_max = 1)

    def __post_init__(self) -> None:
        object.__setattr__(self, "grid", tuple(int(v) for v in self.grid))
        if self.family not in FAMILIES:
            _fail(f"unknown family {self.family!r} in experiment {self.name!r}; known: {', '.join(FAMILIES)}")
        ndim = 3 if FAMILIES[self.family].kind == "air3d" else 4
        if len(self.grid) != ndim or any(n < 3 for n in self.grid):
            _fail(f"experiment {self.name!r}: grid needs {ndim} axes of >= 3 nodes, got {list(self.grid)}")
        for key in ("n_train", "n_test", "seed"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                _fail(f"experiment {self.name!r}: {key} must be a non-negative integer, got {value!r}")
        if self.n_train + self.n_test == 0:
            _fail(f"experiment {self.name!r}: n_train + n_test must be > 0")
        if self.family == "parametric" and self.n_train > self.parametric_grid**2:
            _fail(f"experiment {self.name!r}: n_train {self.n_train} exceeds the {self.parametric_grid}^2 lattice")
        unknown = set(self.solver) - _SOLVER_KEYS
        if unknown:
            _fail(f"experiment {self.name!r}: unknown solver options {sorted(unknown)}; known {sorted(_SOLVER_KEYS)}")
        if self.solver.get("accuracy", "high") not in ACCURACIES:
            _fail(f"experiment {self.name!r}: solver accuracy must be one of {ACCURACIES}")
        if self.solver.get("criterion", "interior") not in CRITERIA:
            _fail(f"experiment {self.name!r}: solver criterion must be one of {CRITERIA}")
        if not (isinstance(self.inflation, int | float) and math.isfinite(self.inflation) and self.inflation >= 0):
            _fail(f"experiment {self.name!r}: inflation must be a finite number of metres >= 0, got {self.inflation!r}")
        if self.inflation and FAMILIES[self.family].kind == "air3d":
            _fail(f"experiment {self.name!r}: inflation applies to car families, not {self.family}")
        if self.accel_ratio is not None:
            ratio = tuple(self.accel_ratio) if isinstance(self.accel_ratio, list | tuple) else ()
            if len(ratio) != 2 or not all(isinstance(r, int | float) and 0 < r < math.inf for r in ratio) \
                    or ratio[0] > ratio[1] or FAMILIES[self.family].kind != "car" or self.family == "parametric":
                _fail(f"experiment {self.name!r}: accel_ratio must be [lo, hi] with 0 < lo <= hi, for a car family "
                      f"other than parametric, got {self.accel_ratio!r}")
            object.__setattr__(self, "accel_ratio", tuple(float(r) for r in ratio))
        make_scenario(self.family, self.seed, **self.options)  # unknown or bad options fail here, early

    def count(self, split: str) -> int:
        return self.n_train if split == "train" else self.n_test

    def as_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["grid"] = list(self.grid)
        for key in ("inflation", "accel_ratio"):  # configs without them keep the digests they always had
            if not d[key]:
                d.pop(key)
        if self.accel_ratio:
            d["accel_ratio"] = list(self.accel_ratio)
        return d

    def digest(self) -> str:
        """Identity of the samples this config produces (the name is only a label)."""
        d = self.as_dict()
        d.pop("name")
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]

    def scenario(self, split: str, index: int) -> Scenario:
        """The scenario of sample ``index`` of ``split``: seeded, reproducible, independent of sharding."""
        seed = self.seed + index + (TEST_SEED_OFFSET if split == "test" else 0)
        options = dict(self.options)
        if self.family == "parametric":
            if split == "train":
                a, k = parametric_train_grid(self.parametric_grid)[index]
            else:
                rng = np.random.default_rng([self.seed, TEST_SEED_OFFSET])
                a, k = parametric_test_diagonal(self.n_test, rng)[index]
            options.update(a_max=a, kappa_max=k)
        if self.accel_ratio:  # drawn from its own stream: the geometry of sample i does not depend on it
            lo, hi = np.log(self.accel_ratio)
            rng = np.random.default_rng([seed, 0xACCE1])
            turn = "omega_max" if options.get("robot") == "diff_drive" else "kappa_max"
            options.update({"a_max": float(np.exp(rng.uniform(lo, hi))), turn: 1.0, "v_max": 1.0})
        return make_scenario(self.family, seed, **options)

    def target(self, scenario: Scenario, grid: GridSpec) -> np.ndarray:
        """The solver's target: l on ``grid``, minus ``inflation`` for the car.

        l sampled at grid nodes and interpolated in between overestimates the exact clearance near
        obstacles smaller than a cell or at convex corners (by up to ``grid.half_cell_diagonal``, h/√2
        for cells of side h, since l is 1-Lipschitz): V∞ then comes out > 0 inside such obstacles.
        Subtracting that makes the interpolated target ≤ the exact clearance everywhere
        (docs/design.md, "Inflation")."""
        return scenario.target(grid) - np.float32(self.inflation)


def config_dir() -> Path:
    """``config/experiments`` of a source checkout, else of the installed share folder."""
    here = Path(__file__).resolve().parents[2] / "config" / "experiments"
    return here if here.is_dir() else Path(sys.prefix) / "share" / "hjrno_ros" / "config" / "experiments"


def load_config(experiment: str, path: str | Path | None = None) -> ExperimentConfig:
    """The experiment's YAML (``config/experiments/NAME.yaml`` unless ``path`` is given), validated."""
    path = Path(path) if path else config_dir() / f"{experiment}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in config_dir().glob("*.yaml"))
        _fail(f"no config for experiment {experiment!r} at {path}; known experiments: {', '.join(known)}")
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as err:
        raise ValueError(f"{path}: not valid YAML ({str(err).splitlines()[0]})") from None
    if not isinstance(raw, dict):
        _fail(f"{path}: expected a mapping of settings")
    unknown = set(raw) - _CONFIG_KEYS
    if unknown:
        _fail(f"{path}: unknown key(s) {sorted(unknown)}; known: {sorted(_CONFIG_KEYS)}")
    raw.setdefault("name", experiment)
    missing = {"family", "grid", "n_train", "n_test"} - set(raw)
    if missing:
        _fail(f"{path}: missing key(s) {sorted(missing)}")
    return ExperimentConfig(**raw)


# ---------------------------------------------------------------------------------------------
# One sample.


def sample_path(root: Path, split: str, index: int) -> Path:
    return root / "samples" / split / f"{index:06d}.h5"


def solve_sample(config: ExperimentConfig, split: str, index: int) -> tuple[Scenario, np.ndarray, np.ndarray, Any]:
    scenario = config.scenario(split, index)
    grid = scenario.grid(config.grid)
    target = config.target(scenario, grid)
    value, report = solve(scenario.dynamics(), grid, target, **config.solver)
    return scenario, target, value, report


def write_sample(root: Path, config: ExperimentConfig, split: str, index: int) -> dict:
    """Solve sample ``index`` of ``split`` and store it atomically; returns a short summary."""
    scenario, target, value, report = solve_sample(config, split, index)

    def write(f: h5py.File) -> None:
        f.attrs.update(format=SAMPLE_FORMAT, digest=config.digest(), split=split, index=index,
                       converged=report.converged, scenario=json.dumps(scenario.as_dict()),
                       report=json.dumps(report.as_dict()))
        f.create_dataset("target", data=target, compression="gzip")
        f.create_dataset("value", data=value, compression="gzip")

    atomic_h5(sample_path(root, split, index), write)
    return {"split": split, "index": index, "converged": report.converged, "wall_time": report.wall_time}


def read_sample(path: Path, digest: str, grid_shape: tuple[int, ...]) -> dict:
    """A validated sample file; ValueError when it is foreign, truncated or inconsistent."""
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != SAMPLE_FORMAT or f.attrs.get("digest") != digest:
                _fail(f"{path}: not a sample of this experiment config")
            sample = {k: f.attrs[k] for k in ("split", "index", "converged", "scenario", "report")}
            sample["target"], sample["value"] = f["target"][...], f["value"][...]
    except (OSError, KeyError) as err:
        raise ValueError(f"{path}: unreadable sample ({err})") from None
    for key in ("target", "value"):
        if sample[key].shape != tuple(grid_shape) or not np.all(np.isfinite(sample[key])):
            _fail(f"{path}: {key} has shape {sample[key].shape} or non-finite values")
    return sample


# ---------------------------------------------------------------------------------------------
# Generation.


def parse_shard(text: str | None) -> tuple[int, int]:
    if not text:
        return 0, 1
    try:
        k, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise ValueError(f"--shard must look like K/N (e.g. 0/4), got {text!r}") from None
    if not (n >= 1 and 0 <= k < n):
        raise ValueError(f"--shard K/N needs 0 <= K < N, got {text!r}")
    return k, n


def prepare_root(root: Path, config: ExperimentConfig) -> None:
    """Create ``root`` for ``config``, or check that an existing one was made with the same config."""
    marker = root / "experiment.json"
    if marker.exists():
        try:
            old = json.loads(marker.read_text())
        except json.JSONDecodeError:
            _fail(f"{marker} is corrupt; move the folder away or choose another --out")
        if old.get("digest") != config.digest():
            _fail(f"{root} holds samples of a different config ({old.get('name')}); choose another --out")
        return
    root.mkdir(parents=True, exist_ok=True)
    tmp = marker.with_suffix(".tmp")
    tmp.write_text(json.dumps({"digest": config.digest(), **config.as_dict()}, indent=1))
    tmp.replace(marker)


def pending(root: Path, config: ExperimentConfig, shard: tuple[int, int]) -> list[tuple[str, int]]:
    """(split, index) of this shard's samples that have no valid file yet; invalid files are removed."""
    todo = []
    for split in SPLITS:
        folder = root / "samples" / split
        for stray in folder.glob(".*.tmp"):
            stray.unlink()
        for index in range(config.count(split)):
            if index % shard[1] != shard[0]:
                continue
            path = sample_path(root, split, index)
            if path.exists():
                try:
                    read_sample(path, config.digest(), config.grid)
                    continue
                except ValueError as err:
                    print(f"redoing {err}", file=sys.stderr)
                    path.unlink()
            todo.append((split, index))
    return todo


def generate(config: ExperimentConfig, root: Path, shard: str | None = None, workers: int = 1,
             progress: bool = True, executor: Executor | None = None) -> dict:
    """Solve every missing sample of this shard, then consolidate the splits that are complete.  ``executor``
    (e.g. a Dask cluster's, datasets/cluster.py) solves the samples instead of ``workers`` local processes; its
    workers write the sample files, so they must see ``root``."""
    shard_kn = parse_shard(shard)
    if workers < 1:
        _fail(f"--workers must be >= 1, got {workers}")
    root = Path(root)
    prepare_root(root, config)
    todo = pending(root, config, shard_kn)
    start = time.perf_counter()
    results = _run(config, root, todo, workers, progress, executor)
    summary = {
        "experiment": config.name,
        "solved": len(results),
        "not_converged": sum(not r["converged"] for r in results),
        "wall_s": time.perf_counter() - start,
        "outputs": [str(p) for p in consolidate_complete(root, config)],
    }
    summary["bytes"] = sum(Path(p).stat().st_size for p in summary["outputs"])
    return summary


def _run(config: ExperimentConfig, root: Path, todo: list, workers: int, progress: bool,
         executor: Executor | None) -> list[dict]:
    from tqdm import tqdm

    bar = tqdm(total=len(todo), unit="sample", desc=f"generate {config.name}", disable=not progress)
    results = []

    def done(r: dict) -> None:
        results.append(r)
        bar.update(1)
        if not r["converged"]:
            bar.write(f"{r['split']} sample {r['index']}: NOT converged (kept, flagged)")

    def run_on(pool: Executor) -> None:
        futures = [pool.submit(write_sample, root, config, s, i) for s, i in todo]
        for future in as_completed(futures):
            done(future.result())

    with bar:
        if executor is not None:
            run_on(executor)
        elif workers == 1:
            for split, index in todo:
                done(write_sample(root, config, split, index))
        else:
            with ProcessPoolExecutor(workers, mp_context=get_context("spawn"), initializer=exit_with_parent,
                                     initargs=(os.getpid(),)) as pool:
                run_on(pool)
    return results


def exit_with_parent(parent: int, poll_s: float = 0.5) -> None:
    """Worker initializer: end this worker once ``parent`` is gone.  A generating process killed
    alone (``kill PID``, SIGKILL) runs no clean-up, and its workers would otherwise keep solving
    queued samples for nobody; the sample in hand is lost whole (files are written atomically)."""
    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll_s)
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="exit-with-parent").start()


def consolidate_complete(root: Path, config: ExperimentConfig) -> list[Path]:
    """Write ``<split>.h5`` for every split whose samples are all present in ``root``."""
    written = []
    for split in SPLITS:
        n = config.count(split)
        if n and all(sample_path(root, split, i).exists() for i in range(n)):
            written.append(consolidate(root, config, split, [sample_path(root, split, i) for i in range(n)]))
    return written


def consolidate(root: Path, config: ExperimentConfig, split: str, paths: list[Path]) -> Path:
    """One HDF5 file holding all samples of ``split`` (validated), written atomically."""
    samples = [read_sample(p, config.digest(), config.grid) for p in paths]
    if [int(s["index"]) for s in samples] != list(range(config.count(split))):
        _fail(f"{split}: samples do not cover indices 0..{config.count(split) - 1} exactly once")
    grid = config.scenario(split, 0).grid(config.grid)
    reports = [json.loads(s["report"]) for s in samples]

    def write(f: h5py.File) -> None:
        f.attrs.update(format=SPLIT_FORMAT, split=split, digest=config.digest(),
                       config=json.dumps(config.as_dict()), grid=json.dumps(grid.as_dict()),
                       versions=json.dumps(versions.versions()),
                       created=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                       solve_wall_s=float(sum(r["wall_time"] for r in reports)))
        for key in ("target", "value"):
            f.create_dataset(key, data=np.stack([s[key] for s in samples]), chunks=(1, *config.grid),
                             compression="gzip")
        f.create_dataset("converged", data=np.array([bool(s["converged"]) for s in samples]))
        f.create_dataset("scenario", data=[s["scenario"] for s in samples], dtype=h5py.string_dtype())
        f.create_dataset("report", data=[s["report"] for s in samples], dtype=h5py.string_dtype())

    return atomic_h5(root / f"{split}.h5", write)


def merge(root: Path, sources: list[Path]) -> list[Path]:
    """Gather the sample files of shard folders ``sources`` into ``root`` and consolidate it."""
    root = Path(root)
    configs = [json.loads((Path(s) / "experiment.json").read_text()) for s in [root, *sources]
               if (Path(s) / "experiment.json").exists()]
    if not configs:
        _fail(f"no experiment.json in {root} or the shard folders")
    if len({c["digest"] for c in configs}) != 1:
        _fail("the shard folders were generated with different configs")
    raw = {k: v for k, v in configs[0].items() if k != "digest"}
    config = ExperimentConfig(**raw)
    prepare_root(root, config)
    for source in sources:
        for path in sorted(Path(source).glob("samples/*/[0-9]*.h5")):
            dest = root / path.relative_to(source)
            if not dest.exists():
                read_sample(path, config.digest(), config.grid)
                dest.parent.mkdir(parents=True, exist_ok=True)
                tmp = dest.with_name(f".{dest.name}.tmp")
                tmp.write_bytes(path.read_bytes())
                tmp.replace(dest)
    missing = {split: config.count(split) - len(list((root / "samples" / split).glob("[0-9]*.h5")))
               for split in SPLITS}
    if any(missing.values()):
        _fail(f"cannot merge: samples still missing {missing}")
    return consolidate_complete(root, config)


# ---------------------------------------------------------------------------------------------
# Reading.


@dataclasses.dataclass
class Split:
    """A consolidated split, loaded: arrays ``(n, *grid)``, flags and per-sample metadata."""

    config: ExperimentConfig
    grid: Any
    target: np.ndarray
    value: np.ndarray
    converged: np.ndarray
    scenarios: list[Scenario]
    reports: list[dict]
    attrs: dict


def load_split(path: str | Path, converged_only: bool = False,
               warn: Callable[[str], None] = lambda m: print(m, file=sys.stderr)) -> Split:
    """Read a consolidated split; ValueError when the file is not one or is damaged."""
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != SPLIT_FORMAT:
                _fail(f"{path}: not an hjrno dataset file (format {f.attrs.get('format')!r})")
            attrs = {k: f.attrs[k] for k in f.attrs}
            target, value, converged = f["target"][...], f["value"][...], f["converged"][...]
            scen = [json.loads(s) for s in f["scenario"].asstr()[...]]
            reports = [json.loads(s) for s in f["report"].asstr()[...]]
    except (OSError, KeyError) as err:
        raise ValueError(f"{path}: unreadable or incomplete dataset file ({err})") from None
    config = ExperimentConfig(**json.loads(attrs["config"]))
    grid = GridSpec.from_dict(json.loads(attrs["grid"]))
    n = config.count(str(attrs["split"]))
    if target.shape != (n, *grid.shape) or value.shape != target.shape or len(converged) != n:
        _fail(f"{path}: arrays do not match {n} samples on grid {grid.shape}")
    keep = converged if converged_only else np.ones(n, bool)
    if converged_only and not keep.all():
        warn(f"{path}: dropping {int((~keep).sum())} non-converged sample(s)")
    return Split(config, grid, target[keep], value[keep], converged[keep],
                 [Scenario.from_dict(s) for s, k in zip(scen, keep, strict=True) if k],
                 [r for r, k in zip(reports, keep, strict=True) if k], attrs)

