"""Evaluating trained operators like the HJRNO paper (Tables 1-2), plus safety-relevant metrics.

Errors are over whole value tables: every (v, θ) slice of a sample is predicted and compared.
- relative L2: ‖V_pred − V_gt‖₂ / ‖V_gt‖₂ per sample, averaged over samples;
- BRT IoU: |{V_pred ≤ 0} ∩ {V_gt ≤ 0}| / |{V_pred ≤ 0} ∪ {V_gt ≤ 0}|;
- false-safe rate: among states with V_gt ≤ 0, the fraction predicted safe (V_pred > 0).
Results accumulate in ``<out>/evaluation.json`` (one row per experiment and model) and are
rendered to ``evaluation.md`` and ``evaluation.csv``.
"""

from __future__ import annotations

import csv
import json
import math
import time
from pathlib import Path

import numpy as np
import torch

from hjrno_ros.core.model_card import ModelCard
from hjrno_ros.core.tables import records_table
from hjrno_ros.datasets.dataset import load_split
from hjrno_ros.learning import checkpoint
from hjrno_ros.learning.slices import InputSpec, param_value


@torch.no_grad()
def predict_table(model, spec: InputSpec, grid, target: np.ndarray, params: np.ndarray | None = None,
                  batch: int = 64, shift: float = 0.0) -> np.ndarray:
    """V_pred on the whole grid of one sample (l given on the same grid), in metres; with ``shift`` r the
    model runs on target + r and r comes off its output (``held_out.INFLATION_AT``).  A table model predicts
    it in one pass."""
    if spec.table:
        if tuple(grid.shape[2:]) != spec.table:
            raise ValueError(f"a table model of (v, theta) shape {spec.table} cannot predict a {grid.shape} grid")
        v0 = target[None, :, :, 0, 0] + np.float32(shift)
        p = None if params is None else params[None]
        pred = model(spec.inputs(v0, np.zeros(1), np.zeros(1), p))[0].numpy() * spec.value_scale - np.float32(shift)
        return np.ascontiguousarray(np.moveaxis(pred.reshape(*spec.table, *grid.shape[:2]), (0, 1), (2, 3)))
    angle_axis = grid.ndim - 1
    rest = grid.shape[2:]
    index = np.stack(np.unravel_index(np.arange(int(np.prod(rest))), rest), -1)
    out = np.empty(grid.shape, np.float32)
    for i in range(0, len(index), batch):
        sl = index[i:i + batch]
        v0 = np.stack([target[(slice(None), slice(None), *s)] for s in sl]) + np.float32(shift)
        v = grid.axis(2)[sl[:, 0]] if spec.kind == "car" else np.zeros(len(sl))
        angle = grid.axis(angle_axis)[sl[:, -1]]
        p = None if params is None else np.repeat(params[None], len(sl), 0)
        pred = model(spec.inputs(v0, v, angle, p))[:, 0].numpy() * spec.value_scale - np.float32(shift)
        for k, s in enumerate(sl):
            out[(slice(None), slice(None), *s)] = pred[k]
    return out


def sample_params(spec: InputSpec, scenario) -> np.ndarray | None:
    """The varying parameters of a scenario in the spec's channel order (None if there are none)."""
    return (np.array([param_value(scenario.params, k) for k in spec.param_ranges], np.float32)
            if spec.param_ranges else None)


EDGE_CELLS = 2  # the ring of the window where walls beyond its edge shape V unseen


def table_metrics(pred: np.ndarray, truth: np.ndarray) -> dict:
    """Relative L2, RMS error (the table's units: the same absolute error reads as a larger relative one where V
    is small, in clutter), BRT IoU and false-safe rate of one table."""
    unsafe_t, unsafe_p = truth <= 0, pred <= 0
    union = np.sum(unsafe_t | unsafe_p)
    return {
        "rel_l2": float(np.linalg.norm(pred - truth) / max(np.linalg.norm(truth), 1e-12)),
        "rms_error": float(np.sqrt(np.mean(np.square(pred - truth)))),
        "iou": float(np.sum(unsafe_t & unsafe_p) / union) if union else 1.0,
        "false_safe": float(np.mean(~unsafe_p[unsafe_t])) if unsafe_t.any() else 0.0,
    }


