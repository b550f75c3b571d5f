"""Symmetry averaging: an operator made exactly equivariant under the square's group D4.

The car's dynamics commute with the 8 symmetries of a square window (quarter turns about its
centre, the reflection y → −y; headings move with them), see :func:`hjrno_ros.learning.slices.symmetry`.
A trained operator is only approximately equivariant; averaging its 8 predictions, each made on a
transformed input and mapped back, gives an operator that is equivariant exactly and whose error
is the mean of 8 partly independent errors.  Cost: 8 forward passes, stacked into batches of at
most ``max_stack`` samples where the input is that small (the symmetry-stacking study in
docs/results.md measured the best size on CPU).

Input layout as everywhere (docs/design.md, "Conventions"): [B, C, Nx, Ny], dim 2 is x, dim 3 is y; the heading
enters as two constant channels (cos θ, sin θ) whose indices are given.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn


class SymmetryAverage(nn.Module):
    """``model`` averaged over D4 (or over ``elements`` of it); element k (0..7) as in
    :func:`hjrno_ros.learning.slices.symmetry`."""

    def __init__(self, model: nn.Module, cos_channel: int, sin_channel: int, max_stack: int = 16,
                 elements: tuple[int, ...] = tuple(range(8))) -> None:
        super().__init__()
        self.model, self.cos_channel, self.sin_channel = model, cos_channel, sin_channel
        self.max_stack = max_stack
        self.elements = tuple(elements)  # a subset averages over those elements only (not equivariant then)

    def transform(self, x: Tensor, k: int) -> Tensor:
        """Element k applied to inputs: reflect y (k ≥ 4, θ → −θ), then k mod 4 quarter turns (θ + π/2 each)."""
        x = torch.flip(x, dims=(3,)) if k >= 4 else x.clone()
        c, s = x[:, self.cos_channel].clone(), x[:, self.sin_channel].clone()
        s = -s if k >= 4 else s
        cos_t, sin_t = ((1, 0), (0, 1), (-1, 0), (0, -1))[k % 4]  # cos, sin of (k mod 4) π/2, exact
        x[:, self.cos_channel] = cos_t * c - sin_t * s
        x[:, self.sin_channel] = sin_t * c + cos_t * s
        return torch.rot90(x, k % 4, dims=(2, 3))

    @staticmethod
    def restore(y: Tensor, k: int) -> Tensor:
        """The inverse of element k on outputs (undo the turns, then the reflection)."""
        y = torch.rot90(y, -(k % 4), dims=(2, 3))
        return torch.flip(y, dims=(3,)) if k >= 4 else y

    def forward(self, x: Tensor) -> Tensor:
        """[B, C, N, N] -> [B, 1, N, N]; the x-y grid must be square (same nodes after a quarter turn)."""
        if x.ndim != 4 or x.shape[2] != x.shape[3]:
            raise ValueError(f"symmetry averaging needs a square x-y grid [B, C, N, N], got {tuple(x.shape)}")
        n = len(self.elements)
        # elements per forward pass; all in one while torch.export traces (ONNX export), where a group size
        # computed from the batch would fix the graph's batch size
        group = n if torch.compiler.is_compiling() else min(n, max(1, self.max_stack // x.shape[0]))
        total = 0.0
        for first in range(0, n, group):
            ks = self.elements[first:first + group]
            outs = self.model(torch.cat([self.transform(x, k) for k in ks]))
            outs = outs.unflatten(0, (len(ks), x.shape[0])).unbind(0)  # not chunk(): exports with a free batch
            total = total + sum(self.restore(y, k) for k, y in zip(ks, outs, strict=True))
        return total / n
