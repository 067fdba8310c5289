"""Local mapping of the visual pipeline: what a new keyframe adds to the map.

A keyframe takes over the points its frame matched, adds new ones (from depth for RGB-D, by
triangulation with its covisible keyframes with parallax and reprojection checks for
monocular, once a local bundle adjustment has set the keyframe's pose among its
neighbours), fuses duplicate points with its neighbours, culls points seldom found where
predicted, starts a local bundle adjustment of its neighbourhood (pycolmap/Ceres, the
keyframes that also see its points held fixed) and culls neighbours whose points three
others see (ORB-SLAM's LocalMapping).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from slamcli.geometry import inverse
from slamcli.pipelines.visual.atlas import Keyframe
from slamcli.pipelines.visual.bundle import BundleAdjuster
from slamcli.pipelines.visual.frames import Frame
from slamcli.pipelines.visual.inertial import Inertial
from slamcli.pipelines.visual.parts import Part, Shared
from slamcli.pipelines.visual.search import in_view, project_match
from slamcli.vision.matching import TH_LOW, match_ratio, match_ratio_grouped
from slamcli.vision.two_view import triangulate_checked

I64 = NDArray[np.int64]

_CHI2_2D = 5.991
INERTIAL_FIXED = 20
"""Keyframes outside an inertial window that see its points, held in its adjustment (the
ones that see the most)."""
INERTIAL_MAX_GAP_S = 0.5
"""An inertial map's keyframe is culled only if its neighbours in time are this close."""


