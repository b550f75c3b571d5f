"""An ensemble: the mean of several trained operators' outputs, one module, one checkpoint.

Members trained apart err partly independently; their mean errs less where it matters for the
filter (README, closed loop: three indoor CNNs trained with different losses collided 3-5 times
in 500 episodes where each alone collided 23-69 times).  Cost: one forward pass per member.

Config: ``in_channels`` and ``members``, a list of ``{"kind": ..., "config": {...}}`` that
:func:`hjrno_ros.operators.build_model` rebuilds; members are "fno", "tno" or "cnn" (no nesting).
State-dict keys are ``members.<i>.<member key>``.
"""

from __future__ import annotations

from typing import Any

from torch import Tensor, nn

from hjrno_ros.operators import check_int


class Ensemble(nn.Module):
    """[B, in_channels, Nx, Ny] -> [B, 1, Nx, Ny]: the mean of the members' outputs."""

    kind = "ensemble"

    def __init__(self, *, in_channels: int, members: list[dict[str, Any]]) -> None:
        from hjrno_ros.operators import MODELS, build_model

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
        self.members = nn.ModuleList(build_model(m["kind"], **m["config"]) for m in members)
        self.in_channels = in_channels
        self.config: dict[str, Any] = {"in_channels": in_channels,
                                       "members": [{"kind": m.kind, "config": m.config} for m in self.members]}

    def forward(self, x: Tensor) -> Tensor:
        return sum(m(x) for m in self.members) / len(self.members)
