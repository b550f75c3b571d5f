"""An ensemble: the mean of several trained operators' outputs, one module, one checkpoint.

Members trained apart err partly independently; their mean errs less where it matters for the
filter (docs/results.md, closed loop: three indoor CNNs trained with different losses collided 3-5 times
in 500 episodes where each alone collided 23-69 times).  Cost: one forward pass per member.

Where the members disagree the mean is least trusted: ``pessimism`` k ≥ 0 lowers the output by k
times the members' standard deviation (mean − k·std, per grid node), so the filter intervenes
earlier exactly there.  k = 0 (the default, and what cards without the key mean) is the plain mean.

Config: ``in_channels``, ``pessimism`` and ``members``, a list of ``{"kind": ..., "config": {...}}`` that
:func:`hjrno_ros.learning.operators.build_model` rebuilds; members are "fno", "tno" or "cnn" (no nesting).
State-dict keys are ``members.<i>.<member key>``.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import Tensor, nn

from hjrno_ros.learning.operators.base import NeuralOperator, check_int, construct
from hjrno_ros.learning.operators.cnn import CNN
from hjrno_ros.learning.operators.fno import FNO
from hjrno_ros.learning.operators.tno import TNO

MODELS: dict[str, type[NeuralOperator]] = {"fno": FNO, "tno": TNO, "cnn": CNN}  # the single operators: members


class Ensemble(nn.Module):
    """[B, in_channels, Nx, Ny] -> [B, 1, Nx, Ny]: the mean of the members' outputs, less ``pessimism``
    times their standard deviation."""

    kind = "ensemble"

    def __init__(self, *, in_channels: int, members: list[dict[str, Any]], pessimism: float = 0.0) -> None:
        super().__init__()
        in_channels = check_int("in_channels", in_channels, 1)
        if not isinstance(members, list) or len(members) < 2:
            raise ValueError(f"an ensemble needs a list of at least 2 members, got {members!r}")
        for i, m in enumerate(members):
            if not isinstance(m, dict) or m.get("kind") not in MODELS or not isinstance(m.get("config"), dict):
                raise ValueError(f"ensemble member {i} must be {{'kind': one of {sorted(MODELS)}, 'config': {{...}}}}, "
                                 f"got {m!r}")
            if m["config"].get("in_channels") != in_channels:
                raise ValueError(f"ensemble member {i} takes {m['config'].get('in_channels')} input channels, "
                                 f"the ensemble {in_channels}")
        if isinstance(pessimism, bool) or not isinstance(pessimism, int | float) or not (
                math.isfinite(pessimism) and pessimism >= 0):
            raise ValueError(f"ensemble pessimism must be a finite number >= 0, got {pessimism!r}")
        self.members = nn.ModuleList(construct(MODELS, m["kind"], m["config"]) for m in members)
        self.in_channels, self.pessimism = in_channels, float(pessimism)
        self.config: dict[str, Any] = {"in_channels": in_channels, "pessimism": self.pessimism,
                                       "members": [{"kind": m.kind, "config": m.config} for m in self.members]}

    def forward(self, x: Tensor) -> Tensor:
        if not self.pessimism:
            return sum(m(x) for m in self.members) / len(self.members)
        outputs = torch.stack([m(x) for m in self.members])
        return outputs.mean(0) - self.pessimism * outputs.std(0, correction=0)
