"""Seeded fuzzing of slamcli's readers through its commands.

Each case copies one small, valid input (an MCAP log, a TUM RGB-D folder, a map, trajectory files,
a landmark log, a g2o graph, ROS 1 bags with uncompressed, bz2 and lz4 chunks, ROS 2 bag folders
of sqlite3 and MCAP storage, CARMEN laser logs plain and gzipped, KITTI and EuRoC stereo
folders), damages one of its files with one seeded mutation (flipped bits, overwritten runs,
truncation, repeated ranges or records, inflated length and size fields, bag record and chunk
lengths, bz2 and lz4 decompression bombs, huge image headers, YAML alias bombs, lines over the
readers' 1 MiB limit, text edits) and runs one command on it. A case finds a problem when the
command

- exits with anything but 0, 1 or 3, or raises (a traceback), or prints more than one error line;
- leaves a half-written output: an ``--out`` folder without run.json (or plan.json), a run.json
  naming a file that is missing, or a hidden staging or temporary file beside the outputs;
- runs longer than ``WALL_LIMIT_S`` or peaks above ``RSS_LIMIT_MB`` of resident memory.

Cases run in long-lived worker processes that call the CLI in-process (fast), and every
``--subprocess-every``-th case as ``python -m slamcli`` in a child with resource limits (exact).
A worker that hangs or dies is killed and replaced, and that case counts as a problem.

    python tests/fuzzing.py --cases 10000 --seed 0      # make fuzz
"""

from __future__ import annotations

import argparse
import bz2
import functools
import gzip
import itertools
import json
import multiprocessing
import os
import random
import re
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
import traceback
import zlib
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(
    os.environ.get("SLAMCLI_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data")
)

WALL_LIMIT_S = 20.0
"""A case may run this long (wall clock). Any input must fail within 60 s (the rule the limits
in docs/hostile-input.md keep); the corpus's inputs are small, each valid one runs in under
6 s, so a case past 20 s is already running away."""
RSS_LIMIT_MB = 600.0
"""Peak resident memory of a case, the rule for any input; the valid inputs peak under
350 MB (a visual run on three KITTI pairs)."""
AS_LIMIT_BYTES = 4 << 30
"""Virtual memory a case may reserve: Open3D and OpenBLAS reserve far more than they touch."""
CPU_LIMIT_S = 60
"""CPU seconds of a subprocess case, a backstop behind the wall-clock limit."""
RETIRE_RSS_MB = 500.0
"""A worker whose resident memory stays above this after a case is replaced. A case run
in-process is measured from the worker's resident set at its start (the interpreter keeps
what earlier cases freed, and every library a command loaded: about 450 MB once all have run),
so a worker that kept growing would charge its growth to the next case."""
OK_EXIT_CODES = frozenset({0, 1, 3})


@dataclass(frozen=True)
class Target:
    """A valid input in the corpus and the commands a case may run on it.

    ``files`` are the paths (relative to the target's folder) a mutation may damage. Command
    templates use ``{in}`` for the case's copy of the target folder, ``{case}`` for the case folder
    and ``{out}`` for the run folder a command writes (``{case}/out``).
    """

    name: str
    kind: str
    files: tuple[str, ...]
    commands: tuple[tuple[str, ...], ...]
    weight: float = 1.0


@dataclass
class Case:
    case_id: str
    target: str
    file: str
    mutation: str
    argv: list[str]
    subprocess: bool


@dataclass
class Outcome:
    case: Case
    exit_code: int | None
    seconds: float
    peak_rss_mb: float
    problems: list[str] = field(default_factory=list)
    output_head: str = ""


# --- the corpus ----------------------------------------------------------------------------------

_ROOM_COMMANDS = (
    ("info", "{in}/log.mcap"),
    ("info", "{in}/log.mcap", "--deep"),
    ("run", "odometry", "{in}/log.mcap", "--max-frames", "3", "--out", "{out}"),
    ("convert", "{in}/log.mcap", "{case}/gt.tum", "--gt-topic", "/groundtruth"),
)


_SCAN_BAG_COMMANDS = (
    ("info", "{in}/scans.bag"),
    ("info", "{in}/scans.bag", "--deep"),
    ("run", "lidar", "{in}/scans.bag", "--out", "{out}"),
)
_ROS2_BAG_COMMANDS = (
    ("info", "{in}/bag"),
    ("info", "{in}/bag", "--deep"),
    ("run", "odometry", "{in}/bag", "--max-frames", "3", "--out", "{out}"),
)
_STEREO_COMMANDS = (
    ("info", "{in}"),
    ("info", "{in}", "--deep"),
    ("run", "visual", "{in}", "--max-frames", "3", "--out", "{out}"),
)
EUROC_FIRST_STAMP = 1403715273262142976
"""The first image of the shared EuRoC excerpt, the first of the corpus's three pairs."""
SCAN_BAG_MESSAGES = 30
"""Laser scans copied from the shared ROS 1 bag into the corpus's bags."""
SCAN_BAG_CHUNK_BYTES = 64 * 1024
"""Chunk size of the corpus's ROS 1 bags: several chunks of a few scans each."""


