"""Occupancy grids stored losslessly in a NumPy ``.npz`` archive (float32 prob with NaN,
resolution, origin), and read back with every array checked before it is loaded."""

from __future__ import annotations

import math
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.atomic import atomic_path
from slamcli.errors import FormatError, InputError
from slamcli.formats.base import npy_header
from slamcli.formats.images import MAX_IMAGE_PIXELS
from slamcli.formats.occupancy.grid import check_grid
from slamcli.types import OccupancyGrid

NPZ_FORMAT = "slamcli.occupancy_grid"
NPZ_FORMAT_VERSION = 1
"""Version of the ``.npz`` layout: ``format``, ``format_version``, ``prob`` (H, W) float32 with
NaN, ``resolution_m`` float64, ``origin_xy_yaw`` (3,) float64."""

_NPZ_EXPECTED = (
    "a slamcli occupancy grid, a NumPy .npz archive with the arrays format, format_version, "
    "prob, resolution_m and origin_xy_yaw"
)
_NPZ_HINT = (
    "such files are written by slamcli.formats.occupancy.write_map_npz; 'slamcli map build' "
    "writes a map_server map.yaml, which 'slamcli plan' and 'slamcli map show' also read"
)

_NPZ_ARRAYS = ("format", "format_version", "prob", "resolution_m", "origin_xy_yaw")


def write_map_npz(path: str | Path, grid: OccupancyGrid) -> Path:
    """Write the grid losslessly (float32 prob with NaN, resolution, origin), atomically.

    Raises:
        MapError: the grid is malformed.
        ExportError: the folder does not exist or the write failed.
    """
    prob = check_grid(grid)
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
    if f"{name}.npy" not in z.zip.namelist():
        raise FormatError(p, f"'{name}' is not an .npy array", hint=_NPZ_HINT)
    header = npy_header(z, name)
    if header is None:
        raise FormatError(p, f"array '{name}' has an .npy format version numpy cannot read")
    shape, dtype = header
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
