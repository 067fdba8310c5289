"""``slamcli.LandmarkObservations``: range-bearing landmark observations as JSON MCAP messages.

A schema of slamcli's own (there is no standard ROS or Foxglove message for it), shipped as
``schemas/LandmarkObservations.json`` (JSON Schema 2020-12). A channel carries it with schema
name ``slamcli.LandmarkObservations``, schema encoding ``jsonschema`` and message encoding
``json``. One message holds what was seen at one instant::

    {"timestamp": {"sec": 1700000000, "nsec": 100000000},
     "frame_id": "base_link",
     "observations": [{"id": 2, "range": 3.55, "bearing": -0.89},
                      {"id": -1, "range": 4.98, "bearing": 1.39, "range_sigma": 0.1}]}

``id`` is the landmark's id, -1 or absent when the correspondence is unknown; ``range`` is in
metres (>= 0); ``bearing`` in radians, counter-clockwise from the robot's heading (x forward,
y left); ``range_sigma`` / ``bearing_sigma`` (> 0) are optional and are checked but not used by
slamcli (the EKF's noise comes from its configuration). Extra keys are allowed and ignored.

:func:`landmark_frame` reads a message into a :class:`~slamcli.types.LandmarkFrame`, stamped
with the message's ``timestamp`` (the log time only where that is zero, as for every other
message type). It checks each message against the schema's rules itself (``jsonschema`` is not
a runtime dependency): a violation is a :class:`~slamcli.formats.mcap.decode.DecodeError`
naming the topic and the offending field, like any other undecodable message.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import cache
from importlib import resources
from typing import Any

import numpy as np

from slamcli.errors import ExportError
from slamcli.formats.mcap.decode import DecodeError
from slamcli.types import LandmarkFrame

SCHEMA_NAME = "slamcli.LandmarkObservations"
SCHEMA_ENCODING = "jsonschema"
MESSAGE_ENCODING = "json"

_NS = 1_000_000_000


@cache
def landmark_schema() -> bytes:
    """The JSON Schema of ``slamcli.LandmarkObservations`` (package data)."""
    path = resources.files("slamcli.formats.mcap") / "schemas" / "LandmarkObservations.json"
    try:
        return path.read_bytes()
    except FileNotFoundError as exc:
        raise ExportError(f"slamcli is installed without its {SCHEMA_NAME} schema") from exc


def landmark_message(
    stamp_ns: int,
    ids: Sequence[int],
    ranges_m: Sequence[float],
    bearings_rad: Sequence[float],
    frame_id: str = "base_link",
) -> dict[str, Any]:
    """A ``slamcli.LandmarkObservations`` message (a dict to ``json.dumps``)."""
    sec, nsec = divmod(int(stamp_ns), _NS)
    observations = [
        {"id": int(i), "range": float(r), "bearing": float(b)}
        for i, r, b in zip(ids, ranges_m, bearings_rad, strict=True)
    ]
    return {
        "timestamp": {"sec": sec, "nsec": nsec},
        "frame_id": frame_id,
        "observations": observations,
    }


def _bad(topic: str, what: str) -> DecodeError:
    return DecodeError(
        f"channel {topic}: not a valid {SCHEMA_NAME} message: {what}",
        hint="see the schema the log stores for this channel, or docs/landmark_observations.md",
    )


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _integer(value: Any) -> int | None:
    """The integer a JSON number stands for (``3`` or ``3.0``, as JSON Schema counts them)."""
    if isinstance(value, bool) or not _is_number(value):
        return None
    if isinstance(value, float):
        return int(value) if value.is_integer() else None
    return int(value)


def _number(topic: str, obs: dict[str, Any], key: str, where: str) -> float:
    value = obs[key]
    if not _is_number(value) or not math.isfinite(value):
        raise _bad(topic, f"{where}.{key} is {value!r}, not a finite number")
    return float(value)


def _stamp(topic: str, msg: dict[str, Any], log_time_ns: int) -> int:
    ts = msg.get("timestamp")
    if not isinstance(ts, dict):
        raise _bad(topic, "'timestamp' {sec, nsec} is missing" if ts is None else "bad timestamp")
    sec, nsec = _integer(ts.get("sec")), _integer(ts.get("nsec"))
    if sec is None or nsec is None or sec < 0 or not 0 <= nsec < _NS:
        raise _bad(topic, f"timestamp {ts!r} needs integers sec >= 0 and nsec in 0-999999999")
    ns = sec * _NS + nsec
    return ns if ns > 0 else log_time_ns


def landmark_frame(msg: Any, log_time_ns: int, topic: str) -> LandmarkFrame:
    """Adapter: a decoded ``slamcli.LandmarkObservations`` JSON message -> LandmarkFrame.

    Raises:
        DecodeError: the message breaks the schema (names the topic and the field).
    """
    if not isinstance(msg, dict):
        raise _bad(topic, f"expected a JSON object, got {type(msg).__name__}")
    stamp = _stamp(topic, msg, log_time_ns)
    frame_id = msg.get("frame_id", "")
    if not isinstance(frame_id, str):
        raise _bad(topic, f"frame_id is {frame_id!r}, not a string")
    observations = msg.get("observations")
    if not isinstance(observations, list):
        what = "missing" if observations is None else f"{type(observations).__name__}"
        raise _bad(topic, f"'observations' must be a list, it is {what}")
    n = len(observations)
    ids = np.full(n, -1, dtype=np.int64)
    ranges = np.empty(n, dtype=np.float64)
    bearings = np.empty(n, dtype=np.float64)
    for k, obs in enumerate(observations):
        where = f"observations[{k}]"
        if not isinstance(obs, dict):
            raise _bad(topic, f"{where} is {obs!r}, not an object")
        for key in ("range", "bearing"):
            if key not in obs:
                raise _bad(topic, f"{where} has no {key!r}")
        ranges[k] = _number(topic, obs, "range", where)
        if ranges[k] < 0:
            raise _bad(topic, f"{where}.range is {ranges[k]!r}, below 0")
        bearings[k] = _number(topic, obs, "bearing", where)
        if "id" in obs:
            landmark = _integer(obs["id"])
            if landmark is None or landmark < -1:
                raise _bad(topic, f"{where}.id is {obs['id']!r}, not an integer >= -1")
            ids[k] = landmark
        for key in ("range_sigma", "bearing_sigma"):
            if key in obs and not _number(topic, obs, key, where) > 0:
                raise _bad(topic, f"{where}.{key} is {obs[key]!r}, not above 0")
    return LandmarkFrame(stamp, ids, ranges, bearings)
