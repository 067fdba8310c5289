"""Reading ROS map_server maps (YAML + image) as Nav2's ``nav2_map_server`` does, pixel for pixel.

See :mod:`slamcli.formats.occupancy` for the format: the YAML keys, how a pixel's shade becomes a
cell in each mode, and what is checked more strictly than Nav2 does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import FormatError, InputError
from slamcli.formats.images import decode_image, read_image_file, size_problem
from slamcli.formats.text import (
    MAX_YAML_BYTES,
    check_yaml_expansion,
    read_limited_text,
    yaml_problem,
)
from slamcli.types import OccupancyGrid

MAP_MODES = ("trinary", "scale", "raw")
"""map_server's ``mode`` values."""

_REQUIRED_KEYS = ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh")
_KEYS_HINT = "a map_server YAML needs image, resolution, origin: [x, y, yaw], negate, "
_KEYS_HINT += "occupied_thresh and free_thresh (mode is optional)"

MAP_RESOLUTION_RANGE = (1e-6, 1e6)
"""Accepted cell sizes (m): beyond these, cell <-> world conversions overflow or lose every
digit of a world coordinate."""

MAP_ORIGIN_MAX = 1e9
"""Largest accepted magnitude of an origin value (m, rad): beyond any geo-referenced map."""

MAX_RGB = 65535.0
"""GraphicsMagick Q16's quantum range: 8-bit samples v are stored as v * 257."""


@dataclass(frozen=True)
class _MapYaml:
    path: Path
    text: str
    image: str
    image_path: Path
    resolution: float
    origin: tuple[float, float, float]
    negate: int
    occupied_thresh: float
    free_thresh: float
    mode: str
    lines: dict[str, int]


def read_map_yaml(path: str | Path) -> OccupancyGrid:
    """A ROS map_server map (YAML plus the image it names) as an :class:`OccupancyGrid`.

    Cells are decoded exactly as Nav2's map_server does (see the module docstring); ``prob`` is
    ``value / 100`` as float32 with NaN for unknown, row 0 the lowest y. ``source_format``
    records how the map was stored so :func:`write_map_yaml` can reproduce it.

    Raises:
        InputError: the YAML file does not exist.
        FormatError: bad YAML, a missing key or a bad value (names the key and, where known,
            the line), or a missing or undecodable image (names the image's path).
    """
    meta = _read_map_meta(Path(path))
    rgb_sum, alpha, header, levels = _read_image(meta)
    if levels is not None:
        # 8-bit pixels without alpha, the usual map: decode each possible sum of R, G and B
        # (0..765, grey counted three times) once and look the pixels up.
        sums = np.arange(766, dtype=np.float64) * 257.0
        table = decode_cells(
            sums, None, meta.mode, meta.negate, meta.free_thresh, meta.occupied_thresh
        )
        prob = _prob_from_cells(table)[np.flipud(levels)]
    else:
        cells = decode_cells(
            rgb_sum, alpha, meta.mode, meta.negate, meta.free_thresh, meta.occupied_thresh
        )
        prob = _prob_from_cells(np.flipud(cells))
    source = {
        "format": "map_server",
        "yaml_text": meta.text,
        "image": meta.image,
        "mode": meta.mode,
        "negate": meta.negate,
        "occupied_thresh": meta.occupied_thresh,
        "free_thresh": meta.free_thresh,
        "resolution": meta.resolution,
        "origin": list(meta.origin),
        "pgm_header": header,
    }
    return OccupancyGrid(prob, meta.resolution, meta.origin, source_format=source)


