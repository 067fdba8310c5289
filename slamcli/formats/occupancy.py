"""Occupancy grids on disk: ROS map_server maps (YAML + image), lossless ``.npz``, PNG previews.

**map_server maps** follow Nav2's ``nav2_map_server/src/map_io.cpp`` (``loadMapYaml``,
``loadMapFromFile``, ``tryWriteMapToFile``), pixel for pixel:

- YAML keys ``image`` (relative to the YAML's folder unless absolute), ``resolution`` (m/cell),
  ``origin: [x, y, yaw]`` (pose of the lower-left pixel), ``negate`` (0/1 or a bool),
  ``occupied_thresh``, ``free_thresh`` (all required, as in Nav2) and ``mode`` (``trinary``, the
  default, ``scale`` or ``raw``).
- Reading: each pixel's ``shade`` is the mean of its red, green and blue channels (plus alpha in
  trinary mode when the image has an alpha channel) on a 0-1 scale, computed in the 16-bit
  quantum arithmetic of GraphicsMagick Q16 (the build ROS uses). ``occ = shade`` when negated,
  else ``1 - shade``. Trinary: ``occ > occupied_thresh`` -> 100, ``occ < free_thresh`` -> 0,
  else unknown. Scale: a pixel that is not fully opaque is unknown, else like trinary but the
  band between the thresholds becomes ``rint((occ - free) / (occupied - free) * 100)``. Raw:
  ``round(shade * 255)`` when it is 0-100 (negate ignored), else unknown. Image row 0 is the top
  of the map, so rows are flipped into :class:`OccupancyGrid` order (row 0 = lowest y); a cell
  value ``v`` becomes ``prob = v / 100`` (float32), unknown becomes NaN.
- Writing (map_saver): cells are ``rint(prob * 100)``. Trinary: ``0 <= v <= rint(free * 100)``
  -> 254, ``v >= rint(occupied * 100)`` -> 0, else 205. Scale: grey ``(100 - v) / 100`` through
  GraphicsMagick's truncating quantum conversions, unknown -> transparent (needs a PNG). Raw:
  ``v``, unknown -> 255. The PGM header is ``P5\\n<w> <h>\\n255\\n`` and the YAML is the text
  yaml-cpp emits for map_saver (no final newline), except that a number is written with more
  than map_saver's three significant digits when three would not read back equal (map_saver
  rounds an origin of -12.345 to -12.3; slamcli keeps it).
- Default thresholds for writing: ``occupied_thresh`` 0.65 as map_saver, but ``free_thresh``
  0.196 (ROS 1's) rather than Nav2 map_saver's 0.25: with 0.25 map_server reads the 205
  "unknown" pixels map_saver writes as free (1 - 205/255 = 0.196 < 0.25), a known Nav2 quirk.
  In scale mode the defaults are 0 and 1 (see :data:`SCALE_THRESHOLDS`). Thresholds with which
  the written pixels would not load back as the same cells are allowed (they may be the map's
  own) but logged as a warning.

Stricter than Nav2 on purpose: thresholds must satisfy ``0 <= free_thresh < occupied_thresh
<= 1``, the resolution must be positive and the origin finite.

**Byte-identical round trips.** :func:`read_map_yaml` records in ``grid.source_format`` the
YAML text, the values it parsed and the PGM header (comments included). :func:`write_map_yaml`
writes that YAML text back verbatim when every value it would write (image name, mode, negate,
thresholds, resolution, origin) is unchanged, and that header when the size and resolution are
unchanged; the pixels are regenerated from the cells. A map whose pixels already hold the
values map_saver writes for its mode (0/205/254 for trinary) therefore comes back byte for
byte.

**Overwriting.** Like the other writers in :mod:`slamcli.formats` (``write_ply``,
``write_tum``), these write atomically (a temporary file renamed into place) and replace an
existing file; refusing to overwrite is the job of the command (``--force``) and
:class:`slamcli.rundir.RunDir`.

**Cells and the world.** :func:`world_to_cell` and :func:`cell_to_world` honour the origin's yaw
(the grid's axes are rotated by it about the origin). Nav2 ignores the yaw for lookups; for the
usual yaw of 0 both agree exactly.
"""