def targets() -> list[Target]:
    """The corpus entries, by kind; ``build_corpus`` writes their files."""
    return [
        Target("mcap-zstd", "mcap", ("log.mcap",), _ROOM_COMMANDS, 2.0),
        Target("mcap-lz4", "mcap", ("log.mcap",), _ROOM_COMMANDS),
        Target("mcap-raw", "mcap", ("log.mcap",), _ROOM_COMMANDS, 2.0),
        Target("mcap-foxglove-jpeg", "mcap", ("log.mcap",), _ROOM_COMMANDS),
        Target("mcap-png-depth", "mcap", ("log.mcap",), _ROOM_COMMANDS),
        Target(
            "mcap-nav2",
            "mcap",
            ("log.mcap",),
            (
                ("info", "{in}/log.mcap"),
                ("info", "{in}/log.mcap", "--deep"),
                ("convert", "{in}/log.mcap", "{case}/gt.tum", "--gt-topic", "/amcl_pose"),
            ),
        ),
        Target(
            "mcap-landmarks",
            "mcap",
            ("log.mcap",),
            (("info", "{in}/log.mcap"), ("run", "ekf", "{in}/log.mcap", "--out", "{out}")),
        ),
        Target(
            "tum",
            "tum",
            (
                "rgb.txt",
                "depth.txt",
                "groundtruth.txt",
                "camera.yaml",
                "rgb/0.png",
                "rgb/1.png",
                "depth/0.png",
                "depth/1.png",
            ),
            (
                ("info", "{in}"),
                ("info", "{in}", "--deep"),
                ("run", "odometry", "{in}", "--max-frames", "3", "--out", "{out}"),
            ),
            3.0,
        ),
        Target(
            "map",
            "map",
            ("map.yaml", "map.pgm"),
            (
                ("info", "{in}/map.yaml"),
                ("map", "show", "{in}/map.yaml"),
                (
                    "plan",
                    "{in}/map.yaml",
                    "--start",
                    "-2,-0.5",
                    "--goal",
                    "-1,0.5",
                    "--out",
                    "{out}",
                ),
            ),
            2.0,
        ),
        Target(
            "trajectory",
            "trajectory",
            ("gt.txt", "est.txt"),
            (
                ("eval", "{in}/gt.txt", "{in}/est.txt"),
                ("eval", "{in}/gt.txt", "{in}/est.txt", "--align", "sim3", "--rpe-delta", "1"),
                ("info", "{in}/est.txt"),
            ),
            2.0,
        ),
        Target(
            "trajectory-euroc",
            "trajectory",
            ("gt.csv", "est.txt"),
            (
                ("eval", "{in}/gt.csv", "{in}/est.txt", "--format", "euroc"),
                ("info", "{in}/gt.csv"),
            ),
        ),
        Target(
            "landmarks",
            "landmarks",
            ("odometry.csv", "measurements.csv", "landmarks.csv", "groundtruth.tum", "world.json"),
            (("info", "{in}"), ("run", "ekf", "{in}", "--out", "{out}")),
            2.0,
        ),
        Target(
            "g2o",
            "g2o",
            ("graph.g2o",),
            (("info", "{in}/graph.g2o"), ("info", "{in}/graph.g2o", "--json")),
            2.0,
        ),
        Target("rosbag1", "rosbag1", ("scans.bag",), _SCAN_BAG_COMMANDS, 2.0),
        Target("rosbag1-bz2", "rosbag1", ("scans.bag",), _SCAN_BAG_COMMANDS, 1.5),
        Target("rosbag1-lz4", "rosbag1", ("scans.bag",), _SCAN_BAG_COMMANDS, 1.5),
        Target(
            "rosbag2-sqlite3",
            "rosbag2",
            ("bag/metadata.yaml", "bag/metadata.yaml", "bag/bag_0.db3"),
            _ROS2_BAG_COMMANDS,
            2.0,
        ),
        Target(
            "rosbag2-mcap",
            "rosbag2",
            ("bag/metadata.yaml", "bag/bag_0.mcap"),
            _ROS2_BAG_COMMANDS,
        ),
        Target(
            "carmen",
            "carmen",
            ("laser.log",),
            (
                ("info", "{in}/laser.log"),
                ("run", "lidar", "{in}/laser.log", "--out", "{out}"),
                ("run", "lidar", "{in}/laser.log", "--out", "{out}", "--odometry", "none"),
            ),
            2.0,
        ),
        Target(
            "carmen-gz",
            "carmen",
            ("laser.log.gz",),
            (
                ("info", "{in}/laser.log.gz"),
                ("run", "lidar", "{in}/laser.log.gz", "--out", "{out}"),
            ),
        ),
        Target(
            "kitti",
            "kitti",
            (
                "calib.txt",
                "calib.txt",
                "poses.txt",
                "times.txt",
                "image_l/000000.png",
                "image_r/000001.png",
            ),
            _STEREO_COMMANDS,
            2.0,
        ),
        Target(
            "euroc",
            "euroc",
            (
                "mav0/cam0/data.csv",
                "mav0/cam1/data.csv",
                "mav0/cam0/sensor.yaml",
                "mav0/cam1/sensor.yaml",
                "mav0/imu0/data.csv",
                "mav0/imu0/sensor.yaml",
                f"mav0/cam0/data/{EUROC_FIRST_STAMP}.png",
            ),
            _STEREO_COMMANDS,
            2.0,
        ),
    ]


TARGET_KINDS = {t.name: t.kind for t in targets()}


def _slamcli(*args: str | Path) -> None:
    subprocess.run(
        [sys.executable, "-m", "slamcli", *map(str, args)],
        check=True,
        stdout=subprocess.DEVNULL,
        cwd=REPO,
    )


def _head_lines(src: Path, dst: Path, keep: int) -> None:
    """Copy comment lines and the first ``keep`` data lines."""
    out, n = [], 0
    for line in src.read_text().splitlines(keepends=True):
        if line.startswith("#"):
            out.append(line)
        elif n < keep:
            out.append(line)
            n += 1
    dst.write_text("".join(out))


def _recompress(src: Path, dst: Path, compression: str) -> None:
    """Rewrite an MCAP log with another chunk compression ("lz4" or "" for none)."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    kind = {"lz4": CompressionType.LZ4, "": CompressionType.NONE}[compression]
    with src.open("rb") as f_in, dst.open("wb") as f_out:
        reader = make_reader(f_in)
        writer = Writer(f_out, compression=kind)
        writer.start(profile=reader.get_header().profile, library="slamcli fuzz corpus")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(
                    schema.name, schema.encoding, schema.data
                )
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic,
                    channel.message_encoding,
                    schemas.get(schema.id, 0) if schema is not None else 0,
                    dict(channel.metadata),
                )
            writer.add_message(
                channels[channel.id],
                message.log_time,
                message.data,
                message.publish_time,
                message.sequence,
            )
        writer.finish()


def _tum_folder(dst: Path, frames: int) -> None:
    """The first ``frames`` frames of the sample RGB-D folder, images renamed 0.png, 1.png, ..."""
    src = REPO / "sample_data" / "rgbd_room"
    (dst / "rgb").mkdir(parents=True)
    (dst / "depth").mkdir()
    for listing in ("rgb.txt", "depth.txt"):
        lines, n = [], 0
        for line in (src / listing).read_text().splitlines():
            if line.startswith("#"):
                lines.append(line)
            elif n < frames:
                stamp, name = line.split()
                new = f"{Path(name).parent}/{n}.png"
                shutil.copyfile(src / name, dst / new)
                lines.append(f"{stamp} {new}")
                n += 1
        (dst / listing).write_text("\n".join(lines) + "\n")
    _head_lines(src / "groundtruth.txt", dst / "groundtruth.txt", frames + 2)
    shutil.copyfile(src / "camera.yaml", dst / "camera.yaml")


def _g2o_slice(src: Path, dst: Path, vertices: int) -> None:
    """The first ``vertices`` poses of a 2-D graph and the edges between them."""
    out = []
    for line in src.read_text().splitlines(keepends=True):
        parts = line.split()
        if (parts[0].startswith("VERTEX") and int(parts[1]) < vertices) or (
            parts[0].startswith("EDGE") and max(int(parts[1]), int(parts[2])) < vertices
        ):
            out.append(line)
    dst.write_text("".join(out))


def build_corpus(root: Path) -> list[Target]:
    """Write every target's valid input under ``root/<target name>``; return the targets."""
    room = REPO / "sample_data" / "rgbd_room"
    made = {t.name: root / t.name for t in targets()}
    for folder in made.values():
        folder.mkdir(parents=True)
    frames = ("--max-frames", "4")
    _slamcli("convert", room, made["mcap-zstd"] / "log.mcap", *frames)
    _recompress(made["mcap-zstd"] / "log.mcap", made["mcap-lz4"] / "log.mcap", "lz4")
    _recompress(made["mcap-zstd"] / "log.mcap", made["mcap-raw"] / "log.mcap", "")
    _slamcli(
        "convert", room, made["mcap-foxglove-jpeg"] / "log.mcap", *frames,
        "--flavor", "foxglove", "--compress-images", "jpeg",
    )  # fmt: skip
    _slamcli(
        "convert", room, made["mcap-png-depth"] / "log.mcap", *frames, "--compress-images", "png"
    )
    shutil.copyfile(SHARED_DATA / "mcap" / "nav2_turtlebot.mcap", made["mcap-nav2"] / "log.mcap")

    landmarks = made["landmarks"]
    landmarks.rmdir()
    _slamcli("synth", "landmarks", landmarks, "--duration", "10")
    _slamcli("convert", landmarks, made["mcap-landmarks"] / "log.mcap", "--force")

    _tum_folder(made["tum"], 4)

    maps = SHARED_DATA / "maps"
    yaml = (maps / "turtlebot3_world.yaml").read_text()
    (made["map"] / "map.yaml").write_text(yaml.replace("turtlebot3_world.pgm", "map.pgm"))
    shutil.copyfile(maps / "turtlebot3_world.pgm", made["map"] / "map.pgm")

    trajectories = SHARED_DATA / "trajectories"
    _head_lines(trajectories / "freiburg1_xyz-groundtruth.txt", made["trajectory"] / "gt.txt", 400)
    _head_lines(trajectories / "freiburg1_xyz-rgbdslam.txt", made["trajectory"] / "est.txt", 100)
    _head_lines(trajectories / "V102_groundtruth.csv", made["trajectory-euroc"] / "gt.csv", 600)
    _head_lines(trajectories / "V102.txt", made["trajectory-euroc"] / "est.txt", 100)

    _g2o_slice(SHARED_DATA / "pose_graphs" / "intel.g2o", made["g2o"] / "graph.g2o", 150)

    ccny = SHARED_DATA / "lidar" / "rosbag1" / "ccny_scan_matcher_demo.bag"
    for name, compression in (("rosbag1", ""), ("rosbag1-bz2", "bz2"), ("rosbag1-lz4", "lz4")):
        _scan_bag(ccny, made[name] / "scans.bag", compression)
    _ros2_bag(made["mcap-raw"] / "log.mcap", made["rosbag2-sqlite3"] / "bag", "sqlite3")
    _ros2_bag(made["mcap-raw"] / "log.mcap", made["rosbag2-mcap"] / "bag", "mcap")

    carmen = SHARED_DATA / "lidar" / "carmen" / "intel-corrected.log.gz"
    with gzip.open(carmen, "rb") as fh:
        head = b"".join(fh.readline() for _ in range(CARMEN_LINES))
    (made["carmen"] / "laser.log").write_bytes(head)
    (made["carmen-gz"] / "laser.log.gz").write_bytes(gzip.compress(head, mtime=0))

    _kitti_folder(SHARED_DATA / "stereo" / "kitti_excerpt_1", made["kitti"], STEREO_PAIRS)
    _euroc_folder(SHARED_DATA / "stereo" / "euroc_V1_01_micro", made["euroc"], STEREO_PAIRS)
    return targets()


