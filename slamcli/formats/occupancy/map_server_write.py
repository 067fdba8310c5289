"""Writing ROS map_server maps (YAML + image) as Nav2's map_saver does, byte for byte where a
map read by :func:`~slamcli.formats.occupancy.read_map_yaml` is written back unchanged.

See :mod:`slamcli.formats.occupancy` for the format, the default thresholds and the round trip.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.atomic import atomic_path
from slamcli.errors import ConfigError, ExportError, FormatError, MapError
from slamcli.formats.occupancy.grid import check_grid
from slamcli.formats.occupancy.map_server_read import (
    MAP_MODES,
    MAX_RGB,
    decode_cells,
    parse_p5_header,
)
from slamcli.types import OccupancyGrid

log = logging.getLogger(__name__)

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

_WRITE_SUFFIXES = (".pgm", ".png", ".bmp")
UNKNOWN_GREY = 205
"""map_saver's grey for an unknown cell in trinary mode."""
_FREE_GREY = 254


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
    prob = check_grid(grid)
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
        grey = np.full(cells.shape, UNKNOWN_GREY, dtype=np.uint8)
        grey[~unknown & (cells >= occupied_int)] = 0
        grey[~unknown & (cells <= free_int)] = _FREE_GREY
    elif mode == "scale":
        # ColorGray((100 - v) / 100): a truncating double -> Q16 conversion, then Q16 -> 8 bits
        # by integer division by 257 (GraphicsMagick's ScaleQuantumToChar).
        shade = np.where(unknown, 0.5, (100.0 - cells) / 100.0)
        grey = (np.floor(shade * MAX_RGB).astype(np.int64) // 257).astype(np.uint8)
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
    decoded = decode_cells(levels * 3.0, None, mode, negate, free, occupied)[grey]
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
            w, h, maxval, offset = parse_p5_header(Path("header"), stored.encode("latin-1"))
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
