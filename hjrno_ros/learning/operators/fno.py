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

import functools
import math
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


def dft_matrices(nx: int, ny: int, m1: int, m2: int, dtype: torch.dtype, device: torch.device
                 ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Real matrices of the truncated ``rfft2`` and its ``irfft2`` (``norm="forward"``) on an nx x ny grid.

    Kept frequencies: kx in 0..m1-1, nx-m1..nx-1 (x, full DFT) and ky in 0..m2-1 (y, real DFT).  Each
    matrix multiplies from the right, contracting the last dim ("[Re | Im]": real parts, then imaginary):

    * ``fy`` [ny, 2 m2]: y -> [Re | Im] of the y transform (cos | -sin, divided by ny);
    * ``fx`` [2 nx, 4 m1]: [Re | Im] over x -> [Re | Im] of the kept kx (divided by nx);
    * ``ix`` [4 m1, 2 nx]: [Re | Im] of the kept kx -> [Re | Im] over x (the inverse, unnormalised);
    * ``iy`` [2 m2, ny]: [Re | Im] of the kept ky -> y, the c2r inverse: weight 1 for ky = 0 and for the
      Nyquist bin ky = ny/2, 2 otherwise; the imaginary parts of those two bins drop out (their sine is 0),
      as irfft ignores them.

    Angles 2π (k j mod n) / n in float64, cast to ``dtype`` at the end.  Cached per argument set (plain
    tensors, never in a state dict), except while torch.export traces: then built in the graph.
    """
    if torch.compiler.is_compiling():
        return _dft_matrices(nx, ny, m1, m2, dtype, device)
    return _cached_dft_matrices(nx, ny, m1, m2, dtype, device)


def _dft_matrices(nx: int, ny: int, m1: int, m2: int, dtype: torch.dtype, device: torch.device
                  ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    def cos_sin(k: Tensor, j: Tensor, n: int) -> tuple[Tensor, Tensor]:
        angle = (2.0 * math.pi / n) * torch.remainder(k[:, None] * j[None, :], n).to(torch.float64)
        return torch.cos(angle), torch.sin(angle)  # [len(k), len(j)]

    ints = {"dtype": torch.int64, "device": "cpu"}
    cy, sy = cos_sin(torch.arange(m2, **ints), torch.arange(ny, **ints), ny)  # [m2, ny]
    kx = torch.cat([torch.arange(m1, **ints), torch.arange(nx - m1, nx, **ints)])
    cx, sx = cos_sin(kx, torch.arange(nx, **ints), nx)  # [2 m1, nx]
    ix = torch.cat([torch.cat([cx, sx], 1), torch.cat([-sx, cx], 1)])  # rows Re, Im of Y; columns Re, Im of Z
    weight = torch.full((m2, 1), 2.0, dtype=torch.float64)
    weight[0] = 1.0
    if ny % 2 == 0 and m2 == ny // 2 + 1:
        weight[-1] = 1.0  # the Nyquist bin
    matrices = torch.cat([cy, -sy]).T / ny, ix.T / nx, ix, torch.cat([weight * cy, -weight * sy])
    return tuple(m.to(dtype=dtype, device=device).contiguous() for m in matrices)


@functools.lru_cache(maxsize=16)
def _cached_dft_matrices(nx: int, ny: int, m1: int, m2: int, dtype: torch.dtype, device: torch.device
                         ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    with torch.inference_mode(False):  # a first call under inference_mode must not cache tensors autograd refuses
        return _dft_matrices(nx, ny, m1, m2, dtype, device)


class SpectralConv2d(nn.Module):
    """Learnable multiplication of the lowest ``modes`` x ``modes`` Fourier coefficients.

    Along x (full DFT) frequencies 0..modes-1 and -modes..-1 are kept, along y (real DFT)
    frequencies 0..modes-1.  The complex weights are stored as one real tensor
    ``[2 * modes, modes, 2, in, out]``: x frequency (0..modes-1, then -modes..-1), y frequency,
    real / imaginary part, channel matrix.  Channel mixing runs as real batched matmuls over the
    modes: torch's complex ``einsum``/``bmm`` on CPU loops over the batch and was measured to
    spend half the FNO's time in copies.

    The truncated ``rfft2`` and the ``irfft2`` back (``norm="forward"``) are real matmuls with the
    DFT matrices of the kept modes (:func:`dft_matrices`), not ``torch.fft``: complex tensors do not
    export to ONNX, and at these grid sizes the matmuls are faster than the FFT path they replaced
    (bundled default, 32 x 32 nodes padded to 39 x 39, CPU: batch 1, 1 thread 4.5 vs 5.7 ms per forward;
    batch 64 forward + backward, 1 thread 0.85 vs 1.01 s).  The same numbers as torch.fft up to float
    rounding (test/learning/test_onnx_export.py).
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
        cout = w.shape[-1]
        fy, fx, ix, iy = dft_matrices(nx, ny, m1, m2, x.dtype, x.device)
        # Every transform is one matmul on the last dim; permutes bring the next contracted dim last.
        t = torch.matmul(x, fy).reshape(b, cin, nx, 2, m2)  # [B, I, x, (re, im), ky]
        t = t.permute(0, 1, 4, 3, 2).reshape(b, cin, m2, 2 * nx)
        low = torch.matmul(t, fx).reshape(b, cin, m2, 2, 2 * m1)  # [B, I, ky, (re, im), kx]
        # [P, (re, im) x B, I] with P = 2 m1 m2 modes; (ar + i ai)(wr + i wi) with two real bmm.
        a = low.permute(4, 2, 3, 0, 1).reshape(2 * m1 * m2, 2 * b, cin)
        r, i = torch.bmm(a, w[:, 0]), torch.bmm(a, w[:, 1])  # [P, 2B, O]
        mixed = torch.stack([r[:, :b] - i[:, b:], i[:, :b] + r[:, b:]])  # [(re, im), P, B, O]
        mixed = mixed.reshape(2, 2 * m1, m2, b, cout).permute(3, 4, 2, 0, 1).contiguous()  # [B, O, ky, (re, im), kx]
        mixed = mixed.reshape(b, cout, m2, 4 * m1)  # contiguous: one GEMM, not a batch of clones
        z = torch.matmul(mixed, ix).reshape(b, cout, m2, 2, nx)  # [B, O, ky, (re, im), x]
        z = z.permute(0, 1, 4, 3, 2).reshape(b, cout, nx, 2 * m2)
        return torch.matmul(z, iy)  # [B, O, x, y]


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
