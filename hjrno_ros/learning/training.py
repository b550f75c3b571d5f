"""Training an operator on a dataset's 2D slices: seeded, resumable, honest about failure.

Loss: relative L2 per slice (the paper's metric), Adam with cosine decay.  After every epoch the
model *and* optimiser state go to ``<out>.train.safetensors`` + ``<out>.train.json``; a rerun with
the same settings resumes from there.  A NaN/Inf loss stops training with a clear message and
keeps the last good checkpoint.  The final model is written as ``<out>.safetensors`` + card.
"""

from __future__ import annotations

import dataclasses
import json
import math
import resource
import shlex
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from hjrno_ros import versions
from hjrno_ros.core.similarity import Coverage, number_names
from hjrno_ros.datasets.dataset import load_split
from hjrno_ros.learning import checkpoint
from hjrno_ros.learning.onnx_export import export_model
from hjrno_ros.learning.operators import build_model, count_parameters
from hjrno_ros.learning.slices import (
    SliceSet,
    SliceUnion,
    TableSet,
    angle_difference_l2,
    as_slices,
    level_set_weight,
    relative_l2,
    spec_for,
)

DEFAULT_MODEL_CONFIGS = {
    "fno": {"width": 24, "modes": 12, "n_layers": 4},
    "tno": {"d_model": 64, "n_heads": 4, "n_layers": 3, "latent": 24},
    "cnn": {"channels": 24, "depth": 3},
}


@dataclasses.dataclass
class TrainConfig:
    data: str  # experiment folder(s) with train.h5 and test.h5, comma-separated to combine datasets
    model: str = "fno"
    model_config: dict = dataclasses.field(default_factory=dict)
    epochs: int = 10
    slices_per_epoch: int = 8192  # random (sample, v, θ) slices drawn per epoch
    batch: int = 16
    lr: float = 3e-3
    weight_decay: float = 1e-5
    seed: int = 0
    max_minutes: float = 30.0  # stop (with a checkpoint) when this much wall time is spent
    out: str = "models/model"
    allow_unconverged: bool = False  # also train on samples whose solve missed the tolerance (flagged in the card)
    augment: bool = False  # draw each training slice under a random exact symmetry of the car (slices.symmetry)
    level_set_weight: float = 0.0  # extra loss weight at V∞ = 0 (slices.level_set_weight); 0 = plain rel. L2
    level_set_width: float = 0.2  # m: how far from V∞ = 0 that weight reaches
    angle_pair_weight: float = 0.0  # weight of the loss on V's change to the next angle (slices.angle_difference_l2)
    init: str = ""  # model stem to start from (fine-tuning: its weights, a fresh optimiser and schedule)
    table: bool = False  # one output channel per (v, θ) node: the whole table in one pass (slices.TableSet)

    def resume_key(self) -> dict:
        d = dataclasses.asdict(self)
        d.pop("max_minutes")
        if not self.table:  # checkpoints of slice models written before tables existed still resume
            d.pop("table")
        return d


class TrainingDiverged(RuntimeError):
    pass


def _optimizer_tensors(opt: torch.optim.Optimizer) -> tuple[dict, dict]:
    sd = opt.state_dict()
    tensors = {f"opt.{i}.{k}": v for i, st in sd["state"].items() for k, v in st.items()}
    return tensors, {"param_groups": sd["param_groups"], "indices": sorted(sd["state"])}


def _restore_optimizer(opt: torch.optim.Optimizer, tensors: dict, meta: dict) -> None:
    state = {i: {k.split(".", 2)[2]: v for k, v in tensors.items() if k.startswith(f"opt.{i}.")}
             for i in meta["indices"]}
    opt.load_state_dict({"state": state, "param_groups": meta["param_groups"]})


def _save_state(cfg: TrainConfig, model, opt, epoch: int, history: list, card: dict) -> None:
    opt_tensors, opt_meta = _optimizer_tensors(opt)
    tensors = {**{f"model.{k}": v for k, v in model.state_dict().items()}, **opt_tensors}
    train_card = {**card, "resume": {"key": cfg.resume_key(), "epoch": epoch, "history": history,
                                     "optimizer": opt_meta}}
    checkpoint.save(cfg.out + ".train", tensors, train_card)


