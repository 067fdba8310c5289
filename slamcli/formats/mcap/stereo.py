"""Stereo pairs from the image topics of a log (MCAP, ROS 1 bag, ROS 2 bag).

Which topics: ``--left-topic`` and ``--right-topic``; with one of them, the topic named like it
with left/right, cam0/cam1, infra1/infra2 or fisheye1/fisheye2 swapped; with neither, the one
pair of image topics named so (``/zed/left/image_rect_color`` + ``/zed/right/image_rect_color``,
``/cam0/image_raw`` + ``/cam1/image_raw``, ``/camera/infra1/image_rect_raw`` +
``/camera/infra2/image_rect_raw``). Several such pairs, or none, stop with a
:class:`~slamcli.errors.TopicNotFoundError` naming the pairs and the options.

Pairing: left and right images by header stamp, greedy one to one, nearest first (TUM's
``associate.py`` rule), within half the left stream's frame period; settled while streaming as
colour and depth are (:class:`~slamcli.formats.mcap.ordering.StreamPairer`). A left image
without a right one within that is skipped, logged and counted in the source's
:class:`~slamcli.formats.base.ReadStats`, so a run that loses pairs exits with code 3.

Calibration: each camera's ``camera_info`` topic beside its image topic, rectified as
:mod:`slamcli.formats.mcap.stereo_calibration` describes. IMU readings read with the pairs
come out merged with them in stamp order (IMU first at equal stamps), as the EuRoC folder
source gives them.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable, Collection, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from slamcli.errors import InputError, TopicNotFoundError
from slamcli.formats.base import ReadStats, StreamInfo
from slamcli.formats.euroc.kalibr import KalibrCalibration
from slamcli.formats.mcap.decode import decoder_for
from slamcli.formats.mcap.mounting import TfIndex
from slamcli.formats.mcap.ordering import FORCE_FLUSH, ORDER_BUFFER, StreamPairer
from slamcli.formats.mcap.reader import MessageLog
from slamcli.formats.mcap.records import ImageRecord, PoseRecord
from slamcli.formats.mcap.stereo_calibration import (
    CameraInfo,
    StereoCalibration,
    body_from_camera,
    calibrate_stereo,
    read_camera_info,
)
from slamcli.formats.mcap.topics import (
    CAMERA_SCHEMAS,
    IMAGE_SCHEMAS,
    TopicChooser,
    rate,
    sibling_camera_topic,
)
from slamcli.formats.pairing import associate_stamps
from slamcli.types import ImuFrame, PinholeCamera, StereoFrame

log = logging.getLogger(__name__)

STEREO_WORDS = (("left", "right"), ("cam0", "cam1"), ("infra1", "infra2"), ("fisheye1", "fisheye2"))
"""The words that tell the left camera's topic from the right one's (as whole path words)."""

BODY_FRAMES = ("base_link", "base_footprint")
"""Body frames tried in tf, in this order, after the child frame of an odometry topic."""

_FLAGS = "--left-topic and --right-topic"


@dataclass(frozen=True)
class StereoTopics:
    """The left and right image topics, and how they were chosen (for ``info``)."""

    left: str
    right: str
    how: str


@dataclass(frozen=True)
class StereoSetup:
    """Everything reading the pairs of a log needs, found once.

    Attributes:
        topics: the image topics.
        calibration: the rectification and the rig.
        max_dt_ns: pairing tolerance, half the left stream's frame period.
    """

    topics: StereoTopics
    calibration: StereoCalibration
    max_dt_ns: int


def stereo_pairs(topics: Iterable[str]) -> list[tuple[str, str]]:
    """(left, right) of the topics named alike but for a word of :data:`STEREO_WORDS`."""
    by_lower = {t.lower(): t for t in topics}
    out: list[tuple[str, str]] = []
    for low, topic in sorted(by_lower.items()):
        for left, right in STEREO_WORDS:
            for m in re.finditer(rf"(?<![a-z0-9]){left}(?![a-z0-9])", low):
                other = by_lower.get(low[: m.start()] + right + low[m.end() :])
                if other is not None and (topic, other) not in out:
                    out.append((topic, other))
    return out


def choose_stereo_topics(
    path: Path, chooser: TopicChooser, left: str | None, right: str | None
) -> StereoTopics:
    """The pair's topics (see the module docstring).

    Raises:
        TopicNotFoundError: a named topic is missing or not an image topic; none or several
            pairs fit (the table lists the image topics).
    """
    images = [t for t in chooser.of(IMAGE_SCHEMAS) if chooser.image_role(t) != "depth"]
    rows = [chooser.candidate_row(t) for t in images]
    for flag, wanted in (("--left-topic", left), ("--right-topic", right)):
        if wanted is not None and wanted not in chooser.channels:
            raise TopicNotFoundError(
                f"{path}: no topic {wanted} ({flag})",
                hint="the table lists the image topics",
                candidates=rows,
            )
        if wanted is not None and chooser.schema[wanted] not in IMAGE_SCHEMAS:
            raise TopicNotFoundError(
                f"{path}: {flag} {wanted} has type {chooser.channels[wanted].schema_name}, not "
                "an image type",
                candidates=rows,
            )
    if left is not None and right is not None:
        return StereoTopics(left, right, f"given by {_FLAGS}")
    pairs = stereo_pairs(images)
    if left is not None:
        pairs, how = [p for p in pairs if p[0] == left], "named like --left-topic"
    elif right is not None:
        pairs, how = [p for p in pairs if p[1] == right], "named like --right-topic"
    else:
        how = "the only left/right pair of image topics"
    if len(pairs) == 1:
        return StereoTopics(pairs[0][0], pairs[0][1], how)
    found = "; ".join(f"{a} + {b}" for a, b in pairs)
    if pairs:
        what = f"{len(pairs)} stereo pairs of image topics ({found})"
    elif left is not None or right is not None:
        what = f"no image topic named like {left or right} with left/right or cam0/cam1 swapped"
    else:
        what = "no stereo pair of image topics (named like left/right, cam0/cam1 or infra1/infra2)"
    raise TopicNotFoundError(
        f"{path}: {what} found; choose one with {_FLAGS}",
        hint="the table lists the image topics",
        candidates=rows,
    )


def open_stereo(
    path: Path,
    chooser: TopicChooser,
    want: dict[str, str | None],
    message_log: MessageLog,
    first_readable: Callable[[str], Any],
    transforms: Callable[[], Iterable[Any]],
    fallback_dt_ns: int,
    calib: KalibrCalibration | None = None,
) -> StereoSetup:
    """Choose the topics, read both calibrations and tf, and set the pairing tolerance.

    With a Kalibr camera chain (``calib``) the pair is rectified from it, not from the log's
    CameraInfo: on the IMU when the chain places it, else with the left camera where tf puts
    it on the body.

    Args:
        path: the log, for messages.
        chooser: the log's topics.
        want: role -> topic named by a flag (``left``, ``right``).
        message_log: the log's messages.
        first_readable: the first decodable record of a topic (odometry child frames).
        transforms: the log's transform records.
        fallback_dt_ns: pairing tolerance when the left stream's rate is unknown.

    Raises:
        TopicNotFoundError: no pair, several, or a camera without its CameraInfo.
        InputError: a calibration that cannot rectify the pair (see
            :func:`~slamcli.formats.mcap.stereo_calibration.calibrate_stereo`).
    """
    topics = choose_stereo_topics(path, chooser, want.get("left"), want.get("right"))
    if calib is not None and calib.cameras:
        if calib.camera_topics[:2] == (topics.left, topics.right):
            topics = StereoTopics(topics.left, topics.right, f"the rostopic of {calib.chain_path}")
        index = TfIndex.read(transforms())
        body = body_frame(index.frames(), _odometry_children(chooser, first_readable))
        first = first_readable(topics.left)
        frame = first.frame_id if isinstance(first, ImageRecord) else ""
        body_from_cam, found = body_from_camera(index.buffer, body, frame)
        placed = calib.imu_placed or not found
        rectified = calib.stereo(None if placed else body_from_cam)
        c = rectified.rig.camera
        calibration = StereoCalibration(
            rectified.rig,
            rectified,
            f"rectified by stereoRectify from {calib.chain_path} (--calib, "
            f"{calib.cameras[0].model})",
            (c.width, c.height),
            "" if placed else found,
        )
        tolerance = pairing_tolerance_ns(message_log, chooser, topics.left, fallback_dt_ns)
        return StereoSetup(topics, calibration, tolerance)
    left = _camera_info(path, chooser, message_log, topics.left, None)
    right = _camera_info(path, chooser, message_log, topics.right, left.topic)
    index = TfIndex.read(transforms())
    body = body_frame(index.frames(), _odometry_children(chooser, first_readable))
    named_rect = all(
        any(part.startswith("image_rect") for part in t.split("/"))
        for t in (topics.left, topics.right)
    )
    calibration = calibrate_stereo(path, (left, right), index.buffer, body, named_rect)
    tolerance = pairing_tolerance_ns(message_log, chooser, topics.left, fallback_dt_ns)
    return StereoSetup(topics, calibration, tolerance)


def _camera_info(
    path: Path, chooser: TopicChooser, message_log: MessageLog, image: str, taken: str | None
) -> CameraInfo:
    """The first CameraInfo beside ``image`` (not ``taken``, the other camera's)."""
    cameras = chooser.of(CAMERA_SCHEMAS)
    topic = sibling_camera_topic(image, cameras)
    expected = image.rsplit("/", 1)[0] + "/camera_info"
    problem = "no CameraInfo"
    if topic is not None and topic != taken:
        for raw in message_log.messages([topic]):
            return read_camera_info(decoder_for(raw.channel)(raw.data), topic)
        expected, problem = topic, "no CameraInfo message"
    raise TopicNotFoundError(
        f"{path}: {expected}: {problem} for {image}; a stereo pair needs both cameras' calibration",
        hint="record each camera's camera_info beside its image topic; the table lists the "
        "calibration topics",
        candidates=[chooser.candidate_row(t) for t in cameras],
    )


def _odometry_children(chooser: TopicChooser, first_readable: Callable[[str], Any]) -> list[str]:
    """The child frames of the log's odometry topics, the ground-truth topic's first."""
    reference = chooser.chosen.get("groundtruth")
    topics = sorted(chooser.of({"nav_msgs/msg/Odometry"}), key=lambda t: t != reference)
    out = []
    for topic in topics:
        try:
            rec = first_readable(topic)
        except InputError:
            continue
        if isinstance(rec, PoseRecord) and rec.child_frame_id:
            out.append(rec.child_frame_id.lstrip("/"))
    return out


def body_frame(frames: Collection[str], children: Iterable[str]) -> str | None:
    """The body in tf: an odometry child frame, else one of :data:`BODY_FRAMES`; None when
    tf has none of them."""
    for name in (*children, *BODY_FRAMES):
        if name in frames:
            return name
    return None


def pairing_tolerance_ns(
    message_log: MessageLog, chooser: TopicChooser, topic: str, fallback_ns: int
) -> int:
    """Half the frame period of ``topic`` (from the log's statistics), or ``fallback_ns``."""
    st = message_log.stats().get(chooser.channels[topic].id)
    hz = rate(st.count, st.first_ns, st.last_ns) if st else None
    return round(0.5e9 / hz) if hz else fallback_ns


class StereoStream:
    """Left and right images into rectified :class:`StereoFrame` s, IMU readings merged in.

    Feed records in log-time order with :meth:`add` / :meth:`add_imu`; each returns the frames
    that are settled, in stamp order; :meth:`finish` returns the rest.

    Args:
        path: the log, for messages.
        setup: topics, calibration and tolerance.
        stats: where frames read and pairs skipped are counted.
        stamps: the left stamp of every frame yielded is appended here.
    """

    def __init__(self, path: Path, setup: StereoSetup, stats: ReadStats, stamps: list[int]) -> None:
        self.path = path
        self.setup = setup
        self.stats = stats
        self.stamps = stamps
        self.pairer = StreamPairer(setup.max_dt_ns, 0)
        self.imu: list[ImuFrame] = []
        self.newest_left: int | None = None

    def add(self, role: str, rec: ImageRecord) -> list[StereoFrame | ImuFrame]:
        """Take an image of the ``left`` or ``right`` topic."""
        topic = self.setup.topics.left if role == "left" else self.setup.topics.right
        if rec.kind == "depth":
            raise InputError(
                f"{self.path}: {topic} holds depth images ({rec.encoding}), not a camera's",
                hint=f"choose the pair's grey or colour image topics with {_FLAGS}",
            )
        if role == "left":
            self.pairer.add("rgb", rec)
            newest = self.newest_left
            self.newest_left = rec.stamp_ns if newest is None else max(newest, rec.stamp_ns)
        else:
            self.pairer.add("depth", rec)
        return self._settle(final=False)

    def add_imu(self, frame: ImuFrame) -> list[StereoFrame | ImuFrame]:
        """Take an IMU reading; it comes out once no pair stamped before it can follow."""
        self.imu.append(frame)
        return self._settle(final=False)

    def finish(self) -> list[StereoFrame | ImuFrame]:
        """Every frame still held."""
        return self._settle(final=True)

    def _settle(self, final: bool) -> list[StereoFrame | ImuFrame]:
        lefts, rights = self.pairer.buf["rgb"], self.pairer.buf["depth"]
        dropped = []
        if not final and not rights and len(lefts) > FORCE_FLUSH:
            dropped, lefts[:] = lefts[:-FORCE_FLUSH], lefts[-FORCE_FLUSH:]
        if not final and not lefts and len(rights) > FORCE_FLUSH:
            del rights[:-FORCE_FLUSH]
        before = list(lefts)
        pairs = self.pairer.ready(final)
        paired = {id(a) for a, _ in pairs}
        removed = before[: len(before) - len(self.pairer.buf["rgb"])]
        for rec in dropped + [r for r in removed if id(r) not in paired]:
            self._skip(rec)
        ready: list[tuple[int, int, StereoFrame | ImuFrame]] = []
        for a, b in pairs:
            pair = self._frame(a, b)
            if pair is not None:
                ready.append((pair.stamp_ns, 1, pair))
        held = self.pairer.buf["rgb"]
        if final:
            horizon = None
        elif held:
            horizon = min(r.stamp_ns for r in held)
        else:
            horizon = self.newest_left + 1 if self.newest_left is not None else None
        keep = []
        for imu in self.imu:
            if final or (horizon is not None and imu.stamp_ns < horizon):
                ready.append((imu.stamp_ns, 0, imu))
            else:
                keep.append(imu)
        if len(keep) > ORDER_BUFFER:
            ready.extend((imu.stamp_ns, 0, imu) for imu in keep[:-ORDER_BUFFER])
            keep = keep[-ORDER_BUFFER:]
        self.imu = keep
        ready.sort(key=lambda item: (item[0], item[1]))
        out = [frame for _, _, frame in ready]
        for frame in out:
            if isinstance(frame, StereoFrame):
                self.stats.read += 1
                self.stamps.append(frame.stamp_ns)
        return out

    def _skip(self, rec: ImageRecord) -> None:
        name = f"{self.setup.topics.left}@{rec.stamp_ns}"
        log.warning(
            "skipping the left image %s: no image of %s within %.1f ms",
            name,
            self.setup.topics.right,
            self.setup.max_dt_ns * 1e-6,
        )
        self.stats.skipped += 1
        self.stats.skipped_names.append(name)

    def _frame(self, left: ImageRecord, right: ImageRecord) -> StereoFrame | None:
        topics = self.setup.topics
        calibration = self.setup.calibration
        a, b = left.array, right.array
        sizes = [(x.shape[1], x.shape[0]) for x in (a, b)]
        if sizes[0] != sizes[1]:
            raise InputError(
                f"{self.path}: {topics.left} images are {_size(sizes[0])} but {topics.right} "
                f"images {_size(sizes[1])}; a stereo pair needs two images of one size",
                hint=f"check {_FLAGS} name the two cameras of one pair",
            )
        if sizes[0] != calibration.size:
            raise InputError(
                f"{self.path}: {topics.left} images are {_size(sizes[0])} but their CameraInfo "
                f"is calibrated for {_size(calibration.size)}",
                hint="the calibration must be of the images recorded (binning, ROI or a "
                "resized stream change it)",
            )
        if a.ndim != b.ndim:
            log.warning(
                "skipping the stereo pair %s@%d: one image is grey, the other colour",
                topics.left,
                left.stamp_ns,
            )
            self._skip(left)
            return None
        a, b = calibration.rectify(a, b)
        return StereoFrame(
            left.stamp_ns,
            a,
            b,
            calibration.rig,
            right.stamp_ns,
            f"{topics.left}@{left.stamp_ns}",
        )


def _count_read(frames: Callable[[], Iterable[Any]], stats: ReadStats) -> tuple[int, int]:
    """(pairs read, images skipped) by reading every pair."""
    skipped = stats.skipped
    pairs = sum(isinstance(frame, StereoFrame) for frame in frames())
    return pairs, stats.skipped - skipped


def _size(size: tuple[int, int]) -> str:
    return f"{size[0]}x{size[1]}"


@dataclass
class StereoSummary:
    """What ``info`` reports of a log's stereo pairs.

    Attributes:
        stream: the ``stereo`` stream (pairs, rate, span, the topics and how they were
            chosen); None when the log has no pair of image topics.
        details: topics, baseline, image size, unpaired left images, ...
        problems: one line each.
        camera: the rectified camera, with where it came from.
    """

    stream: StreamInfo | None = None
    details: dict[str, Any] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)
    camera: PinholeCamera | None = None
    camera_source: str = ""