CARMEN_LINES = 400
"""Lines of the shared Intel log in the corpus's CARMEN logs (16 scans and their odometry)."""
STEREO_PAIRS = 3
"""Stereo pairs of the corpus's KITTI and EuRoC folders."""


def _scan_bag(src: Path, dst: Path, compression: str) -> None:
    """The first :data:`SCAN_BAG_MESSAGES` scans of a ROS 1 bag, written again by rosbags
    with chunks of :data:`SCAN_BAG_CHUNK_BYTES` (``compression``: "", "bz2" or "lz4")."""
    from rosbags.rosbag1 import Writer

    from slamcli.formats.rosbag.ros1_log import Ros1BagLog

    with Ros1BagLog(src) as log:
        messages = list(itertools.islice(log.messages(), SCAN_BAG_MESSAGES))
    writer = Writer(dst)
    writer.chunk_threshold = SCAN_BAG_CHUNK_BYTES
    if compression:
        writer.set_compression(getattr(Writer.CompressionFormat, compression.upper()))
    with writer:
        conns: dict[int, object] = {}
        for m in messages:
            ch = m.channel
            if ch.id not in conns:
                pkg, name = ch.schema_name.split("/")
                conns[ch.id] = writer.add_connection(
                    ch.topic,
                    f"{pkg}/msg/{name}",
                    msgdef=ch.schema_data.decode(),
                    md5sum=ch.metadata["md5sum"],
                )
            writer.write(conns[ch.id], m.log_time_ns, m.data)  # type: ignore[arg-type]


def _ros2_bag(mcap: Path, out: Path, storage: str) -> None:
    """A ROS 2 bag folder (``storage``: sqlite3 or mcap) holding an MCAP log's messages, its
    one storage file renamed ``bag_0`` so the targets name it."""
    from mcap.reader import make_reader
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(out, version=Writer.VERSION_LATEST, storage_plugin=plugin) as writer:
        conns: dict[str, object] = {}
        with mcap.open("rb") as fh:
            for schema, channel, message in make_reader(fh).iter_messages(log_time_order=True):
                if channel.topic not in conns:
                    assert schema is not None
                    conns[channel.topic] = writer.add_connection(
                        channel.topic, schema.name, typestore=store
                    )
                writer.write(conns[channel.topic], message.log_time, message.data)  # type: ignore[arg-type]
    (stored,) = [f for f in out.iterdir() if f.name != "metadata.yaml"]
    renamed = f"bag_0{stored.suffix}"
    stored.rename(out / renamed)
    meta = out / "metadata.yaml"
    meta.write_text(meta.read_text().replace(stored.name, renamed))


def _kitti_folder(src: Path, dst: Path, pairs: int) -> None:
    """The first ``pairs`` stereo pairs of a KITTI excerpt, its calibration, their poses and
    KITTI's 10 Hz times."""
    for folder in ("image_l", "image_r"):
        (dst / folder).mkdir(parents=True, exist_ok=True)
        for k in range(pairs):
            shutil.copyfile(src / folder / f"{k:06d}.png", dst / folder / f"{k:06d}.png")
    shutil.copyfile(src / "calib.txt", dst / "calib.txt")
    _head_lines(src / "poses.txt", dst / "poses.txt", pairs)
    (dst / "times.txt").write_text("".join(f"{0.1 * k:.6e}\n" for k in range(pairs)))


