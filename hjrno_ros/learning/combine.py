"""``hjrno ensemble``: several trained models saved as one checkpoint whose output is their mean
(optionally lowered where they disagree, ``--pessimism``).

The members must read the same inputs the same way (input normalisation, window, grid, dynamics)
and come from the same datasets, so that the card's test splits are held out for every member and
``hjrno calibrate`` / ``simulate`` / the node treat the ensemble like any model.  The result is an
ordinary safetensors + JSON pair (kind "ensemble", :class:`~hjrno_ros.learning.operators.ensemble.Ensemble`);
it has no ε until ``hjrno calibrate`` measures one for it.  Members enter plain: their own ε and
symmetry averaging do not carry over (``calibrate --symmetry-average`` averages the ensemble).
"""

from __future__ import annotations

import json
from pathlib import Path

from hjrno_ros import versions
from hjrno_ros.learning import checkpoint
from hjrno_ros.learning.onnx_export import export_model
from hjrno_ros.learning.operators import build_model, count_parameters

SHARED = ("inputs", "grid", "window", "dynamics")  # card entries every member must have alike


def _check_alike(cards: list[dict], stems: list[str]) -> None:
    for key in SHARED:
        if any(json.dumps(c[key], sort_keys=True) != json.dumps(cards[0][key], sort_keys=True) for c in cards):
            raise ValueError(f"ensemble members differ in their model cards' {key!r} ({', '.join(stems)}); "
                             "members must be trained for the same inputs")
    digests = [c.get("dataset", {}).get("digests") for c in cards]
    if any(d != digests[0] for d in digests):
        raise ValueError(f"ensemble members were trained on different datasets ({', '.join(stems)}); "
                         "their test splits would not be held out for all of them")
    if any(c["kind"] == "ensemble" for c in cards):
        raise ValueError("an ensemble member cannot itself be an ensemble; list its members instead")


def combine(stems: list[str], out: str | Path, command: str, pessimism: float = 0.0) -> Path:
    """Write the ensemble of the models ``stems`` (≥ 2) to ``out``, output mean − ``pessimism`` · std
    (:class:`~hjrno_ros.learning.operators.ensemble.Ensemble`); returns the weights' path."""
    if len(stems) < 2:
        raise ValueError(f"an ensemble needs at least 2 models, got {len(stems)}")
    loaded = [checkpoint.load_model(s, average=False) for s in stems]
    cards = [card for _, card in loaded]
    _check_alike(cards, stems)
    model = build_model("ensemble", in_channels=cards[0]["config"]["in_channels"], pessimism=pessimism,
                        members=[{"kind": c["kind"], "config": c["config"]} for c in cards])
    for member, (trained, _) in zip(model.members, loaded, strict=True):
        member.load_state_dict(trained.state_dict())
    first = cards[0]
    card = {"kind": "ensemble", "config": model.config, "parameters": count_parameters(model),
            **{k: first[k] for k in SHARED}, "dataset": first["dataset"],
            "training": {"wall_s": sum(c["training"].get("wall_s", 0.0) for c in cards),
                         "peak_rss_mb": max((c["training"].get("peak_rss_mb") or 0) for c in cards),
                         "note": "the members' training times summed, their peak memory's maximum"},
            "members": [{"stem": str(s), "kind": c["kind"], "command": c.get("command"),
                         "epsilon": c.get("epsilon"), "symmetry_average": c.get("symmetry_average", False)}
                        for s, c in zip(stems, cards, strict=True)],
            "epsilon": None, "command": command, "versions": versions.versions()}
    weights, _ = checkpoint.save(out, {f"model.{k}": v for k, v in model.state_dict().items()}, card)
    export_model(out)
    return weights