def stereo_info(
    path: Path,
    chooser: TopicChooser,
    options: tuple[dict[str, str | None], int],
    message_log: MessageLog,
    setup: Callable[[], StereoSetup],
    reader: tuple[Callable[[], Iterable[Any]], ReadStats] | None,
) -> StereoSummary:
    """The stereo pairs of a log for ``info``: counted by log time, or, given ``reader`` (the
    source's frames of kind ``stereo`` and the stats it counts in), by reading every pair
    (header stamps).

    Args:
        path: the log, for messages.
        chooser: the log's topics.
        options: role -> topic named by a flag (``left``, ``right``), and the pairing
            tolerance when the left stream's rate is unknown (ns).
        message_log: the log's messages.
        setup: the source's stereo setup (:func:`open_stereo`), found once.
        reader: read every pair to count them.

    Errors of the choice and the calibration become problems; a log without any pair of
    image topics (and no flag naming one) has no stereo summary.
    """
    want, fallback_dt_ns = options
    out = StereoSummary()
    flagged = want.get("left") is not None or want.get("right") is not None
    images = [t for t in chooser.of(IMAGE_SCHEMAS) if chooser.image_role(t) != "depth"]
    if not flagged and not stereo_pairs(images):
        return out
    try:
        topics = choose_stereo_topics(path, chooser, want.get("left"), want.get("right"))
    except TopicNotFoundError as exc:
        out.problems.append(f"no stereo pairs: {exc.msg}")
        return out
    max_dt = pairing_tolerance_ns(message_log, chooser, topics.left, fallback_dt_ns)
    out.details.update(
        left_topic=topics.left,
        right_topic=topics.right,
        stereo_topics_chosen=topics.how,
        stereo_max_dt_s=max_dt * 1e-9,
    )
    try:
        s = setup()
        topics = s.topics  # how they were chosen, as the run reads them
        out.details["stereo_topics_chosen"] = topics.how
        rig = s.calibration.rig
        out.camera, out.camera_source = rig.camera, s.calibration.method
        out.details.update(
            baseline_m=rig.baseline_m,
            image_size=list(s.calibration.size),
            body_frame=s.calibration.body_frame or None,
            body_from_left=rig.body_from_left.tolist(),
        )
    except InputError as exc:
        out.problems.append(f"stereo calibration: {exc.msg}")
    left_times = [r.log_time_ns for r in message_log.messages([topics.left])]
    if reader is not None and out.camera is not None:
        pairs, unpaired = _count_read(*reader)
    else:
        right_times = [r.log_time_ns for r in message_log.messages([topics.right])]
        pairs = len(associate_stamps(left_times, right_times, max_dt)[0])
        unpaired = len(left_times) - pairs
    out.details["unpaired_left"] = unpaired
    if unpaired:
        out.problems.append(
            f"{unpaired} left image(s) of {topics.left} have no image of {topics.right} within "
            f"{max_dt * 1e-6:.1f} ms; reading skips them"
        )
    st = np.asarray(left_times, dtype=np.int64)
    out.stream = StreamInfo(
        "stereo",
        "stereo",
        pairs,
        rate(st.size, int(st.min()), int(st.max())) if st.size else None,
        float(st.min()) * 1e-9 if st.size else None,
        float(st.max()) * 1e-9 if st.size else None,
        f"{topics.left} + {topics.right} ({topics.how})",
    )
    return out


__all__ = [
    "BODY_FRAMES",
    "STEREO_WORDS",
    "StereoSetup",
    "StereoStream",
    "StereoSummary",
    "StereoTopics",
    "body_frame",
    "choose_stereo_topics",
    "open_stereo",
    "pairing_tolerance_ns",
    "stereo_info",
    "stereo_pairs",
]