class LocalMapping(Part):
    """Keyframes into the map: :meth:`start_map` for a new RGB-D map's first keyframe,
    :meth:`insert_keyframe` for the keyframes that follow."""

    def __init__(self, shared: Shared, ba: BundleAdjuster, inertial: Inertial) -> None:
        super().__init__(shared)
        self.ba = ba
        self.inertial = inertial

    def start_map(self, cur: Frame) -> Keyframe | None:
        """The first keyframe of a new RGB-D map, made from ``cur`` at the origin with points
        from its depth; None when the frame has too little depth to start one."""
        has = np.isfinite(cur.depth)
        if np.count_nonzero(has) < 100:
            self.stats.counts["init_too_little_depth"] += 1
            return None
        # A new map has a frame of its own until a merge relates it to the others.
        cur.cam_from_world = np.eye(4)
        kf = self.new_keyframe(cur)
        self._points_from_depth(kf)
        self.atlas.open_map(cur.index)
        return kf

    def insert_keyframe(self, cur: Frame, parent: Keyframe) -> Keyframe:
        """A keyframe made from the tracked frame ``cur``, hung from ``parent`` (the frame's
        reference keyframe), with everything it adds to the map."""
        kf = self.new_keyframe(cur)
        kf.parent = parent.id
        self.inertial.new_keyframe(kf)
        rows = np.flatnonzero(cur.point_ids >= 0)
        for r, pid in zip(rows.tolist(), cur.point_ids[rows].tolist(), strict=True):
            if self.map.alive[pid] and kf.id not in self.map.obs[pid]:
                self.map.observe(kf, r, pid)
        self.map.update_geometry(kf.point_ids[kf.point_ids >= 0])
        if not self.rig.mono:
            self._points_from_depth(kf)
        elif len(self.map.live(kf.map_id)) > 2:
            # A monocular keyframe's pose is adjusted with its neighbours before it makes new
            # points. Facing a wall, one frame's pose trades translation for rotation almost
            # freely (a short step and a turn look alike): tracked alone, it can be off by
            # several steps at an equally small reprojection error. Points triangulated from
            # such a pose's baseline come out far too near, and the map's scale goes with
            # them. The keyframes that share its points pin it down.
            self._local_ba(kf)
        if self.rig.mono or self.rig.stereo:
            # Stereo far points have no depth: they are triangulated from the motion.
            self._triangulate(kf)
        # The previous keyframe's adjustment has had this keyframe's new points to finish in.
        if self.ba.settle(within="mapping"):
            self._repose(kf)
        self._fuse_neighbours(kf)
        self._cull_points(kf)
        self._local_ba(kf)
        self._cull_keyframes(kf)
        return kf

    def new_keyframe(self, cur: Frame) -> Keyframe:
        assert cur.cam_from_world is not None
        kf = Keyframe(
            id=len(self.map.keyframes),
            frame=cur.index,
            stamp_ns=cur.stamp_ns,
            map_id=self.atlas.current,
            cam_from_world=cur.cam_from_world.copy(),
            keypoints=cur.keypoints,
            octaves=cur.octaves,
            descriptors=cur.descriptors,
            depth=cur.depth,
            colors=cur.colors,
            point_ids=np.full(len(cur.keypoints), -1, np.int64),
        )
        self.map.add_keyframe(kf)
        return kf

    def _points_from_depth(self, kf: Keyframe) -> None:
        free = np.flatnonzero((kf.point_ids < 0) & np.isfinite(kf.depth))
        if free.size == 0:
            return
        from slamcli.geometry.camera import unproject

        cam = self.rig.camera
        pc = unproject(cam, kf.keypoints[free], kf.depth[free])
        w = inverse(kf.cam_from_world)
        self.map.add_points(kf, free, pc @ w[:3, :3].T + w[:3, 3])

    def _fuse_neighbours(self, kf: Keyframe) -> None:
        """Project the neighbours' points into the new keyframe: a match to a keypoint without
        a point adds an observation, to one with another point fuses the two."""
        neighbours = [self.map.keyframes[k] for k, _ in self.map.covisible(kf)[:10]]
        if not neighbours:
            return
        ids = np.unique(np.concatenate([nb.point_ids[nb.point_ids >= 0] for nb in neighbours]))
        ids = ids[self.map.alive[ids]]
        ids = np.setdiff1d(ids, kf.point_ids[kf.point_ids >= 0])
        self.fuse_into(kf, ids)

    def fuse_into(self, kf: Keyframe, ids: I64, radius: float = 3.0) -> int:
        """Fuse points ``ids`` into keyframe ``kf`` by projection; returns how many matched."""
        if ids.size == 0:
            return 0
        visible, dist = in_view(self.rig.camera, self.map, kf.cam_from_world, ids)
        ids, dist = ids[visible], dist[visible]
        if ids.size == 0:
            return 0
        octv = self.map.predict_octave(ids, dist)
        pairs = project_match(
            self.rig.camera,
            self.map.sigma,
            kf,
            kf.cam_from_world,
            self.map.pos[ids],
            self.map.desc[ids],
            octv,
            radius,
            ratio=1.0,
            max_distance=TH_LOW,
        )
        # Reprojection check with the keypoint's scale (and, RGB-D, its depth as a stereo
        # disparity, as ORB-SLAM's Fuse).
        cam = self.rig.camera
        p = self.map.pos[ids[pairs[:, 0]]] @ kf.cam_from_world[:3, :3].T + kf.cam_from_world[:3, 3]
        uv = np.stack([cam.fx * p[:, 0] / p[:, 2] + cam.cx, cam.fy * p[:, 1] / p[:, 2] + cam.cy], 1)
        err2 = np.sum((uv - kf.keypoints[pairs[:, 1]]) ** 2, axis=1)
        sig = self.map.sigma[kf.octaves[pairs[:, 1]]]
        z_kp = kf.depth[pairs[:, 1]]
        stereo = np.isfinite(z_kp)
        bf = cam.fx * self.rig.baseline_m
        disp = np.where(stereo, bf / p[:, 2] - bf / np.where(stereo, z_kp, 1.0), 0.0)
        pairs = pairs[err2 + disp**2 <= np.where(stereo, 7.815, _CHI2_2D) * sig**2]
        n = 0
        for row, kp in pairs.tolist():
            pid = int(ids[row])
            if not self.map.alive[pid]:
                continue
            other = int(kf.point_ids[kp])
            if other < 0:
                if kf.id not in self.map.obs[pid]:
                    self.map.observe(kf, kp, pid)
                    n += 1
            elif other != pid and self.map.alive[other]:
                keep, drop = (
                    (pid, other)
                    if len(self.map.obs[pid]) >= len(self.map.obs[other])
                    else (other, pid)
                )
                self.map.replace(drop, keep)
                n += 1
        return n

    def _cull_points(self, kf: Keyframe) -> None:
        """Points made in the last keyframes that are seldom found where predicted, or seen by
        too few keyframes, are removed (ORB-SLAM's recent-point culling)."""
        lo = max(0, self.map.n - 20000)
        ids = np.arange(lo, self.map.n)
        ids = ids[self.map.alive[ids] & (self.map.map_id[ids] == kf.map_id)]
        ids = ids[self.map.first_kf[ids] >= kf.id - 2]
        ratio = self.map.found[ids] / np.maximum(self.map.visible[ids], 1)
        n_obs = np.array([len(self.map.obs[p]) for p in ids.tolist()], dtype=np.int64)
        # An RGB-D point is made from one keyframe's depth; a monocular one from two views.
        th_obs = 2 if self.rig.mono else 1
        age = kf.id - self.map.first_kf[ids]
        bad = (ratio < 0.25) | ((age >= 2) & (n_obs <= th_obs))
        for pid in ids[bad].tolist():
            self.map.cull_point(pid)
        self.stats.counts["points_culled"] += int(np.count_nonzero(bad))

    def _local_ba(self, kf: Keyframe) -> None:
        """Adjust ``kf`` and its covisible neighbours (``local_window``) with the keyframes that
        also see their points held fixed (or, without any, the map's first); in an
        initialised visual-inertial map, :meth:`_inertial_ba` instead."""
        if self.inertial.active(kf.map_id):
            self._inertial_ba(kf)
            return
        window = [kf] + [
            self.map.keyframes[k] for k, _ in self.map.covisible(kf)[: self.config.local_window]
        ]
        window_ids = {k.id for k in window}
        pids = np.unique(np.concatenate([k.point_ids[k.point_ids >= 0] for k in window]))
        pids = pids[self.map.alive[pids]]
        if pids.size == 0:
            return
        fixed_ids: list[int] = []
        for pid in pids.tolist():
            for k in self.map.obs[pid]:
                if k not in window_ids and k not in fixed_ids and not self.map.keyframes[k].culled:
                    fixed_ids.append(k)
        fixed_ids = sorted(fixed_ids)[:40]
        if not fixed_ids and self.map.live(kf.map_id)[0].id in window_ids:
            first = self.map.live(kf.map_id)[0]
            window = [first] + [k for k in window if k.id != first.id]
            fixed = [True] + [False] * (len(window) - 1)
        else:
            fixed = [False] * len(window) + [True] * len(fixed_ids)
            window = window + [self.map.keyframes[k] for k in fixed_ids]
        self.stats.counts["local_ba"] += 1
        if self.rig.mono:
            # A map without depth is adjusted at once: the next keyframe triangulates its new
            # points from these poses, and scale errors left in them would compound.
            self.ba.bundle(window, np.array(fixed), pids, self.config.ba_iterations)
            return
        self.ba.start(window, np.array(fixed), pids, self.config.ba_iterations)

    def _inertial_ba(self, kf: Keyframe) -> None:
        """ORB-SLAM3's local inertial bundle adjustment: the last ``local_window`` keyframes
        in time, joined by IMU terms, the one before them held (pose, velocity, bias), and
        the other keyframes that see their points held."""
        chain = self.inertial.chain(kf.map_id)[-(self.config.local_window + 1) :]
        if len(chain) < 2:
            return
        window = chain[1:]
        pids = np.unique(np.concatenate([k.point_ids[k.point_ids >= 0] for k in window]))
        pids = pids[self.map.alive[pids]]
        if pids.size == 0:
            return
        in_chain = {k.id for k in chain}
        counts: dict[int, int] = {}
        for pid in pids.tolist():
            for k in self.map.obs[pid]:
                if k not in in_chain and not self.map.keyframes[k].culled:
                    counts[k] = counts.get(k, 0) + 1
        fixed_ids = sorted(counts, key=lambda k: (-counts[k], k))[:INERTIAL_FIXED]
        kfs = chain + [self.map.keyframes[k] for k in sorted(fixed_ids)]
        fixed = np.array([False] * len(chain) + [True] * len(fixed_ids))
        terms = self.inertial.terms(chain, held=1)
        self.stats.counts["local_ba"] += 1
        self.stats.counts["local_inertial_ba"] += 1
        if self.rig.mono:
            self.ba.bundle(kfs, fixed, pids, self.config.ba_iterations, terms)
            return
        self.ba.start(kfs, fixed, pids, self.config.ba_iterations, terms)

    def _repose(self, kf: Keyframe) -> None:
        """Refine a new keyframe's pose against the older points it sees, where the adjustment
        just moved them (it was tracked against where they were); the points made from its own
        depth move with it."""
        pids = kf.point_ids
        rows = np.flatnonzero(pids >= 0)
        rows = rows[self.map.alive[pids[rows]]]
        own = rows[self.map.first_kf[pids[rows]] == kf.id]
        older = rows[self.map.first_kf[pids[rows]] != kf.id]
        if older.size < 10:
            return
        est = self.rig.refine(
            kf.cam_from_world,
            kf.keypoints[older],
            self.map.pos[pids[older]],
            self.map.sigma[kf.octaves[older].astype(np.int64)],
            kf.depth[older],
            rounds=2,
        )
        if est is None or est.num_inliers < 10:
            return
        # world -> old camera -> new world: the own points keep their place in the camera.
        move = inverse(est.cam_from_world) @ kf.cam_from_world
        ids = pids[own]
        self.map.pos[ids] = self.map.pos[ids] @ move[:3, :3].T + move[:3, 3]
        kf.cam_from_world = est.cam_from_world

    def _cull_keyframes(self, kf: Keyframe) -> None:
        """A covisible keyframe whose points are 90% seen by three others at the same or a
        finer scale is redundant: it is culled (its pose then follows its parent)."""
        first = self.map.live(kf.map_id)[0].id
        # One point -> row table for all candidates, cleared after each (the map holds far
        # more points than a keyframe sees).
        row_of = np.full(self.map.n, -1, dtype=np.int64)
        for k, _w in self.map.covisible(kf):
            cand = self.map.keyframes[k]
            if cand.id == first or cand.id == kf.id or cand.culled or cand.loop_edges:
                continue
            if self.inertial.active(kf.map_id) and not self._cullable_in_time(cand):
                continue
            rows = np.flatnonzero(cand.point_ids >= 0)
            if not self.rig.mono:
                rows = rows[np.isfinite(cand.depth[rows])]
            if rows.size == 0:
                continue
            # How many other keyframes see each of these points at the same or a finer
            # scale: its observers are the keyframes covisible with it.
            level = cand.octaves[rows].astype(np.int64)
            row_of[cand.point_ids[rows]] = np.arange(rows.size)
            seen = np.zeros(rows.size, dtype=np.int64)
            for k2, _ in self.map.covisible(cand):
                other = self.map.keyframes[k2]
                kps = np.flatnonzero(other.point_ids >= 0)
                r = row_of[other.point_ids[kps]]
                kps, r = kps[r >= 0], r[r >= 0]
                finer = other.octaves[kps] <= level[r] + 1
                seen += np.bincount(r[finer], minlength=rows.size)
            row_of[cand.point_ids[rows]] = -1
            if np.count_nonzero(seen >= 3) > 0.9 * rows.size:
                self._cull(cand)

    def _cullable_in_time(self, cand: Keyframe) -> bool:
        """In an inertial map a keyframe is culled only when its neighbours in time stay
        within ``INERTIAL_MAX_GAP_S`` of each other: the IMU terms that join them
        integrate longer, and grow less certain, as the gap grows (ORB-SLAM3's rule)."""
        chain = self.inertial.chain(cand.map_id)
        ids = [k.id for k in chain]
        if cand.id not in ids:
            return True
        i = ids.index(cand.id)
        if i == 0 or i == len(chain) - 1:
            return False
        return (chain[i + 1].stamp_ns - chain[i - 1].stamp_ns) * 1e-9 <= INERTIAL_MAX_GAP_S

    def _cull(self, cand: Keyframe) -> None:
        nbs = [k for k, _ in self.map.covisible(cand) if k != cand.id]
        parent = cand.parent if cand.parent is not None else (nbs[0] if nbs else None)
        if parent is None:
            return
        # Re-hang children on the parent.
        for other in self.map.keyframes:
            if other.parent == cand.id and not other.culled:
                other.parent = parent
        cand.culled = True
        self.map.version += 1
        cand.parent = parent
        cand.from_parent = cand.cam_from_world @ inverse(self.map.world_pose(parent))
        for kp in np.flatnonzero(cand.point_ids >= 0).tolist():
            self.map.forget(cand, kp)
        self.places.remove(cand.id)
        self.stats.counts["keyframes_culled"] += 1

    # -- maps --------------------------------------------------------------------------------

    def _triangulate(self, kf: Keyframe) -> None:
        """New monocular points: unmatched keypoints of ``kf`` matched to those of its best
        covisible keyframes, checked against the epipolar line, triangulated, and kept when
        the rays have parallax, the point is in front of both cameras and reprojects well."""
        cam = self.rig.camera
        # ORB-SLAM searches 20 neighbours of a monocular keyframe, 10 of a stereo one.
        nn = 20 if self.rig.mono else 10
        neighbours = [self.map.keyframes[k] for k, _ in self.map.covisible(kf)[:nn]]
        c1 = kf.center
        made = 0
        for nb in neighbours:
            free_kf = np.flatnonzero(kf.point_ids < 0)
            free_nb = np.flatnonzero(nb.point_ids < 0)
            if free_kf.size == 0 or free_nb.size == 0:
                break
            nb_depths = self._median_depth(nb)
            if not np.isfinite(nb_depths) or np.linalg.norm(nb.center - c1) / nb_depths < 0.01:
                continue
            pairs = self._pair_free(kf, free_kf, nb, free_nb)
            if len(pairs) == 0:
                continue
            i_nb, i_kf = free_nb[pairs[:, 0]], free_kf[pairs[:, 1]]
            world, ok = triangulate_checked(
                cam,
                kf.cam_from_world,
                nb.cam_from_world,
                kf.keypoints[i_kf],
                nb.keypoints[i_nb],
                self.map.sigma[kf.octaves[i_kf]],
                self.map.sigma[nb.octaves[i_nb]],
            )
            if not np.any(ok):
                continue
            i_kf, i_nb, world = i_kf[ok], i_nb[ok], world[ok]
            pids = self.map.add_points(kf, i_kf, world)
            for kp, pid in zip(i_nb.tolist(), pids.tolist(), strict=True):
                self.map.observe(nb, kp, pid)
            self.map.update_geometry(pids)
            made += int(pids.size)
        self.stats.counts["points_triangulated"] += made

    def _pair_free(self, kf: Keyframe, free_kf: I64, nb: Keyframe, free_nb: I64) -> I64:
        """(K, 2) pairs (row of ``free_nb``, row of ``free_kf``) of keypoints without points
        that look alike: brute force for a monocular map, within the vocabulary's third-level
        nodes for a stereo one (whose keyframes hold more keypoints)."""
        if self.rig.mono:
            return match_ratio(nb.descriptors[free_nb], kf.descriptors[free_kf], 0.6, TH_LOW)
        return match_ratio_grouped(
            nb.descriptors[free_nb],
            self._nodes(nb)[free_nb],
            kf.descriptors[free_kf],
            self._nodes(kf)[free_kf],
            0.8,
            TH_LOW,
        )

    def _nodes(self, kf: Keyframe) -> NDArray[np.int32]:
        """Each keypoint's vocabulary node at depth 3 (kept on the keyframe)."""
        if kf.nodes is None:
            vocabulary = self.places.db.vocabulary
            kf.nodes = vocabulary.nodes(kf.descriptors, min(3, vocabulary.levels))
        return kf.nodes

    def _median_depth(self, kf: Keyframe) -> float:
        pids = kf.point_ids[kf.point_ids >= 0]
        if pids.size == 0:
            return float("nan")
        z = self.map.pos[pids] @ kf.cam_from_world[2, :3] + kf.cam_from_world[2, 3]
        return float(np.median(z))

    def discard_map(self, map_id: int) -> None:
        for k in self.map.keyframes:
            if k.map_id == map_id and not k.culled:
                for kp in np.flatnonzero(k.point_ids >= 0).tolist():
                    self.map.forget(k, kp)
                k.culled = True
                self.map.version += 1
                k.parent = None
