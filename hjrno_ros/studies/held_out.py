"""Held-out solved scenarios (dataset test splits) and a model's value tables on them.

Calibration and the closed-loop study both need scenarios the model never trained on, with
their ground truth.  A test split is cut in two (:func:`held_out_halves`): the first half
calibrates ε, the second ("fresh") half tests the calibrated model, in numbers and in closed loop.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from hjrno_ros.core.grids import GridSpec
from hjrno_ros.datasets.dataset import load_split
from hjrno_ros.truth.scenarios import Scenario

PARTS = ("calibration", "fresh", "all")
# Where a dataset's inflation r meets the model.  "input": the model reads l − r, as brt_node feeds it.
# "output": the model reads l and r comes off its output, exact for the true operator (V∞[l − r] =
# V∞[l] − r: the constant passes through the min over time and the sup/inf over controls and
# disturbances) and in-distribution for a model trained on uninflated data; kept for the comparison
# in docs/results.md (v5 indoors: 61 / 63 / 67 collisions against 27 / 20 / 19 with "input").
INFLATION_AT = ("input", "output")


@dataclasses.dataclass(frozen=True)
class Solved:
    """One held-out scenario: its exact geometry, grid, l − inflation and V∞ (``(Nx, Ny, Nv, Nθ)``)."""

    name: str
    scenario: Scenario
    grid: GridSpec
    target: np.ndarray
    value: np.ndarray
    inflation: float = 0.0  # m, the dataset's (target = l − inflation)


def load(folders: list[str | Path], part: str = "fresh", unconverged: bool = False) -> list[Solved]:
    """Converged (with ``unconverged``: all) test-split scenarios of the dataset folders, restricted to ``part``
    (``all`` takes every one, so a folder of a single scenario can be simulated)."""
    if part not in PARTS:
        raise ValueError(f"part must be one of {PARTS}, got {part!r}")
    out = []
    for folder in folders:
        split = load_split(Path(folder) / "test.h5", converged_only=not unconverged)
        if split.grid.ndim != 4:
            raise ValueError(f"{folder}: closed-loop and calibration need car datasets, not {split.config.family}")
        chosen = list(range(len(split.scenarios))) if part == "all" else _half(folder, len(split.scenarios), part)
        out += [Solved(f"{split.config.name}/{split.scenarios[i].seed}", split.scenarios[i], split.grid,
                       split.target[i], split.value[i], split.config.inflation) for i in chosen]
    return out


def held_out_halves(n: int) -> tuple[list[int], list[int]]:
    """Indices of a test split as (calibration, fresh test): the first ⌈n/2⌉ calibrate, the rest test."""
    if n < 2:
        raise ValueError(f"calibration needs at least 2 held-out scenarios (one to calibrate, one to test), got {n}")
    half = (n + 1) // 2
    return list(range(half)), list(range(half, n))


def _half(folder: str | Path, n: int, part: str) -> list[int]:
    """The calibration or fresh half of a test split of ``n`` scenarios; ValueError naming the folder."""
    try:
        calib, fresh = held_out_halves(n)
    except ValueError as err:  # name the folder: the user passes several, or the card's
        raise ValueError(f"{folder}: {err}; leave it out with --data") from None
    return calib if part == "calibration" else fresh


def has_halves(folder: str | Path, unconverged: bool = False) -> bool:
    """Whether a folder's test split has the 2 usable scenarios that a calibration and a fresh half need."""
    split = load_split(Path(folder) / "test.h5", converged_only=not unconverged, warn=lambda m: None)
    return len(split.scenarios) >= 2


def data_folders(data: str | None, stem: str, unconverged: bool) -> list[str]:
    """``data`` (comma-separated folders), or else the model card's test folders that can be halved (a one-room
    split is left out, with a note on stderr)."""
    import sys

    from hjrno_ros.learning import checkpoint

    if data:
        return data.split(",")
    folders = checkpoint.folders_with_test_split(checkpoint.load_card(stem))
    kept = [f for f in folders if has_halves(f, unconverged)]
    for f in folders:
        if f not in kept:
            print(f"{f}: fewer than 2 held-out scenarios, left out (choose folders with --data)", file=sys.stderr)
    return kept or folders  # none usable: the full list, so that loading names the first problem


def refine(solved: list[Solved], predicted: list[np.ndarray], horizon: float) -> list[np.ndarray]:
    """Each scenario's predicted table after ``horizon`` simulated s of the solver warm-started from it
    (what brt_node's ``refine_horizon`` does over a map)."""
    from hjrno_ros.truth.map_refinement import refine as solve_from

    out = []
    for s, p in zip(solved, predicted, strict=True):
        *_, (_, table, _) = solve_from(s.scenario.dynamics(), s.grid, s.target, p, horizon, horizon)
        out.append(table)
    return out


def predict(stem: str | Path, solved: list[Solved], average: bool | None = None,
            inflation_at: str = "input", frames: list | None = None) -> list[np.ndarray]:
    """The model's V on each scenario's whole grid (metres), min'd with l − r as the node does
    (``average``: symmetry-averaged or not, ``frames``: an ensemble's member frames; default: as the card
    says; ``inflation_at``: INFLATION_AT)."""
    import torch

    from hjrno_ros.learning import checkpoint
    from hjrno_ros.learning.slices import InputSpec
    from hjrno_ros.studies.evaluation import predict_table, sample_params

    if inflation_at not in INFLATION_AT:
        raise ValueError(f"inflation_at must be one of {INFLATION_AT}, got {inflation_at!r}")
    model, card = checkpoint.load_typed(stem, average=average, frames=frames)
    spec = InputSpec.from_dict(card.inputs)
    if spec.kind != "car":
        raise ValueError(f"{stem}: a car model is needed, this one is {spec.kind!r}")
    with torch.no_grad():
        return [np.minimum(predict_table(model, spec, s.grid, s.target, sample_params(spec, s.scenario),
                                         shift=s.inflation if inflation_at == "output" else 0.0), s.target)
                for s in solved]