from __future__ import annotations

import json
import logging
import math
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slamcli.atomic import atomic_path
from slamcli.errors import (
    ConfigError,
    ExportError,
    FormatError,
    InputError,
    MapError,
    UnknownFormatError,
)
from slamcli.formats.images import (
    MAX_IMAGE_PIXELS,
    decode_image,
    read_image_file,
    size_problem,
)
from slamcli.formats.text import yaml_problem
from slamcli.types import OccupancyGrid

log = logging.getLogger(__name__)

MAP_MODES = ("trinary", "scale", "raw")
"""map_server's ``mode`` values."""

DEFAULT_OCCUPIED_THRESH = 0.65
"""map_saver's default ``occupied_thresh`` (``checkSaveParameters``)."""

DEFAULT_FREE_THRESH = 0.196
"""Default ``free_thresh`` written in trinary and raw mode: ROS 1 map_saver's value. Nav2's
map_saver writes 0.25, with which map_server reads map_saver's own unknown pixels (205, occ
50/255 = 0.196) as free; with 0.196 they load back unknown."""

NAV2_FREE_THRESH = 0.25
"""Nav2 map_saver's default ``free_thresh`` (``checkSaveParameters``); not used by default, see
:data:`DEFAULT_FREE_THRESH`."""

SCALE_THRESHOLDS = (0.0, 1.0)
"""(free, occupied) written by default in scale mode: the only pair for which map_saver's grey
levels, ``(100 - v) / 100``, load back as the same cells (checked for every v in 0-100)."""

NPZ_FORMAT = "slamcli.occupancy_grid"
NPZ_FORMAT_VERSION = 1
"""Version of the ``.npz`` layout: ``format``, ``format_version``, ``prob`` (H, W) float32 with
NaN, ``resolution_m`` float64, ``origin_xy_yaw`` (3,) float64."""

MAP_SUFFIXES = {".yaml": "map_server YAML", ".yml": "map_server YAML", ".npz": "slamcli grid"}

_NPZ_EXPECTED = (
    "a slamcli occupancy grid, a NumPy .npz archive with the arrays format, format_version, "
    "prob, resolution_m and origin_xy_yaw"
)
_NPZ_HINT = (
    "such files are written by slamcli.formats.occupancy.write_map_npz; 'slamcli map build' "
    "writes a map_server map.yaml, which 'slamcli plan' and 'slamcli map show' also read"
)

_NPZ_ARRAYS = ("format", "format_version", "prob", "resolution_m", "origin_xy_yaw")
_REQUIRED_KEYS = ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh")
_KEYS_HINT = "a map_server YAML needs image, resolution, origin: [x, y, yaw], negate, "
_KEYS_HINT += "occupied_thresh and free_thresh (mode is optional)"

MAP_RESOLUTION_RANGE = (1e-6, 1e6)
"""Accepted cell sizes (m): beyond these, cell <-> world conversions overflow or lose every
digit of a world coordinate."""

MAP_ORIGIN_MAX = 1e9
"""Largest accepted magnitude of an origin value (m, rad): beyond any geo-referenced map."""

_MAX_RGB = 65535.0
"""GraphicsMagick Q16's quantum range: 8-bit samples v are stored as v * 257."""
_WRITE_SUFFIXES = (".pgm", ".png", ".bmp")
_UNKNOWN_GREY = 205
_FREE_GREY = 254


# --- reading ---------------------------------------------------------------------------------


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
    rgb_sum, alpha, header = _read_image(meta)
    cells = _decode_cells(
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
        text = p.read_bytes().decode("utf-8")
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
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None, str | None]:
    """The image as Q16 quanta: (sum of R, G, B (H, W), alpha (H, W) or None, P5 header)."""
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
        grey, header = _decode_p5(img, data)
        return grey * 3.0, None, header
    return (*_decode_with_opencv(img, data), None)


