"""Transformer neural operator with Galerkin-type linear attention (Cao 2021), sized for a CPU.

Lift (1x1 conv to ``d_model``) -> resample to a fixed ``latent`` x ``latent`` token grid ->
``n_layers`` x [Galerkin attention + residual, pointwise MLP + residual] -> bilinear upsampling
to the input grid, plus a pointwise skip path from the full-resolution lifted field ->
projection (1x1 conv, GELU, 1x1 conv) to 1 channel.

Galerkin attention per head: ``Q (LN(K)^T LN(V)) / n`` over the n tokens, layer norm on K and
V only (no softmax), cost linear in n.  Q, K, V projections use Cao's initialisation (Xavier
with a small gain plus a small diagonal), which keeps early training stable.

Resolution: the token grid is fixed, so the operator runs at any input size.  Latent nodes
are end-point inclusive like the input's, so they sit at the same physical places whatever
the input resolution.  Downsampling is separable full-weighting restriction (a hat-weighted
average of physical width one latent spacing: no aliasing at fine inputs, consistent across
resolutions); upsampling is bilinear with ``align_corners=True``.  (torch's
``interpolate(..., antialias=True, align_corners=True)`` was measured to be asymmetric, so
it is not used.)
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from hjrno_ros.learning.operators.base import NeuralOperator, check_int


def to_latent_matrix(n: int, m: int, like: Tensor) -> Tensor:
    """[m, n] matrix taking ``n`` end-point-inclusive nodes on [-1, 1] to ``m`` such nodes.

    Downsampling (n > m) is full-weighting restriction: the normalised transpose of linear
    interpolation from m to n nodes, i.e. a hat-weighted average whose physical width is the
    latent spacing at every input resolution (no aliasing, consistent across resolutions).
    Otherwise it is linear interpolation (align_corners=True), the identity when n == m.
    """
    if n <= m:
        eye = torch.eye(n, dtype=like.dtype, device=like.device)
        return F.interpolate(eye[None], size=m, mode="linear", align_corners=True)[0].T
    eye = torch.eye(m, dtype=like.dtype, device=like.device)
    up = F.interpolate(eye[None], size=n, mode="linear", align_corners=True)[0]  # [m, n]: latent -> input
    return up / up.sum(dim=1, keepdim=True)


class GalerkinAttention(nn.Module):
    """Multi-head Galerkin linear attention on tokens [B, n, d_model]."""

    def __init__(self, d_model: int, n_heads: int, xavier_gain: float = 1e-2, diagonal: float = 1e-2) -> None:
        super().__init__()
        self.n_heads, self.d_head = n_heads, d_model // n_heads
        self.q, self.k, self.v = (nn.Linear(d_model, d_model) for _ in range(3))
        for lin in (self.q, self.k, self.v):
            nn.init.xavier_uniform_(lin.weight, gain=xavier_gain)
            with torch.no_grad():
                lin.weight.add_(diagonal * torch.eye(d_model))
            nn.init.zeros_(lin.bias)
        self.k_norm = nn.LayerNorm(self.d_head)
        self.v_norm = nn.LayerNorm(self.d_head)
        self.out = nn.Linear(d_model, d_model)

    def forward(self, z: Tensor) -> Tensor:
        b, n, d = z.shape
        q = self.q(z).view(b, n, self.n_heads, self.d_head)
        k = self.k_norm(self.k(z).view(b, n, self.n_heads, self.d_head))
        v = self.v_norm(self.v(z).view(b, n, self.n_heads, self.d_head))
        kv = torch.einsum("bnhd,bnhe->bhde", k, v) / n
        return self.out(torch.einsum("bnhd,bhde->bnhe", q, kv).reshape(b, n, d))


class GalerkinBlock(nn.Module):
    """Attention with residual, then a pointwise MLP with residual."""

    def __init__(self, d_model: int, n_heads: int, mlp_ratio: int) -> None:
        super().__init__()
        self.attention = GalerkinAttention(d_model, n_heads)
        self.mlp = nn.Sequential(
            nn.Linear(d_model, mlp_ratio * d_model), nn.GELU(), nn.Linear(mlp_ratio * d_model, d_model)
        )

    def forward(self, z: Tensor) -> Tensor:
        z = z + self.attention(z)
        return z + self.mlp(z)


class TNO(NeuralOperator):
    """Galerkin-transformer operator: [B, in_channels, Nx, Ny] -> [B, 1, Nx, Ny] at any resolution.

    Config: ``in_channels`` (required), ``d_model=64``, ``n_heads=4`` (must divide d_model),
    ``n_layers=3``, ``latent=24`` (token grid side, ≥ 2), ``mlp_ratio=2``,
    ``prior="none"`` ("none" | "below_input").
    """

    kind = "tno"

    def __init__(
        self,
        *,
        in_channels: int,
        d_model: int = 64,
        n_heads: int = 4,
        n_layers: int = 3,
        latent: int = 24,
        mlp_ratio: int = 2,
        prior: str = "none",
    ) -> None:
        config: dict[str, Any] = {
            "in_channels": in_channels,
            "d_model": check_int("d_model", d_model, 1),
            "n_heads": check_int("n_heads", n_heads, 1),
            "n_layers": check_int("n_layers", n_layers, 1),
            "latent": check_int("latent", latent, 2),
            "mlp_ratio": check_int("mlp_ratio", mlp_ratio, 1),
            "prior": prior,
        }
        if d_model % n_heads:
            raise ValueError(f"n_heads ({n_heads}) must divide d_model ({d_model})")
        super().__init__(config)
        d = d_model
        self.lift = nn.Conv2d(config["in_channels"] + 2, d, 1)
        self.blocks = nn.ModuleList(GalerkinBlock(d, n_heads, mlp_ratio) for _ in range(n_layers))
        self.skip = nn.Conv2d(d, d, 1)
        self.project = nn.Sequential(nn.Conv2d(d, d, 1), nn.GELU(), nn.Conv2d(d, 1, 1))

    def forward_raw(self, z: Tensor) -> Tensor:
        b, _, nx, ny = z.shape
        m = self.config["latent"]
        h = self.lift(z)
        rx, ry = to_latent_matrix(nx, m, h), to_latent_matrix(ny, m, h)
        t = torch.einsum("bcxy,ix,jy->bijc", h, rx, ry).reshape(b, m * m, -1)  # tokens [B, m*m, d]
        for block in self.blocks:
            t = block(t)
        t = t.transpose(1, 2).reshape(b, -1, m, m)
        up = F.interpolate(t, size=(nx, ny), mode="bilinear", align_corners=True)
        return self.project(up + self.skip(h))
