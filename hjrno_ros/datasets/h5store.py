"""HDF5 files written atomically (see ``atomic``) and read with validation; metadata is JSON."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np

from hjrno_ros.core.atomic import atomic_write
from hjrno_ros.core.grids import GridSpec

SOLUTION_FORMAT = "hjrno-solution-1"


def atomic_h5(path: str | os.PathLike, write: Callable[[h5py.File], None]) -> Path:
    """Call ``write(f)`` on a new HDF5 file that appears at ``path`` in one rename."""

    def create(tmp: str) -> None:
        with h5py.File(tmp, "w") as f:
            write(f)

    return atomic_write(path, create)


def write_solution(path, grid: GridSpec, target: np.ndarray, value: np.ndarray, meta: dict) -> Path:
    """Store one solved problem: l and V∞ on ``grid``, plus JSON metadata (report, parameters, ...)."""

    def write(f: h5py.File) -> None:
        f.attrs["format"] = SOLUTION_FORMAT
        f.attrs["grid"] = json.dumps(grid.as_dict())
        f.attrs["meta"] = json.dumps(meta)
        f.create_dataset("target", data=np.asarray(target, np.float32), compression="gzip")
        f.create_dataset("value", data=np.asarray(value, np.float32), compression="gzip")

    return atomic_h5(path, write)


def read_solution(path) -> tuple[GridSpec, np.ndarray, np.ndarray, dict]:
    """(grid, l, V∞, meta) from a file of :func:`write_solution`; ValueError if it is not one."""
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != SOLUTION_FORMAT:
                raise ValueError(f"{path}: not an hjrno solution file (format {f.attrs.get('format')!r})")
            grid = GridSpec.from_dict(json.loads(f.attrs["grid"]))
            target, value = f["target"][...], f["value"][...]
            meta = json.loads(f.attrs["meta"])
    except (OSError, KeyError) as err:
        raise ValueError(f"{path}: unreadable or incomplete solution file ({err})") from None
    if target.shape != grid.shape or value.shape != grid.shape:
        raise ValueError(f"{path}: arrays {target.shape}/{value.shape} do not match grid {grid.shape}")
    return grid, target, value, meta