def _decode_p5(path: Path, data: bytes) -> tuple[NDArray[np.float64], str | None]:
    """Binary PGM as Q16 quanta (H, W), and its header text when it is 8-bit."""
    width, height, maxval, offset = _parse_p5_header(path, data)
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
    if maxval == 255:
        quanta = raw.astype(np.float64) * 257.0
        return quanta, data[:offset].decode("latin-1")
    # GraphicsMagick scales other depths to its quantum range, rounding half up.
    return np.floor(raw.astype(np.float64) * _MAX_RGB / maxval + 0.5), None


def _parse_p5_header(path: Path, data: bytes) -> tuple[int, int, int, int]:
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
    path: Path, data: bytes
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
    img, reason = decode_image(data)
    if img is None:
        raise FormatError(path, f"map image {reason}")
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


def _decode_cells(
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
    shade = (total / n) / _MAX_RGB
    occ = shade if negate else 1.0 - shade
    cells: NDArray[np.float64]
    if mode == "trinary":
        cells = np.where(occupied < occ, 100.0, np.where(occ < free, 0.0, -1.0))
    elif mode == "scale":
        between = np.rint((occ - free) / (occupied - free) * 100.0)
        cells = np.where(occupied < occ, 100.0, np.where(occ < free, 0.0, between))
        if alpha is not None:
            cells = np.where(alpha != _MAX_RGB, -1.0, cells)
    else:
        x = shade * 255.0
        floor = np.floor(x)
        percent = floor + (x - floor >= 0.5)  # std::round: halves away from zero
        cells = np.where((percent >= 0) & (percent <= 100), percent, -1.0)
    return cells.astype(np.int8)


def _prob_from_cells(cells: NDArray[Any]) -> NDArray[np.float32]:
    values = cells.astype(np.float32) / np.float32(100.0)
    return np.where(cells < 0, np.float32(np.nan), values).astype(np.float32)


# --- writing ---------------------------------------------------------------------------------


def write_map_yaml(
    path_yaml: str | Path,
    grid: OccupancyGrid,
    *,
    mode: str | None = None,
    occupied_thresh: float | None = None,
    free_thresh: float | None = None,
    negate: bool | None = None,
    image_name: str | None = None,
) -> list[Path]:
    """Write ``grid`` as a map_server map, as Nav2's map_saver does; returns [yaml, image].

    Args:
        path_yaml: the YAML file; its folder must exist.
        mode: ``trinary``, ``scale`` or ``raw``; default: the mode the grid was read in, else
            ``trinary``.
        occupied_thresh, free_thresh: default: the grid's own when it was read in the same
            mode, else 0.65 and 0.196 (trinary, raw; see :data:`DEFAULT_FREE_THRESH` for why not
            map_saver's 0.25) or 1.0 and 0.0 in scale mode, the pair with which map_saver's
            scale images load back unchanged. Others may not load back the same: a warning is
            logged then.
        negate: write inverted grey levels and ``negate: 1``; default: as read, else 0.
        image_name: the image file, relative to the YAML's folder (or absolute); default
            ``<yaml stem>.pgm`` (``.png`` in scale mode). ``.pgm``, ``.png`` and ``.bmp`` are
            supported; scale mode needs ``.png`` when the grid has unknown cells (they are
            stored as transparent pixels).

    Both files are written to temporary names first and renamed into place only when both
    are complete (image first), replacing existing files.

    Raises:
        ConfigError: a bad mode, thresholds or image name.
        MapError: the grid is malformed, or holds unknown cells a scale-mode image without
            alpha cannot store.
        ExportError: the folder does not exist or the write failed.
    """
    yaml_path = Path(path_yaml)
    prob = _check_grid(grid)
    src = grid.source_format if _is_map_server(grid.source_format) else None
    mode = mode if mode is not None else str(src["mode"]) if src else "trinary"
    if mode not in MAP_MODES:
        raise ConfigError(f"map mode must be trinary, scale or raw, got {mode!r}")
    same_mode = src is not None and src["mode"] == mode
    defaults = (
        SCALE_THRESHOLDS if mode == "scale" else (DEFAULT_FREE_THRESH, DEFAULT_OCCUPIED_THRESH)
    )
    if free_thresh is None:
        free_thresh = float(src["free_thresh"]) if src and same_mode else defaults[0]
    if occupied_thresh is None:
        occupied_thresh = float(src["occupied_thresh"]) if src and same_mode else defaults[1]
    if not (0.0 <= free_thresh < occupied_thresh <= 1.0):
        raise ConfigError(
            f"map thresholds need 0 <= free_thresh < occupied_thresh <= 1, got free_thresh "
            f"{free_thresh} and occupied_thresh {occupied_thresh}"
        )
    negate_int = int(bool(negate)) if negate is not None else int(src["negate"]) if src else 0
    if image_name is None:
        image_name = yaml_path.stem + (".png" if mode == "scale" else ".pgm")
    if not image_name or "\n" in image_name or "\r" in image_name:
        raise ConfigError(f"map image name {image_name!r} is not a usable file name")
    image_path = (
        Path(image_name) if Path(image_name).is_absolute() else yaml_path.parent / image_name
    )
    suffix = image_path.suffix.lower()
    if suffix not in _WRITE_SUFFIXES:
        raise ConfigError(
            f"map image {image_name}: cannot write {suffix or 'files without a suffix'}",
            hint="name the image *.pgm, *.png or *.bmp",
        )
    if image_path.resolve() == yaml_path.resolve():
        raise ConfigError(f"map image {image_name} would overwrite the YAML file")

    cells = np.flipud(_cells_from_prob(prob))
    grey, alpha = _encode_cells(cells, mode, free_thresh, occupied_thresh, negate_int)
    _warn_if_lossy(yaml_path, cells, grey, alpha, mode, free_thresh, occupied_thresh, negate_int)
    if alpha is not None and suffix != ".png":
        raise MapError(
            f"{image_path}: a scale-mode {suffix} image cannot store the grid's unknown cells",
            hint="name the image *.png; scale mode stores unknown cells as transparent pixels",
        )
    header = _pgm_header(grid, src, prob.shape) if suffix == ".pgm" else ""
    image_bytes = _encode_image(grey, alpha, suffix, header)

    values = {
        "image": image_name,
        "mode": mode,
        "negate": negate_int,
        "occupied_thresh": float(occupied_thresh),
        "free_thresh": float(free_thresh),
        "resolution": float(grid.resolution_m),
        "origin": [float(v) for v in grid.origin_xy_yaw],
    }
    if src is not None and all(src.get(k) == v for k, v in values.items()):
        text = str(src["yaml_text"])
    else:
        text = _map_saver_yaml(values)
    with atomic_path(yaml_path) as tmp_yaml, atomic_path(image_path) as tmp_image:
        tmp_image.write_bytes(image_bytes)
        tmp_yaml.write_bytes(text.encode("utf-8"))
    return [yaml_path, image_path]


def _is_map_server(source: dict[str, Any] | None) -> bool:
    return isinstance(source, dict) and source.get("format") == "map_server"


def _check_grid(grid: OccupancyGrid) -> NDArray[np.float32]:
    """The grid's prob as a validated (H, W) float32 array."""
    prob = np.asarray(grid.prob)
    if prob.ndim != 2 or prob.size == 0:
        raise MapError(f"occupancy grid must be a non-empty (H, W) array, got shape {prob.shape}")
    if not np.issubdtype(prob.dtype, np.floating):
        raise MapError(f"occupancy grid prob must be floating point, got {prob.dtype}")
    prob = prob.astype(np.float32, copy=False)
    known = prob[~np.isnan(prob)]
    bad = int(np.count_nonzero(~((known >= 0.0) & (known <= 1.0))))
    if bad:
        raise MapError(f"occupancy grid has {bad} cells outside [0, 1] (or infinite)")
    res = float(grid.resolution_m)
    if not (math.isfinite(res) and res > 0):
        raise MapError(f"occupancy grid resolution must be a positive number, got {res}")
    if len(grid.origin_xy_yaw) != 3 or not all(math.isfinite(v) for v in grid.origin_xy_yaw):
        raise MapError(f"occupancy grid origin must be 3 finite numbers, got {grid.origin_xy_yaw}")
    return prob


def _cells_from_prob(prob: NDArray[np.float32]) -> NDArray[np.int16]:
    """nav_msgs/OccupancyGrid values: rint(prob * 100), -1 for NaN."""
    known = ~np.isnan(prob)
    cells = np.full(prob.shape, -1, dtype=np.int16)
    cells[known] = np.rint(prob[known].astype(np.float64) * 100.0)
    return cells


def _encode_cells(
    cells: NDArray[np.int16], mode: str, free: float, occupied: float, negate: int
) -> tuple[NDArray[np.uint8], NDArray[np.uint8] | None]:
    """map_saver's grey levels (and alpha in scale mode when a cell is unknown)."""
    unknown = (cells < 0) | (cells > 100)
    alpha: NDArray[np.uint8] | None = None
    if mode == "trinary":
        free_int, occupied_int = int(np.rint(free * 100.0)), int(np.rint(occupied * 100.0))
        grey = np.full(cells.shape, _UNKNOWN_GREY, dtype=np.uint8)
        grey[~unknown & (cells >= occupied_int)] = 0
        grey[~unknown & (cells <= free_int)] = _FREE_GREY
    elif mode == "scale":
        # ColorGray((100 - v) / 100): a truncating double -> Q16 conversion, then Q16 -> 8 bits
        # by integer division by 257 (GraphicsMagick's ScaleQuantumToChar).
        shade = np.where(unknown, 0.5, (100.0 - cells) / 100.0)
        grey = (np.floor(shade * _MAX_RGB).astype(np.int64) // 257).astype(np.uint8)
        if unknown.any():
            alpha = np.where(unknown, 0, 255).astype(np.uint8)
    else:
        grey = np.where(unknown, 255, cells).astype(np.uint8)
    if negate and mode != "raw":
        grey = (255 - grey).astype(np.uint8)
    return grey, alpha


def _warn_if_lossy(
    path: Path,
    cells: NDArray[np.int16],
    grey: NDArray[np.uint8],
    alpha: NDArray[np.uint8] | None,
    mode: str,
    free: float,
    occupied: float,
    negate: int,
) -> None:
    """Log when map_server would read the written pixels back as other cells than written."""
    # every grey level through map_server's decoding, then looked up per pixel
    levels = np.arange(256, dtype=np.float64) * 257.0
    decoded = _decode_cells(levels * 3.0, None, mode, negate, free, occupied)[grey]
    if alpha is not None:
        decoded = np.where(alpha != 255, -1, decoded)
    if mode == "trinary":
        # trinary keeps only free, occupied and unknown by design
        free_int, occupied_int = int(np.rint(free * 100.0)), int(np.rint(occupied * 100.0))
        known = (cells >= 0) & (cells <= 100)
        expected = np.where(
            known & (cells <= free_int), 0, np.where(known & (cells >= occupied_int), 100, -1)
        )
    else:
        expected = np.where((cells < 0) | (cells > 100), -1, cells)
    changed = int(np.count_nonzero(decoded != expected))
    if changed:
        log.warning(
            "%s: with free_thresh %s and occupied_thresh %s in %s mode, %d cells will load "
            "back as other values than written",
            path,
            free,
            occupied,
            mode,
            changed,
        )


def _pgm_header(grid: OccupancyGrid, src: dict[str, Any] | None, shape: tuple[int, ...]) -> str:
    height, width = shape
    stored = src.get("pgm_header") if src else None
    if (
        isinstance(stored, str)
        and src is not None
        and src.get("resolution") == float(grid.resolution_m)
    ):
        try:
            w, h, maxval, offset = _parse_p5_header(Path("header"), stored.encode("latin-1"))
        except FormatError:
            w = h = maxval = offset = -1
        if (w, h, maxval, offset) == (width, height, 255, len(stored)):
            return stored
    return f"P5\n{width} {height}\n255\n"


def _encode_image(
    grey: NDArray[np.uint8], alpha: NDArray[np.uint8] | None, suffix: str, header: str
) -> bytes:
    if suffix == ".pgm":
        return header.encode("latin-1") + np.ascontiguousarray(grey).tobytes()
    import cv2

    # Scale mode's image is true colour with alpha, as map_saver writes it.
    image = grey if alpha is None else np.dstack([grey, grey, grey, alpha])
    ok, buf = cv2.imencode(suffix, image)
    if not ok:
        raise ExportError(f"OpenCV could not encode the map image as {suffix}")
    return bytes(buf.tobytes())


def _map_saver_yaml(values: dict[str, Any]) -> str:
    """The YAML yaml-cpp emits for map_saver (``YAML::Precision(3)``, no final newline)."""
    x, y, yaw = values["origin"]
    lines = [
        f"image: {_yaml_string(values['image'])}",
        f"mode: {values['mode']}",
        f"resolution: {_number_text(values['resolution'])}",
        f"origin: [{_number_text(x)}, {_number_text(y)}, {_number_text(yaw)}]",
        f"negate: {values['negate']}",
        f"occupied_thresh: {_number_text(values['occupied_thresh'])}",
        f"free_thresh: {_number_text(values['free_thresh'])}",
    ]
    return "\n".join(lines)


def _number_text(value: float) -> str:
    """map_saver's 3 significant digits when they read back exactly, else the shortest text
    that does (map_saver would lose the difference)."""
    value = float(value) + 0.0  # no "-0"
    text = f"{value:.3g}"
    return text if float(text) == value else repr(value)


def _yaml_string(name: str) -> str:
    import yaml

    if yaml.safe_load(f"k: {name}") == {"k": name}:
        return name
    return json.dumps(name)  # a JSON string is a YAML double-quoted scalar


# --- npz, png, dispatch ----------------------------------------------------------------------


def write_map_npz(path: str | Path, grid: OccupancyGrid) -> Path:
    """Write the grid losslessly (float32 prob with NaN, resolution, origin), atomically.

    Raises:
        MapError: the grid is malformed.
        ExportError: the folder does not exist or the write failed.
    """
    prob = _check_grid(grid)
    with atomic_path(path) as tmp, tmp.open("wb") as fh:
        np.savez_compressed(
            fh,
            format=np.array(NPZ_FORMAT),
            format_version=np.array(NPZ_FORMAT_VERSION, dtype=np.int64),
            prob=prob,
            resolution_m=np.array(float(grid.resolution_m), dtype=np.float64),
            origin_xy_yaw=np.array([float(v) for v in grid.origin_xy_yaw], dtype=np.float64),
        )
    return Path(path)


def read_map_npz(path: str | Path) -> OccupancyGrid:
    """Read a grid written by :func:`write_map_npz`.

    Raises:
        InputError: the file does not exist.
        FormatError: not an npz archive, not a slamcli grid, a newer format version, or bad
            arrays (names the array).
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: no such file")
    try:
        z = np.load(p, allow_pickle=False)
        if not isinstance(z, np.lib.npyio.NpzFile):
            raise FormatError(
                p,
                f"holds a single array, not a slamcli .npz grid ({_NPZ_EXPECTED})",
                hint=_NPZ_HINT,
            )
        with z:
            wanted = [n for n in _NPZ_ARRAYS if n in z.files]
            for name in wanted:
                _check_npz_member_size(p, z, name)
            arrays = {name: z[name] for name in wanted}
    except FormatError:
        raise
    except OSError as exc:
        raise FormatError(p, f"cannot be read ({exc.strerror or exc})") from exc
    except (
        ValueError,
        EOFError,
        zipfile.BadZipFile,
        zlib.error,
        NotImplementedError,
        RuntimeError,
    ) as exc:
        # numpy's own words ("pickled data", "bad zip") say nothing about what a map should be.
        # zipfile raises NotImplementedError for a damaged version or method field and
        # RuntimeError for a damaged encryption flag.
        raise FormatError(
            p, f"is not a readable .npz archive: expected {_NPZ_EXPECTED}", hint=_NPZ_HINT
        ) from exc
    if "format" not in arrays or str(arrays["format"]) != NPZ_FORMAT:
        raise FormatError(
            p,
            f"is not a slamcli occupancy grid (no format '{NPZ_FORMAT}'): expected {_NPZ_EXPECTED}",
            hint=_NPZ_HINT,
        )
    for name in ("format_version", "prob", "resolution_m", "origin_xy_yaw"):
        if name not in arrays:
            raise FormatError(p, f"missing array '{name}'")
    version = arrays["format_version"]
    if version.shape != () or not np.issubdtype(version.dtype, np.integer):
        raise FormatError(p, f"'format_version' must be an integer, got {version!r}")
    if int(version) != NPZ_FORMAT_VERSION:
        raise FormatError(
            p,
            f"format_version {int(version)} is not supported (this slamcli reads "
            f"{NPZ_FORMAT_VERSION})",
            hint="upgrade slamcli" if int(version) > NPZ_FORMAT_VERSION else None,
        )
    prob = arrays["prob"]
    if prob.ndim != 2 or prob.size == 0 or prob.dtype != np.float32:
        raise FormatError(
            p, f"'prob' must be a non-empty (H, W) float32 array, got {prob.dtype} {prob.shape}"
        )
    known = prob[~np.isnan(prob)]
    if not np.all((known >= 0.0) & (known <= 1.0)):
        raise FormatError(p, "'prob' has values outside [0, 1]")
    res = arrays["resolution_m"]
    if not (_is_real(res, ()) and np.isfinite(res) and float(res) > 0):
        raise FormatError(p, f"'resolution_m' must be a positive number, got {res!r}")
    origin = arrays["origin_xy_yaw"]
    if not (_is_real(origin, (3,)) and np.all(np.isfinite(origin))):
        raise FormatError(p, f"'origin_xy_yaw' must be 3 finite numbers, got {origin!r}")
    x, y, yaw = (float(v) for v in origin)
    return OccupancyGrid(prob, float(res), (x, y, yaw))


def _check_npz_member_size(p: Path, z: Any, name: str) -> None:
    """Refuse an array whose header declares more than a map at the image limit, unread.

    A compressed member of zeros declaring gigabytes is a few kilobytes on disk.
    """
    member = f"{name}.npy"
    if member not in z.zip.namelist():
        raise FormatError(p, f"'{name}' is not an .npy array", hint=_NPZ_HINT)
    with z.zip.open(member) as fh:
        version = np.lib.format.read_magic(fh)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
        elif version == (2, 0):
            shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
        else:
            raise FormatError(p, f"array '{name}' has .npy format version {version}")
    cells = math.prod(shape)
    if cells * dtype.itemsize > MAX_IMAGE_PIXELS * 8:
        raise FormatError(
            p,
            f"array '{name}' declares shape {shape} of {dtype}, more than the limit of "
            f"{MAX_IMAGE_PIXELS / 1e6:g} million cells",
        )


def _is_real(a: NDArray[Any], shape: tuple[int, ...]) -> bool:
    return a.shape == shape and (
        np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)
    )


def write_map_png(path: str | Path, grid: OccupancyGrid, *, scale: int = 1) -> Path:
    """A preview image: free white, occupied black, probabilities in between as greys
    (``255 * (1 - prob)``), unknown light grey (205, map_saver's), y up; written atomically.

    Args:
        scale: each cell becomes ``scale`` x ``scale`` pixels (a positive integer).

    Raises:
        ConfigError: a bad scale. MapError: a malformed grid.
        ExportError: the folder does not exist or the write failed.
    """
    import cv2

    if isinstance(scale, bool) or not isinstance(scale, (int, np.integer)) or scale < 1:
        raise ConfigError(f"preview scale must be a positive integer, got {scale!r}")
    prob = _check_grid(grid)
    grey = np.where(
        np.isnan(prob), _UNKNOWN_GREY, np.rint(255.0 * (1.0 - prob.astype(np.float64)))
    ).astype(np.uint8)
    grey = np.flipud(grey)
    if scale > 1:
        grey = np.repeat(np.repeat(grey, scale, axis=0), scale, axis=1)
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(grey))
    if not ok:
        raise ExportError(f"{path}: OpenCV could not encode the preview PNG")
    with atomic_path(path) as tmp:
        tmp.write_bytes(buf.tobytes())
    return Path(path)


def read_map(path: str | Path) -> OccupancyGrid:
    """Read an occupancy grid by suffix: ``.yaml``/``.yml`` (map_server) or ``.npz`` (slamcli).

    Raises:
        UnknownFormatError: another suffix. InputError, FormatError: as the reader raises.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix in (".yaml", ".yml"):
        return read_map_yaml(p)
    if suffix == ".npz":
        return read_map_npz(p)
    known = [f"{name} ({s})" for s, name in MAP_SUFFIXES.items()]
    raise UnknownFormatError(p, known, "occupancy maps are read by their suffix")


# --- cells and the world ---------------------------------------------------------------------


def world_to_cell(grid: OccupancyGrid, xy: ArrayLike) -> NDArray[np.int64]:
    """World points (..., 2) in metres -> (..., 2) int64 ``(row, col)`` of the cell holding each.

    Row 0 is the lowest y. The grid's axes are rotated by the origin's yaw about the origin
    (Nav2 ignores the yaw; for yaw 0 the results agree). A point on a cell's lower or left edge
    belongs to that cell. Indices outside the grid are returned as they are: check them
    against ``grid.prob.shape``.
    """
    p = np.asarray(xy, dtype=np.float64)
    if p.shape[-1:] != (2,):
        raise ValueError(f"xy must have shape (..., 2), got {p.shape}")
    x0, y0, yaw = (float(v) for v in grid.origin_xy_yaw)
    dx, dy = p[..., 0] - x0, p[..., 1] - y0
    c, s = math.cos(yaw), math.sin(yaw)
    res = float(grid.resolution_m)
    col = np.floor((c * dx + s * dy) / res)
    row = np.floor((-s * dx + c * dy) / res)
    return np.stack([row, col], axis=-1).astype(np.int64)


def cell_to_world(grid: OccupancyGrid, rc: ArrayLike) -> NDArray[np.float64]:
    """``(row, col)`` cells (..., 2) -> (..., 2) world x, y of their centres in metres.

    The inverse of :func:`world_to_cell` for cell centres; honours the origin's yaw.
    """
    q = np.asarray(rc, dtype=np.float64)
    if q.shape[-1:] != (2,):
        raise ValueError(f"rc must have shape (..., 2), got {q.shape}")
    x0, y0, yaw = (float(v) for v in grid.origin_xy_yaw)
    res = float(grid.resolution_m)
    u, v = (q[..., 1] + 0.5) * res, (q[..., 0] + 0.5) * res
    c, s = math.cos(yaw), math.sin(yaw)
    return np.stack([x0 + c * u - s * v, y0 + s * u + c * v], axis=-1)


__all__ = [
    "DEFAULT_FREE_THRESH",
    "DEFAULT_OCCUPIED_THRESH",
    "MAP_MODES",
    "NPZ_FORMAT_VERSION",
    "SCALE_THRESHOLDS",
    "cell_to_world",
    "read_map",
    "read_map_npz",
    "read_map_yaml",
    "world_to_cell",
    "write_map_npz",
    "write_map_png",
    "write_map_yaml",
]
