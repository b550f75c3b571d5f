"""Fourier neural operator (Li et al. 2021), plain and small enough for a robot CPU.

Lifting (1x1 conv) -> domain padding -> ``n_layers`` x [spectral conv + 1x1 conv, GELU between]
-> crop -> projection MLP (1x1 conv, GELU, 1x1 conv).

Discretisation invariance.  The grid has ``n`` nodes over [-1, 1] *end points included*, so
the spacing is h = 2 / (n - 1), and the FFT sees a period of ``N * h`` where ``N`` is the padded
size.  A Fourier weight acts on the physical frequency k / (N h), so the padded size is
``N = round((1 + 2 * padding) * (n - 1))``: the physical period is then (almost) the same at
every resolution (2.516 at n = 32, 2.508 at n = 64, exactly 2.5 at n = 33, 65, 129 with the
default padding) instead of drifting with n as a fixed cell count would.  The FFT uses
``norm="forward"``, so Fourier coefficients do not scale with n.  Modes are clipped to what
the padded grid supports; a clipped weight keeps its physical frequency.

Domain padding (value functions are not periodic).  All padding cells are appended after the
last node (a circular convolution does not care where the padding sits on the circle).
``pad_mode="blend"`` (default) fills them with a linear blend of the reflection about the last
node and the reflection about the first node: a continuous periodic extension without a seam,
defined by physical position.  Measured on one spectral convolution of a signed distance
(rel. max error of the 33-node result against a 513-node one): zeros 0.175, two-sided reflect
0.095, blend 0.011, and blend converges at second order (zeros and reflect at first order,
their jump moves with h).  On random 4-layer FNOs, 32 vs 64 nodes: zeros ≈ 5 %, reflect
≈ 4 %, blend ≈ 0.7 % of the output range.  "zeros" and "reflect" remain available.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from hjrno_ros.learning.operators.base import NeuralOperator, check_choice, check_float, check_int

PAD_MODES = ("blend", "reflect", "zeros")


def padded_size(n: int, padding: float) -> int:
    """Padded FFT length for ``n`` end-point-inclusive nodes: keeps the physical period N h ≈ constant."""
    if padding <= 0.0 or n < 2:
        return n
    return max(n + 2, round((1.0 + 2.0 * padding) * (n - 1)))


def extend_last_dim(h: Tensor, pad: int, mode: str) -> Tensor:
    """Append ``pad`` cells to the last dim of ``h`` (the FFT's circle closes after them).

    Padding cell j = 1..pad sits between the last node (j = 0) and the first node (j = pad + 1).
    "zeros" fills zeros; "reflect" mirrors the last nodes about the last node for the first
    half and the first nodes about the first node for the second half (two-sided reflection,
    rotated; a jump where the halves meet); "blend" mixes the two mirror images linearly,
    ``(1 - w) h[n-1-j] + w h[pad+1-j]`` with w = j / (pad + 1): a continuous periodic
    extension with no seam, defined by physical position so it converges at second order.
    """
    n = h.shape[-1]
    if pad == 0:
        return h
    if mode == "zeros" or n < 2:
        return F.pad(h, (0, pad))
    j = torch.arange(1, pad + 1, device=h.device)
    right = h.index_select(-1, (n - 1 - j).clamp(min=0))
    left = h.index_select(-1, (pad + 1 - j).clamp(max=n - 1))
    if mode == "reflect":
        w = (j > (pad + 1) // 2).to(h.dtype)
    else:
        w = j.to(h.dtype) / (pad + 1)
    return torch.cat([h, torch.lerp(right, left, w)], dim=-1)


class SpectralConv2d(nn.Module):
    """Learnable multiplication of the lowest ``modes`` x ``modes`` Fourier coefficients.

    Along x (full FFT) frequencies 0..modes-1 and -modes..-1 are kept, along y (rfft)
    frequencies 0..modes-1.  The complex weights are stored as one real tensor
    ``[2 * modes, modes, 2, in, out]``: x frequency (0..modes-1, then -modes..-1), y frequency,
    real / imaginary part, channel matrix.  Channel mixing runs as real batched matmuls over the
    modes: torch's complex ``einsum``/``bmm`` on CPU loops over the batch and was measured to
    spend half the FNO's time in copies.
    """

    def __init__(self, in_channels: int, out_channels: int, modes: int) -> None:
        super().__init__()
        self.modes = modes
        scale = 1.0 / (in_channels * out_channels)
        self.weight = nn.Parameter(scale * torch.rand(2 * modes, modes, 2, in_channels, out_channels))

    def mode_weights(self, m1: int, m2: int) -> Tensor:
        """Weights of x frequencies 0..m1-1, -m1..-1 and y frequencies 0..m2-1: [2 m1 m2, 2, in, out]."""
        w, m = self.weight, self.modes
        if (m1, m2) != (m, m):  # clipped grid: each weight keeps its physical frequency
            w = torch.cat([w[:m1, :m2], w[2 * m - m1 :, :m2]])
        return w.reshape(2 * m1 * m2, *w.shape[2:])

    def forward(self, x: Tensor) -> Tensor:
        b, cin, nx, ny = x.shape
        m1, m2 = min(self.modes, nx // 2), min(self.modes, ny // 2 + 1)
        w = self.mode_weights(m1, m2)
        x_ft = torch.fft.rfft2(x, norm="forward")
        low = torch.cat([x_ft[:, :, :m1, :m2], x_ft[:, :, nx - m1 :, :m2]], dim=2)  # [B, I, 2 m1, m2]
        # [P, (re, im) x B, I] with P = 2 m1 m2 modes; (ar + i ai)(wr + i wi) with two real bmm.
        a = torch.view_as_real(low).permute(2, 3, 4, 0, 1).reshape(-1, 2 * b, cin)
        r, i = torch.bmm(a, w[:, 0]), torch.bmm(a, w[:, 1])  # [P, 2B, O]
        mixed = torch.complex(r[:, :b] - i[:, b:], i[:, :b] + r[:, b:])  # [P, B, O]
        mixed = mixed.reshape(2 * m1, m2, b, -1).permute(2, 3, 0, 1)  # [B, O, 2 m1, m2]
        out_ft = x_ft.new_zeros(b, mixed.shape[1], nx, ny // 2 + 1)
        out_ft[:, :, :m1, :m2] = mixed[:, :, :m1]
        out_ft[:, :, nx - m1 :, :m2] = mixed[:, :, m1:]
        return torch.fft.irfft2(out_ft, s=(nx, ny), norm="forward")


class FNO(NeuralOperator):
    """Fourier neural operator: [B, in_channels, Nx, Ny] -> [B, out_channels, Nx, Ny] at any resolution.

    Config: ``in_channels`` (required), ``out_channels=1`` (a whole (v, θ) table: one channel per slice, see
    :class:`hjrno_ros.learning.slices.InputSpec`), ``width=24``, ``modes=12``, ``n_layers=4``, ``proj=64``,
    ``padding=0.125`` (fraction of the window added per side: the FFT runs on
    ``round((1 + 2 padding)(n - 1))`` nodes, at least n + 2; 0 = periodic input, no padding; at
    most 0.5), ``pad_mode="blend"`` ("blend" | "reflect" | "zeros"), ``prior="none"``
    ("none" | "below_input").
    """

    kind = "fno"

    def __init__(
        self,
        *,
        in_channels: int,
        out_channels: int = 1,
        width: int = 24,
        modes: int = 12,
        n_layers: int = 4,
        proj: int = 64,
        padding: float = 0.125,
        pad_mode: str = "blend",
        prior: str = "none",
    ) -> None:
        config: dict[str, Any] = {
            "in_channels": in_channels,
            "width": check_int("width", width, 1),
            "modes": check_int("modes", modes, 1),
            "n_layers": check_int("n_layers", n_layers, 1),
            "proj": check_int("proj", proj, 1),
            "padding": check_float("padding", padding, 0.0, 0.5),
            "pad_mode": check_choice("pad_mode", pad_mode, PAD_MODES),
            "prior": prior,
        }
        if out_channels != 1:  # cards of single-slice models keep the config they always had
            config["out_channels"] = check_int("out_channels", out_channels, 1)
        super().__init__(config)
        c = config
        self.lift = nn.Conv2d(c["in_channels"] + 2, c["width"], 1)
        self.spectral = nn.ModuleList(SpectralConv2d(c["width"], c["width"], c["modes"]) for _ in range(c["n_layers"]))
        self.pointwise = nn.ModuleList(nn.Conv2d(c["width"], c["width"], 1) for _ in range(c["n_layers"]))
        self.project = nn.Sequential(nn.Conv2d(c["width"], c["proj"], 1), nn.GELU(),
                                     nn.Conv2d(c["proj"], out_channels, 1))

    def forward_raw(self, z: Tensor) -> Tensor:
        nx, ny = z.shape[2], z.shape[3]
        h = self.lift(z)
        padding, mode = self.config["padding"], self.config["pad_mode"]
        h = extend_last_dim(h, padded_size(ny, padding) - ny, mode)
        h = extend_last_dim(h.transpose(2, 3), padded_size(nx, padding) - nx, mode).transpose(2, 3)
        last = len(self.spectral) - 1
        for i, (spectral, pointwise) in enumerate(zip(self.spectral, self.pointwise, strict=True)):
            h = spectral(h) + pointwise(h)
            if i < last:
                h = F.gelu(h)
        h = h[:, :, :nx, :ny]
        return self.project(h)
