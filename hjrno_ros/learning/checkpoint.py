"""Models on disk: safetensors weights plus a JSON model card, nothing else.

``<stem>.safetensors`` holds tensors only (no code, no pickle); ``<stem>.json`` holds the
architecture and its config, input normalisation, window and grid, dynamics parameters, the
dataset, training facts, metrics and the command that reproduces the model.  Both are written
atomically; loading refuses anything that is not such a pair, with a one-line reason.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from hjrno_ros.core.atomic import atomic_write
from hjrno_ros.core.model_card import CARD_FORMAT, REQUIRED, ModelCard, load_card, paths  # noqa: F401  (re-exported)


def save(stem: str | Path, tensors: dict[str, torch.Tensor], card: dict) -> tuple[Path, Path]:
    """Write weights (any flat dict of tensors) and the card; returns their paths."""
    weights, card_path = paths(stem)
    card = {"format": CARD_FORMAT, **card}
    missing = [k for k in REQUIRED if k not in card]
    if missing:
        raise ValueError(f"model card lacks {missing}")
    flat = {k: v.detach().contiguous().cpu() for k, v in tensors.items()}
    atomic_write(weights, lambda tmp: save_file(flat, tmp, metadata=trained_for(card)))
    return weights, _write_card(card_path, card)


TRAINED_FOR = ("grid", "window", "dynamics", "inputs")  # recorded in the weights' metadata, checked against the card


def trained_for(card: dict) -> dict[str, str]:
    """The safetensors metadata of a model's weights: the format and what they were trained for, so a card
    edited afterwards (another grid, window, robot or inputs) is refused at load instead of running on."""
    return {"format": CARD_FORMAT, **{k: json.dumps(card[k], sort_keys=True) for k in TRAINED_FOR if k in card}}


def check_trained_for(stem: str | Path, card: dict) -> None:
    """ValueError naming the first card field that contradicts the weights' record (weights saved before the
    record existed carry none and pass)."""
    from safetensors import safe_open

    weights = paths(stem)[0]
    try:
        with safe_open(str(weights), "pt") as f:
            meta = f.metadata() or {}
    except (SafetensorError, OSError, ValueError, RuntimeError) as err:
        raise ValueError(f"{weights} is not a readable safetensors file ({str(err).splitlines()[0]})") from None
    for key in TRAINED_FOR:
        if key in meta and json.loads(meta[key]) != json.loads(json.dumps(card.get(key), sort_keys=True)):
            raise ValueError(f"{paths(stem)[1]}: field '{key}' is {json.dumps(card.get(key))}, but the weights "
                             f"were trained for {meta[key]}")


def _write_card(path: Path, card: dict) -> Path:
    text = json.dumps(card, indent=1, sort_keys=False)
    atomic_write(path, lambda tmp: Path(tmp).write_text(text))
    return path


def folders_with_test_split(card: dict | ModelCard) -> list[str]:
    """The dataset folders of a card (its dict or :class:`ModelCard`) that hold a test split (cards before
    ``test_folders``: all)."""
    dataset = card.dataset if isinstance(card, ModelCard) else card["dataset"]
    if "folders" not in dataset:
        raise ValueError(f"{getattr(card, 'source', 'model card')}: field 'dataset.folders' is missing")
    return list(dataset.get("test_folders", dataset["folders"]))


def update_card(stem: str | Path, changes: dict) -> Path:
    """Merge ``changes`` into an existing model card (atomically; the weights are untouched)."""
    return _write_card(paths(stem)[1], {**load_card(stem), **changes})


def load_tensors(stem: str | Path) -> dict[str, torch.Tensor]:
    weights, _ = paths(stem)
    if not weights.is_file():
        raise ValueError(f"model weights {weights} not found")
    try:
        return load_file(weights)
    except (SafetensorError, OSError, ValueError, RuntimeError) as err:
        raise ValueError(f"{weights} is not a readable safetensors file ({str(err).splitlines()[0]})") from None


def load_model(stem: str | Path, device: str | torch.device = "cpu", average: bool | None = None,
               frames: list | None = None) -> tuple[torch.nn.Module, dict]:
    """(model in eval mode, the card's dict) from a safetensors + JSON pair; ValueError on anything else.
    As :func:`load_typed`, for callers that copy or rewrite the card."""
    model, card = load_typed(stem, device, average, frames)
    return model, card.data


def load_typed(stem: str | Path, device: str | torch.device = "cpu", average: bool | None = None,
               frames: list | None = None) -> tuple[torch.nn.Module, ModelCard]:
    """(model in eval mode, its :class:`ModelCard`) from a safetensors + JSON pair; ValueError on anything else:
    a card that :meth:`ModelCard.from_dict` refuses, input channels that are not the ones its ``inputs`` give,
    weights of another architecture than ``kind`` and ``config`` (other input channels included).

    ``average``: wrap the model in :class:`~hjrno_ros.learning.operators.average.SymmetryAverage`
    (default: as the card's ``symmetry_average`` says, which ``hjrno calibrate`` records);
    ``frames``: an ensemble's member frames (:func:`framed_members`; default: the card's ``member_frames``)."""
    from hjrno_ros.learning.operators import build_model
    from hjrno_ros.learning.slices import InputSpec

    weights, source = paths(stem)
    card = ModelCard.load(stem)
    channels = card.inputs["channels"]
    try:
        implied = InputSpec.from_dict(card.inputs).channels
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"{source}: field 'inputs' is invalid ({type(err).__name__}: {err})") from None
    if implied != channels:
        raise ValueError(f"{source}: field 'inputs.channels' is {channels}, but a {card.family} model with "
                         f"param_ranges {list(card.inputs.get('param_ranges', {}))} reads {implied}")
    model = build_model(card.kind, **card.config)
    if model.in_channels != len(channels):
        raise ValueError(f"{source}: the {card.kind} built from field 'config' takes {model.in_channels} input "
                         f"channels, inputs.channels lists {len(channels)}")
    tensors = {k[len("model."):]: v for k, v in load_tensors(stem).items() if k.startswith("model.")}
    expected = model.state_dict()
    if set(tensors) != set(expected):
        odd = sorted(set(tensors) ^ set(expected))
        raise ValueError(f"{weights} does not match the architecture in its model card ({len(odd)} tensor names "
                         f"differ, e.g. {odd[0]!r})")
    wrong = [k for k in expected if tensors[k].shape != expected[k].shape]
    if wrong:
        k = wrong[0]
        raise ValueError(f"{weights} does not match the architecture in its model card ({k}: weights "
                         f"{tuple(tensors[k].shape)}, card {tuple(expected[k].shape)}; input channels: card "
                         f"{len(channels)})")
    check_trained_for(stem, card.data)
    model.load_state_dict(tensors)
    frames = card.member_frames if frames is None else frames
    if frames:
        framed_members(model, card, frames)
    if card.symmetry_average if average is None else average:
        model = symmetry_averaged(model, card)
    return model.to(device).eval(), card


def framed_members(model: torch.nn.Module, card: ModelCard, frames: list) -> None:
    """``frames`` (the card's ``member_frames``: one list of D4 elements per ensemble member, as in
    :func:`hjrno_ros.learning.slices.symmetry`): each member predicts in those frames and is averaged over
    them, so members err in different frames at the cost of one pass per listed element."""
    members = getattr(model, "members", None)
    if card.kind != "ensemble" or not isinstance(frames, list) or len(frames) != len(members):
        raise ValueError(f"{card.source}: member_frames needs an ensemble and one list per member, got {frames!r}")
    for i, ks in enumerate(frames):
        if (not isinstance(ks, list) or not ks or len(set(ks)) != len(ks)
                or not all(isinstance(k, int) and not isinstance(k, bool) and 0 <= k < 8 for k in ks)):
            raise ValueError(f"{card.source}: member_frames[{i}] must be distinct D4 elements 0..7, got {ks!r}")
        members[i] = symmetry_averaged(members[i], card, tuple(ks))


def symmetry_averaged(model: torch.nn.Module, card: ModelCard,
                      elements: tuple[int, ...] = tuple(range(8))) -> torch.nn.Module:
    """``model`` averaged over the square's symmetries (or ``elements`` of them); ValueError unless it is
    a car model on a square window."""
    from hjrno_ros.learning.operators.average import SymmetryAverage

    channels = card.inputs["channels"]
    if "cos_theta" not in channels:
        raise ValueError(f"{card.source}: symmetry averaging is for car models, this one is {card.family!r}")
    (nx, ny), (wx, wy) = card.grid.shape[:2], card.window
    if nx != ny or abs(wx - wy) > 1e-9:
        raise ValueError(f"{card.source}: symmetry averaging needs a square x-y window, this one has {nx} x "
                         f"{ny} nodes over {wx:g} m x {wy:g} m")
    return SymmetryAverage(model, channels.index("cos_theta"), channels.index("sin_theta"), elements=elements)
