"""MCAP logs as a :class:`~slamcli.formats.base.Source`: topic selection, sync, ground truth.

Topics are chosen per role (colour, depth, camera, odometry, landmarks, ground truth, IMU): a
flag names one, otherwise the one topic of the right type is taken; with none or several the
source stops with :class:`~slamcli.errors.TopicNotFoundError` listing the candidates. Colour
and depth are told apart by the encoding of their first message (16UC1/32FC1/compressedDepth =
depth).

The camera comes from, in this order: ``--camera-info-topic``; the ``camera_info`` topic beside
the colour topic (``/cam/color/image_raw`` -> ``/cam/color/camera_info``); a calibration topic
whose frame id matches the colour images'; ``--camera``/``--fx ...`` (or a camera file next to
the log); the only calibration topic of the log.

Colour and depth are paired with the TUM ``associate.py`` rule (greedy by smallest |Δt| below
``max_dt``) while streaming: images are held until no later message can change their pairing
(a gap of at least ``max_dt`` in the merged stamps behind both streams' newest stamps), so
memory stays bounded by a handful of frames.

Odometry (``nav_msgs/msg/Odometry``: v = twist.linear.x, omega = twist.angular.z, and the
pose; ``Twist``/``TwistStamped``: v and omega) and landmark observations
(``slamcli.LandmarkObservations``, see :mod:`slamcli.formats.mcap.observations`) come out in
the order of their own stamps, odometry first at equal stamps, even where a detector's messages
were logged late: a frame waits until every stream read has passed its stamp (at most
``_ORDER_BUFFER`` frames wait).

Ground truth comes from a pose topic (``--gt-topic``) or from tf (``--gt-frame``: the pose of
that frame in the root of its tree). Before any frame has been read, :meth:`groundtruth` returns
the poses as recorded. After frames have been read it is interpolated (SLERP) to the stamps of
the frames read, so that it pairs one to one with an estimate made from them: the colour stamps
when images were read; otherwise (a log without images, e.g. odometry and landmarks for the
EKF) the odometry and landmark stamps. Stamps outside the ground truth's time span are left
out. With ground truth, :meth:`start_pose` is its planar pose at the first odometry or landmark
stamp, for pipelines that start there instead of at the origin.
"""

from __future__ import annotations

import bisect
import heapq
import itertools
import logging
from collections.abc import Callable, Collection, Iterator
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError, InputError, TopicNotFoundError
from slamcli.formats import sniff
from slamcli.formats.base import Frame, ReadStats, SourceBase, SourceInfo, StreamInfo
from slamcli.formats.mcap.adapters import Adapter, adapter_for, normalize_schema_name
from slamcli.formats.mcap.decode import DecodeError, decoder_for
from slamcli.formats.mcap.observations import SCHEMA_NAME as LANDMARK_SCHEMA_NAME
from slamcli.formats.mcap.reader import DEFAULT_MAX_CHUNK_BYTES, McapLog
from slamcli.formats.mcap.records import (
    CameraInfoRecord,
    ChannelInfo,
    ImageRecord,
    PoseRecord,
    TwistRecord,
)
from slamcli.formats.mcap.tf import moving_frame_poses
from slamcli.formats.pairing import associate_stamps
from slamcli.formats.text import format_stamp
from slamcli.geometry import interpolate_planar, interpolate_poses, se3_to_planar
from slamcli.types import (
    ImageFrame,
    ImuFrame,
    LandmarkFrame,
    LandmarkMap,
    OdometryFrame,
    PinholeCamera,
    ProgressFn,
    RgbdFrame,
    Trajectory,
)

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
FRAME_KINDS = ("rgbd", "image", "odometry", "landmarks", "imu")

_FORCE_FLUSH = 32
"""Buffered images at which pairing is settled even without a safe gap (very dense streams)."""
START_POSE_MAX_WAIT_S = 30.0
"""``start_pose`` takes the first ground-truth pose if it is at most this late (the robot has
barely moved in a log's first seconds); as :mod:`slamcli.formats.landmarks` does."""
_ORDER_BUFFER = 10_000
"""Odometry/landmark frames held for stamp order at most; beyond it the oldest goes out (a
stream that stopped, or stamps on clocks far apart)."""