def edge_error_share(pred: np.ndarray, truth: np.ndarray, cells: int = EDGE_CELLS) -> float:
    """Share of the squared error of a table (x, y first) within ``cells`` of the window's edge."""
    err = np.square(pred - truth)
    inner = err[cells:-cells, cells:-cells].sum()
    total = err.sum()
    return float((total - inner) / total) if total > 0 else 0.0


def split_metrics(model, spec: InputSpec, split, limit: int | None = None) -> dict:
    """Mean table metrics over the first ``limit`` samples, plus ``rel_l2_converged``: the mean
    relative L2 over those whose solve converged (NaN if none), to separate model error from
    the error of a ground truth that had not settled."""
    n = len(split.target) if limit is None else min(limit, len(split.target))
    rows = []
    for i in range(n):
        params = sample_params(spec, split.scenarios[i])
        pred = predict_table(model, spec, split.grid, split.target[i], params)
        rows.append(table_metrics(pred, split.value[i]) | {"edge_error_share": edge_error_share(pred, split.value[i])})
    converged = [r["rel_l2"] for r, ok in zip(rows, split.converged[:n], strict=True) if ok]
    return ({k: float(np.mean([r[k] for r in rows])) for k in rows[0]} | {"n": n}
            | {"rel_l2_converged": float(np.mean(converged)) if converged else math.nan})


def inference_ms(model, spec: InputSpec, shape: tuple[int, int], repeats: int = 30) -> float:
    """Median wall time of one forward pass of batch 1, ms: one 2D slice, or a table model's whole table."""
    x = spec.inputs(np.zeros((1, *shape), np.float32), np.zeros(1), np.zeros(1),
                    np.ones((1, len(spec.param_ranges)), np.float32) if spec.param_ranges else None)
    return median_ms(model, x, repeats)


@torch.no_grad()
def median_ms(model, x: torch.Tensor, repeats: int, warmup: int = 3) -> float:
    """Median wall time of ``model(x)`` after ``warmup`` untimed calls, ms."""
    for _ in range(warmup):
        model(x)
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        model(x)
        times.append(time.perf_counter() - t)
    return 1e3 * float(np.median(times))


def evaluate(stem: str | Path, data: str | Path | None = None, train_limit: int = 20,
             figures: str | Path | None = None, unconverged: bool = False) -> list[dict]:
    """Results rows of a trained model, one per dataset folder (its card's, or ``data``); with
    ``figures``, also a ground truth | prediction | error PNG per folder there.  Samples whose solve
    missed the tolerance are left out unless ``unconverged``."""
    model, card = checkpoint.load_typed(stem)
    folders = [Path(d) for d in (str(data).split(",") if data else checkpoint.folders_with_test_split(card))]
    return [_evaluate_folder(model, card, Path(stem), folder, train_limit, figures, unconverged) for folder in folders]


