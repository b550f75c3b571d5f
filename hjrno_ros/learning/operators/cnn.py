"""Convolutional encoder-decoder baseline (U-Net-like); runs at any size but is not invariant.

``depth`` resolution levels, each a [conv3x3, GELU, conv3x3, GELU] block with ``channels * 2**i``
channels; 2x2 max pooling between levels going down, 2x2 transposed convolutions going up,
skip connections by concatenation, 1x1 conv to 1 channel.  The input is padded (replicate)
to a multiple of the downsampling factor ``2**(depth - 1)`` and the output cropped back.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from hjrno_ros.learning.operators.base import NeuralOperator, check_int


def conv_block(cin: int, cout: int) -> nn.Sequential:
    """conv3x3-GELU-conv3x3-GELU, size preserving."""
    return nn.Sequential(nn.Conv2d(cin, cout, 3, padding=1), nn.GELU(), nn.Conv2d(cout, cout, 3, padding=1), nn.GELU())


class CNN(NeuralOperator):
    """U-Net baseline: [B, in_channels, Nx, Ny] -> [B, 1, Nx, Ny] for any Nx, Ny.

    Config: ``in_channels`` (required), ``channels=24`` (at the finest level, doubled per
    level), ``depth=3`` (resolution levels incl. the bottleneck; 1 = no downsampling),
    ``prior="none"`` ("none" | "below_input").
    """

    kind = "cnn"

    def __init__(self, *, in_channels: int, channels: int = 24, depth: int = 3, prior: str = "none") -> None:
        config: dict[str, Any] = {
            "in_channels": in_channels,
            "channels": check_int("channels", channels, 1),
            "depth": check_int("depth", depth, 1),
            "prior": prior,
        }
        super().__init__(config)
        widths = [channels * 2**i for i in range(depth)]
        self.encoders = nn.ModuleList()
        cin = config["in_channels"] + 2
        for w in widths:
            self.encoders.append(conv_block(cin, w))
            cin = w
        self.ups = nn.ModuleList(nn.ConvTranspose2d(widths[i + 1], widths[i], 2, stride=2) for i in range(depth - 1))
        self.decoders = nn.ModuleList(conv_block(2 * widths[i], widths[i]) for i in range(depth - 1))
        self.head = nn.Conv2d(widths[0], 1, 1)

    def forward_raw(self, z: Tensor) -> Tensor:
        nx, ny = z.shape[2], z.shape[3]
        factor = 2 ** (self.config["depth"] - 1)
        px, py = -nx % factor, -ny % factor
        if px or py:
            z = F.pad(z, (0, py, 0, px), mode="replicate")
        skips = []
        h = z
        for i, encoder in enumerate(self.encoders):
            if i:
                h = F.max_pool2d(h, 2)
            h = encoder(h)
            skips.append(h)
        for i in reversed(range(len(self.decoders))):
            h = self.decoders[i](torch.cat([self.ups[i](h), skips[i]], dim=1))
        return self.head(h)[:, :, :nx, :ny]
