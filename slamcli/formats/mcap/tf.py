"""A transform tree built from tf / tf_static / Foxglove FrameTransform records.

Each frame has at most one parent. An edge ``parent -> child`` holds ``parent_from_child``: one
pose for a static edge, or time-sorted samples for a dynamic one. A lookup walks from both frames
up to their closest common ancestor and interpolates every dynamic edge on the way at the query
time (SLERP for rotation, linear for translation), as tf2 does; unlike tf2 it also answers for
many query times at once with array maths.

Frame ids are compared without a leading ``/`` (ROS 1 wrote ``/odom`` where ROS 2 writes
``odom``). Times are int64 nanoseconds; poses are (4, 4) float64.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slamcli.errors import InputError
from slamcli.formats.mcap.records import PoseRecord, TransformRecord
from slamcli.formats.text import format_stamp
from slamcli.geometry import compose, interpolate_poses, inverse

log = logging.getLogger(__name__)

DEFAULT_MAX_GAP_NS = 50_000_000
"""How far (ns) beyond the first or last sample of a dynamic edge a lookup may fall by default;
there the end sample is held. Inside an edge's time span samples are always interpolated."""

_INITIAL_CAPACITY = 64


@dataclass(frozen=True)
class TfEdge:
    """A summary of one edge of the tree (for listings and messages)."""

    parent: str
    child: str
    static: bool
    count: int
    first_ns: int | None
    last_ns: int | None


class _Edge:
    """``parent_from_child`` samples of one edge, kept in a growable, time-sorted array."""

    def __init__(self, parent: str, static: bool) -> None:
        self.parent = parent
        self.static = static
        self._stamps = np.empty(_INITIAL_CAPACITY if not static else 1, dtype=np.int64)
        self._poses = np.empty((self._stamps.size, 4, 4), dtype=np.float64)
        self._n = 0
        self._sorted = True

    def add(self, stamp_ns: int, pose: NDArray[np.float64]) -> None:
        if self.static:
            # The latest static transform replaces the previous one, as tf2's static buffer does.
            self._stamps[0], self._poses[0], self._n = stamp_ns, pose, 1
            return
        if self._n and stamp_ns == self._stamps[self._n - 1]:
            self._poses[self._n - 1] = pose
            return
        if self._n == self._stamps.size:
            self._stamps = np.resize(self._stamps, 2 * self._n)
            self._poses = np.resize(self._poses, (2 * self._n, 4, 4))
        if self._n and stamp_ns < self._stamps[self._n - 1]:
            self._sorted = False
        self._stamps[self._n] = stamp_ns
        self._poses[self._n] = pose
        self._n += 1

    def samples(self) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """(N,) strictly increasing stamps and (N, 4, 4) poses; of equal stamps the last added."""
        if not self._sorted:
            stamps, poses = self._stamps[: self._n], self._poses[: self._n]
            order = np.argsort(stamps, kind="stable")
            stamps, poses = stamps[order], poses[order]
            keep = np.append(stamps[1:] != stamps[:-1], True)
            n = int(keep.sum())
            self._stamps[:n], self._poses[:n], self._n = stamps[keep], poses[keep], n
            self._sorted = True
        return self._stamps[: self._n], self._poses[: self._n]

    def evaluate(
        self, query_ns: NDArray[np.int64], max_gap_ns: int
    ) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
        """(M,) valid mask and (M, 4, 4) parent_from_child at the query times."""
        stamps, poses = self.samples()
        if self.static:
            return np.ones(query_ns.shape, dtype=bool), np.broadcast_to(
                poses[0], (*query_ns.shape, 4, 4)
            )
        valid = (query_ns >= stamps[0] - max_gap_ns) & (query_ns <= stamps[-1] + max_gap_ns)
        _, out = interpolate_poses(stamps, poses, np.clip(query_ns, stamps[0], stamps[-1]))
        return valid, out