def _evaluate_folder(model, card: ModelCard, stem: Path, data: Path, train_limit: int, figures,
                     unconverged: bool) -> dict:
    spec = InputSpec.from_dict(card.inputs)
    train, test = (load_split(data / f"{s}.h5", converged_only=not unconverged) for s in ("train", "test"))
    if not test.scenarios:
        raise ValueError(f"{data}/test.h5: no converged test samples to score (--allow-unconverged scores the flagged)")
    flagged = int((~train.converged).sum() + (~test.converged).sum())
    if figures:
        error_figure(model, card.kind, spec, test,
                     Path(figures) / f"{test.config.name}_{checkpoint.paths(stem)[0].stem}.png")
        if test.config.family == "parametric":
            diagonal_figure(model, card.kind, spec, test,
                            Path(figures) / f"{test.config.name}_{checkpoint.paths(stem)[0].stem}_diagonal.png")
    tr, te = split_metrics(model, spec, train, train_limit), split_metrics(model, spec, test)
    solve_s = float(np.mean([r["wall_time"] for r in train.reports + test.reports]))
    infer = inference_ms(model, spec, tuple(test.grid.shape[:2]))
    table_ms = infer if spec.table else infer * int(np.prod(test.grid.shape[2:]))  # every slice of the solved table
    weights, _ = checkpoint.paths(stem)
    return {
        "experiment": test.config.name,
        "model": f"{card.kind} ({checkpoint.paths(stem)[0].stem}{', D4-averaged' if averaged(model) else ''})",
        "grid": "x".join(map(str, test.grid.shape)),
        "n_train/n_test": f"{len(train.scenarios)}/{len(test.scenarios)}"
                          + (f" ({flagged} unconverged)" if flagged else ""),
        "train_rel_l2": round(tr["rel_l2"], 4),
        "test_rel_l2": round(te["rel_l2"], 4),
        "test_iou": round(te["iou"], 4),
        "test_false_safe": round(te["false_safe"], 4),
        "test_rms_error": round(te["rms_error"], 4),
        "test_edge_error_share": round(te["edge_error_share"], 2),
        **({"test_rel_l2_converged": _rounded(te["rel_l2_converged"])} if flagged else {}),
        "dataset_time_h": round(float(train.attrs["solve_wall_s"] + test.attrs["solve_wall_s"]) / 3600, 2),
        "train_time_min": round(card.training.get("wall_s", float("nan")) / 60, 1),
        "params_M": round(card.parameters / 1e6, 3) if card.parameters is not None else None,
        "train_peak_MB": card.training.get("peak_rss_mb"),
        "data_MB": round(sum((data / f"{s}.h5").stat().st_size for s in ("train", "test")) / 1e6, 1),
        "checkpoint_MB": round(weights.stat().st_size / 1e6, 2),
        "solve_s": round(solve_s, 1),
        "infer_ms": round(infer, 2),
        "speedup": round(1e3 * solve_s / infer),
        "table_ms": round(table_ms, 2),
        "table_speedup": round(1e3 * solve_s / table_ms),
        "train_samples_scored": tr["n"],
    }


def _rounded(x: float) -> float | None:
    """``x`` to 4 digits; None for NaN (no sample to average), which JSON and CSV can hold."""
    return None if math.isnan(x) else round(x, 4)


def averaged(model) -> bool:
    """Whether ``model`` is symmetry-averaged (8 forward passes per prediction)."""
    from hjrno_ros.learning.operators.average import SymmetryAverage

    return isinstance(model, SymmetryAverage)


CARD_METRICS = ("test_rel_l2", "test_iou", "test_false_safe", "infer_ms", "table_ms", "checkpoint_MB")


def record_in_card(stem: str | Path, rows: list[dict]) -> Path:
    """Write evaluation rows into the model card's ``metrics``: the first row's as the headline, every row's
    under ``by_dataset``; the card's other metrics stay."""
    card = checkpoint.load_card(stem)
    metrics = {**card.get("metrics", {}), **{k: rows[0][k] for k in CARD_METRICS}, "headline": rows[0]["experiment"],
               "by_dataset": {r["experiment"]: {k: r[k] for k in CARD_METRICS} for r in rows}}
    return checkpoint.update_card(stem, {"metrics": metrics})


