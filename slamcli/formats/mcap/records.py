"""Records passed between the MCAP reader, the message decoders and the adapters.

The reader yields :class:`RawMessage`; a decoder turns its bytes into a message object; an
adapter turns that object into one of the typed records below (or a core frame such as
:class:`~slamcli.types.ImuFrame`). Times are int64 nanoseconds; poses are (4, 4) float64
``parent_from_child`` transforms.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.types import PinholeCamera, ScanFrame


@dataclass(frozen=True)
class ChannelInfo:
    """One channel of a log with its schema."""

    id: int
    topic: str
    message_encoding: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes = b""
    metadata: dict[str, str] = field(default_factory=dict)

    @classmethod
    def from_records(cls, channel: Any, schema: Any | None) -> ChannelInfo:
        """From the ``mcap`` package's Channel and Schema records (schema None: schemaless)."""
        return cls(
            id=channel.id,
            topic=channel.topic,
            message_encoding=channel.message_encoding,
            schema_name=schema.name if schema is not None else "",
            schema_encoding=schema.encoding if schema is not None else "",
            schema_data=schema.data if schema is not None else b"",
            metadata=dict(channel.metadata),
        )


@dataclass(frozen=True)
class RawMessage:
    """One undecoded message. ``data`` is the serialised payload."""

    channel: ChannelInfo
    log_time_ns: int
    publish_time_ns: int
    sequence: int
    data: bytes


@dataclass
class ChannelStats:
    """Message count and time span of one channel (from the summary, or counted by a scan)."""

    count: int = 0
    first_ns: int | None = None
    last_ns: int | None = None


@dataclass
class LogHealth:
    """What reading a log found wrong with it; complete once a full pass has been made."""

    summary_present: bool = True
    truncated: bool = False
    truncated_at_byte: int | None = None
    last_good_time_ns: int | None = None
    crc_checked: bool = False
    bad_chunks: list[tuple[int, int, int]] = field(default_factory=list)
    """(start_ns, end_ns, byte offset) of each chunk skipped because its CRC or data was bad."""
    oversized: dict[int, tuple[str, str]] = field(default_factory=dict)
    """(``"chunk"`` or ``"message"``, why) for each byte offset in ``bad_chunks`` that was
    skipped for being larger than the reader's limit."""
    chunk_overlap: bool = False
    reordered: int = 0
    dropped_late: int = 0

    @property
    def data_lost(self) -> bool:
        return self.truncated or bool(self.bad_chunks) or self.dropped_late > 0

    def loss_problems(self) -> list[str]:
        """The problems that lost data (truncation, bad chunks, late messages)."""
        out = []
        if self.truncated:
            at = self.truncated_at_byte
            where = f" at byte {at}" if at is not None else ""
            read = (
                "no message could be read"
                if self.last_good_time_ns is None
                else f"messages up to {_sec(self.last_good_time_ns)} were read"
            )
            out.append(
                f"truncated: the log ends without a footer{where}; {read} (try 'mcap recover')"
            )
        for start, end, offset in self.bad_chunks:
            lost = f"messages {_sec(start)}-{_sec(end)} lost"
            too_big = self.oversized.get(offset)
            if too_big is None:
                out.append(f"bad chunk at byte {offset} skipped: {lost}")
            else:
                what, why = too_big
                out.append(
                    f"{what} at byte {offset} skipped: it {why}; {lost} "
                    "(raise --max-chunk-mb to read it)"
                )
        if self.dropped_late:
            out.append(f"{self.dropped_late} message(s) came too late to reorder and were dropped")
        return out

    def problems(self) -> list[str]:
        """Human-readable one-line descriptions, for ``info`` and run reports."""
        out = self.loss_problems()
        if not self.summary_present and not self.truncated:
            out.append("no summary section: statistics were counted by a full scan")
        if self.chunk_overlap:
            out.append("chunks overlap in time: messages were merged into log-time order")
        return out


def _sec(ns: int | None) -> str:
    return "?" if ns is None else f"{ns * 1e-9:.3f} s"


@dataclass(frozen=True)
class ImageRecord:
    """A decoded image.

    ``kind`` is ``"rgb"`` (array (H, W, 3) uint8 RGB), ``"mono"`` ((H, W) uint8) or
    ``"depth"`` ((H, W) float32 metres, 0 = no reading).
    """

    stamp_ns: int
    frame_id: str
    kind: str
    array: NDArray[Any]
    encoding: str


@dataclass(frozen=True)
class CameraInfoRecord:
    stamp_ns: int
    frame_id: str
    camera: PinholeCamera


@dataclass(frozen=True)
class PoseRecord:
    """A pose of ``child_frame_id`` (may be empty) in ``frame_id``: (4, 4) parent_from_child."""

    stamp_ns: int
    frame_id: str
    child_frame_id: str
    parent_from_child: NDArray[np.float64]
    twist: tuple[float, float] | None = None
    """(forward velocity m/s, yaw rate rad/s) where the message carries a twist (Odometry)."""


@dataclass(frozen=True)
class TransformRecord:
    """Transforms of one message (tf, tf_static, foxglove.FrameTransform(s))."""

    transforms: tuple[PoseRecord, ...]
    static: bool


@dataclass(frozen=True)
class TwistRecord:
    stamp_ns: int
    v: float
    omega: float


@dataclass(frozen=True)
class ScanRecord:
    """A decoded laser scan, before its mounting on the body is known.

    ``scan.body_from_sensor`` is still zero: the source finds it in tf from ``frame_id``.
    ``frame_from_scan`` is the (4, 4) float64 pose of the scan's origin in ``frame_id``
    (Foxglove's ``pose`` field), None where the message has none (ROS: the origin is the frame).
    """

    frame_id: str
    scan: ScanFrame
    frame_from_scan: NDArray[np.float64] | None = None

    @property
    def stamp_ns(self) -> int:
        return self.scan.stamp_ns
