"""The options every source takes (pairing, camera, topics, robot, ...), as one record.

The CLI gives them as flags (:mod:`slamcli.cli.source_options`), a batch manifest as a
``source`` table; both end in :meth:`SourceOptions.open_kwargs` for
:func:`slamcli.formats.open_source`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from slamcli.errors import ConfigError


@dataclass(frozen=True)
class SourceOptions:
    """The shared source options, as given on the command line (None = not given)."""

    max_dt: float = 0.02
    dt_offset: float = 0.0
    depth_factor: float | None = None
    camera: str | None = None
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    undistort: bool = False
    strict: bool = False
    max_chunk_mb: int | None = None
    robot: int | str | None = None
    ignore_ids: bool = False
    rgb_topic: str | None = None
    depth_topic: str | None = None
    camera_info_topic: str | None = None
    odom_topic: str | None = None
    gt_topic: str | None = None
    gt_frame: str | None = None
    landmark_topic: str | None = None
    scan_topic: str | None = None
    left_topic: str | None = None
    right_topic: str | None = None
    odometry: str | None = None
    groundtruth: str | None = None
    max_range: float | None = None
    calib: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        # One --calib file from a manifest may be given as text; several as a list.
        if isinstance(self.calib, str):
            object.__setattr__(self, "calib", (self.calib,))
        elif isinstance(self.calib, list):
            object.__setattr__(self, "calib", tuple(self.calib))
        # "--robot 2" arrives as text; one robot is recorded as the number it names.
        if isinstance(self.robot, str) and self.robot.strip().isdigit():
            object.__setattr__(self, "robot", int(self.robot))

    def open_kwargs(self) -> dict[str, Any]:
        """Keyword arguments for :func:`slamcli.formats.open_source`.

        Only options that differ from their defaults are passed, so a format that takes fewer
        options is not handed ones the user never set.
        """
        return {
            f.name: getattr(self, f.name)
            for f in fields(self)
            if getattr(self, f.name) != getattr(DEFAULTS, f.name)
        }

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], where: str = "source") -> SourceOptions:
        """Options from a table of names (``max_dt`` or ``max-dt``) and values; a
        :class:`~slamcli.errors.ConfigError` names an unknown option or a value of the wrong
        type."""
        known = {f.name: f for f in fields(cls)}
        picked: dict[str, Any] = {}
        for key, value in values.items():
            name = key.replace("-", "_")
            if name not in known:
                raise ConfigError(
                    f"{where}: unknown source option {key!r}",
                    hint=f"known: {', '.join(sorted(known))}",
                )
            default = getattr(DEFAULTS, name)
            if not _fits(value, default, known[name].type):
                raise ConfigError(
                    f"{where}.{key}: expected {_kind(known[name].type)}, got {value!r}"
                )
            picked[name] = (
                float(value)
                if isinstance(default, float) and not isinstance(value, bool)
                else value
            )
        return cls(**picked)


DEFAULTS = SourceOptions()
"""Default values, for commands' parameter defaults."""


def _fits(value: Any, default: Any, annotation: Any) -> bool:
    text = str(annotation)
    if value is None:
        return "None" in text
    if "tuple[str" in text:
        items = value if isinstance(value, list) else [value]
        return bool(items) and all(isinstance(v, str) for v in items)
    if "int | str" in text:
        return isinstance(value, int | str) and not isinstance(value, bool)
    if "bool" in text:
        return isinstance(value, bool)
    if "int" in text:
        return isinstance(value, int) and not isinstance(value, bool)
    if "float" in text:
        return isinstance(value, int | float) and not isinstance(value, bool)
    if "str" in text:
        return isinstance(value, str)
    return True


def _kind(annotation: Any) -> str:
    text = str(annotation)
    if "tuple[str" in text:
        return "a file name or a list of them"
    for name, word in (("bool", "true or false"), ("int", "an integer"), ("float", "a number")):
        if name in text:
            return word
    return "text"
