"""HDF5 files written atomically and read with validation.

A file is written to a temporary sibling, flushed to disk and renamed over the target, so a
crash never leaves a half-written file under the real name.  Metadata is JSON in attributes.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np

from .grids import GridSpec

SOLUTION_FORMAT = "hjrno-solution-1"


def atomic_h5(path: str | os.PathLike, write: Callable[[h5py.File], None]) -> Path:
    """Call ``write(f)`` on a temporary HDF5 file, then move it to ``path`` in one rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the file the usual permissions
    try:
        with h5py.File(tmp, "w") as f:
            write(f)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


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
