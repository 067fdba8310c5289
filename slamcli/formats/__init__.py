"""Everything that reads or writes bytes: input sources and output formats."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from slamcli.errors import ConfigError, InputError, UnknownFormatError
from slamcli.formats.base import Frame, ReadStats, Source, SourceInfo, StreamInfo
from slamcli.formats.landmarks import LandmarkWorldSource, MrclamSource, VictoriaParkSource
from slamcli.formats.mcap.source import McapSource
from slamcli.formats.tum_rgbd import TumRgbdSource

SOURCES: dict[str, Any] = {
    "tum": TumRgbdSource,
    "mcap": McapSource,
    "mrclam": MrclamSource,
    "victoria": VictoriaParkSource,
    "landmarks": LandmarkWorldSource,
}
"""Source classes by format name; each has ``sniff(path) -> bool`` and ``open(path, **options)``.

The sniffers look at disjoint things (TUM: rgb.txt/depth.txt; MCAP: suffix or magic; MRCLAM:
Barcodes.dat and RobotN_Odometry.dat; Victoria Park: the first record's keyword; synth
landmarks: odometry.csv and measurements.csv), so the order only matters for odd mixtures."""

_LAYOUTS = (
    "a TUM RGB-D folder has rgb.txt and depth.txt; an MRCLAM folder Barcodes.dat and "
    "RobotN_Odometry.dat; a 'slamcli synth landmarks' folder odometry.csv and measurements.csv; "
    "an MCAP log starts with the MCAP magic; a Victoria Park file has ODOMETRY and LANDMARK lines"
)


def open_source(path: str | Path, format: str = "auto", **options: Any) -> Source:
    """Open an input log as a :class:`Source`.

    ``format="auto"`` sniffs cheaply (suffix, magic bytes, folder layout). Options are passed to
    the source class (e.g. ``max_dt``, ``depth_factor``, ``camera`` for TUM folders, ``robot``
    and ``ignore_ids`` for MRCLAM folders).
    """
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file or folder")
    if format != "auto":
        if format not in SOURCES:
            raise UnknownFormatError(p, sorted(SOURCES), f"unknown format {format!r}")
        return _open(SOURCES[format], p, options)
    for cls in SOURCES.values():
        if cls.sniff(p):
            return _open(cls, p, options)
    raise UnknownFormatError(p, sorted(SOURCES), _LAYOUTS)


def _open(cls: Any, path: Path, options: dict[str, Any]) -> Source:
    unknown = sorted(set(options) - set(cls.OPTIONS))
    if unknown:
        flags = ", ".join("--" + name.replace("_", "-") for name in unknown)
        raise ConfigError(
            f"{path}: {flags} does not apply to {cls.format_name} inputs",
            hint=f"{cls.format_name} inputs take: "
            + ", ".join("--" + n.replace("_", "-") for n in cls.OPTIONS),
        )
    return cls.open(path, **options)


__all__ = ["SOURCES", "Frame", "ReadStats", "Source", "SourceInfo", "StreamInfo", "open_source"]
