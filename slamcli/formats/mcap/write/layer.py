"""The MCAP layer the writers share, and the names they write.

Zstd chunks, one schema per type, one channel per topic, ``log_time`` = ``publish_time`` = the
data's own stamp, and messages in log-time order so chunks never overlap in time; the log is
written to a temporary file that replaces the output only once it is complete.
"""

from __future__ import annotations

import contextlib
import heapq
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from slamcli.atomic import atomic_path
from slamcli.errors import ConfigError, ExportError

FLAVORS = ("ros2", "foxglove")

WORLD_FRAME = "world"
CAMERA_FRAME = "camera_color_optical_frame"
IMU_FRAME = "camera_accel_frame"
"""The Kinect's accelerometer frame: TUM records its readings as the sensor gave them."""
RESULT_CAMERA_FRAME = "camera"

TOPIC_COLOR = "/camera/color/image_raw"
TOPIC_COLOR_COMPRESSED = "/camera/color/image_raw/compressed"
TOPIC_DEPTH = "/camera/depth/image_raw"
TOPIC_DEPTH_COMPRESSED = "/camera/depth/image_raw/compressedDepth"
TOPIC_CAMERA_INFO = "/camera/color/camera_info"
TOPIC_GROUNDTRUTH = "/groundtruth"
TOPIC_TF = "/tf"
TOPIC_IMU = "/imu"

TOPIC_ODOM = "/odom"
TOPIC_LANDMARKS = "/landmarks"
TOPIC_GROUND_TRUTH = "/ground_truth"
TOPIC_SCAN = "/scan"
TOPIC_TF_STATIC = "/tf_static"
ODOM_FRAME = "odom"
BODY_FRAME = "base_link"
LASER_FRAME = "laser"

TOPIC_RESULT_POSE = "/slamcli/pose"
TOPIC_RESULT_MAP = "/slamcli/map"
TOPIC_RESULT_POINTS = "/slamcli/points"
TOPIC_RESULT_MESH = "/slamcli/mesh"


@dataclass
class McapWriteSummary:
    """What a writer put into a log.

    Attributes:
        path: the MCAP file written.
        topics: topic -> (schema name, message count), in the order channels were created.
        frames: RGB-D frames written (0 for result logs).
        skipped: frames the source skipped because an image was missing or unreadable.
    """

    path: Path
    topics: dict[str, tuple[str, int]] = field(default_factory=dict)
    frames: int = 0
    skipped: int = 0


def check_choice(name: str, value: str, allowed: tuple[str, ...]) -> str:
    """Return ``value`` if it is one of ``allowed``; else a :class:`ConfigError` naming them."""
    if value not in allowed:
        raise ConfigError(f"{name} must be one of {', '.join(allowed)}, got {value!r}")
    return value


class LogWriter:
    """Schemas and channels registered on first use; messages written in log-time order.

    Messages wait in a small heap until :meth:`release` is told that nothing older will come,
    so the chunks' time ranges do not overlap even where a source delivers a depth image
    stamped a few milliseconds before the colour image it was paired with.
    """

    def __init__(self, stream: IO[bytes], profile: str) -> None:
        from mcap.writer import CompressionType, Writer

        from slamcli import __version__

        self._writer = Writer(stream, compression=CompressionType.ZSTD)
        self._writer.start(profile=profile, library=f"slamcli {__version__}")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._schema_of: dict[str, str] = {}
        self._pending: list[tuple[int, int, int, int, bytes]] = []
        self._order = 0
        self.counts: dict[str, int] = {}
        # Channel metadata by topic, given before the topic's first message.
        self.channel_metadata: dict[str, dict[str, str]] = {}

    def add(
        self,
        topic: str,
        schema: tuple[str, str, bytes],
        message_encoding: str,
        stamp_ns: int,
        data: bytes,
    ) -> None:
        """Queue one message; ``schema`` is (name, encoding, definition bytes)."""
        if stamp_ns < 0:
            raise ExportError(
                f"{topic}: timestamp {stamp_ns} ns is before 1970; MCAP log times are unsigned",
                hint="shift the input's timestamps to positive values",
            )
        channel = self._channels.get(topic)
        if channel is None:
            name, encoding, definition = schema
            schema_id = self._schemas.get(name)
            if schema_id is None:
                schema_id = self._writer.register_schema(name, encoding, definition)
                self._schemas[name] = schema_id
            channel = self._writer.register_channel(
                topic, message_encoding, schema_id, self.channel_metadata.get(topic, {})
            )
            self._channels[topic] = channel
            self._schema_of[topic] = name
            self.counts[topic] = 0
        heapq.heappush(self._pending, (stamp_ns, self._order, channel, self.counts[topic], data))
        self._order += 1
        self.counts[topic] += 1

    def release(self, before_ns: int | None = None) -> None:
        """Write the queued messages stamped before ``before_ns`` (None: all of them)."""
        pending = self._pending
        while pending and (before_ns is None or pending[0][0] < before_ns):
            stamp, _, channel, sequence, data = heapq.heappop(pending)
            self._writer.add_message(
                channel, log_time=stamp, data=data, publish_time=stamp, sequence=sequence
            )

    def finish(self) -> None:
        self.release()
        self._writer.finish()

    def topics(self) -> dict[str, tuple[str, int]]:
        return {t: (self._schema_of[t], n) for t, n in self.counts.items()}


def check_out(out: Path, force: bool) -> None:
    """Refuse ``out`` when it is a folder, or exists without ``force``."""
    if out.is_dir():
        raise ExportError(
            f"{out}: is a folder", hint="give the path of the .mcap file to write, e.g. out.mcap"
        )
    if out.exists() and not force:
        raise ExportError(
            f"{out}: already exists", hint="pass --force to overwrite it, or choose another output"
        )


@contextlib.contextmanager
def open_log(out: Path, profile: str, force: bool) -> Iterator[LogWriter]:
    """A log written to a temporary file that replaces ``out`` only once it is complete."""
    check_out(out, force)
    with atomic_path(out) as tmp, tmp.open("wb") as stream:
        mcap_log = LogWriter(stream, profile)
        yield mcap_log
        mcap_log.finish()
