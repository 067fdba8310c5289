"""Foxglove JSON messages: the official schemas, and the pieces every message is made of."""

from __future__ import annotations

import base64
import json
from functools import cache
from importlib import resources
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ExportError
from slamcli.formats.mcap.write.convert import pose_parts, split_ns
from slamcli.formats.mcap.write.layer import TOPIC_TF, WORLD_FRAME, LogWriter


@cache
def foxglove_schema(name: str) -> bytes:
    """The official Foxglove JSON schema of ``foxglove.<name>`` (package data, MIT licence)."""
    path = resources.files("slamcli.formats.mcap") / "foxglove_schemas" / f"{name}.json"
    try:
        return path.read_bytes()
    except FileNotFoundError as exc:
        raise ExportError(f"no Foxglove JSON schema for foxglove.{name} in slamcli") from exc


def fox_time(stamp_ns: int) -> dict[str, int]:
    """A Foxglove ``Time`` of a stamp (ns)."""
    sec, nsec = split_ns(stamp_ns)
    return {"sec": sec, "nsec": nsec}


def fox_pose(
    t: list[float] | tuple[float, ...], q: list[float] | tuple[float, ...]
) -> dict[str, Any]:
    """A Foxglove ``Pose`` of a translation (m) and an xyzw quaternion."""
    return {
        "position": {"x": t[0], "y": t[1], "z": t[2]},
        "orientation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]},
    }


IDENTITY_POSE = fox_pose((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))


def b64(data: bytes) -> str:
    """Bytes as base64 text, Foxglove's JSON convention for binary fields."""
    return base64.b64encode(data).decode("ascii")


def put_json(
    mcap_log: LogWriter, topic: str, name: str, stamp_ns: int, msg: dict[str, Any]
) -> None:
    """Write ``msg`` as a ``foxglove.<name>`` JSON message."""
    try:
        data = json.dumps(msg, separators=(",", ":"), allow_nan=False).encode()
    except ValueError as exc:
        raise ExportError(f"{topic}: a foxglove.{name} message holds a non-finite number") from exc
    mcap_log.add(
        topic, (f"foxglove.{name}", "jsonschema", foxglove_schema(name)), "json", stamp_ns, data
    )


def write_pose_and_tf(
    mcap_log: LogWriter,
    pose_topic: str,
    child_frame: str,
    stamp_ns: int,
    world_from_child: NDArray[np.float64],
) -> None:
    """A ``foxglove.PoseInFrame`` on ``pose_topic`` and the same pose as a world->child tf."""
    t, q = pose_parts(world_from_child)
    pose = {"timestamp": fox_time(stamp_ns), "frame_id": WORLD_FRAME, "pose": fox_pose(t, q)}
    put_json(mcap_log, pose_topic, "PoseInFrame", stamp_ns, pose)
    tf = frame_transform(stamp_ns, WORLD_FRAME, child_frame, world_from_child)
    put_json(mcap_log, TOPIC_TF, "FrameTransform", stamp_ns, tf)


def frame_transform(
    stamp_ns: int, parent: str, child: str, parent_from_child: NDArray[np.float64]
) -> dict[str, Any]:
    """A ``foxglove.FrameTransform`` of a (4, 4) ``parent_from_child`` pose."""
    t, q = pose_parts(parent_from_child)
    return {
        "timestamp": fox_time(stamp_ns),
        "parent_frame_id": parent,
        "child_frame_id": child,
        "translation": {"x": t[0], "y": t[1], "z": t[2]},
        "rotation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]},
    }
