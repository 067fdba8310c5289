"""Occupancy grid files: map_server YAML + image (as Nav2 reads and writes them), npz, PNG."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import shared_path
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from slamcli.errors import (
    ConfigError,
    ExportError,
    FormatError,
    InputError,
    MapError,
    UnknownFormatError,
)
from slamcli.formats.occupancy import (
    cell_to_world,
    read_map,
    read_map_npz,
    read_map_yaml,
    world_to_cell,
    write_map_npz,
    write_map_png,
    write_map_yaml,
)
from slamcli.types import OccupancyGrid

NAV2_MAPS = ["turtlebot3_world", "tb3_sandbox"]


def _pgm_pixels(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img is not None
    return img


def _assert_same_grid(a: OccupancyGrid, b: OccupancyGrid) -> None:
    assert a.prob.dtype == b.prob.dtype == np.float32
    np.testing.assert_array_equal(np.isnan(a.prob), np.isnan(b.prob))
    np.testing.assert_array_equal(a.prob, b.prob)  # NaN == NaN for assert_array_equal
    assert a.resolution_m == b.resolution_m
    assert tuple(a.origin_xy_yaw) == tuple(b.origin_xy_yaw)


def _write_map(folder: Path, pixels: np.ndarray, yaml_lines: str, name: str = "m.pgm") -> Path:
    """A hand-made map: ``pixels`` (image order, row 0 = top) saved as ``name`` plus a YAML."""
    if name.endswith(".pgm") and pixels.ndim == 2 and pixels.dtype == np.uint8:
        h, w = pixels.shape
        (folder / name).write_bytes(f"P5\n{w} {h}\n255\n".encode() + pixels.tobytes())
    else:
        assert cv2.imwrite(str(folder / name), pixels)
    yaml_path = folder / "m.yaml"
    yaml_path.write_text(f"image: {name}\n{yaml_lines}", encoding="utf-8")
    return yaml_path


BASE = "".join(
    [
        "resolution: 0.1\n",
        "origin: [0.0, 0.0, 0.0]\n",
        "negate: 0\n",
        "occupied_thresh: 0.65\n",
        "free_thresh: 0.25\n",
    ]
)


# --- Nav2's own maps ---------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAV2_MAPS)
def test_nav2_map_round_trips_byte_identically(name: str, tmp_path: Path) -> None:
    src = shared_path("maps", f"{name}.yaml")
    grid = read_map_yaml(src)
    written = write_map_yaml(tmp_path / f"{name}.yaml", grid)
    assert [p.name for p in written] == [f"{name}.yaml", f"{name}.pgm"]
    assert (tmp_path / f"{name}.yaml").read_bytes() == src.read_bytes()
    assert (tmp_path / f"{name}.pgm").read_bytes() == (src.parent / f"{name}.pgm").read_bytes()
    # and again from the copy: the same grid
    _assert_same_grid(read_map_yaml(tmp_path / f"{name}.yaml"), grid)


@pytest.mark.parametrize("name", NAV2_MAPS)
def test_nav2_map_cell_counts_match_pixel_values(name: str) -> None:
    src = shared_path("maps", f"{name}.yaml")
    grid = read_map_yaml(src)
    pixels = _pgm_pixels(src.parent / f"{name}.pgm")
    assert grid.prob.shape == pixels.shape == (384, 384)
    assert set(np.unique(pixels).tolist()) == {0, 205, 254}
    assert np.count_nonzero(grid.prob == 0.0) == np.count_nonzero(pixels == 254)
    assert np.count_nonzero(grid.prob == 1.0) == np.count_nonzero(pixels == 0)
    assert np.count_nonzero(np.isnan(grid.prob)) == np.count_nonzero(pixels == 205)
    # image row 0 is the top of the map: grid row r is image row H - 1 - r
    expected = np.where(pixels == 205, np.nan, np.where(pixels == 0, 1.0, 0.0))
    np.testing.assert_array_equal(grid.prob, np.flipud(expected).astype(np.float32))
    assert grid.resolution_m == 0.05
    assert grid.origin_xy_yaw == (-10.0, -10.0, 0.0)


def test_nav2_map_known_cell_world_coordinates() -> None:
    grid = read_map_yaml(shared_path("maps", "turtlebot3_world.yaml"))
    np.testing.assert_allclose(cell_to_world(grid, [0, 0]), [-9.975, -9.975], atol=1e-12)
    np.testing.assert_allclose(cell_to_world(grid, [383, 383]), [9.175, 9.175], atol=1e-12)
    np.testing.assert_allclose(cell_to_world(grid, [10, 20]), [-8.975, -9.475], atol=1e-12)
    assert world_to_cell(grid, [-9.975, -9.975]).tolist() == [0, 0]
    assert world_to_cell(grid, [0.0, 0.0]).tolist() == [200, 200]
    # an obstacle pixel and a free one, found in the PGM (image row = 383 - grid row)
    pixels = _pgm_pixels(shared_path("maps", "turtlebot3_world.pgm"))
    assert world_to_cell(grid, [1.08, -2.62]).tolist() == [147, 221]
    assert pixels[383 - 147, 221] == 0 and grid.prob[147, 221] == 1.0
    assert world_to_cell(grid, [0.825, -2.525]).tolist() == [149, 216]
    assert pixels[383 - 149, 216] == 254 and grid.prob[149, 216] == 0.0


def test_edited_grid_keeps_what_still_applies(tmp_path: Path) -> None:
    grid = read_map_yaml(shared_path("maps", "turtlebot3_world.yaml"))
    moved = dataclasses.replace(grid, origin_xy_yaw=(-10.5, -10.0, 0.0))
    yaml_path, pgm_path = write_map_yaml(tmp_path / "turtlebot3_world.yaml", moved)
    # the YAML no longer describes the grid: written anew, in map_saver's layout
    assert yaml_path.read_text() == (
        "image: turtlebot3_world.pgm\nmode: trinary\nresolution: 0.05\n"
        "origin: [-10.5, -10, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196"
    )
    # same size and resolution: the PGM header, comment included, still applies
    assert pgm_path.read_bytes().startswith(b"P5\n# CREATOR: Map_generator.cpp 0.050 m/pix\n")
    cropped = dataclasses.replace(grid, prob=grid.prob[:100, :50])
    _, pgm_path = write_map_yaml(tmp_path / "crop.yaml", cropped)
    assert pgm_path.read_bytes()[:15] == b"P5\n50 100\n255\n\xcd"


# --- writing what map_saver writes ----------------------------------------------------------


def test_fresh_grid_is_written_like_map_saver(tmp_path: Path) -> None:
    prob = np.array([[0.0, 1.0, np.nan], [0.3, 0.7, 0.2]], dtype=np.float32)
    grid = OccupancyGrid(prob, 0.05, (-1.5, 2.0, 0.0))
    yaml_path, pgm_path = write_map_yaml(tmp_path / "map.yaml", grid)
    assert yaml_path.read_text() == (
        "image: map.pgm\nmode: trinary\nresolution: 0.05\norigin: [-1.5, 2, 0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196"
    )
    data = pgm_path.read_bytes()
    assert data[:11] == b"P5\n3 2\n255\n"
    # image row 0 = grid's top row; 0.3 and 0.7 -> cells 30 (between: 205) and 70 (>= 65: 0)
    assert list(data[11:]) == [205, 0, 254, 254, 0, 205]


def test_yaml_numbers_keep_full_precision(tmp_path: Path) -> None:
    grid = OccupancyGrid(np.zeros((2, 2), np.float32), 0.025, (-12.345, 1e-5, 0.1234567))
    yaml_path, _ = write_map_yaml(tmp_path / "map.yaml", grid)
    assert "resolution: 0.025\norigin: [-12.345, 1e-05, 0.1234567]" in yaml_path.read_text()
    back = read_map_yaml(yaml_path)  # 1e-05 is a string to YAML 1.1; read as yaml-cpp does
    assert back.origin_xy_yaw == (-12.345, 1e-5, 0.1234567)


# --- round trips -------------------------------------------------------------------------------


@settings(max_examples=40, deadline=None)
@given(
    cells=hnp.arrays(
        np.float32,
        hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=12),
        elements=st.sampled_from([0.0, 1.0, float("nan")]),
    ),
    resolution=st.floats(1e-4, 10.0),
    origin=st.tuples(st.floats(-1e4, 1e4), st.floats(-1e4, 1e4), st.floats(-math.pi, math.pi)),
)
def test_trinary_round_trip_is_exact(tmp_path_factory, cells, resolution, origin) -> None:
    folder = tmp_path_factory.mktemp("trinary")
    grid = OccupancyGrid(cells, resolution, origin)
    write_map_yaml(folder / "map.yaml", grid)
    _assert_same_grid(read_map_yaml(folder / "map.yaml"), grid)


@pytest.mark.parametrize("seed", range(3))
def test_scale_round_trip_of_percent_steps(tmp_path: Path, seed: int) -> None:
    rng = np.random.default_rng(seed)
    cells = rng.integers(0, 101, size=(17, 23))
    prob = (cells.astype(np.float32) / np.float32(100)).astype(np.float32)
    prob[rng.random(prob.shape) < 0.2] = np.nan
    grid = OccupancyGrid(prob, 0.05, (1.0, -2.0, 0.5))
    yaml_path, image_path = write_map_yaml(tmp_path / "map.yaml", grid, mode="scale")
    assert image_path.name == "map.png"  # map_saver's default for scale: unknown = transparent
    text = yaml_path.read_text()
    assert "mode: scale" in text
    assert "occupied_thresh: 1\nfree_thresh: 0" in text
    _assert_same_grid(read_map_yaml(yaml_path), grid)


def test_every_percent_survives_scale_mode(tmp_path: Path) -> None:
    prob = (np.arange(101, dtype=np.float32) / np.float32(100)).reshape(1, -1)
    grid = OccupancyGrid(prob.astype(np.float32), 0.1)
    # without unknown cells a PGM holds a scale map too
    yaml_path, pgm_path = write_map_yaml(
        tmp_path / "s.yaml", grid, image_name="s.pgm", mode="scale"
    )
    _assert_same_grid(read_map_yaml(yaml_path), grid)
    # map_saver's grey levels, via GraphicsMagick Q16's truncating conversions
    grey = list(pgm_path.read_bytes()[-101:])
    assert grey[:4] == [255, 252, 249, 247]
    assert grey[50] == 127 and grey[100] == 0


def test_scale_mode_with_nav2_default_thresholds_is_not_identity(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # map_saver writes grey (100 - v)/100 whatever the thresholds; map_server then clips
    # below free and above occupied and stretches the band between.
    prob = np.array([[0.0, 0.2, 0.5, 0.7, 1.0]], dtype=np.float32)
    grid = OccupancyGrid(prob, 0.1)
    yaml_path, _ = write_map_yaml(
        tmp_path / "s.yaml", grid, mode="scale", free_thresh=0.25, occupied_thresh=0.65
    )
    assert "3 cells will load back as other values" in caplog.text
    back = read_map_yaml(yaml_path)
    # 0.5 -> grey 127 -> occ 0.502 -> rint((0.502 - 0.25) / 0.4 * 100) = 63
    np.testing.assert_array_equal(back.prob, np.array([[0.0, 0.0, 0.63, 1.0, 1.0]], np.float32))


def test_nav2_free_thresh_reads_unknown_as_free(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # why the default free_thresh is 0.196: map_saver's 205 has occ 0.196 < 0.25
    grid = OccupancyGrid(np.array([[0.0, 1.0, np.nan]], np.float32), 0.1)
    yaml_path, _ = write_map_yaml(tmp_path / "m.yaml", grid, free_thresh=0.25)
    assert "1 cells will load back as other values" in caplog.text
    np.testing.assert_array_equal(read_map_yaml(yaml_path).prob, [[0.0, 1.0, 0.0]])


def test_scale_unknown_cells_need_a_png(tmp_path: Path) -> None:
    grid = OccupancyGrid(np.array([[0.5, np.nan]], np.float32), 0.1)
    with pytest.raises(MapError, match=r"s\.pgm.*unknown cells"):
        write_map_yaml(tmp_path / "s.yaml", grid, mode="scale", image_name="s.pgm")
    assert list(tmp_path.iterdir()) == []


def test_raw_round_trip(tmp_path: Path) -> None:
    prob = np.append(np.arange(101, dtype=np.float32) / np.float32(100), np.nan)
    grid = OccupancyGrid(prob.reshape(6, 17).astype(np.float32), 0.2, (3.0, 4.0, 0.0))
    yaml_path, pgm_path = write_map_yaml(tmp_path / "r.yaml", grid, mode="raw")
    assert sorted(set(pgm_path.read_bytes()[-102:])) == [*range(101), 255]
    _assert_same_grid(read_map_yaml(yaml_path), grid)


@pytest.mark.parametrize("mode", ["trinary", "scale"])
def test_negate_written_and_read_back(tmp_path: Path, mode: str) -> None:
    prob = np.array([[0.0, 1.0], [1.0, 0.0]], np.float32)
    grid = OccupancyGrid(prob, 0.1)
    yaml_path, image_path = write_map_yaml(
        tmp_path / "n.yaml", grid, mode=mode, negate=True, image_name="n.pgm"
    )
    assert "negate: 1" in yaml_path.read_text()
    pixels = _pgm_pixels(image_path)
    # image row 0 is grid row 1, [1, 0]: negated, occupied is white and free black
    assert pixels[0, 0] > 200 and pixels[0, 1] < 50
    _assert_same_grid(read_map_yaml(yaml_path), grid)


@settings(max_examples=40, deadline=None)
@given(
    prob=hnp.arrays(
        np.float32,
        hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=16),
        elements=st.one_of(st.floats(0.0, 1.0, width=32), st.just(float("nan")), st.just(-0.0)),
    ),
    resolution=st.floats(1e-6, 1e3),
    origin=st.tuples(*[st.floats(-1e6, 1e6)] * 3),
)
def test_npz_round_trip_is_lossless(tmp_path_factory, prob, resolution, origin) -> None:
    path = tmp_path_factory.mktemp("npz") / "grid.npz"
    grid = OccupancyGrid(prob, resolution, origin)
    assert write_map_npz(path, grid) == path
    back = read_map_npz(path)
    _assert_same_grid(back, grid)
    np.testing.assert_array_equal(back.prob.view(np.uint32), prob.view(np.uint32))


def test_read_map_dispatches_by_suffix(tmp_path: Path) -> None:
    grid = OccupancyGrid(np.array([[0.0, np.nan]], np.float32), 0.5, (1.0, 2.0, 0.0))
    write_map_npz(tmp_path / "g.npz", grid)
    write_map_yaml(tmp_path / "g.yml", grid)
    _assert_same_grid(read_map(tmp_path / "g.npz"), grid)
    _assert_same_grid(read_map(tmp_path / "g.yml"), grid)
    (tmp_path / "g.txt").write_text("x")
    with pytest.raises(UnknownFormatError, match=r"g\.txt"):
        read_map(tmp_path / "g.txt")
    with pytest.raises(InputError, match="no such file"):
        read_map(tmp_path / "missing.yaml")


# --- hand-made images with known cells ---------------------------------------------------------


def test_trinary_pixels_and_row_order(tmp_path: Path) -> None:
    pixels = np.array([[0, 254, 205], [100, 89, 90]], np.uint8)
    grid = read_map_yaml(_write_map(tmp_path, pixels, BASE))
    # grid row 0 is image row 1. occ = 1 - v/255: 100 -> 0.608 unknown, 89 -> 0.651
    # occupied, 90 -> 0.647 unknown; 205 -> 0.196, free under free_thresh 0.25 (Nav2's quirk)
    expected = np.array([[np.nan, 1.0, np.nan], [1.0, 0.0, 0.0]], np.float32)
    np.testing.assert_array_equal(grid.prob, expected)


def test_negate_inverts_the_shades(tmp_path: Path) -> None:
    pixels = np.array([[0, 255, 128]], np.uint8)
    yaml_path = _write_map(tmp_path, pixels, BASE.replace("negate: 0", "negate: 1"))
    np.testing.assert_array_equal(read_map_yaml(yaml_path).prob, [[0.0, 1.0, np.nan]])


def test_negate_accepts_booleans(tmp_path: Path) -> None:
    pixels = np.array([[0, 255]], np.uint8)
    yaml_path = _write_map(tmp_path, pixels, BASE.replace("negate: 0", "negate: true"))
    np.testing.assert_array_equal(read_map_yaml(yaml_path).prob, [[0.0, 1.0]])


def test_scale_mode_pixels(tmp_path: Path) -> None:
    pixels = np.array([[255, 0, 128, 200, 50]], np.uint8)
    yaml = BASE.replace("0.65", "0.8").replace("0.25", "0.2") + "mode: scale\n"
    grid = read_map_yaml(_write_map(tmp_path, pixels, yaml))
    # occ = 1 - v/255 = 0, 1, 0.498, 0.216, 0.804; between 0.2 and 0.8: rint((occ-0.2)/0.6*100)
    np.testing.assert_array_equal(grid.prob, np.array([[0, 1.0, 0.5, 0.03, 1.0]], np.float32))


def test_scale_mode_transparent_pixels_are_unknown(tmp_path: Path) -> None:
    bgra = np.array([[[0, 0, 0, 255], [0, 0, 0, 254], [255, 255, 255, 0]]], np.uint8)
    yaml = BASE + "mode: scale\n"
    grid = read_map_yaml(_write_map(tmp_path, bgra, yaml, name="m.png"))
    np.testing.assert_array_equal(grid.prob, [[1.0, np.nan, np.nan]])


def test_trinary_averages_alpha_in(tmp_path: Path) -> None:
    # (254 + 254 + 254 + 0) / 4 = 190.5 -> occ 0.253: unknown (free would need < 0.25)
    bgra = np.array([[[254, 254, 254, 0], [254, 254, 254, 255]]], np.uint8)
    grid = read_map_yaml(_write_map(tmp_path, bgra, BASE, name="m.png"))
    np.testing.assert_array_equal(grid.prob, [[np.nan, 0.0]])


def test_colour_pixels_average_their_channels(tmp_path: Path) -> None:
    # pure red: shade 1/3, occ 0.667 > 0.65; (255, 255, 0): shade 2/3, occ 0.333 unknown
    bgr = np.array([[[0, 0, 255], [0, 255, 255], [255, 255, 255]]], np.uint8)
    grid = read_map_yaml(_write_map(tmp_path, bgr, BASE, name="m.png"))
    np.testing.assert_array_equal(grid.prob, [[1.0, np.nan, 0.0]])


def test_raw_mode_pixels_ignore_negate(tmp_path: Path) -> None:
    pixels = np.array([[0, 37, 100, 101, 255]], np.uint8)
    yaml = BASE.replace("negate: 0", "negate: 1") + "mode: raw\n"
    grid = read_map_yaml(_write_map(tmp_path, pixels, yaml))
    np.testing.assert_array_equal(
        grid.prob, np.array([[0.0, 0.37, 1.0, np.nan, np.nan]], np.float32)
    )


def test_sixteen_bit_pgm(tmp_path: Path) -> None:
    data = np.array([[65535, 0, 32768]], ">u2").tobytes()
    (tmp_path / "m.pgm").write_bytes(b"P5\n# made by hand\n3 1\n65535\n" + data)
    (tmp_path / "m.yaml").write_text("image: m.pgm\n" + BASE)
    np.testing.assert_array_equal(read_map_yaml(tmp_path / "m.yaml").prob, [[0.0, 1.0, np.nan]])


def test_absolute_image_path(tmp_path: Path) -> None:
    (tmp_path / "img").mkdir()
    pixels = np.array([[0, 254]], np.uint8)
    _write_map(tmp_path / "img", pixels, BASE)
    yaml_path = tmp_path / "abs.yaml"
    yaml_path.write_text(f"image: {tmp_path / 'img' / 'm.pgm'}\n{BASE}")
    np.testing.assert_array_equal(read_map_yaml(yaml_path).prob, [[1.0, 0.0]])


# --- bad files ---------------------------------------------------------------------------------

GOOD = {
    "image": "m.pgm",
    "resolution": "0.1",
    "origin": "[0.0, 0.0, 0.0]",
    "negate": "0",
    "occupied_thresh": "0.65",
    "free_thresh": "0.25",
}


def _yaml(**changes: str | None) -> str:
    keys = {**GOOD, **changes}
    return "".join(f"{k}: {v}\n" for k, v in keys.items() if v is not None)


@pytest.mark.parametrize(
    ("text", "match", "line"),
    [
        *[(_yaml(**{key: None}), f"missing key '{key}'", None) for key in GOOD],
        (_yaml(resolution="abc"), "'resolution' must be a number, got 'abc'", 2),
        (_yaml(resolution="0"), "'resolution' must be a positive number", 2),
        (_yaml(resolution="-0.05"), "'resolution' must be a positive number", 2),
        (_yaml(resolution="[1]"), "'resolution' must be a number", 2),
        (_yaml(origin="[0.0, 0.0]"), "'origin' must have 3 elements", 3),
        (_yaml(origin="5"), "'origin' must be a list", 3),
        (_yaml(origin="[0, x, 0]"), "'origin' must be a number, got 'x'", 3),
        (_yaml(negate="maybe"), "'negate' must be 0 or 1", 4),
        (_yaml(occupied_thresh="high"), "'occupied_thresh' must be a number", 5),
        (_yaml(occupied_thresh="1.5"), "'occupied_thresh' must be between 0 and 1", 5),
        (_yaml(free_thresh="-0.1"), "'free_thresh' must be between 0 and 1", 6),
        (_yaml(free_thresh="0.65"), r"'free_thresh' \(0.65\) must be smaller than", 6),
        (_yaml(free_thresh="0.7"), "must be smaller than 'occupied_thresh'", 6),
        (_yaml() + "mode: Trinary\n", "'mode' must be trinary, scale or raw, got 'Trinary'", 7),
        (_yaml(image="''"), "'image' is empty", 1),
        (_yaml(image="[a, b]"), "'image' must be a file name", 1),
        ("image: [m.pgm\n", "not valid YAML", 2),
        ("- a\n- b\n", "expected a mapping", 1),
    ],
)
def test_bad_yaml_names_the_key(tmp_path: Path, text: str, match: str, line: int | None) -> None:
    (tmp_path / "m.pgm").write_bytes(b"P5\n1 1\n255\n\x00")
    (tmp_path / "m.yaml").write_text(text)
    with pytest.raises(FormatError, match=match) as info:
        read_map_yaml(tmp_path / "m.yaml")
    assert info.value.path == tmp_path / "m.yaml"
    assert info.value.line == line


def test_missing_image_names_its_resolved_path(tmp_path: Path) -> None:
    (tmp_path / "m.yaml").write_text(_yaml(image="maps/nowhere.pgm"))
    expected = tmp_path / "maps" / "nowhere.pgm"
    with pytest.raises(FormatError, match=f"image {expected} does not exist") as info:
        read_map_yaml(tmp_path / "m.yaml")
    assert info.value.line == 1


@pytest.mark.parametrize(
    ("data", "match"),
    [
        (b"P5\n2 2\n255\n\x00", "truncated"),
        (b"P5\n2", "header is truncated"),
        (b"P5\n2 x 255\n", "non-number"),
        (b"P5\n0 2\n255\n", "bad size"),
        (b"P5\n1 1\n100\n\xff", "exceed the header's maxval"),
        (b"not an image", "cannot be decoded"),
    ],
)
def test_bad_image_names_the_image(tmp_path: Path, data: bytes, match: str) -> None:
    (tmp_path / "m.pgm").write_bytes(data)
    (tmp_path / "m.yaml").write_text(_yaml())
    with pytest.raises(FormatError, match=match) as info:
        read_map_yaml(tmp_path / "m.yaml")
    assert info.value.path == tmp_path / "m.pgm"


def test_bad_npz_files(tmp_path: Path) -> None:
    grid = OccupancyGrid(np.zeros((2, 2), np.float32), 0.1)
    path = tmp_path / "g.npz"
    path.write_bytes(b"garbage")
    with pytest.raises(FormatError, match=r"not a readable \.npz"):
        read_map_npz(path)
    np.save(tmp_path / "a.npy", np.zeros(3))
    (tmp_path / "a.npy").rename(path)
    with pytest.raises(FormatError, match="single array"):
        read_map_npz(path)
    np.savez(path, prob=np.zeros((2, 2), np.float32))
    with pytest.raises(FormatError, match="not a slamcli occupancy grid"):
        read_map_npz(path)
    write_map_npz(path, grid)
    data = dict(np.load(path))
    for key, value, match in [
        ("format_version", np.int64(2), "format_version 2 is not supported"),
        ("prob", np.zeros((2, 2)), "'prob' must be a non-empty"),
        ("prob", np.full((2, 2), 2.0, np.float32), "outside"),
        ("resolution_m", np.float64(-1.0), "'resolution_m'"),
        ("origin_xy_yaw", np.zeros(2), "'origin_xy_yaw'"),
    ]:
        np.savez(path, **{**data, key: value})
        with pytest.raises(FormatError, match=match):
            read_map_npz(path)
    np.savez(path, **{k: v for k, v in data.items() if k != "prob"})
    with pytest.raises(FormatError, match="missing array 'prob'"):
        read_map_npz(path)


# --- writers: validation and atomicity --------------------------------------------------------


def test_writers_reject_bad_grids_and_options(tmp_path: Path) -> None:
    bad = OccupancyGrid(np.array([[0.5, 1.5]], np.float32), 0.1)
    for writer in (write_map_yaml, write_map_npz, write_map_png):
        with pytest.raises(MapError, match="outside"):
            writer(tmp_path / "x.yaml", bad)
    grid = OccupancyGrid(np.zeros((2, 2), np.float32), 0.1)
    with pytest.raises(MapError, match="resolution"):
        write_map_npz(tmp_path / "x.npz", dataclasses.replace(grid, resolution_m=0.0))
    with pytest.raises(ConfigError, match="mode"):
        write_map_yaml(tmp_path / "x.yaml", grid, mode="binary")
    with pytest.raises(ConfigError, match="free_thresh < occupied_thresh"):
        write_map_yaml(tmp_path / "x.yaml", grid, free_thresh=0.7, occupied_thresh=0.6)
    with pytest.raises(ConfigError, match=r"\.jpg"):
        write_map_yaml(tmp_path / "x.yaml", grid, image_name="x.jpg")
    with pytest.raises(ConfigError, match="preview scale"):
        write_map_png(tmp_path / "x.png", grid, scale=0)
    with pytest.raises(ExportError, match="does not exist"):
        write_map_yaml(tmp_path / "no" / "x.yaml", grid)
    assert list(tmp_path.iterdir()) == []


def test_writers_replace_existing_files(tmp_path: Path) -> None:
    grid = OccupancyGrid(np.zeros((2, 2), np.float32), 0.1)
    (tmp_path / "m.yaml").write_text("old")
    (tmp_path / "m.pgm").write_text("old")
    write_map_yaml(tmp_path / "m.yaml", grid)
    _assert_same_grid(read_map_yaml(tmp_path / "m.yaml"), grid)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.pgm", "m.yaml"]  # no temp files


def test_png_preview(tmp_path: Path) -> None:
    prob = np.array([[0.0, 1.0, np.nan], [0.5, 0.0, 0.0]], np.float32)
    grid = OccupancyGrid(prob, 0.1)
    path = write_map_png(tmp_path / "p.png", grid, scale=3)
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img.shape == (6, 9) and img.dtype == np.uint8
    # y up: the grid's top row (row 1) is the image's first
    assert img[0, 0] == 128 and img[0, 3] == 255
    assert img[3, 0] == 255 and img[3, 3] == 0 and img[3, 6] == 205
    assert img[5, 8] == 205


# --- cells and the world -----------------------------------------------------------------------


@pytest.mark.parametrize("yaw", [0.0, 0.3, -2.5, math.pi / 2])
def test_world_and_cell_invert_each_other(yaw: float) -> None:
    rng = np.random.default_rng(7)
    grid = OccupancyGrid(np.zeros((50, 80), np.float32), 0.07, (1.5, -3.0, yaw))
    rc = rng.integers(-20, 100, size=(500, 2))
    np.testing.assert_array_equal(world_to_cell(grid, cell_to_world(grid, rc)), rc)
    xy = rng.uniform(-10, 10, size=(500, 2))
    centres = cell_to_world(grid, world_to_cell(grid, xy))
    # a point lies within its cell: at most half a diagonal from the centre
    assert np.all(np.linalg.norm(centres - xy, axis=1) <= 0.07 * math.sqrt(0.5) + 1e-12)


def test_yaw_rotates_the_grid_about_its_origin() -> None:
    grid = OccupancyGrid(np.zeros((4, 4), np.float32), 1.0, (10.0, 20.0, math.pi / 2))
    # columns run along +y, rows along -x
    np.testing.assert_allclose(cell_to_world(grid, [0, 0]), [9.5, 20.5])
    np.testing.assert_allclose(cell_to_world(grid, [0, 2]), [9.5, 22.5])
    np.testing.assert_allclose(cell_to_world(grid, [2, 0]), [7.5, 20.5])
    assert world_to_cell(grid, [[7.5, 20.5], [9.9, 23.1]]).tolist() == [[2, 0], [0, 3]]


@pytest.mark.parametrize("mode", ["trinary", "scale", "raw"])
@pytest.mark.parametrize("negate", [0, 1])
@pytest.mark.parametrize("layout", ["grey.pgm", "grey.png", "colour.png"])
def test_eight_bit_lookup_equals_the_per_pixel_rule(
    tmp_path: Path, mode: str, negate: int, layout: str
) -> None:
    """8-bit maps are decoded through a table of every R+G+B sum: the same cells as Nav2's rule
    applied pixel by pixel (``decode_cells`` on each pixel's quanta)."""
    from slamcli.formats.occupancy.map_server_read import decode_cells

    rng = np.random.default_rng(7)
    if layout.startswith("grey"):
        pixels = np.arange(256, dtype=np.uint8).reshape(16, 16)
        sums = pixels.astype(np.float64) * 257.0 * 3.0
    else:
        pixels = rng.integers(0, 256, size=(20, 30, 3), dtype=np.uint8)
        sums = pixels.astype(np.float64).sum(axis=2) * 257.0
    yaml = BASE.replace("negate: 0", f"negate: {negate}") + f"mode: {mode}\n"
    name = "m.pgm" if layout.endswith(".pgm") else "m.png"
    grid = read_map_yaml(_write_map(tmp_path, pixels, yaml, name=name))
    cells = decode_cells(sums, None, mode, negate, 0.25, 0.65)
    expect = np.where(cells < 0, np.nan, cells.astype(np.float32) / np.float32(100.0))
    np.testing.assert_array_equal(grid.prob, np.flipud(expect).astype(np.float32))
