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

One module per job: :mod:`~slamcli.formats.occupancy.map_server_read` and
:mod:`~slamcli.formats.occupancy.map_server_write` (map_server maps),
:mod:`~slamcli.formats.occupancy.npz` (lossless grids), :mod:`~slamcli.formats.occupancy.png`
(previews) and :mod:`~slamcli.formats.occupancy.grid` (checks, cells and the world);
:func:`read_map` picks the reader by suffix.
"""

from __future__ import annotations

from pathlib import Path

from slamcli.errors import UnknownFormatError
from slamcli.formats.occupancy.grid import cell_to_world, world_to_cell
from slamcli.formats.occupancy.map_server_read import (
    MAP_MODES,
    MAP_ORIGIN_MAX,
    MAP_RESOLUTION_RANGE,
    read_map_yaml,
)
from slamcli.formats.occupancy.map_server_write import (
    DEFAULT_FREE_THRESH,
    DEFAULT_OCCUPIED_THRESH,
    NAV2_FREE_THRESH,
    SCALE_THRESHOLDS,
    write_map_yaml,
)
from slamcli.formats.occupancy.npz import (
    NPZ_FORMAT,
    NPZ_FORMAT_VERSION,
    read_map_npz,
    write_map_npz,
)
from slamcli.formats.occupancy.png import write_map_png
from slamcli.types import OccupancyGrid

MAP_SUFFIXES = {".yaml": "map_server YAML", ".yml": "map_server YAML", ".npz": "slamcli grid"}


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


__all__ = [
    "DEFAULT_FREE_THRESH",
    "DEFAULT_OCCUPIED_THRESH",
    "MAP_MODES",
    "MAP_ORIGIN_MAX",
    "MAP_RESOLUTION_RANGE",
    "MAP_SUFFIXES",
    "NAV2_FREE_THRESH",
    "NPZ_FORMAT",
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