def _read_map_meta(p: Path) -> _MapYaml:
    import yaml

    if not p.is_file():
        raise InputError(f"{p}: no such file")
    try:
        text = read_limited_text(p, MAX_YAML_BYTES, "a map YAML file", _KEYS_HINT)
    except OSError as exc:
        raise FormatError(p, f"cannot be read ({exc.strerror})") from exc
    except UnicodeDecodeError as exc:
        raise FormatError(p, f"is not UTF-8 text ({exc.reason})") from exc
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        problem, line = yaml_problem(exc, text)
        raise FormatError(p, f"is not valid YAML ({problem})", line=line) from exc
    check_yaml_expansion(p, data)
    if not isinstance(data, dict) or not isinstance(node, yaml.MappingNode):
        raise FormatError(p, "expected a mapping of map keys", line=1, hint=_KEYS_HINT)
    lines: dict[str, int] = {}
    scalars: dict[str, str] = {}
    for key_node, value_node in node.value:
        if isinstance(key_node, yaml.ScalarNode):
            lines[key_node.value] = value_node.start_mark.line + 1
            if isinstance(value_node, yaml.ScalarNode):
                scalars[key_node.value] = value_node.value
    for key in _REQUIRED_KEYS:
        if key not in data:
            raise FormatError(p, f"missing key '{key}'", hint=_KEYS_HINT)

    def fail(key: str, msg: str) -> FormatError:
        return FormatError(p, msg, line=lines.get(key), hint=_KEYS_HINT)

    image = scalars.get("image", "")
    if not isinstance(data["image"], (str, int, float)) or isinstance(data["image"], bool):
        raise fail("image", f"'image' must be a file name, got {data['image']!r}")
    if not image:
        raise fail("image", "'image' is empty")
    image_path = Path(image) if image.startswith("/") else p.parent / image

    resolution = _number(data["resolution"], "resolution", fail)
    if not (math.isfinite(resolution) and resolution > 0):
        raise fail("resolution", f"'resolution' must be a positive number, got {resolution}")
    lo, hi = MAP_RESOLUTION_RANGE
    if not lo <= resolution <= hi:
        raise fail(
            "resolution", f"'resolution' must be {lo:g} to {hi:g} m per cell, got {resolution}"
        )

    origin_raw = data["origin"]
    if not isinstance(origin_raw, list):
        raise fail("origin", f"'origin' must be a list [x, y, yaw], got {origin_raw!r}")
    if len(origin_raw) != 3:
        raise fail("origin", f"'origin' must have 3 elements [x, y, yaw], not {len(origin_raw)}")
    origin = tuple(_number(v, "origin", fail) for v in origin_raw)
    if not all(math.isfinite(v) for v in origin):
        raise fail("origin", f"'origin' must be finite, got {list(origin)}")
    if any(abs(v) > MAP_ORIGIN_MAX for v in origin):
        raise fail(
            "origin",
            f"'origin' values must be at most {MAP_ORIGIN_MAX:g} in magnitude, got {list(origin)}",
        )

    negate = _negate(data["negate"], fail)
    occupied = _number(data["occupied_thresh"], "occupied_thresh", fail)
    free = _number(data["free_thresh"], "free_thresh", fail)
    for key, value in (("occupied_thresh", occupied), ("free_thresh", free)):
        if not 0.0 <= value <= 1.0:
            raise fail(key, f"'{key}' must be between 0 and 1, got {value}")
    if not free < occupied:
        raise fail(
            "free_thresh",
            f"'free_thresh' ({free}) must be smaller than 'occupied_thresh' ({occupied})",
        )

    mode = data.get("mode", "trinary")
    if mode not in MAP_MODES:
        raise fail("mode", f"'mode' must be trinary, scale or raw, got {mode!r}")
    return _MapYaml(
        path=p,
        text=text,
        image=image,
        image_path=image_path,
        resolution=resolution,
        origin=(origin[0], origin[1], origin[2]),
        negate=negate,
        occupied_thresh=occupied,
        free_thresh=free,
        mode=str(mode),
        lines=lines,
    )


def _number(value: Any, key: str, fail: Any) -> float:
    # yaml-cpp's as<double>() reads any numeric scalar, including forms such as 1e-05 that
    # PyYAML's YAML 1.1 resolver leaves as strings.
    if isinstance(value, bool):
        raise fail(key, f"'{key}' must be a number, got {value!r}")
    if isinstance(value, (int, float)):
        return float(value)
    if isinstance(value, str):
        try:
            return float(value.strip())
        except ValueError:
            pass
    raise fail(key, f"'{key}' must be a number, got {value!r}")


_YAML_CPP_BOOLS = {"y": 1, "Y": 1, "n": 0, "N": 0}
"""yaml-cpp bool spellings that PyYAML's resolver leaves as strings."""


def _negate(value: Any, fail: Any) -> int:
    # Nav2 reads negate as an int (any non-zero negates), falling back to a bool.
    if isinstance(value, (bool, int)):
        return int(bool(value))
    if isinstance(value, str) and value in _YAML_CPP_BOOLS:
        return _YAML_CPP_BOOLS[value]
    raise fail("negate", f"'negate' must be 0 or 1 (or true/false), got {value!r}")


def _read_image(
    meta: _MapYaml,
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None, str | None, NDArray[np.uint16] | None]:
    """The image as Q16 quanta: (sum of R, G, B (H, W), alpha (H, W) or None, P5 header), and,
    for 8-bit pixels without alpha, their sums of R, G and B in 8-bit units (H, W) uint16
    instead (the quanta are then left empty)."""
    img = meta.image_path
    if not img.is_file():
        raise FormatError(
            meta.path,
            f"image {img} does not exist",
            line=meta.lines.get("image"),
            hint="'image' is relative to the YAML file's folder unless it is absolute",
        )
    data, reason = read_image_file(img)
    if data is None:
        raise FormatError(img, f"map image {reason}")
    if data[:2] == b"P5":
        raw, maxval, header = _p5_pixels(img, data)
        if maxval == 255:
            return np.zeros((0, 0)), None, header, raw.astype(np.uint16) * np.uint16(3)
        # GraphicsMagick scales other depths to its quantum range, rounding half up.
        grey = np.floor(raw.astype(np.float64) * MAX_RGB / maxval + 0.5)
        return grey * 3.0, None, header, None
    decoded, reason = decode_image(data)
    if decoded is None:
        raise FormatError(img, f"map image {reason}")
    if decoded.dtype == np.uint8 and (decoded.ndim == 2 or decoded.shape[2] in (1, 3)):
        if decoded.ndim == 2 or decoded.shape[2] == 1:
            levels = decoded.reshape(decoded.shape[:2]).astype(np.uint16) * np.uint16(3)
        else:
            levels = decoded[..., 0].astype(np.uint16)
            levels += decoded[..., 1]
            levels += decoded[..., 2]
        return np.zeros((0, 0)), None, None, levels
    return (*_decode_with_opencv(img, decoded), None, None)