def _euroc_folder(src: Path, dst: Path, pairs: int) -> None:
    """The first ``pairs`` stereo pairs of a EuRoC excerpt (from :data:`EUROC_FIRST_STAMP`),
    its sensor files, and the IMU rows from 0.1 s before the first to 0.1 s after the last."""
    mav, out = src / "mav0", dst / "mav0"
    stamps: list[int] = []
    for cam in ("cam0", "cam1"):
        (out / cam / "data").mkdir(parents=True)
        shutil.copyfile(mav / cam / "sensor.yaml", out / cam / "sensor.yaml")
        rows = [r for r in (mav / cam / "data.csv").read_text().splitlines() if r[:1].isdigit()]
        kept = [r for r in rows if int(r.split(",")[0]) >= EUROC_FIRST_STAMP][:pairs]
        for row in kept:
            name = row.split(",")[1]
            shutil.copyfile(mav / cam / "data" / name, out / cam / "data" / name)
        (out / cam / "data.csv").write_text(
            "#timestamp [ns],filename\n" + "".join(r + "\n" for r in kept)
        )
        stamps += [int(r.split(",")[0]) for r in kept]
    (out / "imu0").mkdir()
    shutil.copyfile(mav / "imu0" / "sensor.yaml", out / "imu0" / "sensor.yaml")
    lo, hi = min(stamps) - 100_000_000, max(stamps) + 100_000_000
    lines = (mav / "imu0" / "data.csv").read_text().splitlines(keepends=True)
    (out / "imu0" / "data.csv").write_text(
        "".join(
            line for line in lines if line.startswith("#") or lo <= int(line.split(",")[0]) <= hi
        )
    )


# --- mutations -----------------------------------------------------------------------------------

Mutator = Callable[[bytes, random.Random], tuple[bytes, str]]

_HUGE_INTS = (2**31 - 1, 2**32 - 1, 2**40, 2**63 - 1, 2**64 - 1)


def _offset(data: bytes, rng: random.Random) -> int:
    return rng.randrange(len(data)) if data else 0