def record(row: dict, out: str | Path) -> Path:
    """Add or replace the row for (experiment, model) and re-render evaluation.md/.csv."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    store = out / "evaluation.json"
    rows = json.loads(store.read_text()) if store.exists() else []
    rows = [r for r in rows if (r["experiment"], r["model"]) != (row["experiment"], row["model"])] + [row]
    rows.sort(key=lambda r: (r["experiment"], r["model"]))
    store.write_text(json.dumps(rows, indent=1))
    keys = list(dict.fromkeys(k for r in rows for k in r))
    with open(out / "evaluation.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, keys)
        writer.writeheader()
        writer.writerows(rows)
    lines = ["# Operator evaluation", "",
             "Written by `hjrno evaluate`. Errors over whole value tables (all v, θ slices) of the test split; "
             "train error on up to `train_samples_scored` training samples. solve_s: mean ground-truth solve of "
             "one sample on this machine; infer_ms: one forward pass, batch 1, CPU (one 2D slice; a table model's "
             "whole table); speedup = solve / infer_ms; table_ms: every slice of a table (slice models: infer_ms "
             "times the slices), table_speedup = solve / table_ms; "
             "test_rms_error: RMS of V_pred − V∞ in the table's units; test_edge_error_share: the part of the squared "
             f"error within {EDGE_CELLS} cells of the window's edge.", "", *records_table(rows, keys)]
    (out / "evaluation.md").write_text("\n".join(lines) + "\n")
    return out / "evaluation.md"


def error_figure(model, kind: str, spec: InputSpec, test, path: str | Path) -> Path:
    """Ground truth | prediction | error for the first test sample: the car at mid speed and θ = 0,
    Air3D at relative heading ψ = 0 (the middle of each axis)."""
    from hjrno_ros.studies.plotting import plt, save_figure

    pred = predict_table(model, spec, test.grid, test.target[0], sample_params(spec, test.scenarios[0]))
    mid = (test.grid.shape[3] // 2,) if test.grid.ndim == 4 else ()
    idx = (slice(None), slice(None), test.grid.shape[2] // 2, *mid)
    x, y = test.grid.axis(0), test.grid.axis(1)
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.4))
    for ax, data_, title in zip(axes, (test.value[0][idx], pred[idx], pred[idx] - test.value[0][idx]),
                                ("ground truth V∞", f"{kind.upper()} prediction", "error"), strict=True):
        limit = float(np.abs(data_).max()) if title == "error" else None
        im = ax.pcolormesh(x, y, data_.T, shading="auto", cmap="RdBu" if limit else "viridis",
                           vmin=-limit if limit else None, vmax=limit)
        if title != "error":
            ax.contour(x, y, data_.T, levels=[0.0], colors="w")
        ax.set_title(title, fontsize=10)
        ax.set_aspect("equal")
        fig.colorbar(im, ax=ax, shrink=0.8)
    where = "mid v, θ = 0" if test.grid.ndim == 4 else "ψ = 0"
    return save_figure(fig, path, f"{test.config.name}: test sample 0, {where}")


def diagonal_figure(model, kind: str, spec: InputSpec, test, path: str | Path) -> Path:
    """The paper's Fig. 4: test error along the (a_max, κ_max) diagonal (trained on a lattice), and the
    ground-truth vs predicted zero level at the lowest, middle and highest limits (v_max, θ = 0)."""
    from hjrno_ros.studies.plotting import plt, save_figure

    limits = np.array([[sc.params["a_max"], sc.params["kappa_max"]] for sc in test.scenarios])
    order = np.argsort(limits[:, 0])
    preds = [predict_table(model, spec, test.grid, test.target[i], sample_params(spec, test.scenarios[i]))
             for i in order]
    errors = [table_metrics(p_, test.value[i])["rel_l2"] for p_, i in zip(preds, order, strict=True)]
    picks = [0, len(order) // 2, len(order) - 1]
    fig, axes = plt.subplots(1, 4, figsize=(14, 3.4))
    axes[0].plot(limits[order, 0], errors, "o-", ms=3)
    axes[0].set_xlabel("a_max = κ_max along the diagonal")
    axes[0].set_ylabel("test relative L2")
    axes[0].set_title("error along the diagonal", fontsize=10)
    x, y = test.grid.axis(0), test.grid.axis(1)
    idx = (slice(None), slice(None), test.grid.shape[2] - 1, test.grid.shape[3] // 2)
    for ax, k in zip(axes[1:], picks, strict=True):
        i = order[k]
        ax.contourf(x, y, test.target[i][idx].T, levels=[-10, 0], colors=["#404040"])
        ax.contour(x, y, test.value[i][idx].T, levels=[0], colors=["k"])
        ax.contour(x, y, preds[k][idx].T, levels=[0], colors=["r"], linestyles="--")
        ax.set_title(f"a_max {limits[i, 0]:.2f}, κ_max {limits[i, 1]:.2f}: rel L2 {errors[k]:.4f}", fontsize=9)
        ax.set_aspect("equal")
    return save_figure(fig, path, f"{test.config.name}: BRT at v_max, θ = 0 (black: ground truth, red: "
                       f"{kind.upper()})")


def superresolution(stems: list[str | Path], data: str | Path, factor: int = 3, samples: int = 3,
                    out: str | Path = "out/bench") -> Path:
    """Zero-shot super-resolution: models trained at the base grid predict at ``factor`` × the x-y
    resolution; compared with ground truth solved at that resolution, and with the baseline
    "predict at the base grid, then interpolate bilinearly"."""
    from scipy.interpolate import RegularGridInterpolator

    from hjrno_ros.truth.solver import solve

    test = load_split(Path(data) / "test.h5", converged_only=True)
    base = test.grid
    fine = base.with_shape((factor * (base.shape[0] - 1) + 1, factor * (base.shape[1] - 1) + 1, *base.shape[2:]))
    truths = []
    for scenario in test.scenarios[:samples]:
        target = test.config.target(scenario, fine)
        value, report = solve(scenario.dynamics(), fine, target, **test.config.solver)
        truths.append((scenario, target, value, report.wall_time))
    rows = []
    for stem in stems:
        model, card = checkpoint.load_typed(stem)
        spec = InputSpec.from_dict(card.inputs)
        direct, interp = [], []
        for scenario, target, value, _ in truths:
            params = sample_params(spec, scenario)
            high = predict_table(model, spec, fine, target, params)
            low = predict_table(model, spec, base, test.config.target(scenario, base), params)
            up = RegularGridInterpolator((base.axis(0), base.axis(1)), low)  # trailing (v, θ) axes ride along
            pts = np.stack(np.meshgrid(fine.axis(0), fine.axis(1), indexing="ij"), -1)
            up_table = up(pts.reshape(-1, 2)).reshape(fine.shape)
            direct.append(table_metrics(high, value))
            interp.append(table_metrics(up_table.astype(np.float32), value))
        rows.append({"model": f"{card.kind} ({checkpoint.paths(stem)[0].stem})",
                     "train_grid": "x".join(map(str, base.shape)), "eval_grid": "x".join(map(str, fine.shape)),
                     "samples": len(truths),
                     "zero_shot_rel_l2": round(float(np.mean([m["rel_l2"] for m in direct])), 4),
                     "base_then_interp_rel_l2": round(float(np.mean([m["rel_l2"] for m in interp])), 4),
                     "zero_shot_iou": round(float(np.mean([m["iou"] for m in direct])), 4),
                     "base_then_interp_iou": round(float(np.mean([m["iou"] for m in interp])), 4),
                     "gt_solve_s": round(float(np.mean([t[3] for t in truths])), 1)})
    keys = list(rows[0])
    lines = ["# Zero-shot super-resolution", "",
             f"`hjrno evaluate --superres {factor}` on {test.config.name} test samples: each model, trained at the "
             "base grid, predicts at the fine grid directly (zero-shot) and at the base grid followed by bilinear "
             "interpolation in x-y (baseline); ground truth solved at the fine grid.", "", *records_table(rows, keys)]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "superres.md").write_text("\n".join(lines) + "\n")
    (out / "superres.json").write_text(json.dumps(rows, indent=1))
    return out / "superres.md"
