"""Occupancy grids built from SLAM results: ``build_map(run_dir)`` and its parts."""

from slamcli.mapping.build import (
    MAP_FILES,
    BuiltMap,
    MapSettings,
    build_map,
    cell_counts,
    parse_height_band,
)
from slamcli.mapping.occupancy import L_FREE, L_MAX, L_MIN, L_OCC, LogOddsGrid
from slamcli.mapping.output import map_run, write_map

__all__ = [
    "L_FREE",
    "L_MAX",
    "L_MIN",
    "L_OCC",
    "MAP_FILES",
    "BuiltMap",
    "LogOddsGrid",
    "MapSettings",
    "build_map",
    "cell_counts",
    "map_run",
    "parse_height_band",
    "write_map",
]
