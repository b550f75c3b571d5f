"""Shared fixtures: the tiny ``ci`` dataset (real solves) and a tiny FNO trained on it (real torch)."""

import time
from pathlib import Path

import numpy as np
import pytest

from hjrno_ros.datasets import dataset
from hjrno_ros.learning import checkpoint
from hjrno_ros.learning.training import TrainConfig, train

SMALL = {"width": 8, "modes": 4, "n_layers": 2}
pytest_plugins = ["dds_driver"]  # the DDS tests' fixtures (model_stem, ros) for every folder
TEST_ROOT = Path(__file__).parent


def pytest_configure(config):
    config.addinivalue_line("markers", "real_time: runs ROS 2 over DDS, a node process or a simulator in real time")


def pytest_collection_modifyitems(config, items):
    """For ``pytest -n 2 --dist loadgroup`` (``make test``): the real-time tests (marked ``real_time``, and all of
    test/ros) run one after the other on one worker, so that no two of them share a ROS domain (each takes its own
    from its process id) or wait for the CPU behind another's node; every other file is a unit that the other
    worker takes (its module fixtures are made once)."""
    for item in items:
        path = Path(item.fspath).relative_to(TEST_ROOT)
        real_time = item.get_closest_marker("real_time") is not None or path.parts[0] == "ros"
        item.add_marker(pytest.mark.xdist_group("real_time" if real_time else str(path)))


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
    """A copy of a model (weights + card, and the ONNX file its card lists) as ``folder/model``, to change its card
    freely."""
    for src in checkpoint.paths(stem):
        (folder / ("model" + src.suffix)).write_bytes(src.read_bytes())
    onnx = checkpoint.load_card(stem).get("onnx")
    if onnx:
        (folder / onnx["file"]).write_bytes(checkpoint.paths(stem)[1].with_name(onnx["file"]).read_bytes())
    return folder / "model"


def wait_for(predicate, timeout: float) -> bool:
    """Poll ``predicate`` every 10 ms for up to ``timeout`` s; its last value."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.01)
    return bool(predicate())


def safe_starts(table, v_min: float, rng: np.random.Generator, count: int = 600, at_rest: float = 0.0) -> np.ndarray:
    """``count`` states (x, y, v, θ) with V > 0.02 in a 9 m × 9 m scene, drawn from 20000 uniform ones (speeds
    from ``v_min`` to 1 m/s, the fraction ``at_rest`` of them at v = 0), in random order."""
    n = 20000
    x0 = np.column_stack([rng.uniform(-4.5, 4.5, n), rng.uniform(-4.5, 4.5, n), rng.uniform(v_min, 1.0, n),
                          rng.uniform(-np.pi, np.pi, n)])
    x0[: int(n * at_rest), 2] = 0.0
    safe = x0[table.value(x0) > 0.02]
    return safe[rng.permutation(len(safe))][:count]


def assert_slower_never_less_safe(forward, reversing) -> None:
    """V rises toward higher |v| by less than the grid tolerances (forwards 1e-3 m on < 1 % of the speed steps;
    reversing, v from -0.6 to 1 m/s, 1e-2 m on < 2 %: the ridge at v = 0 is rounded off by the scheme) in two
    solves (problem, _, value, _).  Measured for the car: 7.5e-4 m forwards, 6.3e-3 m indoors reversing."""
    from hjrno_ros.truth.solver import rise_with_speed

    for (problem, _, value, _), tolerance, share in ((forward, 1e-3, 0.01), (reversing, 1e-2, 0.02)):
        rise = rise_with_speed(problem.grid, value)
        assert rise.max() < tolerance and np.mean(rise > 1e-6) < share, (rise.max(), np.mean(rise > 1e-6))