def train(cfg: TrainConfig, progress: bool = True, command: str | None = None) -> Path:
    """Train (or resume) and write ``cfg.out``.safetensors/.json; returns the weights path."""
    if cfg.model not in DEFAULT_MODEL_CONFIGS:
        raise ValueError(f"unknown model {cfg.model!r}; choose from {', '.join(DEFAULT_MODEL_CONFIGS)}")
    if cfg.epochs < 1 or cfg.batch < 1 or not cfg.lr > 0:
        raise ValueError(f"need epochs >= 1, batch >= 1, lr > 0; got {cfg.epochs}, {cfg.batch}, {cfg.lr}")
    if not (cfg.level_set_weight >= 0 and cfg.level_set_width > 0):
        raise ValueError(f"need level-set weight >= 0 and width > 0 m; got {cfg.level_set_weight}, "
                         f"{cfg.level_set_width}")
    if not cfg.angle_pair_weight >= 0 or (cfg.angle_pair_weight and cfg.batch % 2):
        raise ValueError(f"need angle-pair weight >= 0 and, when > 0, an even batch; got {cfg.angle_pair_weight}, "
                         f"{cfg.batch}")
    folders = [Path(d) for d in cfg.data.split(",") if d]
    converged_only = not cfg.allow_unconverged
    train_splits = [load_split(d / "train.h5", converged_only=converged_only) for d in folders]
    tested = [d for d, part in zip(folders, train_splits, strict=True) if part.config.n_test]  # n_test 0: train only
    test_splits = [load_split(d / "test.h5", converged_only=converged_only) for d in tested]
    if not test_splits:
        raise ValueError("no test split among the datasets: at least one folder needs n_test > 0")
    for split in train_splits + test_splits:
        if not split.scenarios:
            raise ValueError(f"{split.config.name} {split.attrs['split']}: no converged samples to train or test on "
                             "(--allow-unconverged uses the flagged ones)")
    spec = spec_for(train_splits[0], cfg.table)
    if any(spec_for(s, cfg.table) != spec for s in train_splits):
        raise ValueError("datasets to combine need the same inputs (car vs Air3D, parameters, window)")
    if cfg.table and (cfg.model != "fno" or cfg.angle_pair_weight):
        raise ValueError("a table model is an FNO (--model fno) and has no angle pairs (every heading is in its "
                         "output)")
    items = TableSet if cfg.table else SliceSet
    train_set = SliceUnion([items(s, spec) for s in train_splits])
    if cfg.augment:
        for part in train_set.parts:
            part.check_symmetric()
    test_set = SliceUnion([items(s, spec) for s in test_splits])
    torch.manual_seed(cfg.seed)
    model_config = {**DEFAULT_MODEL_CONFIGS[cfg.model], **cfg.model_config, "in_channels": spec.in_channels}
    if cfg.table:
        model_config["out_channels"] = spec.out_channels
    model = build_model(cfg.model, **model_config)
    base_card = _initial_weights(cfg.init, model, spec) if cfg.init else None
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    steps_per_epoch = max(1, cfg.slices_per_epoch // cfg.batch)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=cfg.lr, total_steps=cfg.epochs * steps_per_epoch,
                                                pct_start=0.1)
    card = _card(cfg, model, spec, folders, tested, train_splits, test_splits, command)
    if base_card is not None:
        card["training"]["init"] = {"model": cfg.init, "command": base_card.command,
                                    "wall_s": base_card.training.get("wall_s")}
    start_epoch, history = _resume(cfg, model, opt, sched, steps_per_epoch)
    width = cfg.level_set_width / spec.value_scale  # the loss weight's width in normalised target units
    start = time.perf_counter()
    spent_before = sum(h["wall_s"] for h in history)
    per_step = cfg.batch // 2 if cfg.angle_pair_weight else cfg.batch  # drawn slices; the rest: their pairs
    from tqdm import tqdm

    for epoch in range(start_epoch, cfg.epochs):
        if (time.perf_counter() - start + spent_before) / 60 > cfg.max_minutes:
            print(f"stopping after {epoch} epochs: the {cfg.max_minutes} min budget is spent", file=sys.stderr)
            break
        t0 = time.perf_counter()
        rng = np.random.default_rng([cfg.seed, epoch])
        order = rng.integers(0, len(train_set), steps_per_epoch * per_step)
        sym = rng.integers(0, 8, len(order)) if cfg.augment else None
        model.train()
        losses = []
        for step in tqdm(range(steps_per_epoch), desc=f"epoch {epoch + 1}/{cfg.epochs}", disable=not progress,
                         leave=False):
            chunk = slice(step * per_step, (step + 1) * per_step)
            index, k = order[chunk], None if sym is None else sym[chunk]
            if cfg.angle_pair_weight:  # each slice and its next-angle neighbour under the same symmetry
                index = np.concatenate([index, train_set.angle_neighbour(index)])
                k = None if k is None else np.tile(k, 2)
            x, y = train_set.batch(index, k)
            pred, y = as_slices(model(x)), as_slices(y)
            weight = level_set_weight(y, cfg.level_set_weight, width) if cfg.level_set_weight else None
            loss = relative_l2(pred, y, weight)
            if cfg.angle_pair_weight:
                loss = loss + cfg.angle_pair_weight * angle_difference_l2(pred, y)
            if not torch.isfinite(loss):
                raise TrainingDiverged(f"loss became {loss.item()} in epoch {epoch + 1}, step {step}; "
                                       f"last good checkpoint: {cfg.out}.train.safetensors (try a lower --lr)")
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
            opt.step()
            sched.step()
            losses.append(relative_l2(pred.detach(), y).item())  # the plain metric, whatever the loss
        test_loss = evaluate_slices(model, test_set, cfg.seed, *((32, 8) if cfg.table else (512, 64)))
        history.append({"epoch": epoch + 1, "train_rel_l2": float(np.mean(losses)), "test_rel_l2": test_loss,
                        "wall_s": time.perf_counter() - t0})
        if progress:
            print(f"epoch {epoch + 1}: train rel. L2 {np.mean(losses):.4f}, test (slices) {test_loss:.4f}, "
                  f"{history[-1]['wall_s']:.0f} s", file=sys.stderr)
        _save_state(cfg, model, opt, epoch + 1, history, card)
    base_wall_s = (card["training"].get("init") or {}).get("wall_s") or 0.0  # a fine-tune's time includes its base's
    card["training"].update(epochs_done=len(history), history=history,
                            wall_s=round(sum(h["wall_s"] for h in history) + base_wall_s, 1),
                            peak_rss_mb=round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024))
    card["metrics"] = {"train_rel_l2_slices": history[-1]["train_rel_l2"] if history else math.nan,
                       "test_rel_l2_slices": history[-1]["test_rel_l2"] if history else math.nan}
    weights, _ = checkpoint.save(cfg.out, {f"model.{k}": v for k, v in model.state_dict().items()}, card)
    export_model(cfg.out)  # the ONNX file beside the weights: brt_node runs it without torch
    return weights


