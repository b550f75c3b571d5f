"""map_server's map files (YAML + PGM) loaded as map_server loads them (hjrno_ros.core.map_file)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hjrno_ros.core.map_file import load_map, occupancy_from_pixels, read_pgm

ROOT = Path(__file__).resolve().parents[2]
DEPOT = ROOT.parent / "shared" / "maps" / "depot.yaml"  # CI has ../shared beside the clone

YAML = """image: {image}
mode: {mode}
resolution: 0.1
origin: [-1.0, 2.0, 0.0]
negate: {negate}
occupied_thresh: 0.65
free_thresh: 0.25
"""
# 3 columns x 2 rows; first row is the top of the map
PIXELS = np.array([[0, 128, 254],
                   [255, 200, 100]], np.uint8)


def write_map(folder: Path, pixels: np.ndarray = PIXELS, mode: str = "trinary", negate: int = 0, ascii_pgm=False,
              yaml_text: str | None = None, maxval: int = 255) -> Path:
    h, w = pixels.shape
    if ascii_pgm:
        body = "\n".join(" ".join(str(v) for v in row) for row in pixels)
        (folder / "m.pgm").write_text(f"P2\n# a comment\n{w} {h}\n{maxval}\n{body}\n")
    else:
        (folder / "m.pgm").write_bytes(f"P5\n# made by a test\n{w} {h}\n{maxval}\n".encode() + pixels.tobytes())
    path = folder / "m.yaml"
    path.write_text(yaml_text if yaml_text is not None else YAML.format(image="m.pgm", mode=mode, negate=negate))
    return path


def test_trinary_map_as_map_server_loads_it(tmp_path):
    m = load_map(write_map(tmp_path))
    assert m.occupancy.dtype == np.int8 and m.occupancy.shape == (3, 2)  # [ix, iy]
    assert m.resolution == 0.1 and m.origin == (-1.0, 2.0) and m.size == pytest.approx((0.3, 0.2))
    # occ = 1 - pixel/255: 0 -> 1.0 (occupied), 128 -> 0.498 (unknown), 254 -> 0.004 (free); 255 -> free,
    # 200 -> 0.216 (free), 100 -> 0.608 (unknown)
    top, bottom = m.occupancy[:, 1], m.occupancy[:, 0]  # the image's first row is the largest y
    assert top.tolist() == [100, -1, 0] and bottom.tolist() == [0, 0, -1]


def test_ascii_pgm_equals_binary(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a = load_map(write_map(tmp_path / "a")).occupancy
    b = load_map(write_map(tmp_path / "b", ascii_pgm=True)).occupancy
    np.testing.assert_array_equal(a, b)


def test_negate_scale_and_raw_modes(tmp_path):
    for sub in ("neg", "scale", "raw"):
        (tmp_path / sub).mkdir()
    neg = load_map(write_map(tmp_path / "neg", negate=1)).occupancy
    assert neg[:, 1].tolist() == [0, -1, 100]  # occ = pixel/255: black is free
    scale = load_map(write_map(tmp_path / "scale", mode="scale")).occupancy
    # 128 -> occ 0.498: rint((0.498 - 0.25) / 0.4 * 100) = 62; 100 -> occ 0.608: rint(89.46) = 89
    assert scale[:, 1].tolist() == [100, 62, 0] and scale[:, 0].tolist() == [0, 0, 89]
    raw = load_map(write_map(tmp_path / "raw", mode="raw")).occupancy
    assert raw[:, 1].tolist() == [0, -1, -1] and raw[:, 0].tolist() == [-1, -1, 100]  # the value itself if <= 100


def test_pixel_rule_matches_the_documented_thresholds():
    pixels = np.arange(256, dtype=np.uint8)[None]  # one row
    occ = occupancy_from_pixels(pixels, 255)[:, 0]
    p = (255 - np.arange(256)) / 255
    expected = np.where(p > 0.65, 100, np.where(p < 0.25, 0, -1))
    np.testing.assert_array_equal(occ, expected)


def test_maxval_below_255_scales(tmp_path):
    pixels = np.array([[0, 50, 100]], np.uint8)
    occ = load_map(write_map(tmp_path, pixels=pixels, maxval=100)).occupancy[:, 0]
    assert occ.tolist() == [100, -1, 0]


@pytest.mark.parametrize(("change", "message"), [
    (lambda y: y.replace("origin: [-1.0, 2.0, 0.0]", "origin: [-1.0, 2.0, 0.5]"), "origin yaw 0.5 is not supported"),
    (lambda y: y.replace("origin: [-1.0, 2.0, 0.0]", "origin: [1, 2]"), "'origin' must be three finite numbers"),
    (lambda y: y.replace("resolution: 0.1", "resolution: -0.1"), "'resolution' must be > 0"),
    (lambda y: y.replace("resolution: 0.1", "resolution: .nan"), "'resolution' must be a finite number"),
    (lambda y: y.replace("resolution: 0.1\n", ""), "missing key(s) resolution"),
    (lambda y: y.replace("mode: trinary", "mode: fancy"), "'mode' must be one of"),
    (lambda y: y.replace("negate: 0", "negate: 2"), "'negate' must be 0 or 1"),
    (lambda y: y.replace("free_thresh: 0.25", "free_thresh: 0.9"), "free_thresh <= occupied_thresh"),
    (lambda y: y.replace("image: m.pgm", "image: missing.pgm"), "cannot read the map image"),
    (lambda y: "just text", "a map YAML must be a mapping"),
    (lambda y: "a: [1, 2", "not valid YAML"),
])
def test_bad_yaml_is_one_line_value_error(tmp_path, change, message):
    path = write_map(tmp_path)
    path.write_text(change(path.read_text()))
    with pytest.raises(ValueError) as err:
        load_map(path)
    assert message in str(err.value) and "\n" not in str(err.value) and str(path.parent) in str(err.value)


@pytest.mark.parametrize(("content", "message"), [
    (b"P6\n1 1\n255\n\x00\x00\x00", "not a PGM image"),
    (b"P5\n3 2\n", "truncated PGM header"),
    (b"P5\n3 2\n65535\n" + bytes(12), "only 8-bit images"),
    (b"P5\n3 2\n255\n\x00\x00", "PGM data has 2 bytes, 3 x 2 = 6 expected"),
    (b"P5\n3 x\n255\n", "bad PGM header value"),
    (b"P2\n2 1\n10\n5 11\n", "PGM value 11 exceeds maxval 10"),
    (b"P2\n2 1\n255\n5\n", "PGM data has 1 values"),
])
def test_bad_pgm_is_one_line_value_error(tmp_path, content, message):
    (tmp_path / "bad.pgm").write_bytes(content)
    with pytest.raises(ValueError) as err:
        read_pgm(tmp_path / "bad.pgm")
    assert message in str(err.value) and "\n" not in str(err.value)


def test_missing_yaml_is_one_line_value_error(tmp_path):
    with pytest.raises(ValueError, match="cannot read the map YAML"):
        load_map(tmp_path / "nope.yaml")


@pytest.mark.skipif(not DEPOT.is_file(), reason="../shared/maps/depot.yaml not beside the checkout")
def test_depot_map_facts():
    """The depot map's documented facts (../shared/maps/README.md)."""
    m = load_map(DEPOT)
    assert m.occupancy.shape == (604, 307) and m.resolution == 0.05 and m.origin == (0.0, 0.0)
    assert set(np.unique(m.occupancy)) <= {-1, 0, 100}
    pixels, maxval = read_pgm(DEPOT.parent / "depot.pgm")
    assert maxval == 255 and pixels.shape == (307, 604)
    # the first image row is the map's top: pixel (row r, column c) is cell (c, 306 - r)
    p = (255 - pixels.astype(float)) / 255
    expected = np.where(p > 0.65, 100, np.where(p < 0.25, 0, -1))
    np.testing.assert_array_equal(m.occupancy, expected[::-1].T)
    from hjrno_ros.core.geometry import occupancy_signed_distance

    widest = float(occupancy_signed_distance(m.occupancy, m.resolution).max())
    assert widest == pytest.approx(4.48, abs=0.05)  # "Widest free spot: 4.48 m from the nearest obstacle"
