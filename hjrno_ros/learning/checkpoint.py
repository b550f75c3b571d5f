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
from hjrno_ros.core.model_card import CARD_FORMAT, REQUIRED, load_card, paths  # noqa: F401  (re-exported)


def save(stem: str | Path, tensors: dict[str, torch.Tensor], card: dict) -> tuple[Path, Path]:
    """Write weights (any flat dict of tensors) and the card; returns their paths."""
    weights, card_path = paths(stem)
    card = {"format": CARD_FORMAT, **card}
    missing = [k for k in REQUIRED if k not in card]
    if missing:
        raise ValueError(f"model card lacks {missing}")
    flat = {k: v.detach().contiguous().cpu() for k, v in tensors.items()}
    atomic_write(weights, lambda tmp: save_file(flat, tmp, metadata={"format": CARD_FORMAT}))
    return weights, _write_card(card_path, card)


def _write_card(path: Path, card: dict) -> Path:
    text = json.dumps(card, indent=1, sort_keys=False)
    atomic_write(path, lambda tmp: Path(tmp).write_text(text))
    return path


def folders_with_test_split(card: dict) -> list[str]:
    """The dataset folders of a card that hold a test split (cards before ``test_folders``: all)."""
    return list(card["dataset"].get("test_folders", card["dataset"]["folders"]))


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
    """(model in eval mode, card) from a safetensors + JSON pair; ValueError on anything else.

    ``average``: wrap the model in :class:`~hjrno_ros.learning.operators.average.SymmetryAverage`
    (default: as the card's ``symmetry_average`` says, which ``hjrno calibrate`` records);
    ``frames``: an ensemble's member frames (:func:`framed_members`; default: the card's ``member_frames``)."""
    from hjrno_ros.learning.operators import build_model

    card = load_card(stem)
    model = build_model(card["kind"], **card["config"])
    tensors = {k[len("model."):]: v for k, v in load_tensors(stem).items() if k.startswith("model.")}
    expected = model.state_dict()
    if set(tensors) != set(expected) or any(tensors[k].shape != expected[k].shape for k in expected):
        raise ValueError(f"{paths(stem)[0]} does not match the architecture in its model card")
    model.load_state_dict(tensors)
    frames = card.get("member_frames") if frames is None else frames
    if frames:
        framed_members(model, {**card, "member_frames": frames}, paths(stem)[1])
    if card.get("symmetry_average", False) if average is None else average:
        model = symmetry_averaged(model, card, paths(stem)[1])
    return model.to(device).eval(), card


def framed_members(model: torch.nn.Module, card: dict, source: Path) -> None:
    """The card's ``member_frames`` (one list of D4 elements per ensemble member, as in
    :func:`hjrno_ros.learning.slices.symmetry`): each member predicts in those frames and is averaged over
    them, so members err in different frames at the cost of one pass per listed element."""
    frames = card["member_frames"]
    members = getattr(model, "members", None)
    if card["kind"] != "ensemble" or not isinstance(frames, list) or len(frames) != len(members):
        raise ValueError(f"{source}: member_frames needs an ensemble and one list per member, got {frames!r}")
    for i, ks in enumerate(frames):
        if (not isinstance(ks, list) or not ks or len(set(ks)) != len(ks)
                or not all(isinstance(k, int) and not isinstance(k, bool) and 0 <= k < 8 for k in ks)):
            raise ValueError(f"{source}: member_frames[{i}] must be distinct D4 elements 0..7, got {ks!r}")
        members[i] = symmetry_averaged(members[i], card, source, tuple(ks))


def symmetry_averaged(model: torch.nn.Module, card: dict, source: Path,
                      elements: tuple[int, ...] = tuple(range(8))) -> torch.nn.Module:
    """``model`` averaged over the square's symmetries (or ``elements`` of them); ValueError unless it is
    a car model on a square window."""
    from hjrno_ros.learning.operators.average import SymmetryAverage

    channels = card["inputs"].get("channels", [])
    if "cos_theta" not in channels:
        raise ValueError(f"{source}: symmetry averaging is for car models, this one is {card['inputs'].get('kind')!r}")
    lo, hi, shape = (card["grid"][k] for k in ("lo", "hi", "shape"))
    if shape[0] != shape[1] or abs((hi[0] - lo[0]) - (hi[1] - lo[1])) > 1e-9:
        raise ValueError(f"{source}: symmetry averaging needs a square x-y window, this one has {shape[0]} x "
                         f"{shape[1]} nodes over {hi[0] - lo[0]:g} m x {hi[1] - lo[1]:g} m")
    return SymmetryAverage(model, channels.index("cos_theta"), channels.index("sin_theta"), elements=elements)
