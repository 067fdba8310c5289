"""Everything that reads or writes bytes: input sources and output formats."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

from slamcli.errors import ConfigError, InputError, UnknownFormatError
from slamcli.formats import sniff
from slamcli.formats.base import Frame, ReadStats, Source, SourceInfo, StreamInfo

SOURCES: dict[str, str] = {
    "tum": "slamcli.formats.tum_rgbd:TumRgbdSource",
    "redwood": "slamcli.formats.redwood:RedwoodSource",
    "mcap": "slamcli.formats.mcap.source:McapSource",
    "rosbag1": "slamcli.formats.rosbag.source:Ros1BagSource",
    "rosbag2": "slamcli.formats.rosbag.source:Ros2BagSource",
    "mrclam": "slamcli.formats.landmarks:MrclamSource",
    "victoria": "slamcli.formats.landmarks:VictoriaParkSource",
    "landmarks": "slamcli.formats.landmarks:LandmarkWorldSource",
    "carmen": "slamcli.formats.carmen:CarmenSource",
    "kitti": "slamcli.formats.kitti:KittiSource",
    "euroc": "slamcli.formats.euroc:EurocSource",
}
"""Source classes by format name, as ``module:Class`` so a source's module (and what it
imports: ``mcap``, OpenCV, ...) loads only when that source is used; :func:`source_class`
loads one. Each class has ``sniff(path) -> bool`` and ``open(path, **options)``."""

SNIFFERS: dict[str, Callable[[str | Path], bool]] = {
    "tum": sniff.tum_rgbd,
    "redwood": sniff.redwood,
    "mcap": sniff.mcap,
    "rosbag1": sniff.rosbag1,
    "rosbag2": sniff.rosbag2,
    "mrclam": sniff.mrclam,
    "victoria": sniff.victoria_park,
    "landmarks": sniff.landmark_world,
    "carmen": sniff.carmen,
    "kitti": sniff.kitti,
    "euroc": sniff.euroc,
}
"""The cheap test of each format (what its class's ``sniff`` calls), importing no source.

They look at disjoint things (TUM: rgb.txt/depth.txt; Open3D/Redwood: depth/ beside image/
or color/; MCAP: suffix or magic; MRCLAM: Barcodes.dat and RobotN_Odometry.dat; Victoria Park:
the first record's keyword; synth landmarks: odometry.csv and measurements.csv; CARMEN: a
.log/.clf suffix and the first message's keyword), so the order only matters for odd mixtures.
ROS 1 bags: a .bag suffix or '#ROSBAG V'; ROS 2 bags: a folder with rosbag2's metadata.yaml, or
a .db3 file; KITTI: a folder with calib.txt beside image_0/ (image_2/, image_l/); EuRoC / ASL:
mav0/cam0/data.csv, or a mav0 folder itself."""


def source_class(name: str) -> Any:
    """The source class registered under ``name`` in :data:`SOURCES`, imported on first use.

    Raises:
        UnknownFormatError: no such format.
    """
    if name not in SOURCES:
        raise UnknownFormatError(name, sorted(SOURCES), f"unknown format {name!r}")
    module, _, cls = SOURCES[name].partition(":")
    return getattr(importlib.import_module(module), cls)


_LAYOUTS = (
    "a TUM RGB-D folder has rgb.txt and depth.txt; an Open3D/Redwood RGB-D folder image/ (or "
    "color/) and depth/; an MRCLAM folder Barcodes.dat and RobotN_Odometry.dat; a 'slamcli "
    "synth landmarks' folder odometry.csv and measurements.csv; an MCAP log starts with the "
    "MCAP magic; a Victoria Park file has ODOMETRY and LANDMARK lines; a CARMEN log (.log or "
    ".clf, optionally gzipped) starts with CARMEN messages (PARAM, ODOM, FLASER, ROBOTLASER1, ...)"
    "; a ROS 1 bag starts with '#ROSBAG V2.0'; a ROS 2 bag folder has rosbag2's metadata.yaml "
    "beside its .db3 or .mcap files; a KITTI odometry folder has calib.txt beside image_0/ and "
    "image_1/ (or image_2/ and image_3/, or image_l/ and image_r/); a EuRoC / ASL folder holds "
    "mav0/ (or is mav0/) with cam0/ and cam1/ (data.csv, data/, sensor.yaml) and imu0/"
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
        return _open(source_class(format), p, options)
    for name, looks_like in SNIFFERS.items():
        if looks_like(p):
            return _open(source_class(name), p, options)
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


__all__ = [
    "SNIFFERS",
    "SOURCES",
    "Frame",
    "ReadStats",
    "Source",
    "SourceInfo",
    "StreamInfo",
    "open_source",
    "source_class",
]
