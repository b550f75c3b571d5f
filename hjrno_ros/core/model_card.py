"""The model card: one typed view of ``<stem>.json``, read by the node, the learning code and the studies.

A model on disk is ``<stem>.safetensors`` (tensors only) plus ``<stem>.json`` (this card).  The
card says what the weights were trained for: architecture (``kind``, ``config``), input channels
(``inputs``), the value grid and window (``grid``, ``window`` its x-y part), the robot model the weights
were trained for (``dynamics``: ``model`` names the equations, the other fields are its parameters; a card
from before the product model lists the paper car's {a_max, kappa_max, d_max, v_min, v_max} and reads as
the paper model; an Air3D model's speeds and turn rates), the calibrated
margins (``epsilon``; ``refine_epsilon`` from the refined stage ``refine_calibration.horizon_s``),
metrics, data, the command that reproduces it, and the network's ONNX export (``onnx``: file beside the card, its
SHA-256, input and output names and shapes) for runtimes without torch.  Reading it never imports torch: the
node checks a card before it pays for loading weights.  Every problem is one ``ValueError`` line naming the field.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

from hjrno_ros.core.dynamics import LEGACY_CAR_FIELDS, ROBOT_MODELS, Air3DParams, CarParams, RobotParams
from hjrno_ros.core.grids import GridSpec

CARD_FORMAT = "hjrno-model-1"
REQUIRED = ("format", "kind", "config", "inputs", "grid", "dynamics")
KINDS = ("fno", "tno", "cnn", "ensemble", "solver")  # "solver": no weights, the HJ solver computes V (small maps)
DYNAMICS_FIELDS = ("model", *(f.name for f in dataclasses.fields(CarParams)))  # a car card's dynamics
DEFAULT_EPSILON = 0.1  # m: a card without a calibrated margin
# inputs.kind -> (dynamics class, grid axes, periodic axis, its name); the filter takes "car" models only
FAMILIES = {"car": (CarParams, 4, 3, "(x, y, v, theta)"), "air3d": (Air3DParams, 3, 2, "(x, y, psi)")}


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


def _field(d: dict, name: str, kind: type | tuple, where: str, prefix: str = "") -> Any:
    """``d[name]`` if it has type ``kind``; else ValueError naming ``prefix + name``."""
    if name not in d:
        raise ValueError(f"{where}: field '{prefix}{name}' is missing")
    value = d[name]
    if not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
        raise ValueError(f"{where}: field '{prefix}{name}' has the wrong type ({type(value).__name__})")
    return value


def _optional(d: dict, name: str, kind: type | tuple, where: str, default: Any) -> Any:
    """``d[name]`` if it has type ``kind``, ``default`` if absent or null; else ValueError naming it."""
    if d.get(name) is None:
        return default
    return _field(d, name, kind, where)


def _numbers(values: Any, name: str, where: str, kind: type | tuple = (int, float)) -> list:
    if not isinstance(values, list) or not values or any(
            isinstance(v, bool) or not isinstance(v, kind) for v in values):
        raise ValueError(f"{where}: field '{name}' must be a non-empty list of {getattr(kind, '__name__', 'number')}s, "
                         f"got {values!r}")
    return values


def _margin(value: Any, name: str, where: str) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value < 0:
        raise ValueError(f"{where}: field '{name}' must be a finite number >= 0 or null, got {value!r}")
    return float(value)


@dataclasses.dataclass(frozen=True)
class OnnxFile:
    """The network exported to ONNX (the card's ``onnx``): ``file`` beside the card, its ``sha256``, the input and
    output tensors' names and shapes ("batch": the dynamic first axis), the opset, and what it was exported from
    (``network``: the weights' SHA-256 and the card's ``symmetry_average`` and ``member_frames`` then, so an export
    that predates new weights or a new wrapping is refused)."""

    file: str
    sha256: str
    input_name: str
    input_shape: tuple
    output_name: str
    output_shape: tuple
    opset: int
    network: dict

    def as_dict(self) -> dict:
        return {"file": self.file, "sha256": self.sha256, "input": {"name": self.input_name,
                                                                    "shape": list(self.input_shape)},
                "output": {"name": self.output_name, "shape": list(self.output_shape)}, "opset": self.opset,
                "network": dict(self.network)}


def _onnx(d: dict, where: str, channels: tuple[int, int], shape: tuple[int, int]) -> OnnxFile | None:
    """The card's ``onnx`` entry, checked against its own ``channels`` (in, out) and x-y ``shape``; None if absent."""
    entry = _optional(d, "onnx", dict, where, None)
    if entry is None:
        return None
    name = _field(entry, "file", str, where, "onnx.")
    digest = _field(entry, "sha256", str, where, "onnx.")
    if not name.endswith(".onnx") or Path(name).name != name:
        raise ValueError(f"{where}: field 'onnx.file' must be a file name ending in .onnx, got {name!r}")
    if len(digest) != 64 or any(c not in "0123456789abcdef" for c in digest):
        raise ValueError(f"{where}: field 'onnx.sha256' must be 64 lowercase hex digits, got {digest!r}")
    tensors = []
    for part, channel in (("input", channels[0]), ("output", channels[1])):
        t = _field(entry, part, dict, where, "onnx.")
        expected = ["batch", channel, *shape]
        if _field(t, "shape", list, where, f"onnx.{part}.") != expected:
            raise ValueError(f"{where}: field 'onnx.{part}.shape' is {t['shape']!r}, but the card's config, inputs "
                             f"and grid give {expected!r}")
        tensors.append((_field(t, "name", str, where, f"onnx.{part}."), tuple(expected)))
    network = _field(entry, "network", dict, where, "onnx.")
    return OnnxFile(name, digest, *tensors[0], *tensors[1], _field(entry, "opset", int, where, "onnx."), network)


def _refine_stage(d: dict, where: str = "<card>") -> tuple[float, float] | None:
    """(``refine_epsilon``, the refined stage ``refine_calibration.horizon_s`` it was calibrated at) of a card's
    dict, or None without both: a refine_epsilon only holds from the stage it was calibrated at."""
    eps = _margin(d.get("refine_epsilon"), "refine_epsilon", where)
    refine = d.get("refine_calibration")
    horizon = refine.get("horizon_s") if isinstance(refine, dict) else None
    if eps is None or isinstance(horizon, bool) or not isinstance(horizon, int | float):
        return None
    return eps, float(horizon)


def _grid(d: dict, where: str, family: str) -> GridSpec:
    grid_d = _field(d, "grid", dict, where)
    for name in ("lo", "hi", "shape"):
        _field(grid_d, name, list, where, "grid.")
        _numbers(grid_d[name], f"grid.{name}", where, int if name == "shape" else (int, float))
    try:
        grid = GridSpec.from_dict(grid_d)
    except (ValueError, TypeError) as err:
        raise ValueError(f"{where}: field 'grid' is invalid ({err})") from None
    _, ndim, periodic, axes = FAMILIES[family]
    if grid.ndim != ndim or grid.periodic != (periodic,):
        raise ValueError(f"{where}: field 'grid' must be an {axes} grid with axis {periodic} periodic for a "
                         f"{family} model, got shape {grid.shape}, periodic {grid.periodic}")
    window = d.get("window")
    if window is not None:  # the x-y part of the grid, written next to it: they must agree
        if not isinstance(window, dict):
            raise ValueError(f"{where}: field 'window' has the wrong type ({type(window).__name__})")
        for name in ("lo", "hi", "shape"):
            value = _field(window, name, list, where, "window.")
            expect = getattr(grid, name)[:2]
            if len(value) != 2 or any(isinstance(v, bool) or not isinstance(v, int | float) or abs(v - e) > 1e-9
                                      for v, e in zip(value, expect, strict=False)):
                raise ValueError(f"{where}: field 'window.{name}' is {value!r}, the grid's x-y {name} is "
                                 f"{list(expect)}")
    return grid


def _dynamics(d: dict, where: str, family: str) -> RobotParams | Air3DParams:
    """The card's robot model.  A ground-robot card names it (``dynamics.model``: the car, :data:`DYNAMICS_FIELDS`,
    or the differential drive with ``omega_max`` for ``kappa_max``); one without ``model`` is a paper-model card
    {a_max, kappa_max, d_max, v_min, v_max} (d₀ = d_max, δ = 0)."""
    cls = FAMILIES[family][0]
    dyn = _field(d, "dynamics", dict, where)
    names = [f.name for f in dataclasses.fields(cls)]
    if cls is CarParams:
        if "model" in dyn or "d0" in dyn or "tracking_error" in dyn:
            model = _field(dyn, "model", str, where, "dynamics.")
            if model not in ROBOT_MODELS:
                raise ValueError(f"{where}: field 'dynamics.model' must be one of {sorted(ROBOT_MODELS)}, got "
                                 f"{model!r}")
            cls = ROBOT_MODELS[model]
            names = [f.name for f in dataclasses.fields(cls)]
        else:
            names = list(LEGACY_CAR_FIELDS)
    for name in names:
        value = _field(dyn, name, (int, float), where, "dynamics.")
        if not math.isfinite(value):
            raise ValueError(f"{where}: field 'dynamics.{name}' must be finite, got {value!r}")
    try:
        return cls(**{name: float(dyn[name]) for name in names})
    except (ValueError, TypeError) as err:
        raise ValueError(f"{where}: field 'dynamics' is invalid ({err})") from None


@dataclasses.dataclass(frozen=True)
class ModelCard:
    """The fields every reader needs, typed and validated; ``data`` is the whole JSON."""

    kind: str
    config: dict
    inputs: dict
    grid: GridSpec  # the value grid (x, y, v, θ) the model predicts on
    window: tuple[float, float]  # x-y extent of the grid, m
    dynamics: RobotParams | Air3DParams  # the robot model the weights were trained for (the filter's model):
    # CarParams or DiffDriveParams for a ground robot (inputs.kind "car"), the filter's only kind
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
    parameters: int | None = None  # trainable real scalars (count_parameters), as training recorded them
    onnx: OnnxFile | None = None  # the network exported to ONNX, when the card lists it
    training: dict = dataclasses.field(default_factory=dict)  # training facts: wall_s, peak_rss_mb, history, ...

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
        family = _field(inputs, "kind", str, where, "inputs.")
        if family not in FAMILIES:
            raise ValueError(f"{where}: field 'inputs.kind' must be one of {tuple(FAMILIES)}, got {family!r}")
        channels = _field(inputs, "channels", list, where, "inputs.")
        if kind == "solver" and family == "car":  # a solver card has no operator inputs
            channels = None
        elif not channels or not all(isinstance(c, str) for c in channels):
            raise ValueError(f"{where}: field 'inputs.channels' must be a non-empty list of names, got {channels!r}")
        in_channels = _field(config, "in_channels", int, where, "config.") if channels is not None else 0
        if channels is not None and in_channels != len(channels):
            raise ValueError(f"{where}: field 'config.in_channels' is {in_channels}, but inputs.channels lists "
                             f"{len(channels)}: {channels}")
        grid = _grid(d, where, family)
        dynamics = _dynamics(d, where, family)
        if family == "car":
            if abs(grid.lo[2] - dynamics.v_min) > 1e-9 or abs(grid.hi[2] - dynamics.v_max) > 1e-9:
                raise ValueError(f"{where}: field 'grid' speed axis [{grid.lo[2]:g}, {grid.hi[2]:g}] differs from "
                                 f"dynamics [v_min, v_max] = [{dynamics.v_min:g}, {dynamics.v_max:g}]")
            v_range = inputs.get("v_range")
            if v_range is not None and (len(_numbers(v_range, "inputs.v_range", where)) != 2 or any(
                    abs(a - b) > 1e-9 for a, b in zip(v_range, (grid.lo[2], grid.hi[2]), strict=True))):
                raise ValueError(f"{where}: field 'inputs.v_range' {v_range!r} differs from the grid's speed axis "
                                 f"[{grid.lo[2]:g}, {grid.hi[2]:g}]")
        stage = _refine_stage(d, where)
        frames = _optional(d, "member_frames", list, where, None)
        command = _optional(d, "command", str, where, None)
        table = inputs.get("table")
        if table is not None and not (isinstance(table, list) and len(table) == 2 and all(
                isinstance(n, int) and not isinstance(n, bool) and n > 0 for n in table)):
            raise ValueError(f"{where}: field 'inputs.table' must be two positive integers (nv, ntheta), got "
                             f"{table!r}")
        out_channels = table[0] * table[1] if table else 1
        onnx = _onnx(d, where, (in_channels, out_channels), tuple(grid.shape[:2])) if kind != "solver" else None
        return cls(kind=kind, config=config, inputs=inputs, grid=grid,
                   window=(grid.hi[0] - grid.lo[0], grid.hi[1] - grid.lo[1]), dynamics=dynamics,
                   epsilon=_margin(d.get("epsilon"), "epsilon", where),
                   refine_epsilon=stage[0] if stage else None, refine_horizon=stage[1] if stage else None,
                   symmetry_average=_optional(d, "symmetry_average", bool, where, False),
                   member_frames=frames if frames else None,
                   metrics=dict(_optional(d, "metrics", dict, where, {})),
                   dataset=dict(_optional(d, "dataset", dict, where, {})), command=command, data=d,
                   source=Path(source), parameters=_optional(d, "parameters", int, where, None),
                   training=dict(_optional(d, "training", dict, where, {})), onnx=onnx)

    @classmethod
    def solver(cls, dynamics: RobotParams, cell: float, speeds: int = 9, headings: int = 16, window: float = 10.0,
               epsilon: float = DEFAULT_EPSILON) -> dict:
        """A solver card's JSON: the car ``dynamics`` on an x-y grid of ``cell`` m (a ``window`` m square around
        the robot for the published value grid) with ``speeds`` × ``headings`` nodes; no weights.  The node
        then filters with the HJ solver's table over the whole map (background refinement from the target)."""
        n = int(round(window / cell)) + 1
        grid = {"lo": [-window / 2, -window / 2, dynamics.v_min, -math.pi],
                "hi": [window / 2, window / 2, dynamics.v_max, math.pi], "shape": [n, n, speeds, headings],
                "periodic": [3]}
        return {"format": CARD_FORMAT, "kind": "solver", "config": {}, "inputs": {"kind": "car", "channels": []},
                "grid": grid, "window": {"lo": grid["lo"][:2], "hi": grid["hi"][:2], "shape": [n, n]},
                "dynamics": dynamics.as_dict(), "epsilon": float(epsilon),
                "command": "ModelCard.solver(...)"}

    @classmethod
    def load(cls, stem: str | Path) -> ModelCard:
        return cls.from_dict(load_card(stem), paths(stem)[1])

    @property
    def family(self) -> str:
        """``inputs.kind``: "car" (x, y, v, θ) or "air3d" (x, y, ψ)."""
        return self.inputs["kind"]

    def margin(self) -> float:
        """ε for the operator's value: the calibrated one, else :data:`DEFAULT_EPSILON`."""
        return self.epsilon if self.epsilon is not None else DEFAULT_EPSILON

    def refined_margin(self, horizon: float) -> float | None:
        """ε for a table refined ``horizon`` simulated seconds: ``refine_epsilon`` from its calibrated stage
        on, before that (or without one) the operator's calibrated ε (None if uncalibrated)."""
        if self.refine_epsilon is not None and horizon >= self.refine_horizon:
            return self.refine_epsilon
        return self.epsilon