def _p5_pixels(path: Path, data: bytes) -> tuple[NDArray[Any], int, str | None]:
    """A binary PGM's raw pixels (H, W) (uint8, or big-endian uint16) checked against its
    header, its maxval, and the header text when it is 8-bit (maxval 255)."""
    width, height, maxval, offset = parse_p5_header(path, data)
    size = 1 if maxval < 256 else 2
    need = width * height * size
    if len(data) - offset < need:
        raise FormatError(
            path, f"PGM pixel data is truncated: {len(data) - offset} bytes, expected {need}"
        )
    raw = np.frombuffer(
        data, dtype=np.uint8 if size == 1 else ">u2", count=width * height, offset=offset
    ).reshape(height, width)
    if int(raw.max(initial=0)) > maxval:
        raise FormatError(path, f"PGM pixel values exceed the header's maxval {maxval}")
    return raw, maxval, (data[:offset].decode("latin-1") if maxval == 255 else None)


def parse_p5_header(path: Path, data: bytes) -> tuple[int, int, int, int]:
    """(width, height, maxval, offset of the pixels) of a binary PGM; comments allowed."""
    fields: list[int] = []
    i = 2
    while len(fields) < 3:
        if i >= len(data):
            raise FormatError(path, "PGM header is truncated")
        ch = data[i : i + 1]
        if ch == b"#":
            end = data.find(b"\n", i)
            if end < 0:
                raise FormatError(path, "PGM header is truncated")
            i = end + 1
        elif ch.isspace():
            i += 1
        else:
            j = i
            while j < len(data) and data[j : j + 1].isdigit():
                j += 1
            if j == i:
                raise FormatError(path, f"PGM header has a non-number at byte {i}")
            fields.append(int(data[i:j]))
            i = j
    if i >= len(data) or not data[i : i + 1].isspace():
        raise FormatError(path, "PGM header must end with one whitespace after maxval")
    width, height, maxval = fields
    if width <= 0 or height <= 0 or not 0 < maxval < 65536:
        raise FormatError(path, f"PGM header has a bad size or maxval: {width} {height} {maxval}")
    problem = size_problem(width, height)
    if problem:
        raise FormatError(path, f"map image {problem}")
    return width, height, maxval, i + 1


def _decode_with_opencv(
    path: Path, img: NDArray[Any]
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
    """Decoded pixels (OpenCV's channel order) as Q16 quanta: (R + G + B, alpha or None)."""
    if img.dtype == np.uint8:
        q = img.astype(np.float64) * 257.0
    elif img.dtype == np.uint16:
        q = img.astype(np.float64)
    else:
        raise FormatError(path, f"{img.dtype} pixels are not supported; use 8 or 16 bits")
    if q.ndim == 2 or q.shape[2] == 1:
        grey = q.reshape(q.shape[0], q.shape[1])
        return grey * 3.0, None
    # OpenCV gives grey + alpha images as BGRA
    rgb_sum = q[..., 0] + q[..., 1] + q[..., 2]
    return rgb_sum, q[..., 3] if q.shape[2] == 4 else None


def decode_cells(
    rgb_sum: NDArray[np.float64],
    alpha: NDArray[np.float64] | None,
    mode: str,
    negate: int,
    free: float,
    occupied: float,
) -> NDArray[np.int8]:
    """Nav2's loadMapFromFile per pixel, vectorised; image order (row 0 = top).

    ``rgb_sum`` is the sum of the red, green and blue quanta (Q16) per pixel, ``alpha`` the
    alpha quanta (65535 = opaque) when the image has an alpha channel.
    """
    total, n = rgb_sum, 3.0
    if mode == "trinary" and alpha is not None:
        # Nav2 averages alpha in with the colour channels in trinary mode.
        total, n = rgb_sum + alpha, 4.0
    shade = (total / n) / MAX_RGB
    occ = shade if negate else 1.0 - shade
    cells: NDArray[np.float64]
    if mode == "trinary":
        cells = np.where(occupied < occ, 100.0, np.where(occ < free, 0.0, -1.0))
    elif mode == "scale":
        between = np.rint((occ - free) / (occupied - free) * 100.0)
        cells = np.where(occupied < occ, 100.0, np.where(occ < free, 0.0, between))
        if alpha is not None:
            cells = np.where(alpha != MAX_RGB, -1.0, cells)
    else:
        x = shade * 255.0
        floor = np.floor(x)
        percent = floor + (x - floor >= 0.5)  # std::round: halves away from zero
        cells = np.where((percent >= 0) & (percent <= 100), percent, -1.0)
    return cells.astype(np.int8)


def _prob_from_cells(cells: NDArray[Any]) -> NDArray[np.float32]:
    values = cells.astype(np.float32) / np.float32(100.0)
    return np.where(cells < 0, np.float32(np.nan), values).astype(np.float32)
