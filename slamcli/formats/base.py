"""The Source protocol every input format implements, and what ``info`` reports."""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Collection, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, Generic, Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError, InputError
from slamcli.types import Frame, LandmarkMap, PinholeCamera, ProgressFn, Trajectory

ALL_FRAME_KINDS = ("rgbd", "image", "odometry", "landmarks", "imu", "scan", "stereo")


def known_kinds(kinds: Collection[str]) -> set[str]:
    """The frame kinds asked for (a single name or several), each one of
    :data:`ALL_FRAME_KINDS`.

    Raises:
        ConfigError: a kind no source gives.
    """
    wanted = set([kinds] if isinstance(kinds, str) else kinds)
    unknown = sorted(wanted - set(ALL_FRAME_KINDS))
    if unknown:
        raise ConfigError(
            f"unknown frame kind(s) {', '.join(unknown)}",
            hint=f"kinds: {', '.join(ALL_FRAME_KINDS)}",
        )
    return wanted


def provided_kinds(wanted: set[str], provided: Collection[str], path: Path, label: str) -> set[str]:
    """``wanted``, when a source (``label``, e.g. "a KITTI odometry folder") at ``path``
    gives every one of those kinds.

    Raises:
        InputError: naming the kinds it does not give and those it does.
    """
    absent = sorted(wanted - set(provided))
    if absent:
        raise InputError(
            f"{path}: {label} has no {', '.join(absent)} frames",
            hint=f"it provides {', '.join(provided)}",
        )
    return wanted


"""Every frame kind a source may be asked for."""


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

    @classmethod
    def from_stamps(
        cls, name: str, kind: str, stamps_ns: NDArray[np.int64], detail: str = ""
    ) -> StreamInfo:
        """A stream's count, mean rate (Hz), first and last stamps (s) from its stamps (ns)."""
        n = int(stamps_ns.size)
        if n == 0:
            return cls(name, kind, 0, detail=detail)
        span = (int(stamps_ns[-1]) - int(stamps_ns[0])) * 1e-9
        rate = (n - 1) / span if n > 1 and span > 0 else None
        start, end = float(stamps_ns[0]) * 1e-9, float(stamps_ns[-1]) * 1e-9
        return cls(name, kind, n, rate, start, end, detail)


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
    skipped_hint: str | None = None
    """What a user can do about the skipped frames, from a source whose frames are not images
    (a laser log's damaged lines); None: the hint for missing or unreadable images."""


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

    def groundtruths(self) -> dict[int, Trajectory]:
        """Each robot's ground truth, by robot id, for a log of several robots (else
        empty)."""
        ...


_C = TypeVar("_C", bound="Closing")
_S = TypeVar("_S", bound="SourceBase")
_T = TypeVar("_T")
_R = TypeVar("_R")


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

    def groundtruths(self) -> dict[int, Trajectory]:
        """Each robot's ground truth by robot id; empty for logs of one robot."""
        return {}


class ReadAhead(Generic[_T]):
    """Iterate ``items`` on a reader thread, up to ``depth`` items ahead of the consumer.

    Image decoding (OpenCV, PNG/JPEG) lets go of the interpreter lock, so a pipeline whose
    frames cost more than their decoding gets the decoding for free on a second core. Items
    arrive in order and an exception raised while reading arrives where it happened, so
    results are as without it. Use as a context manager: leaving the block (an error, Ctrl-C)
    stops the reader before the source is closed. Everything the reader does for an item
    (``source.stats`` included) is done by the time the consumer receives it.
    """

    _END = object()

    def __init__(self, items: Iterable[_T], depth: int = 2) -> None:
        self._items = items
        self._queue: queue.Queue[tuple[str, Any]] = queue.Queue(maxsize=max(1, depth))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, name="read-ahead", daemon=True)
        self._thread.start()

    def _put(self, item: tuple[str, Any]) -> bool:
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=0.05)
                return True
            except queue.Full:
                continue
        return False

    def _read(self) -> None:
        try:
            for item in self._items:
                if not self._put(("item", item)):
                    return
        except BaseException as exc:  # handed to the consumer, raised there
            self._put(("error", exc))
            return
        self._put(("end", self._END))

    def __iter__(self) -> Iterator[_T]:
        while True:
            kind, value = self._queue.get()
            if kind == "item":
                yield value
            elif kind == "error":
                raise value
            else:
                return

    def close(self) -> None:
        """Stop the reader (it finishes the item in hand) and wait for it."""
        self._stop.set()
        self._thread.join(timeout=10)

    def __enter__(self) -> ReadAhead[_T]:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _Done(Generic[_R]):
    """A result computed in place, with the interface of a future."""

    def __init__(self, value: _R) -> None:
        self._value = value

    def result(self) -> _R:
        return self._value


class Prefetch(Generic[_T, _R]):
    """``prepare`` applied to each item up to ``depth`` items ahead of its use, on a worker
    thread.

    A pipeline whose per-frame preparation (decoding, ORB features) is a pure function of the
    frame gets it done on a second core while the previous frames are worked on (more than
    one ahead, a slow frame's time is not lost to the preparation waiting): :meth:`push`
    takes a frame and returns the frames whose turn has come, in order, each with its pending
    result (``.result()`` waits for it); :meth:`drain` returns the rest at the end. With
    ``ahead=False`` each item is prepared in place and returned at once. Results do not depend
    on the choice.
    """

    def __init__(
        self, prepare: Callable[[_T], _R], ahead: bool, name: str = "prefetch", depth: int = 1
    ) -> None:
        self._prepare = prepare
        self._ahead = ahead
        self._name = name
        self._depth = max(1, depth)
        self._pool: ThreadPoolExecutor | None = None
        self._queue: list[tuple[_T, Future[_R]]] = []

    def push(self, item: _T) -> list[tuple[_T, Future[_R] | _Done[_R]]]:
        """Take ``item``; the items ready to be worked on now, with their results."""
        if not self._ahead:
            return [(item, _Done(self._prepare(item)))]
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix=self._name)
        self._queue.append((item, self._pool.submit(self._prepare, item)))
        if len(self._queue) > self._depth:
            return [self._queue.pop(0)]
        return []

    def drain(self) -> list[tuple[_T, Future[_R] | _Done[_R]]]:
        """The items still waiting, in order, with their results; the worker thread stops
        once they are prepared."""
        waiting: list[tuple[_T, Future[_R] | _Done[_R]]] = list(self._queue)
        self._queue = []
        return waiting

    def close(self) -> None:
        """Stop the worker thread (after the items in hand are prepared)."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None


def npy_header(npz: Any, name: str) -> tuple[tuple[int, ...], np.dtype[Any]] | None:
    """Shape and dtype that member ``name`` of an open ``np.load``-ed .npz declares, read from
    its header without loading the array; None for a .npy format version numpy's readers do not
    know. Readers check the size before numpy allocates it (a compressed member of zeros can
    declare gigabytes in a few kilobytes)."""
    with npz.zip.open(f"{name}.npy") as fh:
        version = np.lib.format.read_magic(fh)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
        elif version == (2, 0):
            shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
        else:
            return None
    return tuple(int(s) for s in shape), dtype