class McapSource(SourceBase):
    """An MCAP log as a :class:`~slamcli.formats.base.Source`.

    Args:
        path: the ``.mcap`` file.
        rgb_topic, depth_topic, camera_info_topic, odom_topic, landmark_topic, gt_topic: topic
            choices; None picks the one topic of the right type when it is needed.
        gt_frame: take ground truth from tf as the pose of this frame in its tree's root.
        max_dt, dt_offset: colour/depth pairing tolerance and depth stamp offset, seconds.
        camera, fx, fy, cx, cy: camera when the log has no calibration topic (see
            :func:`~slamcli.formats.camera.resolve_camera`).
        strict: a truncated log, a bad chunk or an undecodable message is an error instead
            of being read around.
        max_chunk_bytes: largest uncompressed chunk or message read (see
            :class:`~slamcli.formats.mcap.reader.McapLog`).
    """

    format_name = "mcap"
    OPTIONS = (
        "max_dt",
        "dt_offset",
        "camera",
        "fx",
        "fy",
        "cx",
        "cy",
        "strict",
        "max_chunk_mb",
        "rgb_topic",
        "depth_topic",
        "camera_info_topic",
        "odom_topic",
        "landmark_topic",
        "gt_topic",
        "gt_frame",
    )

    @classmethod
    def open(cls, path: str | Path, **options: Any) -> McapSource:
        """Open ``path`` with the command-line options; ``max_chunk_mb`` is in MB (2^20 B)."""
        mb = options.pop("max_chunk_mb", None)
        if mb is not None:
            options["max_chunk_bytes"] = int(mb) * 2**20
        return cls(path, **options)

    def __init__(
        self,
        path: str | Path,
        *,
        max_dt: float = 0.02,
        dt_offset: float = 0.0,
        camera: str | Path | PinholeCamera | None = None,
        fx: float | None = None,
        fy: float | None = None,
        cx: float | None = None,
        cy: float | None = None,
        strict: bool = False,
        rgb_topic: str | None = None,
        depth_topic: str | None = None,
        camera_info_topic: str | None = None,
        odom_topic: str | None = None,
        landmark_topic: str | None = None,
        gt_topic: str | None = None,
        gt_frame: str | None = None,
        max_chunk_bytes: int = DEFAULT_MAX_CHUNK_BYTES,
    ) -> None:
        if not np.isfinite(max_dt) or max_dt <= 0:
            raise ConfigError(f"max_dt must be a positive number of seconds, got {max_dt}")
        if not np.isfinite(dt_offset):
            raise ConfigError(f"dt_offset must be a finite number of seconds, got {dt_offset}")
        if gt_topic and gt_frame:
            raise ConfigError("give --gt-topic or --gt-frame, not both")
        self.path = Path(path)
        self.strict = strict
        self.max_dt_ns = round(max_dt * 1e9)
        self.dt_offset_ns = round(dt_offset * 1e9)
        self._camera_options = (camera, fx, fy, cx, cy)
        self._want = {
            "rgb": rgb_topic,
            "depth": depth_topic,
            "camera": camera_info_topic,
            "odometry": odom_topic,
            "landmarks": landmark_topic,
            "groundtruth": gt_topic,
        }
        self.gt_frame = gt_frame
        self.stats = ReadStats()
        self.log = McapLog(self.path, strict=strict, max_chunk_bytes=max_chunk_bytes)
        self._channels = {c.topic: c for c in self.log.channels().values()}
        self._schema = {t: normalize_schema_name(c.schema_name) for t, c in self._channels.items()}
        self._probes: dict[str, ImageRecord | None] = {}
        self._chosen: dict[str, str | None] = {}
        self._camera: tuple[PinholeCamera, str] | None = None
        self._frame_stamps: list[int] = []
        self._motion_stamps: list[int] = []
        self._decoders: dict[str, tuple[Callable[[bytes], Any], Adapter]] = {}

    @classmethod
    def sniff(cls, path: str | Path) -> bool:
        """A ``.mcap`` file, or any file starting with the MCAP magic."""
        return sniff.mcap(path)

    def close(self) -> None:
        self.log.close()

    # -- topics ------------------------------------------------------------------------------

    def _topics_of(self, schemas: Collection[str]) -> list[str]:
        return sorted(t for t, s in self._schema.items() if s in schemas)

    def _probe(self, topic: str) -> ImageRecord | None:
        """The first image of a topic (None when it has none or it cannot be decoded)."""
        if topic not in self._probes:
            record = None
            for raw in self.log.messages([topic]):
                try:
                    out = self._adapt(raw.channel, raw.data, raw.log_time_ns)
                except InputError as exc:
                    log.debug("%s: first message undecodable: %s", topic, exc)
                    break
                record = out if isinstance(out, ImageRecord) else None
                break
            self._probes[topic] = record
        return self._probes[topic]

    def _image_role(self, topic: str) -> str:
        probe = self._probe(topic)
        if probe is not None:
            return "depth" if probe.kind == "depth" else "rgb"
        return "depth" if "depth" in topic.lower() else "rgb"

    def _candidate_row(self, topic: str) -> list[str]:
        ch = self._channels[topic]
        encoding = ""
        if self._schema[topic] in IMAGE_SCHEMAS:
            probe = self._probe(topic)
            encoding = probe.encoding if probe is not None else "?"
        st = self._stats().get(ch.id)
        count = st.count if st else 0
        rate = _rate(st.count, st.first_ns, st.last_ns) if st else None
        return [topic, ch.schema_name, encoding, str(count), f"{rate:.1f}" if rate else "-"]

    def _stats(self) -> dict[int, Any]:
        return self.log.stats()

    def topic(self, role: str, required: bool = True) -> str | None:
        """The topic used for ``role`` (rgb, depth, camera, odometry, landmarks, groundtruth,
        imu).

        Without a fitting topic, ``required`` raises TopicNotFoundError listing the candidates,
        even after an optional look-up (``start_pose``, ``info``) found none.
        """
        if role in self._chosen and (self._chosen[role] is not None or not required):
            return self._chosen[role]
        schemas, flag = {
            "rgb": (IMAGE_SCHEMAS, "--rgb-topic"),
            "depth": (IMAGE_SCHEMAS, "--depth-topic"),
            "camera": (CAMERA_SCHEMAS, "--camera-info-topic"),
            "odometry": (ODOM_SCHEMAS, "--odom-topic"),
            "landmarks": (LANDMARK_SCHEMAS, "--landmark-topic"),
            "groundtruth": (POSE_SCHEMAS, "--gt-topic"),
            "imu": (IMU_SCHEMAS, "a single Imu topic"),
        }[role]
        typed = self._topics_of(schemas)
        if role in ("rgb", "depth"):
            candidates = [t for t in typed if self._image_role(t) == role]
        else:
            candidates = typed
        wanted = self._want.get(role)
        chosen: str | None = None
        if wanted is not None:
            if wanted not in self._channels:
                raise TopicNotFoundError(
                    f"{self.path}: no topic {wanted} ({flag})",
                    hint=f"choose one of the {role} candidates below",
                    candidates=[self._candidate_row(t) for t in typed],
                )
            if self._schema[wanted] not in schemas:
                raise TopicNotFoundError(
                    f"{self.path}: {flag} {wanted} has type {self._channels[wanted].schema_name}, "
                    f"not one of {', '.join(sorted(schemas))}",
                    candidates=[self._candidate_row(t) for t in typed],
                )
            chosen = wanted
        elif len(candidates) == 1:
            chosen = candidates[0]
        elif len(candidates) > 1 and role == "groundtruth":
            # Odometry is a pose topic too, but rarely the ground truth a user means.
            non_odom = [t for t in candidates if self._schema[t] != "nav_msgs/msg/Odometry"]
            if len(non_odom) == 1:
                chosen = non_odom[0]
        if chosen is None and (required or len(candidates) > 1):
            what = "no" if not candidates else f"{len(candidates)}"
            listed = candidates or typed
            hint = "the table lists the topics of a fitting type"
            if not listed:
                listed = sorted(self._channels)
                hint = (
                    f"no topic has a fitting type ({', '.join(sorted(schemas))}); "
                    "the table lists the log's topics"
                )
            raise TopicNotFoundError(
                f"{self.path}: {what} {role} topic{'s' if len(candidates) != 1 else ''} "
                f"found; choose one with {flag}",
                hint=hint,
                candidates=[self._candidate_row(t) for t in listed],
            )
        self._chosen[role] = chosen
        return chosen

    # -- camera --------------------------------------------------------------------------------

    def camera(self) -> tuple[PinholeCamera, str]:
        """The colour camera and a description of where it came from."""
        if self._camera is not None:
            return self._camera
        explicit = self._want["camera"]
        cam_topics = self._topics_of(CAMERA_SCHEMAS)
        rgb = str(self.topic("rgb"))
        found: tuple[str, str] | None = None
        if explicit is not None:
            found = (self.topic("camera") or explicit, f"topic {explicit} (--camera-info-topic)")
        else:
            sibling = _sibling_camera_topic(rgb, cam_topics)
            if sibling is not None:
                found = (sibling, f"topic {sibling} (beside {rgb})")
            else:
                probe = self._probe(rgb)
                frame = probe.frame_id if probe is not None else ""
                for t in cam_topics:
                    rec = self._first_record(t)
                    if frame and isinstance(rec, CameraInfoRecord) and rec.frame_id == frame:
                        found = (t, f"topic {t} (frame id {frame} matches {rgb})")
                        break
        options_given = any(v is not None for v in self._camera_options)
        if found is None and not options_given and len(cam_topics) == 1:
            found = (cam_topics[0], f"topic {cam_topics[0]} (the log's only calibration topic)")
        if found is not None:
            rec = self._first_record(found[0])
            if not isinstance(rec, CameraInfoRecord):
                raise InputError(f"{self.path}: camera topic {found[0]} has no readable message")
            self._camera = (rec.camera, found[1])
            return self._camera
        from slamcli.formats.camera import resolve_camera

        camera, fx, fy, cx, cy = self._camera_options
        resolved = resolve_camera(self.path.parent, camera, fx, fy, cx, cy)
        self._camera = (resolved.camera, resolved.source)
        return self._camera

    def _first_record(self, topic: str) -> Any:
        for raw in self.log.messages([topic]):
            return self._adapt(raw.channel, raw.data, raw.log_time_ns)
        return None

    # -- decoding ------------------------------------------------------------------------------

    def _adapt(self, channel: ChannelInfo, data: bytes, log_time_ns: int) -> Any:
        pair = self._decoders.get(channel.topic)
        if pair is None:
            adapter = adapter_for(channel.schema_name)
            if adapter is None:
                raise DecodeError(
                    f"{self.path}: topic {channel.topic} has type {channel.schema_name}, which "
                    "slamcli does not read"
                )
            pair = self._decoders[channel.topic] = (decoder_for(channel), adapter)
        decode, adapt = pair
        return adapt(decode(data), log_time_ns, channel.topic)

    def _records(self, topics: Collection[str]) -> Iterator[tuple[str, Any]]:
        """(topic, record) in log-time order; undecodable messages skipped and counted."""
        for raw in self.log.messages(list(topics)):
            try:
                rec = self._adapt(raw.channel, raw.data, raw.log_time_ns)
            except DecodeError as exc:
                if raw.channel.topic not in self._decoders:
                    raise  # the channel cannot be decoded at all: its error names the channel
                where = f"log time {format_stamp(raw.log_time_ns)} s, sequence {raw.sequence}"
                if self.strict:
                    raise DecodeError(f"{exc.msg} ({where})", hint=exc.hint) from exc
                name = f"{raw.channel.topic}@{raw.log_time_ns}"
                self.stats.skipped += 1
                self.stats.skipped_names.append(name)
                log.warning("skipping undecodable message %s (%s): %s", name, where, exc.msg)
                continue
            yield raw.channel.topic, rec
        self._note_damage()

    def _note_damage(self) -> None:
        # The reader has already warned as it read around the damage; this only records it.
        for problem in self.log.health.loss_problems():
            if problem not in self.stats.data_loss:
                self.stats.data_loss.append(problem)

    # -- frames --------------------------------------------------------------------------------

    def frames(self, kinds: Collection[str] = ("rgbd",)) -> Iterator[Frame]:
        """Frames of the given kinds (rgbd, image, odometry, landmarks, imu) in time order.

        Odometry and landmark frames come in the order of their stamps, odometry first at equal
        stamps (see the module docstring); images and IMU readings in log-time order.
        """
        unknown = set(kinds) - set(FRAME_KINDS)
        if unknown:
            raise ConfigError(f"mcap sources do not provide {', '.join(sorted(unknown))} frames")
        roles: dict[str, str] = {}
        if "rgbd" in kinds or "image" in kinds:
            roles[str(self.topic("rgb"))] = "rgb"
        if "rgbd" in kinds:
            roles[str(self.topic("depth"))] = "depth"
        if "odometry" in kinds:
            roles[str(self.topic("odometry"))] = "odometry"
        if "landmarks" in kinds:
            roles[str(self.topic("landmarks"))] = "landmarks"
        if "imu" in kinds:
            roles[str(self.topic("imu"))] = "imu"
        camera = self.camera()[0] if ("rgbd" in kinds or "image" in kinds) else None
        pairer = _StreamPairer(self.max_dt_ns, self.dt_offset_ns) if "rgbd" in kinds else None
        order = _StampOrder([r for r in roles.values() if r in _MOTION_RANK])
        # Odometry and landmarks are what is read when there are no images (the EKF): count them.
        count_motion = camera is None
        self._frame_stamps = []
        self._motion_stamps = []
        for topic, rec in self._records(roles):
            role = roles[topic]
            if role in ("rgb", "depth") and isinstance(rec, ImageRecord) and camera is not None:
                if pairer is None:
                    yield self._image_frame(rec, camera)
                    continue
                pairer.add(role, rec)
                yield from self._emit(pairer.ready(), camera)
            elif role == "odometry" and isinstance(rec, PoseRecord | TwistRecord):
                yield from self._motion(order.add(role, _odometry_frame(rec)), count_motion)
            elif role == "landmarks" and isinstance(rec, LandmarkFrame):
                yield from self._motion(order.add(role, rec), count_motion)
            elif role == "imu" and isinstance(rec, ImuFrame):
                yield rec
        yield from self._motion(order.flush(), count_motion)
        if pairer is not None and camera is not None:
            yield from self._emit(pairer.ready(final=True), camera)

    def _motion(
        self, frames: list[OdometryFrame | LandmarkFrame], count: bool
    ) -> Iterator[OdometryFrame | LandmarkFrame]:
        for frame in frames:
            self._motion_stamps.append(frame.stamp_ns)
            if count:
                self.stats.read += 1
            yield frame

    def _image_frame(self, rec: ImageRecord, camera: PinholeCamera | None) -> ImageFrame:
        self.stats.read += 1
        self._frame_stamps.append(rec.stamp_ns)
        return ImageFrame(rec.stamp_ns, rec.array, camera, name=f"{rec.frame_id}@{rec.stamp_ns}")

    def _emit(
        self, pairs: list[tuple[ImageRecord, ImageRecord]], camera: PinholeCamera
    ) -> Iterator[RgbdFrame]:
        for rgb, depth in pairs:
            colour = rgb.array if rgb.kind == "rgb" else np.repeat(rgb.array[..., None], 3, 2)
            if colour.shape[:2] != depth.array.shape:
                raise InputError(
                    f"{self.path}: colour images are {colour.shape[1]}x{colour.shape[0]} but "
                    f"depth images {depth.array.shape[1]}x{depth.array.shape[0]}",
                    hint="slamcli needs depth registered to the colour camera "
                    "(e.g. the aligned_depth_to_color topic)",
                )
            self.stats.read += 1
            self._frame_stamps.append(rgb.stamp_ns)
            yield RgbdFrame(
                rgb.stamp_ns,
                colour,
                depth.array,
                camera,
                depth_stamp_ns=depth.stamp_ns,
                name=f"{self.topic('rgb')}@{rgb.stamp_ns}",
            )

    # -- ground truth ----------------------------------------------------------------------------

    def groundtruth(self) -> Trajectory | None:
        """Ground truth; after frames were read, interpolated to their stamps.

        The colour stamps when images were read, else the odometry and landmark stamps; the
        poses as recorded when no frame has been read (see the module docstring).
        """
        samples = self._groundtruth_samples()
        if samples is None:
            return None
        stamps = self._frame_stamps or self._motion_stamps
        if not stamps:
            return samples
        query = np.unique(np.asarray(stamps, dtype=np.int64))
        valid, poses = interpolate_poses(samples.stamps_ns, samples.world_from_body, query)
        if not valid.any():
            log.warning("%s: ground truth does not overlap the frames in time", self.path)
            return None
        return Trajectory(query[valid], poses[valid])

    def start_pose(self) -> NDArray[np.float64] | None:
        """(3,) float64 x (m), y (m), yaw (rad) of the ground truth at the first frame's stamp.

        The first frame is the earliest odometry or landmark frame: of the frames already read,
        else of the first readable message of each topic. The ground truth is interpolated
        there (:func:`~slamcli.geometry.interpolate_planar`); when it starts after that stamp
        by at most :data:`START_POSE_MAX_WAIT_S`, its first pose is taken. None without
        ground truth, without odometry and landmarks, or when the ground truth does not
        cover the start.
        """
        samples = self._groundtruth_samples()
        if samples is None:
            return None
        first = self._first_motion_stamp()
        if first is None:
            return None
        planar = se3_to_planar(samples.world_from_body)
        pose = interpolate_planar(samples.stamps_ns, planar, np.array([first]))[0]
        if np.isfinite(pose).all():
            return np.asarray(pose, dtype=np.float64)
        late_ns = int(samples.stamps_ns[0]) - first
        if 0 < late_ns <= round(START_POSE_MAX_WAIT_S * 1e9):
            return np.asarray(planar[0], dtype=np.float64)
        log.warning(
            "%s: ground truth does not cover the first frame at %s s; no start pose",
            self.path,
            format_stamp(first),
        )
        return None

    def landmark_truth(self) -> LandmarkMap | None:
        """The true landmark positions: an MCAP log does not carry them, so None."""
        return None

    def _first_motion_stamp(self) -> int | None:
        if self._motion_stamps:
            return min(self._motion_stamps)
        firsts = []
        for role in ("odometry", "landmarks"):
            topic = self.topic(role, required=False)
            if topic is None:
                continue
            # A probe: unreadable messages are passed over here and counted when frames are read.
            for raw in self.log.messages([topic]):
                try:
                    rec = self._adapt(raw.channel, raw.data, raw.log_time_ns)
                except DecodeError:
                    if topic not in self._decoders:
                        raise
                    continue
                if isinstance(rec, PoseRecord | TwistRecord | LandmarkFrame):
                    firsts.append(rec.stamp_ns)
                    break
        return min(firsts) if firsts else None

    def _groundtruth_samples(self) -> Trajectory | None:
        if self.gt_frame is not None:
            return self._tf_groundtruth(self.gt_frame)
        topic = self.topic("groundtruth", required=self._want["groundtruth"] is not None)
        if topic is None:
            return None
        stamps, poses = [], []
        for _, rec in self._records([topic]):
            if isinstance(rec, PoseRecord):
                stamps.append(rec.stamp_ns)
                poses.append(rec.parent_from_child)
        return _trajectory(stamps, poses, f"{self.path}: ground-truth topic {topic}")

    def _tf_groundtruth(self, frame: str) -> Trajectory | None:
        records = (rec for _, rec in self._records(self._topics_of(TF_SCHEMAS)))
        stamps, poses = moving_frame_poses(records, frame, self.path)
        return _trajectory(list(stamps), list(poses), f"{self.path}: tf {frame}")

    # -- info ------------------------------------------------------------------------------------

    def info(self, deep: bool = False, progress: ProgressFn | None = None) -> SourceInfo:
        stats = self._stats()
        streams = []
        problems: list[str] = []
        undecodable: dict[str, str] = {}
        for topic, ch in sorted(self._channels.items()):
            st = stats.get(ch.id)
            count = st.count if st else 0
            try:
                decoder_for(ch)
                if adapter_for(ch.schema_name) is None:
                    undecodable[topic] = f"type {ch.schema_name} is not read by slamcli"
            except DecodeError as exc:
                undecodable[topic] = exc.msg
            streams.append(
                StreamInfo(
                    name=topic,
                    kind=_kind(self._schema[topic]),
                    count=count,
                    rate_hz=_rate(count, st.first_ns, st.last_ns) if st else None,
                    start_s=st.first_ns * 1e-9 if st and st.first_ns is not None else None,
                    end_s=st.last_ns * 1e-9 if st and st.last_ns is not None else None,
                    detail=f"{ch.schema_name} ({ch.message_encoding})",
                )
            )
        frames = 0
        camera: PinholeCamera | None = None
        camera_source = ""
        details: dict[str, Any] = {"undecodable": undecodable}
        try:
            rgb, depth = self.topic("rgb"), self.topic("depth")
            camera, camera_source = self.camera()
            details["rgb_topic"], details["depth_topic"] = rgb, depth
            frames = self._count_pairs(deep, progress)
        except TopicNotFoundError as exc:
            if self._topics_of(IMAGE_SCHEMAS) or not self._topics_of(LANDMARK_SCHEMAS):
                problems.append(f"no RGB-D frames: {exc.msg}")
        try:
            landmarks = self.topic("landmarks", required=False)
            if landmarks is not None:
                st = stats.get(self._channels[landmarks].id)
                details["landmark_topic"] = landmarks
                details["landmark_messages"] = st.count if st else 0
                odometry = self.topic("odometry", required=False)
                if odometry is not None:
                    details["odometry_topic"] = odometry
        except TopicNotFoundError as exc:
            problems.append(f"landmarks: {exc.msg}")
        gt_count = 0
        try:
            gt = self._groundtruth_samples()
            gt_count = len(gt) if gt is not None else 0
            if gt is not None:
                details["groundtruth_from"] = (
                    f"tf frame {self.gt_frame}" if self.gt_frame else self._chosen["groundtruth"]
                )
        except InputError as exc:
            problems.append(f"ground truth: {exc.msg}")
        self._note_damage()
        details["data_loss"] = list(self.stats.data_loss)
        health = self.log.health
        details["health"] = {
            "summary_present": health.summary_present,
            "truncated": health.truncated,
            "crc_checked": health.crc_checked,
            "bad_chunks": len(health.bad_chunks),
            "chunk_overlap": health.chunk_overlap,
            "dropped_late": health.dropped_late,
        }
        problems.extend(health.problems())
        problems.extend(
            f"channel {t} cannot be read ({r}); ignored" for t, r in undecodable.items()
        )
        if self.stats.skipped:
            details["unreadable"] = list(self.stats.skipped_names)
        return SourceInfo(
            format="mcap",
            path=str(self.path),
            streams=streams,
            frames=frames,
            groundtruth=gt_count,
            camera=camera,
            camera_source=camera_source,
            problems=problems,
            details=details,
        )

    def _count_pairs(self, deep: bool, progress: ProgressFn | None) -> int:
        """Paired RGB-D frames: by header stamps when ``deep``, else by log times."""
        rgb, depth = str(self.topic("rgb")), str(self.topic("depth"))
        if deep:
            n = 0
            for _ in self.frames(("rgbd",)):
                n += 1
                if progress:
                    progress(n, None)
            self._frame_stamps = []
            return n
        times: dict[str, list[int]] = {rgb: [], depth: []}
        for raw in self.log.messages([rgb, depth]):
            times[raw.channel.topic].append(raw.log_time_ns)
        self._note_damage()
        first, _ = associate_stamps(
            np.asarray(times[rgb], dtype=np.int64),
            np.asarray(times[depth], dtype=np.int64),
            self.max_dt_ns,
            self.dt_offset_ns,
        )
        return len(first)


