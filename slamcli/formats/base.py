"""The Source protocol every input format implements, and what ``info`` reports."""

from __future__ import annotations

from collections.abc import Collection, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray

from slamcli.types import Frame, LandmarkMap, PinholeCamera, ProgressFn, Trajectory


@dataclass
class StreamInfo:
    """One stream of a source (a list file, a topic)."""

    name: str
    kind: str
    count: int
    rate_hz: float | None = None
    start_s: float | None = None
    end_s: float | None = None
    detail: str = ""


@dataclass
class SourceInfo:
    """What ``slamcli info`` prints; ``to_dict`` gives its JSON form."""

    format: str
    path: str
    streams: list[StreamInfo]
    frames: int
    groundtruth: int
    camera: PinholeCamera | None = None
    camera_source: str = ""
    problems: list[str] = field(default_factory=list)
    details: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["camera"] = self.camera.to_dict() if self.camera else None
        return d


@dataclass
class ReadStats:
    """What reading frames cost: frames yielded, skipped (with the names), data lost.

    ``data_loss`` holds one line per damage the reader worked around (a truncated log, a bad
    chunk, messages dropped as too late); a run that has any finishes with exit code 3.
    """

    read: int = 0
    skipped: int = 0
    skipped_names: list[str] = field(default_factory=list)
    data_loss: list[str] = field(default_factory=list)


class Source(Protocol):
    """An input log. Use as a context manager; frames are produced lazily."""

    format_name: str
    path: Path
    stats: ReadStats

    def __enter__(self) -> Source: ...

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None: ...

    def info(self, deep: bool = False, progress: ProgressFn | None = None) -> SourceInfo: ...

    def frames(self, kinds: Collection[str] = ("rgbd",)) -> Iterator[Frame]: ...

    def groundtruth(self) -> Trajectory | None: ...

    def start_pose(self) -> NDArray[np.float64] | None:
        """The ground-truth pose (x, y, yaw) at the first frame, for planar pipelines."""
        ...

    def landmark_truth(self) -> LandmarkMap | None:
        """The surveyed landmark positions, for scoring a landmark map."""
        ...


_C = TypeVar("_C", bound="Closing")
_S = TypeVar("_S", bound="SourceBase")


class Closing:
    """The context-manager protocol of readers: leaving the block calls :meth:`close`."""

    def close(self) -> None:
        """Release files and caches (nothing by default)."""

    def __enter__(self: _C) -> _C:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


class SourceBase(Closing):
    """What every source class shares: ``open`` and the context-manager protocol.

    Subclasses take their options as keyword arguments and release what they hold in
    :meth:`close`.
    """

    @classmethod
    def open(cls: type[_S], path: str | Path, **options: Any) -> _S:
        """Open ``path``; ``options`` are the constructor's keyword arguments."""
        return cls(path, **options)  # type: ignore[call-arg]

    def start_pose(self) -> NDArray[np.float64] | None:
        """The ground-truth pose (x, y, yaw) at the first frame; None for logs without one."""
        return None

    def landmark_truth(self) -> LandmarkMap | None:
        """The surveyed landmark positions; None for logs without landmarks."""
        return None