class TfBuffer:
    """Static and dynamic transforms, queried as ``target_from_source`` at given times."""

    def __init__(self) -> None:
        self._edges: dict[str, _Edge] = {}
        self._reparented: set[str] = set()

    def add(self, record: TransformRecord) -> None:
        """Add every transform of a tf / tf_static / FrameTransform(s) record."""
        for pose in record.transforms:
            self.add_pose(pose, record.static)

    def add_pose(self, pose: PoseRecord, static: bool) -> None:
        """Add one ``parent_from_child`` transform (``frame_id`` is the parent)."""
        parent = _frame(pose.frame_id)
        child = _frame(pose.child_frame_id)
        if not parent or not child or parent == child:
            log.debug("ignoring transform with frames %r -> %r", pose.frame_id, pose.child_frame_id)
            return
        edge = self._edges.get(child)
        if edge is None or edge.parent != parent or edge.static != static:
            if edge is not None and child not in self._reparented:
                self._reparented.add(child)
                log.warning(
                    "frame %r: %s parent %r replaced by %s parent %r",
                    child,
                    "static" if edge.static else "dynamic",
                    edge.parent,
                    "static" if static else "dynamic",
                    parent,
                )
            edge = self._edges[child] = _Edge(parent, static)
        edge.add(int(pose.stamp_ns), np.asarray(pose.parent_from_child, dtype=np.float64))

    def frames(self) -> dict[str, str | None]:
        """Every known frame mapped to its parent (None for a root), sorted by name."""
        out: dict[str, str | None] = {child: edge.parent for child, edge in self._edges.items()}
        for edge in self._edges.values():
            out.setdefault(edge.parent, None)
        return dict(sorted(out.items()))

    def edges(self) -> list[TfEdge]:
        """A summary of every edge, sorted by (parent, child)."""
        out = []
        for child, edge in self._edges.items():
            stamps, _ = edge.samples()
            first = int(stamps[0]) if stamps.size and not edge.static else None
            last = int(stamps[-1]) if stamps.size and not edge.static else None
            out.append(TfEdge(edge.parent, child, edge.static, int(stamps.size), first, last))
        return sorted(out, key=lambda e: (e.parent, e.child))

    def lookup(
        self,
        target_frame: str,
        source_frame: str,
        stamp_ns: int,
        max_gap_ns: int = DEFAULT_MAX_GAP_NS,
    ) -> NDArray[np.float64]:
        """(4, 4) ``target_from_source`` at ``stamp_ns``.

        Raises:
            InputError: the frames are unknown or not connected, or the stamp lies more than
                ``max_gap_ns`` outside the time span of a dynamic edge on the path.
        """
        query = np.array([stamp_ns], dtype=np.int64)
        _, poses, bad_edge = self._resolve(target_frame, source_frame, query, max_gap_ns)
        if bad_edge is not None:
            child, edge = bad_edge
            stamps, _ = edge.samples()
            raise InputError(
                f"no transform {_frame(target_frame)} <- {_frame(source_frame)} at "
                f"{format_stamp(stamp_ns, 3)} s: transform {edge.parent} -> {child} is known from "
                f"{format_stamp(int(stamps[0]), 3)} s to {format_stamp(int(stamps[-1]), 3)} s",
                hint=f"allowed gap beyond that span is {max_gap_ns * 1e-9:g} s",
            )
        return poses[0].copy()

    def lookup_many(
        self,
        target_frame: str,
        source_frame: str,
        stamps_ns: ArrayLike,
        max_gap_ns: int = DEFAULT_MAX_GAP_NS,
    ) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
        """``target_from_source`` at many times.

        Args:
            stamps_ns: (M,) int64 query times.

        Returns:
            valid: (M,) bool, False where a dynamic edge on the path has no sample within
                ``max_gap_ns`` of its time span.
            poses: (M, 4, 4) float64; rows where ``valid`` is False hold the poses obtained by
                holding the nearest samples.

        Raises:
            InputError: the frames are unknown or not connected.
        """
        query = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
        valid, poses, _ = self._resolve(target_frame, source_frame, query, max_gap_ns)
        return valid, poses

    def can_transform(
        self,
        target_frame: str,
        source_frame: str,
        stamp_ns: int,
        max_gap_ns: int = DEFAULT_MAX_GAP_NS,
    ) -> bool:
        """Whether :meth:`lookup` would succeed."""
        try:
            valid, _, _ = self._resolve(
                target_frame, source_frame, np.array([stamp_ns], dtype=np.int64), max_gap_ns
            )
        except InputError:
            return False
        return bool(valid[0])

    def _chain(self, frame: str) -> list[str]:
        """``frame`` and its ancestors up to the root."""
        chain = [frame]
        seen = {frame}
        while (edge := self._edges.get(chain[-1])) is not None:
            if edge.parent in seen:
                raise InputError(
                    f"transform tree has a cycle through {edge.parent!r}",
                    hint="the log's tf data gives a frame two parents over time",
                )
            chain.append(edge.parent)
            seen.add(edge.parent)
        return chain

    def _resolve(
        self, target_frame: str, source_frame: str, query: NDArray[np.int64], max_gap_ns: int
    ) -> tuple[NDArray[np.bool_], NDArray[np.float64], tuple[str, _Edge] | None]:
        target, source = _frame(target_frame), _frame(source_frame)
        known = self.frames()
        for name, given in ((target, target_frame), (source, source_frame)):
            if name not in known:
                raise InputError(
                    f"frame {given!r} is not in the transform tree",
                    hint=f"known frames: {', '.join(known) or '(none)'}",
                )
        up_source, up_target = self._chain(source), self._chain(target)
        on_target = set(up_target)
        common = next((f for f in up_source if f in on_target), None)
        if common is None:
            raise InputError(
                f"frames {target!r} and {source!r} are not connected: their trees are rooted "
                f"at {up_target[-1]!r} and {up_source[-1]!r}",
                hint="check the frame names, or that the log records the transform linking them",
            )
        valid = np.ones(query.shape, dtype=bool)
        bad_edge: tuple[str, _Edge] | None = None

        def to_common(chain: list[str]) -> NDArray[np.float64]:
            nonlocal valid, bad_edge
            common_from_frame = np.broadcast_to(np.eye(4), (*query.shape, 4, 4))
            for child in chain[: chain.index(common)]:
                edge = self._edges[child]
                ok, parent_from_child = edge.evaluate(query, max_gap_ns)
                if bad_edge is None and not ok.all():
                    bad_edge = (child, edge)
                valid &= ok
                # Walking up, each parent_from_child goes on the left of what is built so far.
                common_from_frame = compose(parent_from_child, common_from_frame)
            return common_from_frame

        common_from_source = to_common(up_source)
        common_from_target = to_common(up_target)
        poses = compose(inverse(common_from_target), common_from_source)
        return valid, np.ascontiguousarray(poses), bad_edge


