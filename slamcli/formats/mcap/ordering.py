"""Streams of one log put back into order: motion frames by their stamps, colour and depth
images into pairs, both settled as the streams advance so memory stays bounded."""

from __future__ import annotations

import bisect
import heapq
import itertools
from collections.abc import Collection

import numpy as np

from slamcli.formats.mcap.records import ImageRecord
from slamcli.formats.pairing import associate_stamps
from slamcli.types import LandmarkFrame, OdometryFrame, ScanFrame

FORCE_FLUSH = 32
"""Buffered images at which pairing is settled even without a safe gap (very dense streams)."""
ORDER_BUFFER = 10_000
"""Motion frames held for stamp order at most; beyond it the oldest goes out (a stream that
stopped, or stamps on clocks far apart)."""

MotionFrame = OdometryFrame | LandmarkFrame | ScanFrame
"""The frames put into stamp order."""

MOTION_RANK = {"odometry": 0, "landmarks": 1, "scan": 2}
"""Order of odometry, landmark and scan frames at equal stamps: the motion up to a stamp comes
before what was sensed there."""


class StampOrder:
    """Odometry, landmark and scan frames of several streams put back into stamp order.

    Each stream is taken to be in stamp order by itself (a stream that is not is sorted within
    the buffer). A frame goes out once every stream has delivered a later stamp, so a detector
    whose messages are logged late does not put its observations after later odometry.
    """

    def __init__(self, roles: Collection[str]) -> None:
        self.newest: dict[str, int | None] = dict.fromkeys(roles)
        self.heap: list[tuple[int, int, int, MotionFrame]] = []
        self.count = 0

    def add(self, role: str, frame: MotionFrame) -> list[MotionFrame]:
        """Take one frame; return the frames that can go out now, in order."""
        heapq.heappush(self.heap, (frame.stamp_ns, MOTION_RANK[role], self.count, frame))
        self.count += 1
        newest = self.newest[role]
        self.newest[role] = frame.stamp_ns if newest is None else max(newest, frame.stamp_ns)
        seen = [v for v in self.newest.values() if v is not None]
        horizon = min(seen) if len(seen) == len(self.newest) else None
        out = []
        while self.heap and (
            (horizon is not None and self.heap[0][0] < horizon) or len(self.heap) > ORDER_BUFFER
        ):
            out.append(heapq.heappop(self.heap)[3])
        return out

    def flush(self) -> list[MotionFrame]:
        """Every frame still held, in order."""
        out = [heapq.heappop(self.heap)[3] for _ in range(len(self.heap))]
        return out


class StreamPairer:
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
            if cut is None and len(rgb) + len(depth) > FORCE_FLUSH:
                cut = horizon
                if rgb[0].stamp_ns >= cut and self._key("depth", depth[0]) >= cut:
                    # Nothing is that old: one stream has stopped, and its last stamp holds the
                    # horizon back. Settle what the other has buffered, up to its own newest.
                    cut = max(newest) - self.max_dt
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