_MOTION_RANK = {"odometry": 0, "landmarks": 1}
"""Order of odometry and landmark frames at equal stamps."""


class _StampOrder:
    """Odometry and landmark frames of several streams put back into stamp order.

    Each stream is taken to be in stamp order by itself (a stream that is not is sorted within
    the buffer). A frame goes out once every stream has delivered a later stamp, so a detector
    whose messages are logged late does not put its observations after later odometry.
    """

    def __init__(self, roles: Collection[str]) -> None:
        self.newest: dict[str, int | None] = dict.fromkeys(roles)
        self.heap: list[tuple[int, int, int, OdometryFrame | LandmarkFrame]] = []
        self.count = 0

    def add(
        self, role: str, frame: OdometryFrame | LandmarkFrame
    ) -> list[OdometryFrame | LandmarkFrame]:
        """Take one frame; return the frames that can go out now, in order."""
        heapq.heappush(self.heap, (frame.stamp_ns, _MOTION_RANK[role], self.count, frame))
        self.count += 1
        newest = self.newest[role]
        self.newest[role] = frame.stamp_ns if newest is None else max(newest, frame.stamp_ns)
        seen = [v for v in self.newest.values() if v is not None]
        horizon = min(seen) if len(seen) == len(self.newest) else None
        out = []
        while self.heap and (
            (horizon is not None and self.heap[0][0] < horizon) or len(self.heap) > _ORDER_BUFFER
        ):
            out.append(heapq.heappop(self.heap)[3])
        return out

    def flush(self) -> list[OdometryFrame | LandmarkFrame]:
        """Every frame still held, in order."""
        out = [heapq.heappop(self.heap)[3] for _ in range(len(self.heap))]
        return out