def moving_frame_poses(
    records: Iterable[Any], frame: str, path: Path
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """The poses of ``frame`` in the root of its tree, from the transform records among
    ``records``, at the stamps of the moving transform nearest the frame.

    Returns:
        (N,) int64 stamps (ns) and (N, 4, 4) float64 ``root_from_frame`` poses.

    Raises:
        InputError: tf has no such frame, or nothing in tf moves it (``path`` names the log).
    """
    buffer = TfBuffer()
    moving: dict[str, list[int]] = {}
    for rec in records:
        if isinstance(rec, TransformRecord):
            buffer.add(rec)
            if not rec.static:
                for p in rec.transforms:
                    moving.setdefault(p.child_frame_id.lstrip("/"), []).append(p.stamp_ns)
    parents = buffer.frames()
    frame = frame.lstrip("/")
    if frame not in parents:
        raise InputError(
            f"{path}: tf has no frame {frame!r} (--gt-frame)",
            hint=f"frames in tf: {', '.join(sorted(parents)) or 'none'}",
        )
    # Sample at the stamps of the moving transform nearest the frame (a sensor frame is
    # usually fixed to a base link that odometry moves).
    node, stamps = frame, None
    while True:
        if node in moving:
            stamps = moving[node]
            break
        parent = parents.get(node)
        if not parent:
            break
        node = parent
    root = node
    while parents.get(root):
        root = str(parents[root])
    if stamps is None:
        raise InputError(f"{path}: nothing in tf moves frame {frame!r}; no ground truth")
    query = np.unique(np.asarray(stamps, dtype=np.int64))
    valid, poses = buffer.lookup_many(root, frame, query)
    return query[valid], poses[valid]


def _frame(name: str) -> str:
    return name.lstrip("/")
