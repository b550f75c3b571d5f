"""The operator's inputs as its model card records them (:class:`InputSpec`): which channels, in which units.

Input channels are the V0 slice, then constants: normalised v, cos θ, sin θ (car) or cos ψ, sin ψ (Air3D), then
the normalised varying parameters (a_max, κ_max for the parametric family; ``log_a_max``, the logarithm of
a_max/(v_max·ω_top) in model units, for datasets drawn with an ``accel_ratio`` range).  Values are divided by
``value_scale`` (m).  A *table* model (``table`` = (nv, nθ)) takes V0 and the parameters only and outputs one
channel per (v, θ) node of the card's grid, channel iv·nθ + iθ.  numpy only: the node builds exactly the inputs
the model was trained on without torch.
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class InputSpec:
    kind: str  # "car" or "air3d"
    value_scale: float  # m: V0 and V are divided by this
    v_range: tuple[float, float] = (0.0, 1.0)  # car only
    param_ranges: dict = dataclasses.field(default_factory=dict)  # name -> (lo, hi), e.g. a_max, kappa_max
    table: tuple[int, int] | None = None  # (nv, nθ): the model outputs the whole (v, θ) table at once

    @property
    def channels(self) -> list[str]:
        if self.table:
            return ["v0", *self.param_ranges]
        angle = ["cos_theta", "sin_theta"] if self.kind == "car" else ["cos_psi", "sin_psi"]
        return ["v0"] + (["v"] if self.kind == "car" else []) + angle + list(self.param_ranges)

    @property
    def out_channels(self) -> int:
        return int(np.prod(self.table)) if self.table else 1

    @property
    def in_channels(self) -> int:
        return len(self.channels)

    def as_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["v_range"] = list(self.v_range)
        d["param_ranges"] = {k: list(v) for k, v in self.param_ranges.items()}
        d["channels"] = self.channels
        if self.table:
            d["table"] = list(self.table)
        else:  # cards of single-slice models keep the fields they always had
            d.pop("table")
        return d

    @classmethod
    def from_dict(cls, d: dict) -> InputSpec:
        table = d.get("table")
        return cls(d["kind"], float(d["value_scale"]), tuple(d.get("v_range", (0.0, 1.0))),
                   {k: tuple(v) for k, v in d.get("param_ranges", {}).items()},
                   (int(table[0]), int(table[1])) if table else None)

    def array(self, v0: np.ndarray, v: np.ndarray, angle: np.ndarray, params: np.ndarray | None = None
              ) -> np.ndarray:
        """(B, C, Nx, Ny) float32 from V0 slices (B, Nx, Ny) in metres, speeds v (B,) (ignored for
        Air3D), angles (B,) in rad and parameters (B, P) in the order of ``param_ranges``."""
        v0 = np.asarray(v0, np.float32)
        b, nx, ny = v0.shape
        consts = []
        if self.table:
            v, angle = np.zeros(0), np.zeros(0)
        elif self.kind == "car":
            lo, hi = self.v_range
            consts.append(2.0 * (np.asarray(v, np.float32) - lo) / (hi - lo) - 1.0)
        if not self.table:
            consts += [np.cos(angle), np.sin(angle)]
        for i, (lo, hi) in enumerate(self.param_ranges.values()):
            consts.append(2.0 * (np.asarray(params)[:, i] - lo) / (hi - lo) - 1.0)
        c = np.stack(consts, 1).astype(np.float32) if consts else np.zeros((b, 0), np.float32)  # (B, K)
        x = np.empty((b, 1 + c.shape[1], nx, ny), np.float32)
        x[:, 0] = v0 / self.value_scale
        x[:, 1:] = c[:, :, None, None]
        return x


def param_value(params: dict, name: str) -> float:
    """A parameter channel's value: ``params[name]``, or the logarithm of ``params[X]`` for ``log_X``."""
    return float(np.log(params[name[4:]])) if name.startswith("log_") else float(params[name])
