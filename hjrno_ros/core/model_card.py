"""The model card: one typed view of ``<stem>.json``, read by the node, the learning code and the studies.

A model on disk is ``<stem>.safetensors`` (tensors only) plus ``<stem>.json`` (this card).  The
card says what the weights were trained for: architecture (``kind``, ``config``), input channels
(``inputs``), the value grid and window (``grid``), the car's limits (``dynamics``), the calibrated
margins (``epsilon``; ``refine_epsilon`` from the refined stage ``refine_calibration.horizon_s``),
metrics, data and the command that reproduces it.  Reading it never imports torch: the node checks a
card before it pays for loading weights.  Every problem is one ``ValueError`` line naming the field.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

from hjrno_ros.core.dynamics import CarParams
from hjrno_ros.core.grids import GridSpec

CARD_FORMAT = "hjrno-model-1"
REQUIRED = ("format", "kind", "config", "inputs", "grid", "dynamics")
KINDS = ("fno", "tno", "cnn", "ensemble")
DYNAMICS_FIELDS = tuple(f.name for f in dataclasses.fields(CarParams))
DEFAULT_EPSILON = 0.1  # m: a card without a calibrated margin


def paths(stem: str | Path) -> tuple[Path, Path]:
    """(weights, card) of a model stem; accepts the stem or either file's path."""
    stem = Path(stem)
    if stem.suffix in (".safetensors", ".json"):
        stem = stem.with_suffix("")
    return stem.with_name(stem.name + ".safetensors"), stem.with_name(stem.name + ".json")


def load_card(stem: str | Path) -> dict:
    """The card's JSON as a dict (writers and tests); ValueError unless it is an hjrno card with the
    required fields."""
    _, card_path = paths(stem)
    if not card_path.is_file():
        raise ValueError(f"model card {card_path} not found")
    try:
        card = json.loads(card_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ValueError(f"model card {card_path} is not valid JSON ({err})") from None
    if not isinstance(card, dict) or card.get("format") != CARD_FORMAT:
        found = card.get("format") if isinstance(card, dict) else None
        raise ValueError(f"{card_path} is not an hjrno model card (format {found!r})")
    missing = [k for k in REQUIRED if k not in card]
    if missing:
        raise ValueError(f"model card {card_path} lacks {missing}")
    return card


def _field(d: dict, name: str, kind: type | tuple, where: str) -> Any:
    if name not in d:
        raise ValueError(f"{where}: field '{name}' is missing")
    value = d[name]
    if not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
        raise ValueError(f"{where}: field '{name}' has the wrong type ({type(value).__name__})")
    return value


def _margin(value: Any, name: str, where: str) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value < 0:
        raise ValueError(f"{where}: field '{name}' must be a finite number >= 0 or null, got {value!r}")
    return float(value)


@dataclasses.dataclass(frozen=True)
class ModelCard:
    """The fields every reader needs, typed and validated; ``data`` is the whole JSON."""

    kind: str
    config: dict
    inputs: dict
    grid: GridSpec  # the value grid (x, y, v, θ) the model predicts on
    window: tuple[float, float]  # x-y extent of the grid, m
    dynamics: CarParams
    epsilon: float | None  # calibrated margin for the operator's value, m
    refine_epsilon: float | None  # calibrated margin for solver-refined tables, m
    refine_horizon: float | None  # simulated s of refinement from which refine_epsilon holds
    symmetry_average: bool
    member_frames: list | None
    metrics: dict
    dataset: dict
    command: str | None
    data: dict
    source: Path

    @classmethod
    def from_dict(cls, d: dict, source: str | Path = "<card>") -> ModelCard:
        where = str(source)
        if not isinstance(d, dict) or d.get("format") != CARD_FORMAT:
            found = d.get("format") if isinstance(d, dict) else None
            raise ValueError(f"{where} is not an hjrno model card (format {found!r})")
        kind = _field(d, "kind", str, where)
        if kind not in KINDS:
            raise ValueError(f"{where}: field 'kind' must be one of {KINDS}, got {kind!r}")
        config = _field(d, "config", dict, where)
        inputs = _field(d, "inputs", dict, where)
        _field(inputs, "channels", list, f"{where} inputs")
        grid_d = _field(d, "grid", dict, where)
        for name in ("lo", "hi", "shape"):
            _field(grid_d, name, list, f"{where} grid")
        try:
            grid = GridSpec.from_dict(grid_d)
        except (ValueError, TypeError) as err:
            raise ValueError(f"{where}: field 'grid' is invalid ({err})") from None
        if grid.ndim != 4 or grid.periodic != (3,):
            raise ValueError(f"{where}: field 'grid' must be an (x, y, v, theta) grid with theta periodic, got "
                             f"shape {grid.shape}, periodic {grid.periodic}")
        dyn = _field(d, "dynamics", dict, where)
        missing = [k for k in DYNAMICS_FIELDS if k not in dyn]
        if missing:
            raise ValueError(f"{where}: field 'dynamics.{missing[0]}' is missing")
        try:
            dynamics = CarParams(**{k: float(dyn[k]) for k in DYNAMICS_FIELDS})
        except (ValueError, TypeError) as err:
            raise ValueError(f"{where}: field 'dynamics' is invalid ({err})") from None
        if abs(grid.lo[2] - dynamics.v_min) > 1e-9 or abs(grid.hi[2] - dynamics.v_max) > 1e-9:
            raise ValueError(f"{where}: field 'grid' speed axis [{grid.lo[2]:g}, {grid.hi[2]:g}] differs from "
                             f"dynamics [v_min, v_max] = [{dynamics.v_min:g}, {dynamics.v_max:g}]")
        refine = d.get("refine_calibration") or {}
        refine_eps = _margin(d.get("refine_epsilon"), "refine_epsilon", where)
        horizon = refine.get("horizon_s") if isinstance(refine, dict) else None
        if refine_eps is not None and not isinstance(horizon, int | float):
            refine_eps = None  # a refine_epsilon is only usable with the stage it was calibrated at
        frames = d.get("member_frames")
        return cls(kind=kind, config=config, inputs=inputs, grid=grid,
                   window=(grid.hi[0] - grid.lo[0], grid.hi[1] - grid.lo[1]), dynamics=dynamics,
                   epsilon=_margin(d.get("epsilon"), "epsilon", where), refine_epsilon=refine_eps,
                   refine_horizon=float(horizon) if refine_eps is not None else None,
                   symmetry_average=bool(d.get("symmetry_average", False)),
                   member_frames=frames if frames else None, metrics=dict(d.get("metrics") or {}),
                   dataset=dict(d.get("dataset") or {}), command=d.get("command"), data=d, source=Path(source))

    @classmethod
    def load(cls, stem: str | Path) -> ModelCard:
        return cls.from_dict(load_card(stem), paths(stem)[1])

    def margin(self) -> float:
        """ε for the operator's value: the calibrated one, else :data:`DEFAULT_EPSILON`."""
        return self.epsilon if self.epsilon is not None else DEFAULT_EPSILON

    def refined_margin(self, horizon: float) -> float | None:
        """ε for a table refined ``horizon`` simulated seconds: ``refine_epsilon`` from its calibrated stage
        on, before that (or without one) the operator's calibrated ε (None if uncalibrated)."""
        if self.refine_epsilon is not None and horizon >= self.refine_horizon:
            return self.refine_epsilon
        return self.epsilon
