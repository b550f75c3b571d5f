"""Where the node finds its model: a path, or a bundled model by name in the checkout or the install."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np

import hjrno_ros
from hjrno_ros.core.model_card import ModelCard, paths
from hjrno_ros.core.operator_values import OperatorValues
from hjrno_ros.core.scaled_values import ScaledValueFunction, covered_scaling, filter_params
from hjrno_ros.core.tracked_agents import AgentTable, read_agent_table, robot_options
from hjrno_ros.core.value_source import ValueSource
from hjrno_ros.ros.brt_node.config import NodeConfig
from hjrno_ros.ros.brt_node.robot import robot_params


def bundled_model_candidates(name: str = "default") -> list[Path]:
    """Where the bundled model ``name`` is looked for: the source checkout, then the package's share folder
    (ament index via AMENT_PREFIX_PATH, the install prefix this module lives in, sys.prefix)."""
    package = Path(hjrno_ros.__file__).resolve().parent  # the source tree's or site-packages' hjrno_ros/
    shares = []
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

        try:
            shares.append(Path(get_package_share_directory("hjrno_ros")))
        except (PackageNotFoundError, OSError, ValueError):  # OSError: AMENT_PREFIX_PATH unset
            pass
    except ImportError:
        pass
    if package.parent.name == "site-packages":  # <prefix>/lib/pythonX.Y/site-packages/hjrno_ros
        shares.append(package.parents[3] / "share" / "hjrno_ros")
    shares.append(Path(sys.prefix) / "share" / "hjrno_ros")
    candidates = [package.parent / "models" / name] + [share / "models" / name for share in shares]
    return list(dict.fromkeys(candidates))


def resolve_model(model_path: str) -> Path:
    """The model stem to load: a path to a model, or the name of a bundled one ('' = ``default``, e.g. ``v5``);
    ValueError when no such bundled model is found."""
    if model_path and ("/" in model_path or paths(Path(model_path).expanduser())[1].is_file()):
        return Path(model_path).expanduser()
    name = model_path or "default"
    for stem in bundled_model_candidates(name):
        if paths(stem)[1].is_file():
            return stem
    looked = ", ".join(str(p) for p in bundled_model_candidates(name))
    raise ValueError(f"no bundled model {name!r} found (looked for {looked}); set the model_path parameter "
                     "to a model stem")


AGENT_LIMITS = ("a_max", "omega_max", "v_min", "v_max", "tracking_error")  # the table's robot must be the node's


def load_agent_table(cfg: NodeConfig, robot: Any) -> AgentTable | None:
    """The tracked agents' relative value tables of ``agent_table`` (None for ''), checked against the node's
    ``robot``: they were solved for one robot's limits, which ``hjrno agents`` makes for another.  ValueError, one
    line."""
    if not cfg.agent_table:
        if any(source.type == "agents" for source in cfg.sources):
            raise ValueError("an 'agents' observation source needs the agent_table parameter (hjrno agents makes one)")
        if any(source.track_people for source in cfg.sources):
            raise ValueError("a scan source with track_people needs the agent_table parameter (hjrno agents makes one)")
        return None
    stem = resolve_model(cfg.agent_table)
    table = read_agent_table(stem)
    theirs = {k: table.robot.get(k) for k in AGENT_LIMITS}
    ours = {k: getattr(robot, k, None) for k in AGENT_LIMITS}
    if any(not isinstance(theirs[k], int | float) or abs(theirs[k] - ours[k]) > 1e-6 * max(1.0, abs(ours[k]))
           for k in AGENT_LIMITS):
        raise ValueError(f"agent table {stem} was solved for a robot with {theirs}, the node's has {ours}: make one "
                         f"for this robot with `hjrno agents {robot_options(robot, cfg.footprint_radius)} --out STEM`")
    return table


class SolverGrid:
    """A solver card's :class:`~hjrno_ros.core.value_source.ValueSource`: the grid, the robot and the window of the
    published value grid, but no operator (``predicts`` False): values come from the solver's refined table only."""

    whole_table, predicts, runtime = False, False, "solver"

    def __init__(self, card: ModelCard) -> None:
        self.card, self.grid, self.params, self.window = card, card.grid, card.dynamics, card.window
        self.shape = tuple(card.grid.shape[:2])

    def window_points(self, center: tuple[float, float], shape: tuple[int, int] | None = None) -> np.ndarray:
        nx, ny = shape or self.shape
        x = np.linspace(self.grid.lo[0], self.grid.hi[0], nx) + center[0]
        y = np.linspace(self.grid.lo[1], self.grid.hi[1], ny) + center[1]
        return np.stack(np.meshgrid(x, y, indexing="ij"), -1)

    def local_table(self, *args: Any, **kwargs: Any) -> Any:
        raise TypeError("a solver card has no operator: its tables come from the node's solver")


def load_model(cfg: NodeConfig) -> tuple[ModelCard, ValueSource, Path]:
    """(card, learned value function, stem) for the node's parameters; the card is checked before the network is
    loaded.  The network runs on onnxruntime when the card lists an ONNX export (no torch in the process), else on
    torch (``inference_runtime`` chooses).  A solver card needs ``refine_horizon`` > 0 and loads no weights.
    ValueError, one line."""
    stem = resolve_model(cfg.model_path)
    card = ModelCard.load(stem)
    if card.kind == "solver":
        if robot_params(card.dynamics, cfg) != card.dynamics:
            raise ValueError(f"{stem} is a solver card: write the robot's limits into the card, not the parameters")
        if cfg.refine_horizon <= 0:
            raise ValueError(f"{stem} is a solver card (no weights): set refine_horizon > 0 (simulated s of the "
                             "solver over the map)")
        return card, SolverGrid(card), stem
    robot = robot_params(card.dynamics, cfg)
    scaling = covered_scaling(card.dynamics, robot, card.inputs.get("param_ranges"))
    robot = filter_params(card.dynamics, robot)
    scaled = robot != card.dynamics
    if scaled and cfg.refine_horizon > 0:
        raise ValueError("refine_horizon needs the model card's own car (the refinement solves its dynamics); "
                         f"the robot is {scaling.length:.4g} times its size with limits {robot}")
    vf = operator_values(stem, card, cfg)
    if scaled:
        vf = ScaledValueFunction(vf, scaling, robot)
    return card, vf, stem


def operator_values(stem: Path, card: ModelCard, cfg: NodeConfig) -> OperatorValues:
    """The card's network on onnxruntime (``inference_runtime`` onnx, or auto with an ONNX export in the card) or on
    torch (imported only then: seconds and hundreds of MB)."""
    threads = int(cfg.inference_threads)
    if cfg.inference_runtime == "onnx" or cfg.inference_runtime == "auto" and card.onnx is not None:
        from hjrno_ros.inference.onnx_operator import onnx_values

        return onnx_values(stem, card, cfg.device, threads)
    try:
        from hjrno_ros.learning.value_function import LearnedValueFunction
    except ImportError as err:
        raise ValueError(f"{stem}: its card lists no ONNX export and torch is not installed ({err})") from None
    try:
        return LearnedValueFunction(stem, device=cfg.device or None, threads=threads)
    except (ValueError, KeyError, TypeError, OSError) as err:
        raise ValueError(f"cannot load model {stem}: {err}") from None
