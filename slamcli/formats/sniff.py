"""Cheap tests of what an input is, by suffix, magic bytes or folder layout.

They live apart from the sources so that :func:`slamcli.formats.open_source` can pick a
format without importing every source module (the MCAP source pulls in the ``mcap`` package
and the message decoders); each source class's ``sniff`` calls the function here.
"""

from __future__ import annotations

import re
import zlib
from pathlib import Path

MCAP_MAGIC = b"\x89MCAP0\r\n"
"""The bytes every MCAP file starts (and ends) with."""

ROSBAG_MAGIC = b"#ROSBAG V2.0\n"
ROSRECORD_MAGIC = b"#ROSRECORD V"
"""The start of the first line of ROS bags of formats 1.1 and 1.2 (ROS 0.4 to 1.0, 2009-2010)."""
"""The line a ROS 1 bag (format 2.0) starts with."""

ROSBAG2_METADATA = "metadata.yaml"
"""The file that makes a folder a ROS 2 bag (top-level key ``rosbag2_bagfile_information``)."""

VICTORIA_KEYWORDS = ("ODOMETRY", "LANDMARK")
"""The record keywords that start the lines of a Victoria Park file."""

GZIP_MAGIC = b"\x1f\x8b"
"""The two bytes every gzip stream starts with."""

CARMEN_SUFFIXES = (".log", ".clf")
"""Suffixes of a CARMEN log (each also with ``.gz``)."""

CARMEN_KEYWORD = re.compile(
    r"PARAM|SYNC|ODOM|TRUEPOS|[FR]LASER|LASER\d|RAWLASER\d|ROBOTLASER\d|NMEA\w*|IMU|SONAR|BUMPER",
    re.ASCII,
)
"""The keywords CARMEN's logger starts a message line with."""

REDWOOD_COLOUR_FOLDERS = ("image", "color")
"""The colour-image folders of an Open3D / Redwood RGB-D folder, in the order looked for."""

KITTI_PAIR_FOLDERS = (("image_0", "image_1"), ("image_2", "image_3"), ("image_l", "image_r"))
"""The (left, right) image folders of a KITTI odometry sequence, in the order looked for: grey,
colour, and the ``image_l``/``image_r`` naming of excerpts."""

KITTI_CALIB = "calib.txt"
"""The projection matrices of a KITTI odometry sequence."""

_HEAD_BYTES = 4096


def tum_rgbd(path: str | Path) -> bool:
    """A folder with ``rgb.txt`` or ``depth.txt`` (the source names whichever is missing)."""
    p = Path(path)
    return p.is_dir() and ((p / "rgb.txt").is_file() or (p / "depth.txt").is_file())


def redwood(path: str | Path) -> bool:
    """A folder with a ``depth/`` folder and an ``image/`` or ``color/`` folder beside it."""
    p = Path(path)
    return (
        p.is_dir()
        and (p / "depth").is_dir()
        and any((p / name).is_dir() for name in REDWOOD_COLOUR_FOLDERS)
    )


def mcap(path: str | Path) -> bool:
    """A ``.mcap`` file, or any file starting with the MCAP magic."""
    p = Path(path)
    if not p.is_file():
        return False
    if p.suffix.lower() == ".mcap":
        return True
    with p.open("rb") as fh:
        return fh.read(len(MCAP_MAGIC)) == MCAP_MAGIC


def rosbag1(path: str | Path) -> bool:
    """A ``.bag`` file, or any file starting with ``#ROSBAG V`` (a ROS 1 bag) or
    ``#ROSRECORD V`` (a bag of the formats before 2.0, which the reader names and refuses)."""
    p = Path(path)
    if not p.is_file():
        return False
    if p.suffix.lower() == ".bag":
        return True
    with p.open("rb") as fh:
        head = fh.read(len(ROSRECORD_MAGIC))
    return head.startswith((ROSBAG_MAGIC[:9], ROSRECORD_MAGIC))


def rosbag2(path: str | Path) -> bool:
    """A ROS 2 bag: a folder whose ``metadata.yaml`` is rosbag2's, or a ``.db3`` file."""
    p = Path(path)
    if p.is_file():
        return p.suffix.lower() == ".db3"
    meta = p / ROSBAG2_METADATA
    if not (p.is_dir() and meta.is_file()):
        return False
    try:
        with meta.open("rb") as fh:
            return b"rosbag2_bagfile_information" in fh.read(_HEAD_BYTES)
    except OSError:
        return False


