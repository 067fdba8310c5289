"""Laser scans put on the body from what tf says: the scanner's mounting, and odometry from tf
where a log has no odometry topic.

A :class:`TfIndex` is read once from a log's transform records. It keeps every static
transform (``/tf_static``) and, of each moving one (``/tf``), the first sample and the name of
its parent, so its memory does not grow with the log. A mounting is the transform ``body <-
sensor`` through that tree: a mounting that is published on ``/tf`` (as ROS 1's
``static_transform_publisher`` does) is taken from its first message.

A scan is planar; its mounting becomes (x, y, yaw) of the scanner on the body. A scanner mounted
upside down (its z axis pointing down) sees its beams in mirror image: its angles are negated so
that they count counter-clockwise about the body's z axis again. A scanner tilted out of the
body's x-y plane is used as if it were level, with a warning.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import InputError
from slamcli.formats.mcap.records import PoseRecord, ScanRecord, TransformRecord
from slamcli.formats.mcap.tf import TfBuffer
from slamcli.geometry import compose, se3_to_planar
from slamcli.types import OdometryFrame, ScanFrame

log = logging.getLogger(__name__)

ODOM_FRAME_NAMES = ("odom",)
"""Parents a moving transform is taken to be odometry from, when no scan frame points to one."""
BODY_FRAME_NAMES = ("base_footprint", "base_link")
"""Body frames tried, in this order, when neither odometry nor tf names the body."""
MAX_TILT_DEG = 10.0
"""A scanner whose plane leans more than this against the body's x-y plane is warned about."""
_FLIP = np.diag([1.0, -1.0, -1.0, 1.0])
"""A half turn about x: the frame of an upside-down scanner, turned right side up."""


def _name(frame: str) -> str:
    return frame.lstrip("/")


@dataclass
class TfIndex:
    """The frames of a log's tf: static transforms, and the first sample of each moving one.

    Attributes:
        buffer: every edge, a moving one held at its first sample.
        moving: child -> parent of each edge that moves (published on ``/tf``).
    """

    buffer: TfBuffer = field(default_factory=TfBuffer)
    moving: dict[str, str] = field(default_factory=dict)

    @classmethod
    def read(cls, records: Iterable[Any]) -> TfIndex:
        """Index the transform records among ``records`` (others are passed over)."""
        index = cls()
        for rec in records:
            if not isinstance(rec, TransformRecord):
                continue
            for pose in rec.transforms:
                child = _name(pose.child_frame_id)
                if rec.static:
                    index.buffer.add_pose(pose, static=True)
                elif child not in index.moving:
                    index.moving[child] = _name(pose.frame_id)
                    index.buffer.add_pose(pose, static=True)
        return index

    def frames(self) -> dict[str, str | None]:
        """Every known frame mapped to its parent (None for a root)."""
        return self.buffer.frames()

    def odometry_edge(self, sensor_frame: str | None) -> tuple[str, str] | None:
        """(parent, child) of the moving transform that is the body's odometry, or None.

        The first moving transform above ``sensor_frame`` (the scanner rides on the body that
        odometry moves); without one, the only moving transform from a frame named ``odom``.
        """
        parents = self.frames()
        node = _name(sensor_frame) if sensor_frame else ""
        seen: set[str] = set()
        while node in parents and node not in seen:
            seen.add(node)
            if node in self.moving:
                return self.moving[node], node
            node = parents[node] or ""
        from_odom = [(p, c) for c, p in self.moving.items() if p in ODOM_FRAME_NAMES]
        return from_odom[0] if len(from_odom) == 1 else None

    def body_frame(self, sensor_frame: str | None) -> str | None:
        """The body a scanner is mounted on when odometry does not name it: the child of the
        odometry edge, else the first of :data:`BODY_FRAME_NAMES` tf knows."""
        edge = self.odometry_edge(sensor_frame)
        if edge is not None:
            return edge[1]
        known = self.frames()
        return next((name for name in BODY_FRAME_NAMES if name in known), None)


@dataclass(frozen=True)
class Mounting:
    """Where a scanner sits on the body.

    Attributes:
        body_from_sensor: (4, 4) float64, or None when tf does not link the two frames.
        note: how it was found, or why not, for ``info`` and warnings.
    """

    body_from_sensor: NDArray[np.float64] | None
    note: str


def find_mounting(index: TfIndex, body: str | None, sensor: str) -> Mounting:
    """The transform ``body <- sensor`` in ``index``, or a Mounting without one saying why."""
    sensor = _name(sensor)
    if not sensor:
        return Mounting(None, "the scans name no frame: mounting taken as zero")
    if not body:
        return Mounting(None, f"no body frame for {sensor} is known: mounting taken as zero")
    body = _name(body)
    if body == sensor:
        return Mounting(np.eye(4), f"the scans are taken in the body frame {body}")
    try:
        pose = index.buffer.lookup(body, sensor, 0)
    except InputError as exc:
        return Mounting(None, f"no tf from {sensor} to {body} ({exc.msg}): mounting taken as zero")
    return Mounting(pose, f"tf {body} <- {sensor}")


def planar_mounting(body_from_sensor: NDArray[np.float64]) -> tuple[NDArray[np.float64], bool]:
    """(3,) x (m), y (m), yaw (rad) of a scanner on the body, and whether it is upside down.

    An upside-down scanner's planar pose is that of its frame turned a half turn about its x
    axis; its beam angles must then be negated (see :func:`mount`).
    """
    pose = np.asarray(body_from_sensor, dtype=np.float64)
    mirrored = bool(pose[2, 2] < 0.0)
    if mirrored:
        pose = compose(pose, _FLIP)
    return se3_to_planar(pose)[0], mirrored


