"""Dataset generation on a local 2-worker Dask cluster equals the single-process run, sample for sample."""

import h5py
import numpy as np
import pytest

from hjrno_ros.datasets import dataset
from hjrno_ros.datasets.cluster import dask_executor

CONFIG = dataset.ExperimentConfig("tiny_plans", "plans", (12, 12, 3, 6), 3, 1, options={"robot": "product"},
                                  accel_ratio=(0.5, 4.0), solver={"accuracy": "medium", "max_horizon": 4.0})


def arrays(root):
    out = {}
    for split in dataset.SPLITS:
        with h5py.File(root / f"{split}.h5") as f:
            out[split] = {k: f[k][...] for k in ("target", "value", "converged")}
            out[split]["scenario"] = list(f["scenario"].asstr()[...])
    return out


def test_a_local_two_worker_dask_cluster_gives_the_single_process_result(tmp_path):
    single = dataset.generate(CONFIG, tmp_path / "single", progress=False)
    with dask_executor("local", workers=2) as executor:
        clustered = dataset.generate(CONFIG, tmp_path / "dask", progress=False, executor=executor)
    assert single["solved"] == clustered["solved"] == 4
    a, b = arrays(tmp_path / "single"), arrays(tmp_path / "dask")
    for split in dataset.SPLITS:
        assert a[split]["scenario"] == b[split]["scenario"]
        for key in ("target", "value", "converged"):
            assert np.array_equal(a[split][key], b[split][key]), (split, key)
    with dask_executor("local", workers=2) as executor:  # resumable: nothing left to solve
        assert dataset.generate(CONFIG, tmp_path / "dask", progress=False, executor=executor)["solved"] == 0


def test_an_unreachable_scheduler_is_one_clear_error():
    with pytest.raises(ValueError, match="cannot reach the Dask scheduler"), \
            dask_executor("tcp://127.0.0.1:9", workers=1, timeout_s=3):
        pass
