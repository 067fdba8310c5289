"""Which topic of an MCAP log plays which role: the message types of each role, and the choice
between a log's topics.

A flag names a topic, otherwise the one topic of the role's types is taken; with none or several
the choice stops with :class:`~slamcli.errors.TopicNotFoundError` listing the candidates (topic,
type, image encoding, count, rate), or the log's topics when none has a fitting type. Colour and
depth are told apart by the encoding of their first message (16UC1/32FC1/compressedDepth =
depth).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Collection
from pathlib import Path
from typing import Any

from slamcli.errors import TopicNotFoundError
from slamcli.formats.base import StreamInfo
from slamcli.formats.mcap.adapters import adapter_for, normalize_schema_name
from slamcli.formats.mcap.decode import DecodeError, decoder_for
from slamcli.formats.mcap.observations import SCHEMA_NAME as LANDMARK_SCHEMA_NAME
from slamcli.formats.mcap.records import CameraInfoRecord, ChannelInfo, ImageRecord, ScanRecord

log = logging.getLogger(__name__)

IMAGE_SCHEMAS = frozenset(
    {
        "sensor_msgs/msg/Image",
        "sensor_msgs/msg/CompressedImage",
        "foxglove.RawImage",
        "foxglove.CompressedImage",
    }
)
CAMERA_SCHEMAS = frozenset({"sensor_msgs/msg/CameraInfo", "foxglove.CameraCalibration"})
POSE_SCHEMAS = frozenset(
    {
        "geometry_msgs/msg/PoseStamped",
        "geometry_msgs/msg/PoseWithCovarianceStamped",
        "nav_msgs/msg/Odometry",
        "foxglove.PoseInFrame",
    }
)
ODOM_SCHEMAS = frozenset(
    {"nav_msgs/msg/Odometry", "geometry_msgs/msg/Twist", "geometry_msgs/msg/TwistStamped"}
)
TF_SCHEMAS = frozenset(
    {"tf2_msgs/msg/TFMessage", "foxglove.FrameTransform", "foxglove.FrameTransforms"}
)
IMU_SCHEMAS = frozenset({"sensor_msgs/msg/Imu"})
LANDMARK_SCHEMAS = frozenset({LANDMARK_SCHEMA_NAME})
SCAN_SCHEMAS = frozenset({"sensor_msgs/msg/LaserScan", "foxglove.LaserScan"})

TOPIC_OPTIONS = (
    "rgb_topic",
    "depth_topic",
    "camera_info_topic",
    "odom_topic",
    "landmark_topic",
    "scan_topic",
    "gt_topic",
    "gt_frame",
    "left_topic",
    "right_topic",
)
"""The options that choose topics (or the tf frame of the ground truth), as sources take them."""

ROLES: dict[str, tuple[frozenset[str], str]] = {
    "rgb": (IMAGE_SCHEMAS, "--rgb-topic"),
    "depth": (IMAGE_SCHEMAS, "--depth-topic"),
    "camera": (CAMERA_SCHEMAS, "--camera-info-topic"),
    "odometry": (ODOM_SCHEMAS, "--odom-topic"),
    "landmarks": (LANDMARK_SCHEMAS, "--landmark-topic"),
    "scan": (SCAN_SCHEMAS, "--scan-topic"),
    "groundtruth": (POSE_SCHEMAS, "--gt-topic"),
    "imu": (IMU_SCHEMAS, "a single Imu topic"),
}
"""Each role's message types (normalised schema names) and the flag that chooses its topic."""

_STREAM_KINDS = (
    ("image", IMAGE_SCHEMAS),
    ("camera", CAMERA_SCHEMAS),
    ("tf", TF_SCHEMAS),
    ("odometry", ODOM_SCHEMAS),
    ("pose", POSE_SCHEMAS),
    ("imu", IMU_SCHEMAS),
    ("landmarks", LANDMARK_SCHEMAS),
    ("scan", SCAN_SCHEMAS),
)


def stream_kind(schema: str) -> str:
    """The kind ``info`` gives a stream of a normalised schema name (``other`` if unread)."""
    for kind, schemas in _STREAM_KINDS:
        if schema in schemas:
            return kind
    return "other"


