"""Versions of this package and the libraries that shape its numbers, for file metadata."""

from __future__ import annotations

import platform
from importlib import metadata

from hjrno_ros import __version__

_LIBRARIES = ("numpy", "scipy", "jax", "jaxlib", "hj-reachability", "torch", "h5py")


def versions() -> dict[str, str]:
    out = {"hjrno_ros": __version__, "python": platform.python_version()}
    for name in _LIBRARIES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "missing"
    return out
