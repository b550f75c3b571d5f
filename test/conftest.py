"""Shared fixtures: the tiny ``ci`` dataset (real solves) and a tiny FNO trained on it (real torch)."""

import time
from pathlib import Path

import pytest

from hjrno_ros.datasets import dataset
from hjrno_ros.learning import checkpoint
from hjrno_ros.learning.training import TrainConfig, train

SMALL = {"width": 8, "modes": 4, "n_layers": 2}


@pytest.fixture(scope="session")
def ci_data(tmp_path_factory):
    root = tmp_path_factory.mktemp("ci_data")
    dataset.generate(dataset.load_config("ci"), root, progress=False)
    return root


@pytest.fixture(scope="session")
def trained(ci_data, tmp_path_factory):
    out = tmp_path_factory.mktemp("model") / "fno"
    cfg = TrainConfig(data=str(ci_data), model="fno", model_config=SMALL, epochs=3, slices_per_epoch=256,
                      batch=16, lr=3e-3, out=str(out))
    train(cfg, progress=False, command="test")
    return cfg, out


def copy_model(stem, folder: Path) -> Path:
    """A copy of a model (weights + card) as ``folder/model``, to change its card freely."""
    for src in checkpoint.paths(stem):
        (folder / ("model" + src.suffix)).write_bytes(src.read_bytes())
    return folder / "model"


def wait_for(predicate, timeout: float) -> bool:
    """Poll ``predicate`` every 10 ms for up to ``timeout`` s; its last value."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.01)
    return bool(predicate())
