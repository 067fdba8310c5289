"""MCAP logs as a :class:`~slamcli.formats.base.Source`: topic selection, sync, ground truth.

Topics are chosen per role (colour, depth, camera, odometry, landmarks, scans, ground truth,
IMU): a flag names one, otherwise the one topic of the right type is taken; with none or several the
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
:data:`~slamcli.formats.mcap.ordering.ORDER_BUFFER` frames wait).

Laser scans (``sensor_msgs/msg/LaserScan``, ROS 1 or 2, and ``foxglove.LaserScan``) join that
order, after odometry at equal stamps. A scan whose ranges do not fit its angles, or whose angle
increment is zero, is skipped and counted like an undecodable message (the warning names the
topic and the message's index in it). Each scan's mounting on the body comes from tf
(:mod:`slamcli.formats.mcap.mounting`): the scan's ``header.frame_id`` looked up in
``/tf_static`` and ``/tf`` against the body, which is the odometry's ``child_frame_id`` (else
the body tf moves, else ``base_footprint`` or ``base_link``; a log with none of these and no
odometry has the scanner for its body); without such a transform the mounting is zero, with a
warning, and ``info`` says so. With scans asked for and no odometry topic in the log,
odometry comes from tf: the moving transform nearest above the scan's frame (usually ``odom ->
base_link``), as poses without velocities.

Stereo pairs (``--left-topic``, ``--right-topic``, or the one pair of image topics named like
left/right or cam0/cam1) are paired by header stamp within half a frame period and rectified
from each camera's ``camera_info`` (and tf): see :mod:`slamcli.formats.mcap.stereo`.

Ground truth comes from a pose topic (``--gt-topic``) or from tf (``--gt-frame``: the pose of
that frame in the root of its tree). Before any frame has been read, :meth:`groundtruth` returns
the poses as recorded. After frames have been read it is interpolated (SLERP) to the stamps of
the frames read, so that it pairs one to one with an estimate made from them: the colour stamps
when images were read; the scan stamps when scans were; otherwise (e.g. odometry and landmarks
for the EKF) the odometry and landmark stamps. Stamps outside the ground truth's time span are
left out. With ground truth, :meth:`start_pose` is its planar pose at the first odometry,
landmark or scan stamp, for pipelines that start there instead of at the origin.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Collection, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError, InputError, TopicNotFoundError
from slamcli.formats import sniff
from slamcli.formats.base import Frame, ReadStats, SourceBase, SourceInfo
from slamcli.formats.euroc.calibration import EQUIDISTANT
from slamcli.formats.euroc.kalibr import KalibrCalibration, read_kalibr
from slamcli.formats.mcap.adapters import Adapter, adapter_for, is_static_tf_topic
from slamcli.formats.mcap.decode import DecodeError, decoder_for
from slamcli.formats.mcap.mounting import ScanMounter
from slamcli.formats.mcap.ordering import MOTION_RANK, MotionFrame, StampOrder, StreamPairer
from slamcli.formats.mcap.reader import DEFAULT_MAX_CHUNK_BYTES, McapLog, MessageLog
from slamcli.formats.mcap.records import (
    CameraInfoRecord,
    ChannelInfo,
    ImageRecord,
    PoseRecord,
    ScanRecord,
    TransformRecord,
    TwistRecord,
)
from slamcli.formats.mcap.stereo import (
    StereoSetup,
    StereoStream,
    StereoSummary,
    open_stereo,
    stereo_info,
)
from slamcli.formats.mcap.tf import moving_frame_poses
from slamcli.formats.mcap.topics import (
    IMAGE_SCHEMAS,
    LANDMARK_SCHEMAS,
    SCAN_SCHEMAS,
    TF_SCHEMAS,
    TOPIC_OPTIONS,
    TopicChooser,
)
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
    ScanFrame,
    StereoFrame,
    Trajectory,
)

log = logging.getLogger(__name__)


FRAME_KINDS = ("rgbd", "image", "odometry", "landmarks", "imu", "scan", "stereo")

_StreamPairer = StreamPairer
"""The pairer under the name tests import it by."""
START_POSE_MAX_WAIT_S = 30.0
"""``start_pose`` takes the first ground-truth pose if it is at most this late (the robot has
barely moved in a log's first seconds); as :mod:`slamcli.formats.landmarks` does."""


class McapSource(SourceBase):
    """An MCAP log as a :class:`~slamcli.formats.base.Source`.

    Args:
        path: the ``.mcap`` file.
        rgb_topic, depth_topic, camera_info_topic, odom_topic, landmark_topic, scan_topic,
            gt_topic, left_topic, right_topic: topic choices; None picks the one topic (the
            one stereo pair) of the right type when it is needed.
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
        *("max_dt", "dt_offset", "camera", "fx", "fy", "cx", "cy", "strict", "max_chunk_mb"),
        *TOPIC_OPTIONS,
        "calib",
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
        scan_topic: str | None = None,
        gt_topic: str | None = None,
        gt_frame: str | None = None,
        left_topic: str | None = None,
        right_topic: str | None = None,
        max_chunk_bytes: int = DEFAULT_MAX_CHUNK_BYTES,
        calib: Collection[str | Path] | None = None,
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
            "scan": scan_topic,
            "groundtruth": gt_topic,
            "left": left_topic,
            "right": right_topic,
        }
        self.gt_frame = gt_frame
        self.stats = ReadStats()
        self.log: MessageLog = self._open_log(max_chunk_bytes)
        self._channels = {c.topic: c for c in self.log.channels().values()}
        self._probes: dict[str, ImageRecord | None] = {}
        self._topics = TopicChooser(
            self.path, self._channels, self._want, self.log.stats, self._probe
        )
        self._schema = self._topics.schema
        self._mounter: ScanMounter | None = None
        self._camera: tuple[PinholeCamera, str] | None = None
        self._stereo: StereoSetup | None = None
        self._frame_stamps: list[int] = []
        self._images_read: list[int] = []
        self._motion_stamps: list[int] = []
        self._decoders: dict[str, tuple[Callable[[bytes], Any], Adapter]] = {}
        self.calib = read_kalibr(tuple(calib)) if calib else None
        """The Kalibr files given with ``--calib``: the cameras (and their topics), the IMU's
        noise (and its topic) and the images' time shift, in place of the log's own."""
        if self.calib is not None:
            self._calib_topics(self.calib)

    def _calib_topics(self, calib: KalibrCalibration) -> None:
        """The topics a Kalibr file names (``rostopic``) stand in for flags not given, where the
        log has them."""
        cams = calib.camera_topics
        named = {
            "left": cams[0] if cams else "",
            "rgb": cams[0] if cams else "",
            "right": cams[1] if len(cams) > 1 else "",
            "imu": calib.imu_topic,
        }
        for role, topic in named.items():
            if topic and self._want.get(role) is None and topic in self._channels:
                self._want[role] = topic

    @classmethod
    def sniff(cls, path: str | Path) -> bool:
        """A ``.mcap`` file, or any file starting with the MCAP magic."""
        return sniff.mcap(path)

    def close(self) -> None:
        self.log.close()

    def _open_log(self, max_chunk_bytes: int) -> MessageLog:
        """The reader of the log's messages (the ROS bag sources read theirs otherwise)."""
        return McapLog(self.path, strict=self.strict, max_chunk_bytes=max_chunk_bytes)

    # -- topics ------------------------------------------------------------------------------

    def _topics_of(self, schemas: Collection[str]) -> list[str]:
        return self._topics.of(schemas)

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

    def topic(self, role: str, required: bool = True) -> str | None:
        """The topic used for ``role`` (rgb, depth, camera, odometry, landmarks, scan,
        groundtruth, imu).

        Without a fitting topic, ``required`` raises TopicNotFoundError listing the candidates,
        even after an optional look-up (``start_pose``, ``info``) found none.
        """
        return self._topics.choose(role, required)

    # -- camera --------------------------------------------------------------------------------

    def camera(self) -> tuple[PinholeCamera, str]:
        """The colour camera and a description of where it came from."""
        if self._camera is not None:
            return self._camera
        if self.calib is not None and self.calib.cameras:
            cam0 = self.calib.cameras[0]
            if cam0.model == EQUIDISTANT:
                raise InputError(
                    f"{self.calib.chain_path}: cam0 is an equidistant (fisheye) camera; single "
                    "images from a log are read with radtan calibrations only",
                    hint="run the log as a stereo pair, or convert it to an ASL folder",
                )
            self._camera = (cam0.camera, f"{cam0.path} cam0 (--calib)")
            return self._camera
        options_given = any(v is not None for v in self._camera_options)
        found = self._topics.camera_topic(str(self.topic("rgb")), options_given, self._first_record)
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

    def _first_readable(self, topic: str) -> Any:
        """The first record of ``topic`` that decodes (None: none does). A probe: unreadable
        messages are passed over here and counted when frames are read."""
        for raw in self.log.messages([topic]):
            try:
                return self._adapt(raw.channel, raw.data, raw.log_time_ns)
            except DecodeError:
                if topic not in self._decoders:
                    raise
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
        index: dict[str, int] = {}
        for raw in self.log.messages(list(topics)):
            n = index[raw.channel.topic] = index.get(raw.channel.topic, -1) + 1
            try:
                rec = self._adapt(raw.channel, raw.data, raw.log_time_ns)
            except DecodeError as exc:
                if raw.channel.topic not in self._decoders:
                    raise  # the channel cannot be decoded at all: its error names the channel
                where = (
                    f"message {n} of {raw.channel.topic}, log time "
                    f"{format_stamp(raw.log_time_ns)} s, sequence {raw.sequence}"
                )
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
        """Frames of the given kinds (rgbd, image, odometry, landmarks, imu, scan, stereo) in
        time order.

        Odometry, landmark and scan frames come in the order of their stamps, in that order at
        equal stamps (see the module docstring); images and IMU readings in log-time order;
        stereo pairs and IMU readings read with them in stamp order (IMU first at equal stamps).
        A Kalibr chain's ``timeshift_cam_imu`` is added to the images' stamps (Kalibr: ``t_imu
        = t_cam + shift``), which puts them on the IMU's clock.
        """
        shift = self.calib.time_shift_ns if self.calib is not None else 0
        if not shift:
            yield from self._frames(kinds)
            return
        for frame in self._frames(kinds):
            if isinstance(frame, StereoFrame):
                stamps = {"stamp_ns": frame.stamp_ns + shift}
                if frame.right_stamp_ns is not None:
                    stamps["right_stamp_ns"] = frame.right_stamp_ns + shift
                yield replace(frame, **stamps)
            elif isinstance(frame, ImageFrame | RgbdFrame):
                yield replace(frame, stamp_ns=frame.stamp_ns + shift)
            else:
                yield frame
        # The ground truth is interpolated to the stamps the frames were given.
        self._frame_stamps = [t + shift for t in self._frame_stamps]

    def _frames(self, kinds: Collection[str]) -> Iterator[Frame]:
        unknown = set(kinds) - set(FRAME_KINDS)
        if unknown:
            raise ConfigError(
                f"{self.format_name} sources do not provide {', '.join(sorted(unknown))} frames"
            )
        roles: dict[str, str] = {}
        if "rgbd" in kinds or "image" in kinds:
            roles[str(self.topic("rgb"))] = "rgb"
        if "rgbd" in kinds:
            roles[str(self.topic("depth"))] = "depth"
        if "odometry" in kinds:
            # With scans, tf may stand in for a missing odometry topic.
            odometry = self.topic("odometry", required="scan" not in kinds)
            if odometry is not None:
                roles[odometry] = "odometry"
        if "landmarks" in kinds:
            roles[str(self.topic("landmarks"))] = "landmarks"
        if "imu" in kinds:
            roles[str(self.topic("imu"))] = "imu"
        stereo = None
        if "stereo" in kinds:
            setup = self._stereo_setup()
            roles.update({setup.topics.left: "left", setup.topics.right: "right"})
        scans = None
        if "scan" in kinds:
            roles[str(self.topic("scan"))] = "scan"
            scans = self._scans()
            if "odometry" in kinds and "odometry" not in roles.values():
                if scans.edge is None:
                    self.topic("odometry")  # raises: no odometry topic, and none in tf either
                dynamic = [t for t in self._topics_of(TF_SCHEMAS) if not is_static_tf_topic(t)]
                roles.update(dict.fromkeys(dynamic, "tf odometry"))
        camera = self.camera()[0] if ("rgbd" in kinds or "image" in kinds) else None
        pairer = StreamPairer(self.max_dt_ns, self.dt_offset_ns) if "rgbd" in kinds else None
        streams = {"odometry" if r == "tf odometry" else r for r in roles.values()}
        order = StampOrder(sorted(streams & MOTION_RANK.keys()))
        # Odometry and landmarks are what is read when there are no images (the EKF): count them.
        count_motion = camera is None
        self._frame_stamps = []
        self._motion_stamps = []
        if "stereo" in kinds:
            stereo = StereoStream(self.path, self._stereo_setup(), self.stats, self._frame_stamps)
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
            elif role == "scan" and isinstance(rec, ScanRecord) and scans is not None:
                yield from self._motion(order.add(role, scans.mount(rec)), count_motion)
            elif role == "tf odometry" and isinstance(rec, TransformRecord) and scans is not None:
                for odo in scans.odometry(rec):
                    yield from self._motion(order.add("odometry", odo), count_motion)
            elif role == "imu" and isinstance(rec, ImuFrame):
                yield from stereo.add_imu(rec) if stereo is not None else (rec,)
            elif role in ("left", "right") and isinstance(rec, ImageRecord) and stereo is not None:
                yield from stereo.add(role, rec)
        yield from stereo.finish() if stereo is not None else ()
        yield from self._motion(order.flush(), count_motion)
        if pairer is not None and camera is not None:
            yield from self._emit(pairer.ready(final=True), camera)

    def _motion(self, frames: list[MotionFrame], count: bool) -> Iterator[MotionFrame]:
        for frame in frames:
            self._motion_stamps.append(frame.stamp_ns)
            if isinstance(frame, ScanFrame):
                self._frame_stamps.append(frame.stamp_ns)
            if count:
                self.stats.read += 1
            yield frame

    def _stereo_setup(self) -> StereoSetup:
        """The stereo topics, calibration and pairing tolerance, found once."""
        if self._stereo is None:
            self._stereo = open_stereo(
                self.path,
                self._topics,
                self._want,
                self.log,
                self._first_readable,
                lambda: (rec for _, rec in self._records(self._topics_of(TF_SCHEMAS))),
                self.max_dt_ns,
                self.calib,
            )
        return self._stereo

    # -- scans ---------------------------------------------------------------------------------

    def _scans(self) -> ScanMounter:
        """What puts the scans on the body (see the module docstring), set up once."""
        if self._mounter is None:
            first = self._first_readable(str(self.topic("scan")))
            try:
                odometry = self.topic("odometry", required=False)
            except TopicNotFoundError:
                odometry = None  # several: the body comes from tf unless odometry is read
            rec = self._first_readable(odometry) if odometry is not None else None
            self._mounter = ScanMounter(
                self.path,
                (rec for _, rec in self._records(self._topics_of(TF_SCHEMAS))),
                first.frame_id if isinstance(first, ScanRecord) else None,
                odometry is not None,
                rec.child_frame_id if isinstance(rec, PoseRecord) else "",
            )
        return self._mounter

    def _image_frame(self, rec: ImageRecord, camera: PinholeCamera | None) -> ImageFrame:
        self.stats.read += 1
        self._frame_stamps.append(rec.stamp_ns)
        mounted = self._calib_camera_on_body()
        return ImageFrame(
            rec.stamp_ns,
            rec.array,
            camera,
            name=f"{rec.frame_id}@{rec.stamp_ns}",
            body_from_camera=mounted,
        )

    def _calib_camera_on_body(self) -> NDArray[np.float64] | None:
        """``cam0`` of a Kalibr chain that places the IMU, on the body (the IMU); None
        otherwise (the camera is the body of single images, as without ``--calib``)."""
        if self.calib is None or not self.calib.cameras or not self.calib.imu_placed:
            return None
        return self.calib.cameras[0].body_from_sensor

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

        The colour stamps when images were read, the scan stamps when scans were, else the
        odometry and landmark stamps; the poses as recorded when no frame has been read (see the
        module docstring).
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

        The first frame is the earliest odometry, landmark or scan frame: of the frames already
        read, else of the first readable message of each topic. The ground truth is interpolated
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
        for role in ("odometry", "landmarks", "scan"):
            try:
                topic = self.topic(role, required=False)
            except TopicNotFoundError:
                if role != "scan":
                    raise
                continue  # several scan topics: a pipeline reading scans names one
            rec = self._first_readable(topic) if topic is not None else None
            if isinstance(rec, PoseRecord | TwistRecord | LandmarkFrame | ScanRecord):
                firsts.append(rec.stamp_ns)
        return min(firsts) if firsts else None

    def _groundtruth_samples(self) -> Trajectory | None:
        if self.gt_frame is not None:
            return self._tf_groundtruth(self.gt_frame)
        topic = self._topics.reference(required=self._want["groundtruth"] is not None)
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
        stats = self.log.stats()
        streams, undecodable = self._topics.streams(self._first_readable)
        problems: list[str] = []
        stereo = self._stereo_info(deep)
        frames = stereo.stream.count if stereo.stream is not None else 0
        camera, camera_source = stereo.camera, stereo.camera_source
        details: dict[str, Any] = {"undecodable": undecodable, **stereo.details}
        streams.extend([stereo.stream] if stereo.stream is not None else [])
        problems.extend(stereo.problems)
        try:
            rgb, depth = self.topic("rgb"), self.topic("depth")
            camera, camera_source = self.camera()
            details["rgb_topic"], details["depth_topic"] = rgb, depth
            frames = self._count_pairs(deep, progress)
        except TopicNotFoundError as exc:
            if stereo.stream is None and (
                self._topics_of(IMAGE_SCHEMAS)
                or not self._topics_of(LANDMARK_SCHEMAS | SCAN_SCHEMAS)
            ):
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
        try:
            scan_details, scan_problems = self._scan_info(deep)
            details.update(scan_details)
            problems.extend(scan_problems)
        except InputError as exc:
            problems.append(f"scans: {exc.msg}")
        if self.calib is not None:
            details["calib"] = {
                "files": [str(p) for p in self.calib.paths],
                "body": "imu" if self.calib.imu_placed else "the log's",
                "time_shift_s": self.calib.time_shift_ns * 1e-9,
            }
        try:
            details.update(self._imu_settings(details.get("body_frame")))
        except InputError as exc:
            problems.append(f"imu: {exc.msg}")
        if deep:
            try:
                imu_details, imu_problems = self._imu_info()
                details.update(imu_details)
                problems.extend(imu_problems)
            except InputError as exc:
                problems.append(f"imu: {exc.msg}")
        gt_count = 0
        try:
            gt = self._groundtruth_samples()
            gt_count = len(gt) if gt is not None else 0
            if gt is not None:
                details["groundtruth_from"] = (
                    f"tf frame {self.gt_frame}"
                    if self.gt_frame
                    else self._topics.chosen["groundtruth"]
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
            format=self.format_name,
            path=str(self.path),
            streams=streams,
            frames=frames,
            groundtruth=gt_count,
            camera=camera,
            camera_source=camera_source,
            problems=problems,
            details=details,
        )

    def _imu_settings(self, body_frame: str | None) -> dict[str, Any]:
        """The IMU's noise model and mounting for a visual-inertial run (see
        :func:`~slamcli.formats.mcap.imu_topic.imu_settings`)."""
        from slamcli.formats.mcap.imu_topic import imu_settings

        topic = self.topic("imu", required=False)
        if topic is None:
            return {}

        def message_frame() -> str:
            for raw in self.log.messages([topic]):
                header = getattr(decoder_for(raw.channel)(raw.data), "header", None)
                return str(getattr(header, "frame_id", "") or "").lstrip("/")
            return ""

        metadata = dict(self._channels[topic].metadata)
        return imu_settings(
            topic, metadata, body_frame, self.calib, self._tf_body_from, message_frame
        )

    def _tf_body_from(self, body_frame: str, frame: str) -> NDArray[np.float64]:
        """(4, 4) pose of ``frame`` on the body, from tf at its first stamp.

        Raises:
            InputError: tf does not join the two frames.
        """
        from slamcli.formats.mcap.mounting import TfIndex

        index = TfIndex.read(rec for _, rec in self._records(self._topics_of(TF_SCHEMAS)))
        firsts = [e.first_ns for e in index.buffer.edges() if e.first_ns is not None]
        stamp = min(firsts) if firsts else 0
        return index.buffer.lookup(body_frame, frame, stamp)

    def _imu_info(self) -> tuple[dict[str, Any], list[str]]:
        """The IMU topic's checks (:func:`~slamcli.formats.mcap.imu_topic.check_imu_topic`),
        read in one pass over that topic alone (``info --deep``: a run opens its source with
        ``info`` and need not read the topic twice), lined up with the header stamps of the
        images ``--deep`` has read (the stereo pairs' left images, or the RGB-D pairs' colour
        ones)."""
        from slamcli.formats.mcap.imu_topic import check_imu_topic

        topic = self.topic("imu", required=False)
        if topic is None:
            return {}, []
        records = (rec for _, rec in self._records([topic]))
        return check_imu_topic(topic, records, self._images_read)

    def _scan_info(self, deep: bool) -> tuple[dict[str, Any], list[str]]:
        """Details and problems of the scans (:meth:`ScanMounter.info`); with ``deep`` every
        scan is read, so that bad ones are counted."""
        scan = self.topic("scan", required=False)
        if scan is None:
            return {}, []
        first = self._first_readable(scan)
        out = self._scans().info(scan, first, self._topics.chosen.get("odometry"))
        if deep:
            for _ in self._records([scan]):
                pass
        return out

    def _stereo_info(self, deep: bool) -> StereoSummary:
        """The stereo pairs for ``info``; with ``deep`` every pair is read."""
        reader = ((lambda: self.frames(("stereo",))), self.stats) if deep else None
        want = (self._want, self.max_dt_ns)
        out = stereo_info(self.path, self._topics, want, self.log, self._stereo_setup, reader)
        self._images_read = list(self._frame_stamps)
        self._frame_stamps = []
        return out

    def _count_pairs(self, deep: bool, progress: ProgressFn | None) -> int:
        """Paired RGB-D frames: by header stamps when ``deep``, else by log times."""
        rgb, depth = str(self.topic("rgb")), str(self.topic("depth"))
        if deep:
            n = 0
            for _ in self.frames(("rgbd",)):
                n += 1
                if progress:
                    progress(n, None)
            self._images_read = list(self._frame_stamps)
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
