"""PNG previews of occupancy grids: free white, occupied black, unknown grey, y up."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slamcli.atomic import atomic_path
from slamcli.errors import ConfigError, ExportError
from slamcli.formats.occupancy.grid import check_grid
from slamcli.formats.occupancy.map_server_write import UNKNOWN_GREY
from slamcli.types import OccupancyGrid


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
    prob = check_grid(grid)
    grey = np.where(
        np.isnan(prob), UNKNOWN_GREY, np.rint(255.0 * (1.0 - prob.astype(np.float64)))
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
