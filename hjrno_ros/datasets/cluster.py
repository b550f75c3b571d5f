"""Dataset generation on Dask distributed: the same samples, solved by a cluster's workers.

``hjrno generate --scheduler ADDRESS`` sends every missing sample of the experiment (or of its ``--shard``) to
the Dask scheduler at ADDRESS (``tcp://host:8786``; on SLURM, docs/training.md) as one task each; ``local`` starts
a local cluster of ``--workers`` single-threaded processes.  Each task is :func:`dataset.write_sample`, so the
workers write the atomic sample files themselves (they must share the experiment folder) and the run is
resumable exactly as a local one; the result is bit-for-bit that of a single-process run (test_cluster.py).
Dask moves the task arguments (config, folder, split, index) with cloudpickle between our own processes; no
artifact is ever read as a pickle.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from concurrent.futures import Executor


@contextlib.contextmanager
def dask_executor(scheduler: str, workers: int = 2, timeout_s: float = 30.0) -> Iterator[Executor]:
    """A concurrent.futures executor on the Dask scheduler at ``scheduler``, or on a local cluster of
    ``workers`` single-threaded processes for ``"local"``; ValueError when the scheduler does not answer within
    ``timeout_s``."""
    from distributed import Client, LocalCluster  # only here: the local path needs no Dask

    if scheduler == "local":
        if workers < 1:
            raise ValueError(f"--workers must be >= 1, got {workers}")
        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
                Client(cluster) as client:
            yield client.get_executor(pure=False)
    else:
        try:
            client = Client(scheduler, timeout=timeout_s)
        except (OSError, TimeoutError) as err:
            raise ValueError(f"cannot reach the Dask scheduler at {scheduler!r}: {err}") from None
        with client:
            yield client.get_executor(pure=False)
