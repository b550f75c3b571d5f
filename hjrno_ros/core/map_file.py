"""Occupancy maps from map_server's files (a YAML + an 8-bit PGM), loaded as Nav2's map_server does.

map_server itself is not on PyPI; this is the part of it the tests and benchmarks need (nav2_map_server's
``map_io``): the YAML's ``image`` (relative to the YAML), ``resolution``, ``origin`` [x, y, yaw],
``negate``, ``occupied_thresh``, ``free_thresh`` and ``mode``; the image as binary (P5) or ASCII (P2)
PGM with a maximum value ≤ 255.  Per pixel, shade = pixel / maxval and occ = shade if ``negate`` else
1 − shade; then

- ``trinary`` (the default): occ > occupied_thresh → 100, occ < free_thresh → 0, else −1 (unknown);
- ``scale``: the same ends, and in between round(100 (occ − free) / (occupied − free));
- ``raw``: round(255 shade) when it lies in 0..100, else −1.

The raster is ``[ix, iy]`` (docs/design.md, "Conventions"): the image's first row is the map's top (the
largest y).  Only axis-aligned maps are supported (the node refuses rotated ones): a non-zero origin yaw
is refused.  Every problem is one ``ValueError`` line naming the file.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from pathlib import Path

import numpy as np

MODES = ("trinary", "scale", "raw")


@dataclasses.dataclass(frozen=True)
class MapFile:
    """A loaded map: ``occupancy`` int8 ``[ix, iy]`` in {−1, 0..100}, cell size (m), lower-left corner (m)."""

    occupancy: np.ndarray
    resolution: float
    origin: tuple[float, float]
    image: Path

    @property
    def size(self) -> tuple[float, float]:
        """(width, height) in metres."""
        return self.occupancy.shape[0] * self.resolution, self.occupancy.shape[1] * self.resolution


def read_pgm(path: str | os.PathLike) -> tuple[np.ndarray, int]:
    """(pixels ``[row, col]`` as uint8 with row 0 the image's top, maxval) of an 8-bit P5 or P2 PGM."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as err:
        raise ValueError(f"{path}: cannot read the map image: {err.strerror or err}") from None
    magic = data[:2]
    if magic not in (b"P5", b"P2"):
        raise ValueError(f"{path}: not a PGM image (magic {magic!r}; P5 or P2 expected)")
    header, pos = [], 2
    token = re.compile(rb"\s*(?:#[^\n]*\n\s*)*([^\s#]+)")  # whitespace and comments, then one token
    for _ in range(3):  # width, height, maxval
        m = token.match(data, pos)
        if m is None:
            raise ValueError(f"{path}: truncated PGM header")
        try:
            header.append(int(m.group(1)))
        except ValueError:
            raise ValueError(f"{path}: bad PGM header value {m.group(1)!r}") from None
        pos = m.end()
    width, height, maxval = header
    if width < 1 or height < 1:
        raise ValueError(f"{path}: PGM size {width} x {height} is empty")
    if not 1 <= maxval <= 255:
        raise ValueError(f"{path}: PGM maxval {maxval}: only 8-bit images (maxval <= 255) are supported")
    n = width * height
    if magic == b"P5":
        pos += 1  # exactly one whitespace byte after maxval
        if len(data) - pos < n:
            raise ValueError(f"{path}: PGM data has {max(len(data) - pos, 0)} bytes, {width} x {height} = {n} expected")
        pixels = np.frombuffer(data, np.uint8, n, pos)
    else:
        body = re.sub(rb"#[^\n]*", b"", data[pos:]).split()
        if len(body) < n:
            raise ValueError(f"{path}: PGM data has {len(body)} values, {width} x {height} = {n} expected")
        try:
            pixels = np.array([int(v) for v in body[:n]], np.int64)
        except ValueError:
            raise ValueError(f"{path}: non-integer value in the PGM data") from None
    if pixels.max() > maxval:
        raise ValueError(f"{path}: PGM value {int(pixels.max())} exceeds maxval {maxval}")
    return pixels.astype(np.uint8).reshape(height, width), maxval


def _number(meta: dict, key: str, path: Path) -> float:
    value = meta.get(key)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{path}: '{key}' must be a finite number, got {value!r}")
    return float(value)


def occupancy_from_pixels(pixels: np.ndarray, maxval: int, mode: str = "trinary", negate: bool = False,
                          occupied_thresh: float = 0.65, free_thresh: float = 0.25) -> np.ndarray:
    """map_server's pixel → occupancy rule; ``pixels`` ``[row, col]`` (row 0 = top) → int8 ``[ix, iy]``."""
    shade = pixels.astype(np.float64) / maxval
    occ = shade if negate else 1.0 - shade
    if mode == "raw":
        value = np.round(shade * 255.0)
        cells = np.where((value >= 0) & (value <= 100), value, -1)
    else:
        middle = -1.0 if mode == "trinary" else np.rint((occ - free_thresh) / (occupied_thresh - free_thresh) * 100.0)
        cells = np.where(occ > occupied_thresh, 100, np.where(occ < free_thresh, 0, middle))
    return np.ascontiguousarray(cells.astype(np.int8)[::-1].T)  # rows bottom-up = iy, columns = ix


def load_map(yaml_path: str | os.PathLike) -> MapFile:
    """Load a map_server map (YAML + PGM) as map_server would; one ``ValueError`` line on any problem."""
    import yaml

    path = Path(yaml_path)
    try:
        meta = yaml.safe_load(path.read_text())
    except OSError as err:
        raise ValueError(f"{path}: cannot read the map YAML: {err.strerror or err}") from None
    except yaml.YAMLError as err:
        raise ValueError(f"{path}: not valid YAML: {str(err).splitlines()[0]}") from None
    if not isinstance(meta, dict):
        raise ValueError(f"{path}: a map YAML must be a mapping, got {type(meta).__name__}")
    missing = [k for k in ("image", "resolution", "origin", "occupied_thresh", "free_thresh", "negate")
               if k not in meta]
    if missing:
        raise ValueError(f"{path}: missing key(s) {', '.join(missing)}")
    resolution = _number(meta, "resolution", path)
    if resolution <= 0:
        raise ValueError(f"{path}: 'resolution' must be > 0, got {resolution}")
    origin = meta["origin"]
    if (not isinstance(origin, list) or len(origin) != 3
            or not all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in origin)):
        raise ValueError(f"{path}: 'origin' must be three finite numbers [x, y, yaw], got {origin!r}")
    if origin[2] != 0:
        raise ValueError(f"{path}: origin yaw {origin[2]} is not supported: only axis-aligned maps (yaw 0)")
    occupied, free = _number(meta, "occupied_thresh", path), _number(meta, "free_thresh", path)
    if not 0.0 <= free <= occupied <= 1.0:
        raise ValueError(f"{path}: need 0 <= free_thresh <= occupied_thresh <= 1, got {free} and {occupied}")
    negate = meta["negate"]
    if negate not in (0, 1):  # map_server reads it as an int (0 or 1); YAML's true/false compare equal
        raise ValueError(f"{path}: 'negate' must be 0 or 1, got {negate!r}")
    mode = str(meta.get("mode", "trinary")).lower()
    if mode not in MODES:
        raise ValueError(f"{path}: 'mode' must be one of {', '.join(MODES)}, got {meta.get('mode')!r}")
    if mode == "scale" and occupied == free:
        raise ValueError(f"{path}: scale mode needs free_thresh < occupied_thresh")
    image = meta["image"]
    if not isinstance(image, str) or not image:
        raise ValueError(f"{path}: 'image' must be a file name, got {image!r}")
    image_path = path.parent / image
    pixels, maxval = read_pgm(image_path)
    occupancy = occupancy_from_pixels(pixels, maxval, mode, bool(negate), occupied, free)
    return MapFile(occupancy, resolution, (float(origin[0]), float(origin[1])), image_path)
