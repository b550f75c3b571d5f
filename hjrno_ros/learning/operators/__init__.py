"""Neural operators that map a V0 slice (plus constant channels) to a V∞ slice.

All models share one interface (docs/design.md axis order, dim 2 is x, dim 3 is y)::

    model = build_model("fno", in_channels=4)
    v_inf = model(x)            # x: [B, in_channels, Nx, Ny] -> [B, 1, Nx, Ny]

Inputs are samples on a uniform grid that covers a fixed physical window, end points
included.  Every model appends two coordinate channels (x, y in [-1, 1], ``torch.linspace``)
so it sees position.  FNO and TNO are discretisation invariant (the same weights at any
resolution of the window); the CNN runs at any resolution but is not invariant.

Config is keyword-only and JSON-serialisable; ``model.config`` rebuilds the model exactly
with ``build_model(model.kind, **model.config)``.  ``prior="below_input"`` makes the output
``x[:, 0:1] - softplus(raw)``, so V∞ ≤ V0 holds by construction.

Every parameter is real (the FNO stores its complex spectral weights with a real / imaginary
axis), so state dicts save to safetensors and ``count_parameters`` counts real scalars.
"""

from __future__ import annotations

from typing import Any

from torch import nn

from hjrno_ros.learning.operators.base import (
    PRIOR_SHARPNESS,
    PRIORS,
    NeuralOperator,
    apply_prior,
    check_choice,
    check_float,
    check_int,
    construct,
    coordinates,
    count_parameters,
)
from hjrno_ros.learning.operators.cnn import CNN
from hjrno_ros.learning.operators.ensemble import MODELS, Ensemble
from hjrno_ros.learning.operators.fno import FNO
from hjrno_ros.learning.operators.tno import TNO


def build_model(kind: str, **config: Any) -> nn.Module:
    """The model ``kind`` ("fno", "tno", "cnn", or "ensemble" of those) built from keyword ``config``;
    ValueError on bad input."""
    return construct({**MODELS, Ensemble.kind: Ensemble}, kind, config)


__all__ = [
    "CNN",
    "FNO",
    "MODELS",
    "PRIORS",
    "PRIOR_SHARPNESS",
    "TNO",
    "Ensemble",
    "NeuralOperator",
    "apply_prior",
    "build_model",
    "check_choice",
    "check_float",
    "check_int",
    "coordinates",
    "count_parameters",
]