def _initial_weights(stem: str, model: torch.nn.Module, spec) -> checkpoint.ModelCard:
    """Load a trained model's weights into ``model`` (same architecture and inputs); its card."""
    base, card = checkpoint.load_typed(stem, average=False)
    if card.kind != model.kind or card.config != _as_stored(model.config):
        raise ValueError(f"--init {stem} is a {card.kind} with config {card.config}; pass the same --model and "
                         f"--model-config (got {model.kind} {model.config})")
    if card.inputs != _as_stored(spec.as_dict()):
        raise ValueError(f"--init {stem} was trained on other inputs ({card.inputs['channels']}, window scale "
                         f"{card.inputs['value_scale']} m) than these datasets give")
    model.load_state_dict(base.state_dict())
    return card


def _as_stored(d: dict) -> dict:
    """``d`` as a JSON model card stores it (tuples become lists), for comparisons with a loaded card."""
    return json.loads(json.dumps(d))


def _resume(cfg: TrainConfig, model, opt, sched, steps_per_epoch: int) -> tuple[int, list]:
    stem = cfg.out + ".train"
    if not checkpoint.paths(stem)[1].exists():
        return 0, []
    card = checkpoint.load_card(stem)
    resume = card.get("resume", {})
    if resume.get("key") != _as_stored(cfg.resume_key()):
        raise ValueError(f"{stem}.json was made with other settings; delete it or choose another --out")
    tensors = checkpoint.load_tensors(stem)
    model.load_state_dict({k[6:]: v for k, v in tensors.items() if k.startswith("model.")})
    _restore_optimizer(opt, tensors, resume["optimizer"])
    with warnings.catch_warnings():  # fast-forward the schedule; no optimizer step is due here
        warnings.simplefilter("ignore", UserWarning)
        for _ in range(resume["epoch"] * steps_per_epoch):
            sched.step()
    print(f"resuming from epoch {resume['epoch']}", file=sys.stderr)
    return int(resume["epoch"]), list(resume["history"])