def mrclam_robots(folder: str | Path) -> list[int]:
    """Robot numbers N with a ``RobotN_Odometry.dat`` in ``folder``, sorted."""
    robots: list[int] = []
    for p in Path(folder).glob("Robot*_Odometry.dat"):
        number = p.name[len("Robot") : -len("_Odometry.dat")]
        if number.isdigit():
            robots.append(int(number))
    return sorted(robots)


def mrclam(path: str | Path) -> bool:
    """A folder with ``Barcodes.dat`` and at least one ``RobotN_Odometry.dat``."""
    p = Path(path)
    return p.is_dir() and (p / "Barcodes.dat").is_file() and bool(mrclam_robots(p))


def victoria_park(path: str | Path) -> bool:
    """A file whose first non-blank, non-comment line starts with ODOMETRY or LANDMARK."""
    p = Path(path)
    if not p.is_file():
        return False
    try:
        with p.open("rb") as fh:
            head = fh.read(_HEAD_BYTES).decode("utf-8-sig")
    except (OSError, UnicodeDecodeError):
        return False
    for line in head.splitlines():
        text = line.strip()
        if text and not text.startswith("#"):
            return text.split(maxsplit=1)[0] in VICTORIA_KEYWORDS
    return False


def carmen(path: str | Path) -> bool:
    """A ``.log``/``.clf`` file (also ``.gz``) whose first message is a CARMEN one.

    The first few KB are read, decompressed when they start with the gzip magic (whatever the
    suffix).
    """
    p = Path(path)
    name = p.name.lower().removesuffix(".gz")
    if not (name.endswith(CARMEN_SUFFIXES) and p.is_file()):
        return False
    try:
        with p.open("rb") as fh:
            head = fh.read(_HEAD_BYTES)
        if head.startswith(GZIP_MAGIC):
            head = zlib.decompressobj(16 + zlib.MAX_WBITS).decompress(head, _HEAD_BYTES)
    except (OSError, zlib.error):
        return False
    for line in head.decode("utf-8", errors="replace").splitlines():
        text = line.strip().lstrip("\ufeff")
        if text and not text.startswith("#"):
            return CARMEN_KEYWORD.fullmatch(text.split(maxsplit=1)[0]) is not None
    return False


def kitti(path: str | Path) -> bool:
    """A folder with ``calib.txt`` beside a left image folder of :data:`KITTI_PAIR_FOLDERS`."""
    p = Path(path)
    return (
        p.is_dir()
        and (p / KITTI_CALIB).is_file()
        and any((p / left).is_dir() for left, _ in KITTI_PAIR_FOLDERS)
    )


def euroc(path: str | Path) -> bool:
    """A EuRoC / ASL folder: ``mav0/cam0/data.csv`` inside it, or ``cam0/data.csv`` and
    ``cam1/`` in a folder named ``mav0``."""
    p = Path(path)
    if not p.is_dir():
        return False
    if (p / "mav0" / "cam0" / "data.csv").is_file():
        return True
    return p.name == "mav0" and (p / "cam0" / "data.csv").is_file() and (p / "cam1").is_dir()


def landmark_world(path: str | Path) -> bool:
    """A ``slamcli synth landmarks`` folder: ``odometry.csv`` and ``measurements.csv``."""
    p = Path(path)
    return p.is_dir() and (p / "odometry.csv").is_file() and (p / "measurements.csv").is_file()


__all__ = [
    "CARMEN_KEYWORD",
    "CARMEN_SUFFIXES",
    "GZIP_MAGIC",
    "KITTI_CALIB",
    "KITTI_PAIR_FOLDERS",
    "MCAP_MAGIC",
    "REDWOOD_COLOUR_FOLDERS",
    "ROSBAG2_METADATA",
    "ROSBAG_MAGIC",
    "ROSRECORD_MAGIC",
    "VICTORIA_KEYWORDS",
    "carmen",
    "euroc",
    "kitti",
    "landmark_world",
    "mcap",
    "mrclam",
    "mrclam_robots",
    "redwood",
    "rosbag1",
    "rosbag2",
    "tum_rgbd",
    "victoria_park",
]
