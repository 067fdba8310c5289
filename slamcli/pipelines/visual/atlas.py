"""The atlas of the visual pipeline: every map of a run, the sparse map of keyframes and points
they share, and the record of every tracked frame.

Poses of keyframes are kept as ``cam_from_world`` (4, 4) matrices (what projection needs);
points as world positions. A point records which keyframes observe it and at which keypoint
(``obs[point] = {keyframe id: keypoint index}``), and each keyframe which point each of its
keypoints is (``point_ids``, -1 for none); the two are always changed together, through
:meth:`SparseMap.observe` and :meth:`SparseMap.forget`. Covisibility (how many points two
keyframes share) is derived from them when asked.

Several maps may exist at once (tracking lost and a new map started); each keyframe and point
carries its ``map_id``, and :meth:`Atlas.merge` brings one map into another's frame and
relabels it.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from itertools import chain
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.geometry import inverse
from slamcli.vision.matching import hamming

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


@dataclass
class Keyframe:
    """A keyframe.

    Attributes:
        id: index in :attr:`SparseMap.keyframes`.
        frame: index of the input frame it was made from.
        stamp_ns: its stamp.
        map_id: the map it belongs to.
        cam_from_world: (4, 4) pose.
        keypoints: (N, 2) undistorted pixels.
        octaves: (N,) pyramid levels.
        descriptors: (N, 32) ORB descriptors.
        depth: (N,) metres, NaN where unknown (monocular: all NaN).
        colors: (N, 3) uint8 colour under each keypoint.
        point_ids: (N,) map point of each keypoint, -1 for none.
        bow: the bag-of-words vector (vocabulary dependent), or None.
        nodes: (N,) vocabulary node of each keypoint at a coarse level (for grouped matching),
            or None until needed.
        parent: the keyframe it hangs from in the spanning tree (None for a map's first).
        culled: removed as redundant; its pose then follows ``parent`` by ``from_parent``.
        from_parent: (4, 4) ``cam_from_parentcam`` kept when culled.
        loop_edges: keyframes it closed a loop with.
    """

    id: int
    frame: int
    stamp_ns: int
    map_id: int
    cam_from_world: F64
    keypoints: F64
    octaves: NDArray[np.int16]
    descriptors: NDArray[np.uint8]
    depth: F64
    colors: NDArray[np.uint8]
    point_ids: I64
    bow: Any = None
    nodes: NDArray[np.int32] | None = None
    parent: int | None = None
    culled: bool = False
    from_parent: F64 | None = None
    loop_edges: set[int] = field(default_factory=set)

    @property
    def center(self) -> F64:
        """The camera centre in the world."""
        r = self.cam_from_world[:3, :3]
        return np.asarray(-r.T @ self.cam_from_world[:3, 3], dtype=np.float64)


class SparseMap:
    """Keyframes and points of all maps of one run."""

    def __init__(self, scale: float, levels: int) -> None:
        self.keyframes: list[Keyframe] = []
        self.scale = scale
        self.levels = levels
        self.sigma = scale ** np.arange(levels + 1, dtype=np.float64)
        n = 4096
        self.pos = np.zeros((n, 3))
        self.desc = np.zeros((n, 32), np.uint8)
        self.color = np.zeros((n, 3), np.uint8)
        self.normal = np.zeros((n, 3))
        self.dmax = np.zeros(n)
        self.alive = np.zeros(n, bool)
        self.visible = np.zeros(n, np.int64)
        self.found = np.zeros(n, np.int64)
        self.first_kf = np.zeros(n, np.int64)
        self.ref_kf = np.zeros(n, np.int64)
        self.map_id = np.zeros(n, np.int64)
        self.obs: list[dict[int, int]] = []
        self.n = 0
        # Bumped by every change of observations: covisibility is cached per keyframe until
        # then (frames between keyframes ask for it many times).
        self.version = 0
        self._covisible: dict[int, tuple[int, list[tuple[int, int]]]] = {}

    # -- points ------------------------------------------------------------------------------

    def _grow(self, need: int) -> None:
        cap = self.pos.shape[0]
        if need <= cap:
            return
        new = max(need, cap * 2)
        for name in (
            "pos",
            "desc",
            "color",
            "normal",
            "dmax",
            "alive",
            "visible",
            "found",
            "first_kf",
            "ref_kf",
            "map_id",
        ):
            old = getattr(self, name)
            arr = np.zeros((new, *old.shape[1:]), dtype=old.dtype)
            arr[:cap] = old
            setattr(self, name, arr)

    def add_points(self, kf: Keyframe, kp_idx: I64, world: F64) -> I64:
        """New points at ``world`` (K, 3), observed by ``kf`` at its keypoints ``kp_idx``."""
        self.version += 1
        k = len(kp_idx)
        ids = np.arange(self.n, self.n + k, dtype=np.int64)
        self._grow(self.n + k)
        self.n += k
        self.pos[ids] = world
        self.desc[ids] = kf.descriptors[kp_idx]
        self.color[ids] = kf.colors[kp_idx]
        self.alive[ids] = True
        self.visible[ids] = 1
        self.found[ids] = 1
        self.first_kf[ids] = kf.id
        self.ref_kf[ids] = kf.id
        self.map_id[ids] = kf.map_id
        self.obs.extend({kf.id: kp} for kp in kp_idx.tolist())
        kf.point_ids[kp_idx] = ids
        self.update_geometry(ids)
        return ids

    def observe(self, kf: Keyframe, kp: int, pid: int) -> None:
        """Record that keypoint ``kp`` of ``kf`` is point ``pid``."""
        self.version += 1
        old = int(kf.point_ids[kp])
        if old == pid:
            return
        if old >= 0:
            self.obs[old].pop(kf.id, None)
        prev = self.obs[pid].get(kf.id)
        if prev is not None and prev != kp:
            kf.point_ids[prev] = -1
        kf.point_ids[kp] = pid
        self.obs[pid][kf.id] = kp

    def forget(self, kf: Keyframe, kp: int) -> None:
        """Remove the observation of keypoint ``kp`` of ``kf``."""
        self.version += 1
        pid = int(kf.point_ids[kp])
        if pid < 0:
            return
        kf.point_ids[kp] = -1
        self.obs[pid].pop(kf.id, None)
        if not self.obs[pid]:
            self.alive[pid] = False

    def cull_point(self, pid: int) -> None:
        self.version += 1
        for kf_id, kp in list(self.obs[pid].items()):
            self.keyframes[kf_id].point_ids[kp] = -1
        self.obs[pid].clear()
        self.alive[pid] = False

    def replace(self, pid: int, by: int) -> None:
        """Fuse point ``pid`` into ``by``: its observations move over, it dies."""
        self.version += 1
        if pid == by or not self.alive[pid]:
            return
        for kf_id, kp in list(self.obs[pid].items()):
            kf = self.keyframes[kf_id]
            if kf_id in self.obs[by]:
                kf.point_ids[kp] = -1
            else:
                kf.point_ids[kp] = by
                self.obs[by][kf_id] = kp
        self.visible[by] += self.visible[pid]
        self.found[by] += self.found[pid]
        self.obs[pid].clear()
        self.alive[pid] = False

    def update_geometry(self, ids: I64, descriptors: bool = True) -> None:
        """Mean viewing direction and scale range of points (and, with ``descriptors``, the
        representative descriptor: the observation closest to all others, for points seen at
        least three times)."""
        ids = np.asarray(ids, dtype=np.int64)
        if ids.size == 0:
            return
        pairs = [(i, k, kp) for i, p in enumerate(ids.tolist()) for k, kp in self.obs[p].items()]
        if not pairs:
            return
        table = np.array(pairs, dtype=np.int64)
        row, kf_ids, kps = table[:, 0], table[:, 1], table[:, 2]
        # Centres of the observing keyframes only: a long run has thousands.
        seen_kfs, kf_row = np.unique(kf_ids, return_inverse=True)
        centers = np.stack([self.keyframes[k].center for k in seen_kfs.tolist()])[kf_row]
        d = self.pos[ids[row]] - centers
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        normal = np.zeros((ids.size, 3))
        np.add.at(normal, row, d)
        seen = np.bincount(row, minlength=ids.size) > 0
        norm = np.linalg.norm(normal, axis=1, keepdims=True)
        self.normal[ids[seen]] = (normal / np.maximum(norm, 1e-12))[seen]
        # Scale range from the reference keyframe's observation (or the first one).
        ref = self.ref_kf[ids[row]]
        first = np.r_[True, row[1:] != row[:-1]]
        use = np.where(kf_ids == ref, 0, 1) * 2 + np.where(first, 0, 1)
        order = np.lexsort((use, row))
        pick = order[np.r_[True, row[order][1:] != row[order][:-1]]]
        octave = self._gather("octaves", seen_kfs, kf_row[pick], kps[pick])
        dist = np.linalg.norm(self.pos[ids[row[pick]]] - centers[pick], axis=1)
        self.dmax[ids[row[pick]]] = dist * self.sigma[octave.astype(np.int64)]
        if not descriptors:
            return
        # Representative descriptors, all points with the same number of views at once (the
        # rows of one point are contiguous, in the order of its views).
        descs = self._gather("descriptors", seen_kfs, kf_row, kps)
        views = np.bincount(row, minlength=ids.size)
        start = np.cumsum(views) - views
        for n in np.unique(views[views >= 3]).tolist():
            pts = np.flatnonzero(views == n)
            group = descs[start[pts][:, None] + np.arange(n)]  # (P, n, 32)
            dd = hamming(group[:, :, None, :], group[:, None, :, :])  # (P, n, n)
            best = np.argmin(np.median(dd, axis=2), axis=1)
            self.desc[ids[pts]] = group[np.arange(pts.size), best]

    def _gather(self, attr: str, kf_ids: I64, kf_row: I64, kps: I64) -> NDArray[Any]:
        """``keyframes[kf_ids[kf_row[j]]].<attr>[kps[j]]`` for every j, one keyframe at a
        time."""
        first = getattr(self.keyframes[int(kf_ids[0])], attr)
        out = np.empty((kps.size, *first.shape[1:]), dtype=first.dtype)
        for j, k in enumerate(kf_ids.tolist()):
            rows = np.flatnonzero(kf_row == j)
            if rows.size:
                out[rows] = getattr(self.keyframes[k], attr)[kps[rows]]
        return out

    def predict_octave(self, pid: I64, dist: F64) -> I64:
        ratio = self.dmax[pid] / np.maximum(dist, 1e-9)
        oct_ = np.ceil(np.log(np.maximum(ratio, 1e-9)) / math.log(self.scale))
        return np.clip(oct_, 0, self.levels - 1).astype(np.int64)

    def in_range(self, pid: I64, dist: F64) -> NDArray[np.bool_]:
        dmin = self.dmax[pid] / self.sigma[self.levels - 1]
        return (dist >= 0.8 * dmin) & (dist <= 1.2 * self.dmax[pid])

    # -- keyframes ---------------------------------------------------------------------------

    def add_keyframe(self, kf: Keyframe) -> None:
        self.keyframes.append(kf)

    def live(self, map_id: int | None = None) -> list[Keyframe]:
        return [
            k for k in self.keyframes if not k.culled and (map_id is None or k.map_id == map_id)
        ]

    def covisible(self, kf: Keyframe, min_weight: int = 1) -> list[tuple[int, int]]:
        """(keyframe id, shared points) of the keyframes sharing points with ``kf``, most
        shared first (ties: lower id)."""
        cached = self._covisible.get(kf.id)
        if cached is None or cached[0] != self.version:
            cached = (self.version, self._count_covisible(kf))
            self._covisible[kf.id] = cached
        return [kw for kw in cached[1] if kw[1] >= min_weight]

    def _count_covisible(self, kf: Keyframe) -> list[tuple[int, int]]:
        obs = self.obs
        counts: Counter[int] = Counter(
            chain.from_iterable(obs[p] for p in kf.point_ids[kf.point_ids >= 0].tolist())
        )
        counts.pop(kf.id, None)
        out = [(k, w) for k, w in counts.items() if not self.keyframes[k].culled]
        out.sort(key=lambda kw: (-kw[1], kw[0]))
        return out

    def world_pose(self, kf_id: int) -> F64:
        """``cam_from_world`` of a keyframe, following parents of culled ones."""
        kf = self.keyframes[kf_id]
        chain = []
        while kf.culled and kf.parent is not None:
            assert kf.from_parent is not None
            chain.append(kf.from_parent)
            kf = self.keyframes[kf.parent]
        pose = kf.cam_from_world
        for rel in reversed(chain):
            pose = rel @ pose
        return pose

    def essential_links(
        self, kfs: list[Keyframe], extra: list[tuple[int, int, str]] | None = None
    ) -> list[tuple[int, int, str]]:
        """The essential graph's edges among ``kfs``, as (lower id, higher id, kind): the
        spanning tree, strong covisibility (100 shared points), loops, then ``extra``; each
        pair once, in a fixed order."""
        ids = {k.id for k in kfs}
        links: list[tuple[int, int, str]] = []
        seen: set[tuple[int, int]] = set()

        def add(a: int, b: int, kind: str) -> None:
            key = (min(a, b), max(a, b))
            if a in ids and b in ids and a != b and key not in seen:
                seen.add(key)
                links.append((*key, kind))

        for k in kfs:
            if k.parent is not None:
                add(k.parent, k.id, "tree")
            for nb, _w in self.covisible(k, min_weight=100):
                add(k.id, nb, "covisibility")
            for other in sorted(k.loop_edges):
                add(k.id, other, "loop")
        for a, b, kind in extra or []:
            add(a, b, kind)
        return links


@dataclass
class FrameRecord:
    """What the trajectory needs of a tracked frame: its pose relative to its reference
    keyframe, and the points it matched (for the final re-estimation). One is kept per frame
    for the whole run, so the matches are kept in 32 bits (20 bytes a point, not 40)."""

    stamp_ns: int
    kf: int
    cam_from_kf: F64
    kp: NDArray[np.float32]
    sigma: NDArray[np.float32]
    depth: NDArray[np.float32]
    pids: NDArray[np.int32]
    state: str


@dataclass
class MapRecord:
    """One map of the run: its id, the frame that started it, and the map it was merged into
    (None while it stands on its own)."""

    id: int
    first_frame: int
    merged_into: int | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"id": self.id, "first_frame": self.first_frame, "merged_into": self.merged_into}


class Atlas:
    """Every map of one run: the sparse map they share, the map being tracked (``current``),
    a record per map and per merge, and the record of every tracked frame (``frames``), each
    hung from a keyframe."""

    def __init__(self, scale: float, levels: int) -> None:
        self.map = SparseMap(scale, levels)
        self.current = 0
        self.maps: list[MapRecord] = []
        self.merges: list[dict[str, Any]] = []
        self.frames: list[FrameRecord] = []

    def open_map(self, first_frame: int) -> None:
        """The current map got its first keyframes, made from frame ``first_frame``."""
        self.maps.append(MapRecord(self.current, first_frame))

    def start_new_map(self) -> None:
        """Frames from now on start a map of their own (tracking was lost)."""
        self.current += 1

    def main_map(self) -> int | None:
        """The map that holds the most tracked frames (every map merged into it counted in);
        on a tie the map of the first live keyframe, then the lowest id; None without a live
        keyframe. A map that was lost a few frames after it started does not stand for a run
        that a later map tracked to the end."""
        kfs = self.map.live()
        if not kfs:
            return None
        frames = dict.fromkeys(sorted({k.map_id for k in kfs}), 0)
        for rec in self.frames:
            map_id = self.map.keyframes[rec.kf].map_id
            if map_id in frames:
                frames[map_id] += 1
        first = kfs[0].map_id
        return max(frames, key=lambda m: (frames[m], m == first, -m))

    def merge(self, keep: int, gone: int, keep_from_gone: F64, keyframes: tuple[int, int]) -> None:
        """Bring map ``gone`` into map ``keep``'s frame by the similarity ``keep_from_gone``
        (4, 4; a rigid transform times a scale for monocular maps) and relabel it; the frames
        hanging from its keyframes take its new scale. ``keyframes`` are the two keyframes
        whose recognised place joined the maps, for the record."""
        smap = self.map
        s = self.transform_map(gone, keep_from_gone)
        for k in smap.keyframes:
            if k.map_id == gone:
                k.map_id = keep
        ids = np.flatnonzero(smap.map_id[: smap.n] == gone)
        smap.map_id[ids] = keep
        for m in self.maps:
            if m.id == gone:
                m.merged_into = keep
        if self.current == gone:
            self.current = keep
        self.merges.append(
            {"maps": [keep, gone], "keyframes": list(keyframes), "scale": round(s, 5)}
        )

    def transform_map(self, map_id: int, new_from_old: F64) -> float:
        """Move every keyframe and point of map ``map_id`` by the similarity ``new_from_old``
        (4, 4: a rotation times a scale, and a translation); the frames hanging from its
        keyframes, and its culled keyframes' offsets from their parents, take the new scale.
        Returns the scale."""
        smap, w = self.map, new_from_old
        s = float(np.cbrt(np.linalg.det(w[:3, :3])))
        moved_kfs = {k.id for k in smap.keyframes if k.map_id == map_id}
        for k in smap.keyframes:
            if k.map_id == map_id:
                moved = w @ inverse(k.cam_from_world)
                moved[:3, :3] /= s
                k.cam_from_world = inverse(moved)
                if s != 1.0 and k.from_parent is not None:
                    k.from_parent = k.from_parent.copy()
                    k.from_parent[:3, 3] *= s
        ids = np.flatnonzero(smap.map_id[: smap.n] == map_id)
        smap.pos[ids] = smap.pos[ids] @ w[:3, :3].T + w[:3, 3]
        if s != 1.0:
            # Frames hang from their keyframe in its units, which the similarity rescales.
            for rec in self.frames:
                if rec.kf in moved_kfs:
                    rec.cam_from_kf[:3, 3] *= s
        return s

    def rescale_frames(self, scales: dict[int, float]) -> None:
        """Frames hang from their keyframe in its units: those of the keyframes in ``scales``
        (keyframe id -> factor) change by that factor."""
        for rec in self.frames:
            if rec.kf in scales:
                rec.cam_from_kf[:3, 3] *= scales[rec.kf]