def mount(rec: ScanRecord, mounting: Mounting) -> ScanFrame:
    """The scan of ``rec`` with its planar mounting on the body (zero without one)."""
    pose = mounting.body_from_sensor
    if rec.frame_from_scan is not None:
        pose = rec.frame_from_scan if pose is None else compose(pose, rec.frame_from_scan)
    if pose is None:
        return rec.scan
    xy_yaw, mirrored = planar_mounting(pose)
    scan = rec.scan
    if mirrored:
        scan = replace(
            scan, angle_min_rad=-scan.angle_min_rad, angle_increment_rad=-scan.angle_increment_rad
        )
    return replace(scan, body_from_sensor=xy_yaw)


def tilt_deg(body_from_sensor: NDArray[np.float64]) -> float:
    """Angle (degrees) between a scanner's plane and the body's x-y plane."""
    cos = abs(float(np.asarray(body_from_sensor)[2, 2]))
    return math.degrees(math.acos(min(1.0, cos)))


def describe(mounting: Mounting) -> str:
    """One line for ``info``: the planar mounting and where it came from."""
    if mounting.body_from_sensor is None:
        return mounting.note
    (x, y, yaw), mirrored = planar_mounting(mounting.body_from_sensor)
    text = f"x {x:.3f} m, y {y:.3f} m, yaw {math.degrees(yaw):.1f} deg from {mounting.note}"
    if mirrored:
        text += " (upside down: beam angles mirrored)"
    tilt = tilt_deg(mounting.body_from_sensor)
    if tilt > MAX_TILT_DEG:
        text += f" (tilted {tilt:.0f} deg: used as if level)"
    return text


class ScanMounter:
    """The scans of one log put on the body, and where its odometry comes from.

    Args:
        path: the log, for warnings.
        tf_records: the log's transform records (read once, here).
        sensor_frame: the frame of the log's first scan (None: no readable scan).
        odometry_topic: whether the log has an odometry topic; without one the odometry is
            the moving transform :meth:`TfIndex.odometry_edge` finds (:attr:`edge`).
        odometry_child: the odometry's ``child_frame_id`` ("" where it names none), the body
            the scans are mounted on; else :meth:`TfIndex.body_frame`. A log with neither
            odometry nor a body frame in tf has the scanner for its body (mounting zero).
    """

    def __init__(
        self,
        path: Path,
        tf_records: Iterable[Any],
        sensor_frame: str | None,
        odometry_topic: bool,
        odometry_child: str,
    ) -> None:
        self.path = path
        self.index = TfIndex.read(tf_records)
        self.body = odometry_child or self.index.body_frame(sensor_frame)
        self.edge = None if odometry_topic else self.index.odometry_edge(sensor_frame)
        self.scanner_is_body = not (self.body or odometry_topic)
        self._mountings: dict[str, Mounting] = {}

    def mounting(self, frame_id: str) -> Mounting:
        """The mounting of the scans taken in ``frame_id``, found once (and warned about once
        if missing or tilted)."""
        found = self._mountings.get(frame_id)
        if found is None and self.scanner_is_body:
            note = "the scanner's own frame (the log has no odometry)"
            found = self._mountings[frame_id] = Mounting(np.eye(4), note)
        if found is None:
            found = self._mountings[frame_id] = find_mounting(self.index, self.body, frame_id)
            pose = found.body_from_sensor
            if pose is None:
                log.warning("%s: %s", self.path, found.note)
            elif tilt_deg(pose) > MAX_TILT_DEG:
                log.warning("%s: scans in %s: %s", self.path, frame_id, describe(found))
        return found

    def mount(self, rec: ScanRecord) -> ScanFrame:
        """The scan of ``rec`` with its planar mounting on the body."""
        return mount(rec, self.mounting(rec.frame_id))

    def odometry(self, rec: TransformRecord) -> list[OdometryFrame]:
        """The odometry frames of a transform record (see :func:`tf_odometry`); none without
        an odometry edge."""
        return tf_odometry(rec, self.edge) if self.edge is not None else []

    def info(
        self, topic: str, first: Any, odometry_topic: str | None
    ) -> tuple[dict[str, Any], list[str]]:
        """Details for ``info`` (scan topic, frame, beams, mounting, where odometry comes from)
        and problems, from the first readable record ``first`` of ``topic`` (None: none)."""
        edge = self.edge
        odometry = odometry_topic or (f"tf {edge[0]} -> {edge[1]}" if edge is not None else None)
        details: dict[str, Any] = {"scan_topic": topic, "scan_odometry": odometry}
        if not isinstance(first, ScanRecord):
            return details, [f"scans: topic {topic} has no readable scan"]
        mounting = self.mounting(first.frame_id)
        details["scan_frame"] = first.frame_id
        details["scan_beams"] = int(first.scan.ranges_m.size)
        details["scan_mounting"] = describe(mounting)
        problems = [] if mounting.body_from_sensor is not None else [f"scans: {mounting.note}"]
        return details, problems


def tf_odometry(rec: TransformRecord, edge: tuple[str, str]) -> list[OdometryFrame]:
    """The odometry frames (``parent_from_child`` as ``world_from_body``, no velocities) of
    the transforms of ``rec`` on ``edge`` (parent, child)."""
    parent, child = edge
    return [
        OdometryFrame(p.stamp_ns, world_from_body=np.asarray(p.parent_from_child))
        for p in rec.transforms
        if _is_edge(p, parent, child)
    ]


def _is_edge(pose: PoseRecord, parent: str, child: str) -> bool:
    return _name(pose.frame_id) == parent and _name(pose.child_frame_id) == child