def rate(count: int, first_ns: int | None, last_ns: int | None) -> float | None:
    """Messages per second over a time span; None for fewer than two or an empty span."""
    if count < 2 or first_ns is None or last_ns is None or last_ns <= first_ns:
        return None
    return (count - 1) / ((last_ns - first_ns) * 1e-9)


class TopicChooser:
    """The topics of one log by role, chosen once each.

    Args:
        path: the log, for messages.
        channels: topic -> channel.
        wanted: role -> the topic a flag named (None: choose).
        stats: the log's per-channel statistics (count, first and last log time) by channel id.
        probe: the first image of a topic, or None (tells colour from depth).
    """

    def __init__(
        self,
        path: Path,
        channels: dict[str, ChannelInfo],
        wanted: dict[str, str | None],
        stats: Callable[[], dict[int, Any]],
        probe: Callable[[str], ImageRecord | None],
    ) -> None:
        self.path = path
        self.channels = channels
        self.schema = {t: normalize_schema_name(c.schema_name) for t, c in channels.items()}
        self.wanted = wanted
        self.chosen: dict[str, str | None] = {}
        self._stats = stats
        self._probe = probe

    def of(self, schemas: Collection[str]) -> list[str]:
        """The topics whose type is one of ``schemas``, sorted."""
        return sorted(t for t, s in self.schema.items() if s in schemas)

    def image_role(self, topic: str) -> str:
        probe = self._probe(topic)
        if probe is not None:
            return "depth" if probe.kind == "depth" else "rgb"
        return "depth" if "depth" in topic.lower() else "rgb"

    def candidate_row(self, topic: str) -> list[str]:
        """(topic, type, image encoding, count, rate) of a topic, for error tables."""
        ch = self.channels[topic]
        encoding = ""
        if self.schema[topic] in IMAGE_SCHEMAS:
            probe = self._probe(topic)
            encoding = probe.encoding if probe is not None else "?"
        st = self._stats().get(ch.id)
        count = st.count if st else 0
        hz = rate(st.count, st.first_ns, st.last_ns) if st else None
        return [topic, ch.schema_name, encoding, str(count), f"{hz:.1f}" if hz else "-"]

    def camera_topic(
        self, rgb: str, options_given: bool, first_record: Callable[[str], Any]
    ) -> tuple[str, str] | None:
        """The calibration topic of the colour topic ``rgb`` and where it was found, or None.

        In this order: ``--camera-info-topic``; the topic beside ``rgb``
        (:func:`sibling_camera_topic`); a calibration topic whose first message
        (``first_record``) has the frame id of ``rgb``'s images; the log's only calibration
        topic, unless camera options were given (``options_given``).
        """
        explicit = self.wanted.get("camera")
        cameras = self.of(CAMERA_SCHEMAS)
        if explicit is not None:
            return self.choose("camera") or explicit, f"topic {explicit} (--camera-info-topic)"
        sibling = sibling_camera_topic(rgb, cameras)
        if sibling is not None:
            return sibling, f"topic {sibling} (beside {rgb})"
        probe = self._probe(rgb)
        frame = probe.frame_id if probe is not None else ""
        for t in cameras if frame else ():
            rec = first_record(t)
            if isinstance(rec, CameraInfoRecord) and rec.frame_id == frame:
                return t, f"topic {t} (frame id {frame} matches {rgb})"
        if not options_given and len(cameras) == 1:
            return cameras[0], f"topic {cameras[0]} (the log's only calibration topic)"
        return None

    def streams(
        self, first_readable: Callable[[str], Any]
    ) -> tuple[list[StreamInfo], dict[str, str]]:
        """Every topic as ``info`` lists it (kind, count, rate, span, type; a scan topic's
        beams from its first readable record), and the topics slamcli cannot read, with why."""
        stats = self._stats()
        streams = []
        undecodable: dict[str, str] = {}
        for topic, ch in sorted(self.channels.items()):
            st = stats.get(ch.id)
            count = st.count if st else 0
            try:
                decoder_for(ch)
                if adapter_for(ch.schema_name) is None:
                    undecodable[topic] = f"type {ch.schema_name} is not read by slamcli"
            except DecodeError as exc:
                undecodable[topic] = exc.msg
            detail = f"{ch.schema_name} ({ch.message_encoding})"
            if self.schema[topic] in SCAN_SCHEMAS and topic not in undecodable:
                first = first_readable(topic)
                if isinstance(first, ScanRecord):
                    detail += f", {first.scan.ranges_m.size} beams"
            streams.append(
                StreamInfo(
                    name=topic,
                    kind=stream_kind(self.schema[topic]),
                    count=count,
                    rate_hz=rate(count, st.first_ns, st.last_ns) if st else None,
                    start_s=st.first_ns * 1e-9 if st and st.first_ns is not None else None,
                    end_s=st.last_ns * 1e-9 if st and st.last_ns is not None else None,
                    detail=detail,
                )
            )
        return streams, undecodable

    def reference(self, required: bool) -> str | None:
        """The ground-truth topic. Chosen automatically, it is never the odometry topic being
        read: a run scored against its own input measures nothing."""
        topic = self.choose("groundtruth", required)
        if self.wanted.get("groundtruth") is None and topic == self.chosen.get("odometry"):
            log.info("%s: %s is the odometry read, not taken as ground truth", self.path, topic)
            return None
        return topic

    def choose(self, role: str, required: bool = True) -> str | None:
        """The topic for ``role`` (a key of :data:`ROLES`).

        Without a fitting topic, ``required`` raises TopicNotFoundError listing the candidates,
        even after an optional look-up found none; several fitting topics and no flag raise
        whether required or not.
        """
        if role in self.chosen and (self.chosen[role] is not None or not required):
            return self.chosen[role]
        schemas, flag = ROLES[role]
        typed = self.of(schemas)
        if role in ("rgb", "depth"):
            candidates = [t for t in typed if self.image_role(t) == role]
        else:
            candidates = typed
        wanted = self.wanted.get(role)
        chosen: str | None = None
        if wanted is not None:
            if wanted not in self.channels:
                raise TopicNotFoundError(
                    f"{self.path}: no topic {wanted} ({flag})",
                    hint=f"choose one of the {role} candidates below",
                    candidates=[self.candidate_row(t) for t in typed],
                )
            if self.schema[wanted] not in schemas:
                raise TopicNotFoundError(
                    f"{self.path}: {flag} {wanted} has type {self.channels[wanted].schema_name}, "
                    f"not one of {', '.join(sorted(schemas))}",
                    candidates=[self.candidate_row(t) for t in typed],
                )
            chosen = wanted
        elif len(candidates) == 1:
            chosen = candidates[0]
        elif len(candidates) > 1 and role == "groundtruth":
            # Odometry is a pose topic too, but rarely the ground truth a user means.
            non_odom = [t for t in candidates if self.schema[t] != "nav_msgs/msg/Odometry"]
            if len(non_odom) == 1:
                chosen = non_odom[0]
        if chosen is None and (required or len(candidates) > 1):
            what = "no" if not candidates else f"{len(candidates)}"
            listed = candidates or typed
            hint = "the table lists the topics of a fitting type"
            if not listed:
                listed = sorted(self.channels)
                hint = (
                    f"no topic has a fitting type ({', '.join(sorted(schemas))}); "
                    "the table lists the log's topics"
                )
            raise TopicNotFoundError(
                f"{self.path}: {what} {role} topic{'s' if len(candidates) != 1 else ''} "
                f"found; choose one with {flag}",
                hint=hint,
                candidates=[self.candidate_row(t) for t in listed],
            )
        self.chosen[role] = chosen
        return chosen


def sibling_camera_topic(image_topic: str, camera_topics: Collection[str]) -> str | None:
    """The calibration topic beside an image topic: ``camera_info`` (or ``calibration``) in
    its namespace or the nearest one above (``/cam/color/image_raw`` ->
    ``/cam/color/camera_info``), None when there is none."""
    parts = image_topic.strip("/").split("/")
    for depth in range(len(parts) - 1, 0, -1):
        prefix = "/" + "/".join(parts[:depth])
        for name in ("camera_info", "calibration"):
            if f"{prefix}/{name}" in camera_topics:
                return f"{prefix}/{name}"
    return None