class _StreamPairer:
    """TUM associate.py pairing of two image streams, settled as the streams advance."""

    def __init__(self, max_dt_ns: int, offset_ns: int) -> None:
        self.max_dt = max_dt_ns
        self.offset = offset_ns
        self.buf: dict[str, list[ImageRecord]] = {"rgb": [], "depth": []}
        self.newest: dict[str, int | None] = {"rgb": None, "depth": None}

    def add(self, role: str, rec: ImageRecord) -> None:
        stamp = rec.stamp_ns + (self.offset if role == "depth" else 0)
        buf = self.buf[role]
        keys = [self._key(role, r) for r in buf]
        buf.insert(bisect.bisect_right(keys, stamp), rec)
        newest = self.newest[role]
        self.newest[role] = stamp if newest is None else max(newest, stamp)

    def _key(self, role: str, rec: ImageRecord) -> int:
        return rec.stamp_ns + (self.offset if role == "depth" else 0)

    def ready(self, final: bool = False) -> list[tuple[ImageRecord, ImageRecord]]:
        rgb, depth = self.buf["rgb"], self.buf["depth"]
        if not rgb or not depth:
            if final:
                rgb.clear()
                depth.clear()
            return []
        if final:
            cut = None
        else:
            newest = [v for v in self.newest.values() if v is not None]
            horizon = min(newest) - self.max_dt
            cut = self._safe_cut(horizon)
            if cut is None and len(rgb) + len(depth) > _FORCE_FLUSH:
                cut = horizon
            if cut is None:
                return []
        take_r = [r for r in rgb if cut is None or r.stamp_ns < cut]
        take_d = [d for d in depth if cut is None or self._key("depth", d) < cut]
        i, j = associate_stamps(
            np.array([r.stamp_ns for r in take_r], dtype=np.int64),
            np.array([d.stamp_ns for d in take_d], dtype=np.int64),
            self.max_dt,
            self.offset,
        )
        pairs = sorted(zip(i.tolist(), j.tolist(), strict=True))
        out = [(take_r[a], take_d[b]) for a, b in pairs]
        del rgb[: len(take_r)]
        del depth[: len(take_d)]
        return out

    def _safe_cut(self, horizon: int) -> int | None:
        """A time below ``horizon`` that no candidate pair spans (a gap of >= max_dt)."""
        merged = sorted(
            [r.stamp_ns for r in self.buf["rgb"]]
            + [self._key("depth", d) for d in self.buf["depth"]]
        )
        cut = None
        for a, b in itertools.pairwise(merged):
            if b > horizon:
                break
            if b - a >= self.max_dt:
                cut = b
        return cut


