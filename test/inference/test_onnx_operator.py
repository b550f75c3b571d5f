"""The node's operator on onnxruntime: the same values as torch, and an ONNX file that contradicts its card (another
file, other tensors, an export older than the card's weights or wrapping, no file) refused with one line."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import copy_model

from hjrno_ros.core.model_card import ModelCard, paths
from hjrno_ros.inference.onnx_operator import onnx_values

ROOT = Path(__file__).resolve().parents[2]
MODELS = ROOT / "models"


def v0_window(shape: tuple[int, int]) -> np.ndarray:
    """A signed distance (m) to a disk and a wall on a 10 m window."""
    x, y = np.meshgrid(np.linspace(-5, 5, shape[0]), np.linspace(-5, 5, shape[1]), indexing="ij")
    return np.minimum(np.hypot(x - 1.5, y + 0.5) - 0.6, 4.0 - y).astype(np.float32)


@pytest.mark.parametrize("name", ["default", "car_fno"])
def test_onnxruntime_gives_torchs_tables(name):
    """The whole-table default and a slice model (a stencil around a state, reversing too): onnxruntime's table
    equals torch's within 1e-5 m."""
    from hjrno_ros.learning.value_function import LearnedValueFunction

    torch_vf = LearnedValueFunction(MODELS / name, device="cpu")
    onnx_vf = onnx_values(MODELS / name, ModelCard.load(MODELS / name), "cpu")
    assert (onnx_vf.runtime, torch_vf.runtime) == ("onnxruntime", "torch")
    v0 = v0_window(onnx_vf.shape)
    for v, theta in ((0.4, 0.3), (-0.2, -2.9)):
        (grid_a, a), (grid_b, b) = (vf.local_values(v0, (2.0, -1.0), v, theta, reach=(0.3, 0.5))
                                    for vf in (onnx_vf, torch_vf))
        assert grid_a == grid_b and a.shape == b.shape
        assert np.abs(a - b).max() < 1e-5, np.abs(a - b).max()


def test_an_onnx_file_that_is_not_the_cards_is_refused(tmp_path):
    stem = copy_model(MODELS / "product_cnn", tmp_path)
    card = ModelCard.load(stem)
    assert onnx_values(stem, card, "cpu").table is not None  # the copy loads
    onnx = tmp_path / "product_cnn.onnx"
    data = bytearray(onnx.read_bytes())
    data[-10] ^= 0xFF
    onnx.write_bytes(bytes(data))
    with pytest.raises(ValueError, match="SHA-256 .* differs from its card's") as err:
        onnx_values(stem, card, "cpu")
    assert "\n" not in str(err.value)
    onnx.unlink()
    with pytest.raises(ValueError, match="the ONNX file its card lists is missing"):
        onnx_values(stem, card, "cpu")


def test_an_onnx_file_whose_tensors_contradict_its_card_is_refused(tmp_path):
    """The default's export (144 outputs) put under the product CNN's card, hash and all: its tensors are not the
    card's."""
    stem = copy_model(MODELS / "product_cnn", tmp_path)
    shutil.copy(MODELS / "default.onnx", tmp_path / "product_cnn.onnx")
    raw = json.loads(paths(stem)[1].read_text())
    raw["onnx"]["sha256"] = ModelCard.load(MODELS / "default").onnx.sha256
    paths(stem)[1].write_text(json.dumps(raw))
    with pytest.raises(ValueError, match="contradict its card's"):
        onnx_values(stem, ModelCard.load(stem), "cpu")
    raw["onnx"]["output"]["shape"] = ["batch", 7, 32, 32]  # the card itself inconsistent: refused when read
    paths(stem)[1].write_text(json.dumps(raw))
    with pytest.raises(ValueError, match="onnx.output.shape"):
        ModelCard.load(stem)


def test_an_export_older_than_the_cards_wrapping_is_refused_until_refreshed(tmp_path):
    from hjrno_ros.learning.onnx_export import refresh_export

    stem = copy_model(MODELS / "product_cnn", tmp_path)
    assert refresh_export(stem) is None  # up to date: nothing to do
    raw = json.loads(paths(stem)[1].read_text())
    raw["symmetry_average"] = not raw.get("symmetry_average", False)  # as calibration may change it
    paths(stem)[1].write_text(json.dumps(raw))
    with pytest.raises(ValueError, match="predates the card's weights or its symmetry_average"):
        onnx_values(stem, ModelCard.load(stem), "cpu")
    record = refresh_export(stem)
    assert record is not None and record["network"]["symmetry_average"] == raw["symmetry_average"]
    assert onnx_values(stem, ModelCard.load(stem), "cpu").runtime == "onnxruntime"


def test_the_node_picks_its_runtime_from_the_card_and_its_parameter(tmp_path):
    pytest.importorskip("rclpy")
    from hjrno_ros.ros.brt_node.config import NodeConfig
    from hjrno_ros.ros.brt_node.value_sources import load_model

    assert load_model(NodeConfig())[1].runtime == "onnxruntime"  # the bundled default: no torch needed
    assert load_model(NodeConfig(inference_runtime="torch"))[1].runtime == "torch"
    stem = copy_model(MODELS / "product_cnn", tmp_path)
    raw = json.loads(paths(stem)[1].read_text())
    del raw["onnx"]
    paths(stem)[1].write_text(json.dumps(raw))
    assert load_model(NodeConfig(model_path=str(stem), robot_model="car"))[1].runtime == "torch"  # auto: no export
    with pytest.raises(ValueError, match="lists no ONNX export"):
        load_model(NodeConfig(model_path=str(stem), robot_model="car", inference_runtime="onnx"))