def untouched(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """The valid input itself: shows a command passes the checks and limits before damage."""
    return data, "no change"


def flip_bits(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    if not data:
        return data, "flip bits of an empty file"
    out = bytearray(data)
    n = rng.choice((1, 1, 2, 4, 16))
    for _ in range(n):
        at = _offset(data, rng)
        out[at] ^= 1 << rng.randrange(8)
    return bytes(out), f"flip {n} bit(s)"


def overwrite_run(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    at, n = _offset(data, rng), rng.randint(1, 64)
    fill = rng.choice(("zeros", "ones", "random"))
    run = {
        "zeros": b"\0" * n,
        "ones": b"\xff" * n,
        "random": bytes(rng.randrange(256) for _ in range(n)),
    }[fill]
    return data[:at] + run + data[at + n :], f"overwrite {n} bytes at {at} with {fill}"


def truncate(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    at = _offset(data, rng)
    return data[:at], f"truncate at {at} of {len(data)}"


def repeat_range(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    a = _offset(data, rng)
    b = min(len(data), a + rng.choice((1, 8, 64, 4096)))
    times = rng.choice((1, 2, 10))
    return data[:b] + data[a:b] * times + data[b:], f"repeat bytes {a}:{b} {times} more time(s)"


def delete_range(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    a = _offset(data, rng)
    b = min(len(data), a + rng.choice((1, 8, 64, 4096)))
    return data[:a] + data[b:], f"delete bytes {a}:{b}"


def inflate_int(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    if len(data) < 8:
        return truncate(data, rng)
    at = rng.randrange(len(data) - 8)
    value = rng.choice(_HUGE_INTS)
    packed = (
        struct.pack("<Q", value) if rng.random() < 0.5 else struct.pack("<I", value & 0xFFFFFFFF)
    )
    return data[:at] + packed + data[at + len(packed) :], f"write {value:#x} at {at}"


def _mcap_records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, length) of the data section's records, as far as they parse.

    The walk stops at Data End; the summary section behind it is damaged by the byte-level
    mutations (repeated ranges and inflated integers also shift and break its offsets).
    """
    records, at = [], 8
    while at + 9 <= len(data):
        opcode, length = struct.unpack_from("<BQ", data, at)
        records.append((at, opcode, length))
        if opcode == 0x0F:  # Data End
            break
        at += 9 + length
    return records


def mcap_inflate_length(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    records = _mcap_records(data)
    if not records:
        return inflate_int(data, rng)
    at, opcode, length = rng.choice(records)
    value = rng.choice((*_HUGE_INTS, length + 1, length + 4096, max(0, length - 1)))
    out = data[: at + 1] + struct.pack("<Q", value) + data[at + 9 :]
    return out, f"set length of record op {opcode:#x} at {at} from {length} to {value:#x}"


def mcap_inflate_chunk(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    chunks = [r for r in _mcap_records(data) if r[1] == 0x06]
    if not chunks:
        return mcap_inflate_length(data, rng)
    at, _, _ = rng.choice(chunks)
    # Chunk body: start time, end time, uncompressed size, CRC, compression name, records length.
    (name_len,) = struct.unpack_from("<I", data, at + 9 + 28)
    field_at, what = rng.choice(
        ((at + 9 + 16, "uncompressed_size"), (at + 9 + 32 + name_len, "records length"))
    )
    value = rng.choice(_HUGE_INTS)
    out = data[:field_at] + struct.pack("<Q", value) + data[field_at + 8 :]
    return out, f"set chunk at {at} {what} to {value:#x}"


def mcap_repeat_record(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    records = [r for r in _mcap_records(data) if r[0] + 9 + r[2] <= len(data)]
    if not records:
        return repeat_range(data, rng)
    at, opcode, length = rng.choice(records)
    end = at + 9 + length
    times = rng.choice((1, 3))
    out = data[:end] + data[at:end] * times + data[end:]
    return out, f"repeat record op {opcode:#x} at {at} {times} more time(s)"


def mcap_drop_record(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    records = [r for r in _mcap_records(data) if r[0] + 9 + r[2] <= len(data)]
    if not records:
        return delete_range(data, rng)
    at, opcode, length = rng.choice(records)
    return data[:at] + data[at + 9 + length :], f"drop record op {opcode:#x} at {at}"


def image_dims(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """Raw image messages carry width and height as u32 (CDR) or ASCII (JSON); make them huge."""
    size = rng.choice((40000, 65535, 2**31 - 1, 0))
    spots = [
        m.start() for v in (320, 240) for m in re.finditer(re.escape(struct.pack("<I", v)), data)
    ]
    if spots and rng.random() < 0.7:
        at = rng.choice(spots)
        return data[:at] + struct.pack("<I", size) + data[
            at + 4 :
        ], f"u32 image size at {at} -> {size}"
    return ascii_number(data, rng)


def ascii_number(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """Replace one run of ASCII digits (a JSON field, a PGM header size) with another number."""
    runs = [m.span() for m in re.finditer(rb"\d+", data[:200_000])]
    if not runs:
        return flip_bits(data, rng)
    a, b = rng.choice(runs)
    new = rng.choice((b"40000", b"0", b"-1", b"99999999999999999999", b"1e308", b"nan"))
    return data[:a] + new + data[b:], f"number {data[a:b][:20]!r} at {a} -> {new.decode()}"


def _png_chunks(data: bytes) -> list[tuple[int, bytes, int]]:
    """(offset, type, length) of a PNG's chunks."""
    chunks, at = [], 8
    while at + 8 <= len(data):
        length, kind = struct.unpack_from(">I4s", data, at)
        chunks.append((at, kind, length))
        at += 12 + length
    return chunks


def png_huge_header(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """IHDR width and height set huge (or zero), with a CRC that matches, so decoders trust it."""
    if data[12:16] != b"IHDR":
        return flip_bits(data, rng)
    width, height = rng.choice(
        ((40000, 40000), (2**31 - 1, 1), (1, 2**31 - 1), (0, 240), (65535, 65535))
    )
    body = b"IHDR" + struct.pack(">II", width, height) + data[24:29]
    out = data[:12] + body + struct.pack(">I", zlib.crc32(body)) + data[33:]
    return out, f"PNG IHDR {width}x{height} with a valid CRC"


def png_inflate_chunk(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    chunks = _png_chunks(data)
    if not chunks:
        return inflate_int(data, rng)
    at, kind, _ = rng.choice(chunks)
    value = rng.choice((2**31 - 1, 2**32 - 1, 1 << 24))
    out = data[:at] + struct.pack(">I", value) + data[at + 4 :]
    return out, f"PNG {kind.decode('latin-1')} chunk length -> {value:#x}"


_ODD_NUMBERS = (
    "nan", "inf", "-inf", "1e308", "-1e308", "1e999", "4e-320", "0", "-0",
    "99999999999999999999999", "-1", "", "abc", "0x10", "1,5",
)  # fmt: skip


def _lines(data: bytes) -> list[bytes]:
    return data.splitlines(keepends=True)


def text_delete_lines(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    lines = _lines(data)
    if not lines:
        return data, "delete a line of an empty file"
    a = rng.randrange(len(lines))
    n = rng.choice((1, 1, 5))
    return b"".join(lines[:a] + lines[a + n :]), f"delete lines {a + 1}-{a + n}"


def text_repeat_lines(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    lines = _lines(data)
    if not lines:
        return data, "repeat a line of an empty file"
    a = rng.randrange(len(lines))
    n, times = rng.choice((1, 3)), rng.choice((1, 2, 50))
    block = lines[a : a + n]
    if block and not block[-1].endswith(b"\n"):
        block[-1] += b"\n"
    return b"".join(lines[: a + n] + block * times + lines[a + n :]), (
        f"repeat lines {a + 1}-{a + n} {times} more time(s)"
    )


def text_swap_lines(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    lines = _lines(data)
    if len(lines) < 2:
        return text_delete_lines(data, rng)
    a, b = rng.sample(range(len(lines)), 2)
    lines[a], lines[b] = lines[b], lines[a]
    return b"".join(lines), f"swap lines {a + 1} and {b + 1}"


def _edit_fields(
    data: bytes, rng: random.Random, edit: Callable[[list[bytes]], tuple[list[bytes], str]]
) -> tuple[bytes, str]:
    lines = _lines(data)
    if not lines:
        return data, "edit a field of an empty file"
    a = rng.randrange(len(lines))
    end = b"\n" if lines[a].endswith(b"\n") else b""
    sep = b"," if b"," in lines[a] else b" "
    fields = lines[a].rstrip(b"\r\n").split(sep)
    fields, what = edit(fields)
    lines[a] = sep.join(fields) + end
    return b"".join(lines), f"line {a + 1}: {what}"


def text_odd_number(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    def edit(fields: list[bytes]) -> tuple[list[bytes], str]:
        i = rng.randrange(len(fields))
        new = rng.choice(_ODD_NUMBERS)
        old, fields[i] = fields[i], new.encode()
        return fields, f"field {i + 1} {old[:20]!r} -> {new!r}"

    return _edit_fields(data, rng, edit)


def text_swap_fields(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    def edit(fields: list[bytes]) -> tuple[list[bytes], str]:
        if len(fields) < 2:
            return fields, "no fields to swap"
        i, j = rng.sample(range(len(fields)), 2)
        fields[i], fields[j] = fields[j], fields[i]
        return fields, f"swap fields {i + 1} and {j + 1}"

    return _edit_fields(data, rng, edit)


def text_field_count(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    def edit(fields: list[bytes]) -> tuple[list[bytes], str]:
        if rng.random() < 0.5 and fields:
            i = rng.randrange(len(fields))
            return fields[:i] + fields[i + 1 :], f"drop field {i + 1}"
        return [*fields, b"1"], "add a field"

    return _edit_fields(data, rng, edit)


def text_empty(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    return rng.choice(
        ((b"", "empty file"), (b"\n", "one blank line"), (b"# only\n", "comment only"))
    )


def text_garbage_line(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    lines = _lines(data)
    a = rng.randrange(len(lines) + 1)
    junk = rng.choice(
        (b"\xff\xfe\x00garbage\n", b"\t\t\n", b"x" * 100_000 + b"\n", b": : :\n", b"[{\n", b"1 2\n")
    )
    return b"".join([*lines[:a], junk, *lines[a:]]), f"insert {junk[:12]!r} as line {a + 1}"


LONG_LINE_BYTES = ((1 << 20) + 1, 8 << 20)
"""Lengths of the lines :func:`text_long_line` writes: just over the readers' 1 MiB limit
(slamcli.formats.text.MAX_LINE_BYTES), and well over it."""


def text_long_line(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """A line longer than any reader takes, of digits (one huge number) or of fields."""
    lines = _lines(data)
    a = rng.randrange(len(lines) + 1)
    n = rng.choice(LONG_LINE_BYTES)
    unit = rng.choice((b"1", b"1 "))
    line = (unit * (n // len(unit) + 1))[:n] + b"\n"
    replace = rng.random() < 0.5 and a < len(lines)
    rest = lines[a + 1 :] if replace else lines[a:]
    what = "replace" if replace else "insert before"
    return b"".join([*lines[:a], line, *rest]), f"{what} line {a + 1}: {n} bytes of {unit!r}"


def yaml_alias_bomb(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """Nested YAML aliases (a "billion laughs") that expand to 9**(levels+1) values, and one
    value of the document made an alias of the largest."""
    levels = rng.choice((6, 9, 12))
    bomb = [b"laughs:\n", b"  l0: &l0 [" + b", ".join([b'"lol"'] * 9) + b"]\n"]
    for k in range(1, levels + 1):
        refs = b", ".join([f"*l{k - 1}".encode()] * 9)
        bomb.append(f"  l{k}: &l{k} [".encode() + refs + b"]\n")
    lines = _lines(data)
    values = [i for i, line in enumerate(lines) if re.match(rb"\s*[\w-]+:\s*\S", line)]
    what = "no value replaced"
    if values:
        i = rng.choice(values)
        key = lines[i].split(b":", 1)[0]
        lines[i] = key + f": *l{levels}\n".encode()
        what = f"line {i + 1} ({key.strip()[:30]!r}) made *l{levels}"
    at = 1 if lines and lines[0].startswith(b"%") else 0
    out = b"".join([*lines[:at], *bomb, *lines[at:]])
    return out, f"alias bomb of 9**{levels + 1} values; {what}"


# ROS 1 bags: records of a uint32 header length, name=value fields, a uint32 data length and data.
_ROS1_START = len(b"#ROSBAG V2.0\n")
_ROS1_CHUNK = 0x05
ROS1_MAX_CHUNK = 256 << 20
"""The readers' default chunk limit (slamcli.formats.mcap.reader.DEFAULT_MAX_CHUNK_BYTES)."""
ROS1_BOMB_BYTES = 16 << 20
"""Zeros in a bomb small enough to be declared honestly (under the chunk limit). A command
decompresses it (64 MiB cost 230 MB in a fresh process), which a warm in-process worker would
add to the 450 MB it holds; the lying and over-limit bombs are 1 GiB."""


def _ros1_records(data: bytes) -> list[tuple[int, int, int, dict[bytes, bytes]]]:
    """(offset, header length, data length, header fields) of a bag's top-level records, as far
    as they parse."""
    records, at = [], _ROS1_START
    while at + 4 <= len(data):
        (header_len,) = struct.unpack_from("<I", data, at)
        end = at + 4 + header_len
        if end + 4 > len(data):
            break
        (data_len,) = struct.unpack_from("<I", data, end)
        records.append((at, header_len, data_len, _ros1_fields(data[at + 4 : end])))
        at = end + 4 + data_len
    return records


def _ros1_fields(header: bytes) -> dict[bytes, bytes]:
    fields, at = {}, 0
    while at + 4 <= len(header):
        (n,) = struct.unpack_from("<I", header, at)
        name, _, value = header[at + 4 : at + 4 + n].partition(b"=")
        fields[name] = value
        at += 4 + n
    return fields


def _ros1_record(fields: dict[bytes, bytes], body: bytes) -> bytes:
    header = b"".join(
        struct.pack("<I", len(k) + 1 + len(v)) + k + b"=" + v for k, v in fields.items()
    )
    return struct.pack("<I", len(header)) + header + struct.pack("<I", len(body)) + body


def ros1_inflate_length(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """A record's header or data length set huge, or a little off."""
    records = _ros1_records(data)
    if not records:
        return inflate_int(data, rng)
    at, header_len, data_len, fields = rng.choice(records)
    which, spot, length = rng.choice(
        (("header", at, header_len), ("data", at + 4 + header_len, data_len))
    )
    value = rng.choice(
        (2**31 - 1, 2**32 - 1, 1 << 30, length + 1, length + 4096, max(0, length - 1))
    )
    op = fields.get(b"op", b"?")[:1].hex()
    out = data[:spot] + struct.pack("<I", value) + data[spot + 4 :]
    return out, f"set the {which} length of record op {op} at {at} from {length} to {value:#x}"


def ros1_chunk_size(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """A chunk's declared uncompressed ``size`` set huge, over the limit, or a little off."""
    chunks = [r for r in _ros1_records(data) if r[3].get(b"op") == bytes([_ROS1_CHUNK])]
    if not chunks:
        return ros1_inflate_length(data, rng)
    at, header_len, data_len, fields = rng.choice(chunks)
    old = struct.unpack("<I", fields[b"size"])[0] if len(fields.get(b"size", b"")) == 4 else 0
    value = rng.choice((2**32 - 1, 2**31, ROS1_MAX_CHUNK + 1, 2 * old, max(0, old - 1), 0))
    fields = {**fields, b"size": struct.pack("<I", value)}
    body = data[at + 8 + header_len : at + 8 + header_len + data_len]
    out = data[:at] + _ros1_record(fields, body) + data[at + 8 + header_len + data_len :]
    return out, f"set the chunk at {at} size from {old} to {value:#x}"


@functools.cache
def _zeros_compressed(kind: str, n: int) -> bytes:
    """``n`` zero bytes compressed (bz2 or an lz4 frame), made in 16 MiB steps."""
    import lz4.frame

    step = b"\0" * min(n, 16 << 20)
    if kind == "bz2":
        comp = bz2.BZ2Compressor(9)
        out = b"".join(comp.compress(step) for _ in range(n // len(step)))
        return out + comp.flush()
    lz4c = lz4.frame.LZ4FrameCompressor()
    out = lz4c.begin() + b"".join(lz4c.compress(step) for _ in range(n // len(step)))
    return out + lz4c.flush()


def _ros1_bomb(data: bytes, rng: random.Random, kind: str) -> tuple[bytes, str]:
    """A chunk's data replaced by a ``kind`` (bz2 or lz4) stream of many zeros whose ``size``
    field tells the truth, lies small (the original size), or goes past the limit. A stream
    that fits in the old data of a chunk of that compression is padded to its length, so the
    bag's index still points at the chunks."""
    chunks = [r for r in _ros1_records(data) if r[3].get(b"op") == bytes([_ROS1_CHUNK])]
    if not chunks:
        return ros1_inflate_length(data, rng)
    at, header_len, data_len, fields = rng.choice(chunks)
    n = ROS1_BOMB_BYTES if kind == "bz2" else rng.choice((ROS1_BOMB_BYTES, 1 << 30))
    stream = _zeros_compressed(kind, n)
    old = struct.unpack("<I", fields[b"size"])[0] if len(fields.get(b"size", b"")) == 4 else 0
    declared = rng.choice((n, old, ROS1_MAX_CHUNK + 1))
    same = fields.get(b"compression") == kind.encode() and len(stream) <= data_len
    body = stream + b"\0" * (data_len - len(stream)) if same else stream
    fields = {**fields, b"compression": kind.encode(), b"size": struct.pack("<I", declared)}
    out = data[:at] + _ros1_record(fields, body) + data[at + 8 + header_len + data_len :]
    return out, (
        f"chunk at {at}: {n} zero bytes as {kind} ({len(stream)} bytes"
        f"{', padded' if same else ''}), size field {declared}"
    )


def ros1_bz2_bomb(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """A bz2 decompression bomb in a chunk (see :func:`_ros1_bomb`)."""
    return _ros1_bomb(data, rng, "bz2")


def ros1_lz4_bomb(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """An lz4 decompression bomb in a chunk (see :func:`_ros1_bomb`)."""
    return _ros1_bomb(data, rng, "lz4")


BINARY = (flip_bits, overwrite_run, truncate, repeat_range, delete_range, inflate_int)
MCAP = (
    *BINARY,
    mcap_inflate_length,
    mcap_inflate_chunk,
    mcap_repeat_record,
    mcap_drop_record,
    image_dims,
    mcap_inflate_length,
    mcap_inflate_chunk,
    mcap_repeat_record,
)
PNG = (*BINARY, png_huge_header, png_huge_header, png_inflate_chunk)
PGM = (*BINARY, ascii_number, ascii_number)
ROS1 = (
    *BINARY,
    ros1_inflate_length,
    ros1_inflate_length,
    ros1_chunk_size,
    ros1_bz2_bomb,
    ros1_lz4_bomb,
)
TEXT = (
    text_delete_lines,
    text_repeat_lines,
    text_swap_lines,
    text_odd_number,
    text_odd_number,
    text_odd_number,
    text_swap_fields,
    text_field_count,
    text_empty,
    text_garbage_line,
    flip_bits,
    truncate,
    overwrite_run,
    text_long_line,
)
YAML = (*TEXT, yaml_alias_bomb, yaml_alias_bomb)


def mutators_for(path: str) -> tuple[Mutator, ...]:
    suffix = Path(path).suffix
    return {
        ".mcap": MCAP,
        ".png": PNG,
        ".pgm": PGM,
        ".bag": ROS1,
        ".db3": BINARY,
        ".gz": BINARY,
        ".yaml": YAML,
    }.get(suffix, TEXT)


# --- cases ---------------------------------------------------------------------------------------


def make_case(seed: int, index: int, all_targets: list[Target], subprocess_every: int) -> Case:
    """Case ``index`` of a run seeded with ``seed``: the same numbers always give the same case."""
    rng = random.Random(f"{seed}:{index}")
    target = rng.choices(all_targets, weights=[t.weight for t in all_targets])[0]
    file = rng.choice(target.files)
    mutator = rng.choice(mutators_for(file))
    command = rng.choice(target.commands)
    return Case(
        case_id=f"s{seed}-{index:06d}",
        target=target.name,
        file=file,
        mutation=mutator.__name__,
        argv=list(command),
        subprocess=subprocess_every > 0 and index % subprocess_every == 0,
    )


def _by_name() -> dict[str, Mutator]:
    return {m.__name__: m for m in (untouched, *MCAP, *PNG, *PGM, *ROS1, *YAML)}


def materialize(case: Case, corpus: Path, case_dir: Path, seed: int) -> tuple[list[str], str]:
    """Copy the target into ``case_dir/in``, damage one file; return the argv and the damage."""
    src = corpus / case.target
    dst = case_dir / "in"
    shutil.copytree(src, dst, copy_function=os.link)
    victim = dst / case.file
    data = victim.read_bytes()
    rng = random.Random(f"{seed}:{case.case_id}:mutate")
    mutated, what = _by_name()[case.mutation](data, rng)
    victim.unlink()
    victim.write_bytes(mutated)
    subs = {"{in}": str(dst), "{case}": str(case_dir), "{out}": str(case_dir / "out")}
    argv = []
    for arg in case.argv:
        for key, value in subs.items():
            arg = arg.replace(key, value)
        argv.append(arg)
    return argv, what


def check_outputs(case_dir: Path) -> list[str]:
    """Problems with what a command left in its case folder (run folders and files it writes)."""
    problems = []
    for entry in sorted(case_dir.iterdir()):
        if entry.name.startswith("."):
            problems.append(f"left a hidden staging or temporary entry {entry.name}")
    out = case_dir / "out"
    if out.is_dir():
        run_json, plan_json = out / "run.json", out / "plan.json"
        if run_json.is_file():
            try:
                outputs = json.loads(run_json.read_text())["outputs"]
            except (ValueError, KeyError) as exc:
                return [*problems, f"run.json unreadable: {exc!r}"]
            missing = [name for name in outputs if not (out / name).exists()]
            if missing:
                problems.append(f"run folder misses outputs {missing}")
        elif not plan_json.is_file():
            problems.append(f"half-written --out folder: {sorted(p.name for p in out.iterdir())}")
        problems += [
            f"left a hidden entry {p.name} in --out"
            for p in out.iterdir()
            if p.name.startswith(".")
        ]
    return problems


def check_result(exit_code: int | None, text: str, seconds: float, peak_mb: float) -> list[str]:
    problems = []
    if exit_code not in OK_EXIT_CODES:
        problems.append(f"exit code {exit_code} (expected 0, 1 or 3)")
    if "Traceback (most recent call last)" in text:
        problems.append("printed a traceback")
    errors = [line for line in text.splitlines() if line.lstrip().startswith("error:")]
    if len(errors) > 1:
        problems.append(f"{len(errors)} error lines")
    if seconds > WALL_LIMIT_S:
        problems.append(f"took {seconds:.1f} s (limit {WALL_LIMIT_S:.0f} s)")
    if peak_mb > RSS_LIMIT_MB:
        problems.append(f"peak RSS {peak_mb:.0f} MB (limit {RSS_LIMIT_MB:.0f} MB)")
    return problems


_LAUNCHER = """
import resource, runpy, sys
resource.setrlimit(resource.RLIMIT_AS, (int(sys.argv[1]), int(sys.argv[1])))
resource.setrlimit(resource.RLIMIT_CPU, (int(sys.argv[2]), int(sys.argv[2]) + 5))
sys.argv = ["slamcli", *sys.argv[3:]]
runpy.run_module("slamcli", run_name="__main__", alter_sys=True)
"""


def run_subprocess(argv: list[str], case_dir: Path) -> tuple[int | None, str, float, float]:
    """Run ``python -m slamcli ARGV`` under the memory and CPU limits; (code, output, s, peak MB).

    The limits are set by a launcher inside the child rather than a preexec_fn, which is unsafe
    when the caller has threads. The child is reaped with wait4 for its own peak RSS.
    """
    log = case_dir / "output.txt"
    start = time.monotonic()
    with log.open("wb") as sink:
        proc = subprocess.Popen(
            [sys.executable, "-c", _LAUNCHER, str(AS_LIMIT_BYTES), str(CPU_LIMIT_S), *argv],
            stdout=sink,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            cwd=case_dir,
            env={**os.environ, "COLUMNS": "100", "NO_COLOR": "1"},
        )
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.monotonic() - start > 3 * WALL_LIMIT_S:
                proc.kill()
                pid, status, usage = os.wait4(proc.pid, 0)
                break
            time.sleep(0.01)
    proc.returncode = os.waitstatus_to_exitcode(status)
    seconds = time.monotonic() - start
    text = log.read_text(errors="replace")
    log.unlink()
    return proc.returncode, text, seconds, usage.ru_maxrss / 1024


def _reset_peak_rss() -> None:
    """Reset this process's peak RSS (VmHWM) to its current RSS, so each case measures its own."""
    Path("/proc/self/clear_refs").write_text("5")


def _status_mb(key: str) -> float:
    """A memory figure of this process from /proc/self/status (``VmHWM``: peak resident,
    ``VmRSS``: resident now), MB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(f"{key}:"):
            return int(line.split()[1]) / 1024
    return 0.0


def _peak_mb() -> float:
    return _status_mb("VmHWM")


class _CaseTimeout(Exception):
    pass


def _on_alarm(signum: int, frame: object) -> None:
    raise _CaseTimeout


def run_in_process(argv: list[str], case_dir: Path) -> tuple[int | None, str, float, float]:
    """Run the CLI in this process; an exception escaping it counts as a traceback."""
    from typer.testing import CliRunner

    from slamcli.cli.app import app

    _reset_peak_rss()
    start = time.monotonic()
    signal.alarm(int(WALL_LIMIT_S * 2))
    cwd = Path.cwd()
    try:
        os.chdir(case_dir)
        result = CliRunner().invoke(app, argv, env={"COLUMNS": "100", "NO_COLOR": "1"})
    except _CaseTimeout:
        return None, "timed out (alarm)", time.monotonic() - start, _peak_mb()
    finally:
        signal.alarm(0)
        os.chdir(cwd)
    seconds = time.monotonic() - start
    text = result.output
    code: int | None = result.exit_code
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        text += "\n" + "".join(traceback.format_exception(result.exception))
        code = None if isinstance(result.exception, _CaseTimeout) else code
    return code, text, seconds, _peak_mb()


def run_case(case: Case, corpus: Path, scratch: Path, seed: int, keep: Path | None) -> Outcome:
    """Materialise, run and check one case; keep its folder under ``keep`` if it found a problem."""
    case_dir = scratch / case.case_id
    case_dir.mkdir()
    argv, what = materialize(case, corpus, case_dir, seed)
    case.mutation = f"{case.mutation}: {what}"
    runner = run_subprocess if case.subprocess else run_in_process
    code, text, seconds, peak = runner(argv, case_dir)
    problems = check_result(code, text, seconds, peak) + check_outputs(case_dir)
    outcome = Outcome(case, code, seconds, peak, problems, text[-3000:] if problems else "")
    case.argv = argv
    if problems and keep is not None:
        dest = keep / case.case_id
        case.argv = [arg.replace(str(case_dir), str(dest)) for arg in argv]
        shutil.rmtree(dest, ignore_errors=True)
        shutil.copytree(case_dir, dest, symlinks=True)
        (dest / "case.json").write_text(json.dumps(asdict(outcome), indent=2) + "\n")
    shutil.rmtree(case_dir, ignore_errors=True)
    return outcome


# --- workers -------------------------------------------------------------------------------------


def _worker(
    conn: multiprocessing.connection.Connection, corpus: str, scratch: str, seed: int, keep: str
) -> None:
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (AS_LIMIT_BYTES, AS_LIMIT_BYTES))
    # Native decoders (libpng, zstd) complain on fd 2; what counts is what the CLI prints.
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 2)
    signal.signal(signal.SIGALRM, _on_alarm)
    while True:
        case = conn.recv()
        if case is None:
            return
        outcome = run_case(case, Path(corpus), Path(scratch), seed, Path(keep) if keep else None)
        retire = _status_mb("VmRSS") > RETIRE_RSS_MB
        conn.send((outcome, retire))
        if retire:
            return


@dataclass
class _Slot:
    proc: multiprocessing.process.BaseProcess
    conn: multiprocessing.connection.Connection
    case: Case | None = None
    started: float = 0.0


def run_cases(
    cases: list[Case],
    corpus: Path,
    seed: int,
    workers: int = 2,
    keep: Path | None = None,
    progress: Callable[[Outcome], None] | None = None,
) -> list[Outcome]:
    """Run ``cases`` on ``workers`` worker processes; a hung or crashed worker is replaced."""
    ctx = multiprocessing.get_context("spawn")
    scratch = Path(tempfile.mkdtemp(prefix="slamcli-fuzz-"))
    pending = list(reversed(cases))
    outcomes: list[Outcome] = []

    def start() -> _Slot:
        parent, child = ctx.Pipe()
        proc = ctx.Process(
            target=_worker,
            args=(child, str(corpus), str(scratch), seed, str(keep or "")),
            daemon=True,
        )
        proc.start()
        return _Slot(proc, parent)

    slots = [start() for _ in range(min(workers, len(cases)))]
    try:
        while pending or any(s.case for s in slots):
            for i, slot in enumerate(slots):
                if slot.case is None and pending:
                    slot.case, slot.started = pending.pop(), time.monotonic()
                    slot.conn.send(slot.case)
                if slot.case is None:
                    continue
                died = not slot.proc.is_alive()
                hung = time.monotonic() - slot.started > 4 * WALL_LIMIT_S
                if slot.conn.poll():
                    try:
                        outcome, retired = slot.conn.recv()
                    except (EOFError, OSError):
                        died = True
                    else:
                        outcomes.append(outcome)
                        slot.case = None
                        if progress:
                            progress(outcome)
                        if retired:
                            slot.proc.join(timeout=10)
                            slots[i] = start()
                        continue
                if died or hung:
                    slot.proc.kill()
                    slot.proc.join()
                    why = "hung (killed)" if hung else f"worker died (exit {slot.proc.exitcode})"
                    outcome = Outcome(slot.case, None, time.monotonic() - slot.started, 0.0, [why])
                    outcomes.append(outcome)
                    if progress:
                        progress(outcome)
                    if keep is not None:
                        dest = keep / slot.case.case_id
                        dest.mkdir(parents=True, exist_ok=True)
                        (dest / "case.json").write_text(
                            json.dumps(asdict(outcome), indent=2) + "\n"
                        )
                    shutil.rmtree(scratch / slot.case.case_id, ignore_errors=True)
                    slots[i] = start()
            time.sleep(0.005)
    finally:
        for slot in slots:
            if slot.proc.is_alive():
                slot.conn.send(None)
                slot.proc.join(timeout=10)
                if slot.proc.is_alive():
                    slot.proc.kill()
        shutil.rmtree(scratch, ignore_errors=True)
    return outcomes


def summarize(outcomes: list[Outcome], seconds: float) -> str:
    per_target = Counter(o.case.target for o in outcomes)
    bad = [o for o in outcomes if o.problems]
    bad_per_target = Counter(o.case.target for o in bad)
    codes = Counter(o.exit_code for o in outcomes)
    lines = [
        f"{len(outcomes)} cases in {seconds:.0f} s "
        f"({sum(o.case.subprocess for o in outcomes)} as subprocesses), {len(bad)} found a problem",
        "exit codes: " + ", ".join(f"{k}: {v}" for k, v in sorted(codes.items(), key=str)),
    ]
    for name, n in sorted(per_target.items()):
        lines.append(f"  {name:20s} {n:6d} cases {bad_per_target[name]:5d} problems")
    for o in bad:
        lines.append(f"- {o.case.case_id} [{o.case.target}/{o.case.file}] {o.case.mutation}")
        lines.append(f"    slamcli {' '.join(o.case.argv)}")
        lines.append(f"    {'; '.join(o.problems)}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", type=int, default=int(os.environ.get("FUZZ_CASES", 10_000)))
    parser.add_argument("--seed", type=int, default=int(os.environ.get("FUZZ_SEED", 0)))
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--subprocess-every", type=int, default=25)
    parser.add_argument("--keep", type=Path, default=REPO / "runs" / "fuzz")
    args = parser.parse_args(argv)

    start = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="slamcli-fuzz-corpus-") as tmp:
        corpus = Path(tmp)
        all_targets = build_corpus(corpus)
        cases = [
            make_case(args.seed, i, all_targets, args.subprocess_every) for i in range(args.cases)
        ]
        args.keep.mkdir(parents=True, exist_ok=True)
        done = Counter[str]()

        def progress(outcome: Outcome) -> None:
            done["cases"] += 1
            done["problems"] += bool(outcome.problems)
            if outcome.problems:
                print(f"problem: {outcome.case.case_id} {outcome.problems}", flush=True)
            if done["cases"] % 250 == 0:
                rate = done["cases"] / (time.monotonic() - start)
                print(
                    f"{done['cases']} cases, {done['problems']} problems, {rate:.1f}/s", flush=True
                )

        outcomes = run_cases(cases, corpus, args.seed, args.workers, args.keep, progress)
    report = summarize(outcomes, time.monotonic() - start)
    print(report)
    if any(o.problems for o in outcomes):
        print(f"problem cases saved under {args.keep}/<case id>/ (input, output, case.json)")
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
