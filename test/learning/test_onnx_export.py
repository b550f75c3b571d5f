"""ONNX export: the FNO's real-DFT spectral convolution equals torch.fft's, every bundled model exports and
onnxruntime reproduces torch on realistic windows, and a failed export leaves no file."""

import dataclasses
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

from hjrno_ros.core.geometry import Disk, union_sdf
from hjrno_ros.learning import onnx_export
from hjrno_ros.learning.checkpoint import load_typed
from hjrno_ros.learning.onnx_export import check_export, export_onnx
from hjrno_ros.learning.operators import build_model
from hjrno_ros.learning.operators.fno import SpectralConv2d
from hjrno_ros.learning.slices import InputSpec, param_value

MODELS = Path(__file__).resolve().parents[2] / "models"
BUNDLED = sorted(p.stem for p in MODELS.glob("*.json")  # the operators; the agents' value tables have no network
                 if json.loads(p.read_text()).get("kind") != "agent_relative")


def fft_reference(conv: SpectralConv2d, x: torch.Tensor) -> torch.Tensor:
    """The spectral convolution as the FNO paper writes it: rfft2, complex channel mixing of the kept modes, irfft2."""
    b, _, nx, ny = x.shape
    m1, m2 = min(conv.modes, nx // 2), min(conv.modes, ny // 2 + 1)
    w = conv.mode_weights(m1, m2)  # [2 m1 m2, 2, in, out]
    w = torch.complex(w[:, 0], w[:, 1]).reshape(2 * m1, m2, *w.shape[2:])
    x_ft = torch.fft.rfft2(x, norm="forward")
    low = torch.cat([x_ft[:, :, :m1, :m2], x_ft[:, :, nx - m1 :, :m2]], dim=2)
    mixed = torch.einsum("bixy,xyio->boxy", low, w)
    out_ft = torch.zeros(b, w.shape[-1], nx, ny // 2 + 1, dtype=x_ft.dtype)
    out_ft[:, :, :m1, :m2] = mixed[:, :, :m1]
    out_ft[:, :, nx - m1 :, :m2] = mixed[:, :, m1:]
    return torch.fft.irfft2(out_ft, s=(nx, ny), norm="forward")


# (nx, ny, modes): the bundled FNOs' padded 39 x 39 grid, even and odd sizes, all x frequencies kept (m1 = nx/2),
# and m2 = ny/2 + 1 reaching the Nyquist bin of an even ny (8 x 6, 10 x 22, 13 x 10)
SIZES = [(39, 39, 12), (32, 32, 12), (8, 6, 4), (9, 7, 4), (10, 22, 12), (13, 10, 6), (5, 3, 2), (40, 41, 5)]


@pytest.mark.parametrize(("nx", "ny", "modes"), SIZES)
def test_dft_spectral_conv_equals_the_fft(nx, ny, modes):
    torch.manual_seed(nx * 100 + ny)
    conv = SpectralConv2d(6, 5, modes)
    conv.weight.data.uniform_(-1.0, 1.0)  # weights of order 1, not the init's 1 / (in out), and complex
    x = torch.randn(3, 6, nx, ny)
    assert (conv(x) - fft_reference(conv, x)).abs().max().item() < 1e-5
    conv64, x64 = conv.double(), x.double().requires_grad_()
    out, ref = conv64(x64), fft_reference(conv64, x64)
    assert (out - ref).abs().max().item() < 1e-12
    # the gradients that training uses agree as well
    probe = torch.randn_like(out)
    g_out = torch.autograd.grad((out * probe).sum(), (x64, conv64.weight))
    g_ref = torch.autograd.grad((ref * probe).sum(), (x64, conv64.weight))
    for a, b in zip(g_out, g_ref, strict=True):
        assert (a - b).abs().max().item() < 1e-11
    assert set(conv.state_dict()) == {"weight"}  # the DFT matrices are no state: the safetensors files load as ever



def test_dft_matrices_cached_under_inference_mode_serve_training():
    conv = SpectralConv2d(2, 2, 3)
    with torch.inference_mode():  # the first call at this size (the node, an evaluation) fills the cache
        conv(torch.randn(1, 2, 11, 17))
    x = torch.randn(1, 2, 11, 17, requires_grad=True)
    conv(x).square().sum().backward()  # autograd accepts the cached matrices
    assert x.grad is not None and conv.weight.grad is not None

def windows(card, seed: int = 0, count: int = 3) -> np.ndarray:
    """``count`` model inputs on the card's grid: V0 the signed distance of 3 random disks, a random speed and
    heading (slice models), the card's own robot in the parameter channels, as the node builds them."""
    rng = np.random.default_rng(seed)
    grid, spec = card.grid, InputSpec.from_dict(card.inputs)
    points = np.stack(np.meshgrid(grid.axis(0), grid.axis(1), indexing="ij"), -1)
    params = None
    if spec.param_ranges:
        robot = dataclasses.asdict(card.dynamics)
        params = np.array([[param_value(robot, name) for name in spec.param_ranges]], np.float32)
    out = []
    for _ in range(count):
        disks = [Disk(tuple(rng.uniform(-0.8, 0.8, 2) * grid.hi[:2]), float(rng.uniform(0.3, 1.5))) for _ in range(3)]
        v0 = union_sdf(disks, points).astype(np.float32)
        v, heading = rng.uniform(*spec.v_range, 1), rng.uniform(-np.pi, np.pi, 1)
        out.append(spec.inputs(v0[None], v, heading, params).numpy())
    return np.concatenate(out)


@pytest.mark.parametrize("stem", BUNDLED)
def test_bundled_model_exports_and_onnxruntime_equals_torch(stem, tmp_path):
    model, card = load_typed(MODELS / stem, "cpu")
    spec = InputSpec.from_dict(card.inputs)
    shape = tuple(card.grid.shape[:2])
    path = tmp_path / f"{stem}.onnx"
    record = export_onnx(model, spec.in_channels, shape, path)
    assert record == {"file": f"{stem}.onnx", "sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
                      "input": {"name": "x", "shape": ["batch", spec.in_channels, *shape]},
                      "output": {"name": "y", "shape": ["batch", spec.out_channels, *shape]},
                      "opset": record["opset"]}
    assert record["opset"] >= 17
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]  # one file, no temporary left
    assert str(MODELS.parent).encode() not in path.read_bytes()  # no debug notes naming this checkout
    assert not model.training
    x = windows(card)
    with torch.no_grad():
        assert 0.1 < np.abs(model(torch.from_numpy(x)).numpy()).max() < 10  # outputs of order 1
    assert check_export(model, path, x) < 1e-5  # the free batch: 3 windows, then 1
    assert check_export(model, path, x[:1]) < 1e-5



@pytest.mark.parametrize(("kind", "config"), [("tno", {"d_model": 16, "n_heads": 2, "n_layers": 2, "latent": 8}),
                                              ("fno", {"width": 8, "modes": 20, "n_layers": 2, "proj": 16,
                                                       "prior": "below_input"})])
def test_other_operators_export_on_a_non_square_grid(kind, config, tmp_path):
    torch.manual_seed(0)
    model = build_model(kind, in_channels=3, **config)
    record = export_onnx(model, 3, (30, 41), tmp_path / "model.onnx")
    assert record["input"]["shape"] == ["batch", 3, 30, 41] and record["output"]["shape"] == ["batch", 1, 30, 41]
    assert model.training  # left as it was
    assert check_export(model, tmp_path / "model.onnx", np.random.default_rng(0).normal(size=(3, 3, 30, 41))) < 1e-5

def tiny_model() -> nn.Module:
    torch.manual_seed(0)
    return nn.Sequential(nn.Conv2d(2, 3, 1), nn.GELU())


def test_a_failed_write_leaves_the_old_file_or_none(tmp_path, monkeypatch):
    path = tmp_path / "model.onnx"
    real_write = Path.write_bytes

    def half_then_fail(self, data):
        real_write(self, data[: len(data) // 2])
        raise OSError("disk full")

    with monkeypatch.context() as patch:
        patch.setattr(Path, "write_bytes", half_then_fail)
        with pytest.raises(OSError, match="disk full"):
            export_onnx(tiny_model(), 2, (8, 8), path)
    assert list(tmp_path.iterdir()) == []  # neither the file nor its half-written temporary

    export_onnx(tiny_model(), 2, (8, 8), path)
    before = path.read_bytes()
    with monkeypatch.context() as patch:
        patch.setattr(Path, "write_bytes", half_then_fail)
        with pytest.raises(OSError, match="disk full"):
            export_onnx(nn.Sequential(nn.Conv2d(2, 3, 1)), 2, (8, 8), path)
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == [path.name]

    blocked = tmp_path / "not_a_folder"
    blocked.write_text("")
    with pytest.raises(OSError):
        export_onnx(tiny_model(), 2, (8, 8), blocked / "model.onnx")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([path.name, blocked.name])


class FixedBatch(nn.Module):
    """Uses the batch size as a number: torch.export can only trace it at the example's batch."""

    def __init__(self) -> None:
        super().__init__()
        self.conv = nn.Conv2d(2, 1, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv(x) / float(x.shape[0])


def test_a_graph_with_a_fixed_batch_is_refused(tmp_path):
    with pytest.raises(ValueError, match="exported ONNX graph"):
        export_onnx(FixedBatch(), 2, (8, 8), tmp_path / "model.onnx")
    assert list(tmp_path.iterdir()) == []
    assert onnx_export.OPSET >= 17
