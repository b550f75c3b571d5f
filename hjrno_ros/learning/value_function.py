"""The learned value source run by torch: :class:`~hjrno_ros.core.operator_values.OperatorValues` with the card's
network loaded from its safetensors file (training, evaluation, and the node when a card has no ONNX file)."""

from __future__ import annotations

import numpy as np
import torch

from hjrno_ros.core.operator_values import OperatorValues
from hjrno_ros.learning import checkpoint
from hjrno_ros.learning.operators.cnn import CNN


def channels_last_cnns(model: torch.nn.Module) -> None:
    """Store the CNN members' weights channels-last: oneDNN's faster convolution path on CPU (the bundled
    ensembles 1.2-1.4× faster, outputs equal up to float rounding: docs/results.md, channels-last study).  Only
    CNN modules: the FNO's and TNO's weights are not all 4-D convolution kernels."""
    for module in model.modules():
        if isinstance(module, CNN):
            module.to(memory_format=torch.channels_last)


class LearnedValueFunction(OperatorValues):
    """The card at ``stem`` with its network on ``device`` ('' or None: cuda when available, else cpu), ``threads``
    torch CPU threads."""

    def __init__(self, stem, device: str | torch.device | None = None, threads: int | None = None):
        device = device or ("cuda" if torch.cuda.is_available() else "cpu")
        if threads:
            torch.set_num_threads(threads)
        self.model, card = checkpoint.load_typed(stem, device)
        self.device = torch.device(device)
        if self.device.type == "cpu":
            channels_last_cnns(self.model)
        super().__init__(card, self._forward, stem, runtime="torch")

    @torch.no_grad()
    def _forward(self, x: np.ndarray) -> np.ndarray:
        return self.model(torch.from_numpy(np.ascontiguousarray(x)).to(self.device)).cpu().numpy()