def _sibling_camera_topic(image_topic: str, camera_topics: list[str]) -> str | None:
    parts = image_topic.strip("/").split("/")
    for depth in range(len(parts) - 1, 0, -1):
        prefix = "/" + "/".join(parts[:depth])
        for name in ("camera_info", "calibration"):
            if f"{prefix}/{name}" in camera_topics:
                return f"{prefix}/{name}"
    return None


def _odometry_frame(rec: PoseRecord | TwistRecord) -> OdometryFrame:
    if isinstance(rec, TwistRecord):
        return OdometryFrame(rec.stamp_ns, v=rec.v, omega=rec.omega)
    v, omega = rec.twist if rec.twist is not None else (None, None)
    return OdometryFrame(rec.stamp_ns, v=v, omega=omega, world_from_body=rec.parent_from_child)


def _trajectory(stamps: list[int], poses: list[Any], what: str) -> Trajectory | None:
    if not stamps:
        log.warning("%s has no poses", what)
        return None
    s = np.asarray(stamps, dtype=np.int64)
    order = np.argsort(s, kind="stable")
    s = s[order]
    keep = np.concatenate([[True], np.diff(s) > 0])
    if not keep.all():
        log.debug("%s: %d repeated stamps dropped", what, int((~keep).sum()))
    return Trajectory(s[keep], np.stack(poses)[order][keep])


def _rate(count: int, first_ns: int | None, last_ns: int | None) -> float | None:
    if count < 2 or first_ns is None or last_ns is None or last_ns <= first_ns:
        return None
    return (count - 1) / ((last_ns - first_ns) * 1e-9)


def _kind(schema: str) -> str:
    for kind, schemas in (
        ("image", IMAGE_SCHEMAS),
        ("camera", CAMERA_SCHEMAS),
        ("tf", TF_SCHEMAS),
        ("odometry", ODOM_SCHEMAS),
        ("pose", POSE_SCHEMAS),
        ("imu", IMU_SCHEMAS),
        ("landmarks", LANDMARK_SCHEMAS),
    ):
        if schema in schemas:
            return kind
    return "other"