@torch.no_grad()
def evaluate_slices(model, slice_set: SliceUnion, seed: int, n: int = 512, batch: int = 64) -> float:
    """Relative L2 on a fixed random subset of slices (of tables, for a table model; a cheap per-epoch test score)."""
    model.eval()
    index = np.random.default_rng([seed, 999]).choice(len(slice_set), min(n, len(slice_set)), replace=False)
    scores = [relative_l2(as_slices(model(x)), as_slices(y)).item() * len(x) for x, y in
              (slice_set.batch(index[i:i + batch]) for i in range(0, len(index), batch))]
    return float(sum(scores) / len(index))


def _card(cfg: TrainConfig, model, spec, folders: list[Path], tested: list[Path], train_splits: list,
          test_splits: list, command: str | None) -> dict:
    grid = train_splits[0].grid
    car = train_splits[0].scenarios[0].dynamics_params()
    if "log_a_max" in spec.param_ranges:  # conditioned: the card's own robot is the reference a = κ (ω) = v_max = 1
        car = dataclasses.replace(car, a_max=1.0)
    coverage = ({n: list(r) for n, r in zip(number_names(car.model), Coverage.of(car, spec.param_ranges).ranges,
                                            strict=True)} if spec.kind == "car" else None)
    return {
        "kind": cfg.model,
        "config": model.config,
        "parameters": count_parameters(model),
        "inputs": spec.as_dict(),
        "grid": grid.as_dict(),
        "window": {"lo": list(grid.lo[:2]), "hi": list(grid.hi[:2]), "shape": list(grid.shape[:2])},
        "dynamics": car.as_dict(),
        "coverage": coverage,
        "dataset": {"experiment": "+".join(s.config.name for s in train_splits),
                    "families": [s.config.family for s in train_splits],
                    "folders": [str(d) for d in folders],
                    "test_folders": [str(d) for d in tested],
                    "digests": [s.attrs["digest"] for s in train_splits],
                    "n_train": sum(len(s.scenarios) for s in train_splits),
                    "n_test": sum(len(s.scenarios) for s in test_splits),
                    "unconverged_used": sum(int((~s.converged).sum()) for s in train_splits + test_splits),
                    "grid": list(train_splits[0].config.grid)},
        "training": {"epochs": cfg.epochs, "slices_per_epoch": cfg.slices_per_epoch, "batch": cfg.batch,
                     "lr": cfg.lr, "weight_decay": cfg.weight_decay, "seed": cfg.seed,
                     "loss": "relative L2" + (f", weight 1 + {cfg.level_set_weight} exp(-(V/{cfg.level_set_width} m)^2)"
                                              if cfg.level_set_weight else "")
                     + (f" + {cfg.angle_pair_weight} x relative L2 of V(theta_k+1) - V(theta_k)"
                        if cfg.angle_pair_weight else ""),
                     "augment": "D4 symmetries (slices.symmetry)" if cfg.augment else None,
                     "threads": torch.get_num_threads()},
        "epsilon": None,
        "command": command or " ".join(shlex.quote(a) for a in ["hjrno", *sys.argv[1:]]),
        "versions": versions.versions(),
    }
